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

impl Problems {
    /// Each problem as one line: a reason of several lines (a profile's every problem, each
    /// with its place in the profile) is that many problems at the same place.
    pub fn lines(&self) -> Vec<String> {
        self.0
            .iter()
            .flat_map(|problem| {
                problem
                    .reason
                    .lines()
                    .filter(|line| !line.trim().is_empty())
                    .map(|line| {
                        Problem {
                            reason: line.trim().to_string(),
                            ..problem.clone()
                        }
                        .to_string()
                    })
                    .collect::<Vec<_>>()
            })
            .collect()
    }
}

impl fmt::Display for Problems {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let lines = self.lines();
        let count = lines.len();
        write!(
            f,
            "{count} problem{} in the configuration:",
            if count == 1 { "" } else { "s" }
        )?;
        for line in &lines {
            write!(f, "\n  - {line}")?;
        }
        Ok(())
    }
}

impl std::error::Error for Problems {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reason_of_several_lines_counts_and_shows_as_that_many_problems() {
        let problems = Problems(vec![
            Problem::new(
                "lines[0].devices[0].profile",
                "meter.toml: fields[0].codec: unknown type\nmeter.toml: fields[3].block: no block \"x\"\n",
            ),
            Problem::new("mqtt.url", "missing"),
        ]);
        assert_eq!(
            problems.to_string(),
            "3 problems in the configuration:\n\
             \u{20}\u{20}- lines[0].devices[0].profile: meter.toml: fields[0].codec: unknown type\n\
             \u{20}\u{20}- lines[0].devices[0].profile: meter.toml: fields[3].block: no block \"x\"\n\
             \u{20}\u{20}- mqtt.url: missing"
        );
    }
}
