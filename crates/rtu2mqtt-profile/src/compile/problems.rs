//! The problems of a profile, each with its place: [`ProfileError`] and [`ProfileErrors`] (what
//! [`compile`](super::compile) returns) and the collector every phase of the compiler adds to.

/// One problem in a profile, with its place (`file: fields[3] (gear).write.address`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{place}: {reason}")]
pub struct ProfileError {
    /// Where: the source (a file path or `built-in NAME`), then the line and column of a TOML
    /// syntax error or the key path of a meaning error (`fields[3] (gear).write.address`).
    pub place: String,
    /// What is wrong there, as a sentence.
    pub reason: String,
}

/// Every problem found in one profile, in the file's order; shown one problem a line.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub struct ProfileErrors(
    /// The problems; never empty when returned as an error.
    pub Vec<ProfileError>,
);

impl std::fmt::Display for ProfileErrors {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let lines: Vec<String> = self.0.iter().map(ToString::to_string).collect();
        f.write_str(&lines.join("\n"))
    }
}

/// Collects problems with their places, and warnings: what loads but is likely a mistake.
pub(super) struct Problems<'a> {
    source: &'a str,
    list: Vec<ProfileError>,
    warnings: Vec<ProfileError>,
}

impl<'a> Problems<'a> {
    /// No problems yet; `source` names the file (or built-in) in every place.
    pub(super) fn new(source: &'a str) -> Self {
        Self {
            source,
            list: Vec::new(),
            warnings: Vec::new(),
        }
    }

    /// How many problems are collected so far: a phase compares it before and after a check.
    pub(super) fn count(&self) -> usize {
        self.list.len()
    }

    pub(super) fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// The problems, or `Ok(value)` when there are none.
    pub(super) fn into_result<T>(self, value: T) -> Result<T, ProfileErrors> {
        if self.list.is_empty() {
            Ok(value)
        } else {
            Err(ProfileErrors(self.list))
        }
    }

    /// Adds a warning: the profile loads, and the warning is shown wherever it is loaded.
    pub(super) fn warn(&mut self, place: impl std::fmt::Display, reason: impl Into<String>) {
        self.warnings.push(ProfileError {
            place: format!("{}: {place}", self.source),
            reason: reason.into(),
        });
    }

    /// The warnings collected so far, taken out.
    pub(super) fn take_warnings(&mut self) -> Vec<ProfileError> {
        std::mem::take(&mut self.warnings)
    }

    pub(super) fn add(&mut self, place: impl std::fmt::Display, reason: impl Into<String>) {
        self.list.push(ProfileError {
            place: format!("{}: {place}", self.source),
            reason: reason.into(),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_problem_carries_the_source_and_the_place() {
        let mut problems = Problems::new("meter.toml");
        assert!(problems.is_empty());
        problems.add("fields[2] (gear).write", "no write frame named `x`");
        assert_eq!(problems.count(), 1);
        let errors = problems.into_result(()).unwrap_err();
        assert_eq!(
            errors.0,
            vec![ProfileError {
                place: "meter.toml: fields[2] (gear).write".into(),
                reason: "no write frame named `x`".into(),
            }]
        );
        assert_eq!(
            errors.to_string(),
            "meter.toml: fields[2] (gear).write: no write frame named `x`"
        );
    }

    #[test]
    fn every_problem_is_one_line_in_order() {
        let mut problems = Problems::new("p");
        problems.add("a", "first");
        problems.add("b", "second");
        let errors = problems.into_result(()).unwrap_err();
        assert_eq!(errors.to_string(), "p: a: first\np: b: second");
    }

    #[test]
    fn no_problems_is_the_value() {
        assert_eq!(Problems::new("p").into_result(7), Ok(7));
    }
}
