//! A problem in a configuration, with its place in the file (`lines[0].devices[1].address`)
//! and, where an override set the value, its environment variable; and every problem found.

use std::fmt;

/// One problem with its place in the file (`lines[0].devices[1].address`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// Empty when the problem is about the whole file.
    pub place: String,
    pub reason: String,
    /// The environment variable that set the value, when the problem lies in an override.
    pub variable: Option<String>,
}

impl Problem {
    pub fn new(place: impl Into<String>, reason: impl Into<String>) -> Self {
        Problem {
            place: place.into(),
            reason: reason.into(),
            variable: None,
        }
    }
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(variable) = &self.variable {
            if self.place.is_empty() || self.place == *variable {
                write!(f, "{variable} (environment): {}", self.reason)
            } else {
                write!(
                    f,
                    "{variable} (environment, {}): {}",
                    self.place, self.reason
                )
            }
        } else if self.place.is_empty() {
            write!(f, "{}", self.reason)
        } else {
            write!(f, "{}: {}", self.place, self.reason)
        }
    }
}

/// Every problem found in a configuration.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problems(pub Vec<Problem>);

impl Problems {
    pub fn one(place: impl Into<String>, reason: impl Into<String>) -> Self {
        Problems(vec![Problem::new(place, reason)])
    }
}

impl fmt::Display for Problems {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let count = self.0.len();
        write!(
            f,
            "{count} problem{} in the configuration:",
            if count == 1 { "" } else { "s" }
        )?;
        for problem in &self.0 {
            write!(f, "\n  - {problem}")?;
        }
        Ok(())
    }
}

impl std::error::Error for Problems {}
