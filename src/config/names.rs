//! Names and values as the configuration's checks speak of them: the `[a-z0-9_-]` names of
//! lines and devices (they become topic levels, so they stay short) and a user's value quoted
//! in a message, cut short so that a huge value never becomes a huge log line.

use super::problem::Problem;
use rtu2mqtt_profile::topic_levels;

/// Longest part of a user's value quoted in a message; longer ones are cut and their length
/// given (a 70,000-character name must not become a 70,000-character log line).
const SHOWN_MAX: usize = 48;

/// `value` quoted for a message, cut to [`SHOWN_MAX`] characters.
pub(crate) fn shown(value: &str) -> String {
    if value.chars().count() <= SHOWN_MAX {
        return format!("{value:?}");
    }
    let head: String = value.chars().take(SHOWN_MAX).collect();
    format!("{head:?}… ({} bytes)", value.len())
}

/// Device, line and client names become topic levels: keep them short.
pub(crate) const MAX_NAME_LEN: usize = topic_levels::MAX_NAME_LEN;

/// `[a-z0-9_-]+`, at most 64 characters.
pub(crate) fn is_valid_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= MAX_NAME_LEN
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-')
}

/// The problem of a line or device `name` at `place` that [`is_valid_name`] refuses.
pub(crate) fn invalid_name(place: &str, name: &str) -> Problem {
    Problem::new(
        format!("{place}.name"),
        format!(
            "{} must match [a-z0-9_-]+ (at most {MAX_NAME_LEN} characters)",
            shown(name)
        ),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names() {
        assert!(is_valid_name("dust_collector"));
        assert!(is_valid_name("line-a"));
        for bad in ["", "Dust", "a b", "a/b", "a+", "ä", &"x".repeat(65)] {
            assert!(!is_valid_name(bad), "{bad:?} accepted");
        }
    }

    #[test]
    fn long_values_are_cut() {
        let long = "x".repeat(70_000);
        let text = shown(&long);
        assert!(text.len() < 100, "{text}");
        assert!(text.ends_with("(70000 bytes)"), "{text}");
        assert_eq!(shown("valve"), "\"valve\"");
    }

    #[test]
    fn an_invalid_name_is_placed_at_the_name_key() {
        let problem = invalid_name("lines[1].devices[0]", "Valve 1");
        assert_eq!(
            problem.to_string(),
            "lines[1].devices[0].name: \"Valve 1\" must match [a-z0-9_-]+ (at most 64 characters)"
        );
    }
}
