//! The `[history]` table: where the journal of measured values lives and how far it may grow
//! (the journal itself is `crate::history`'s). Without the table the gateway keeps no history.

use std::path::PathBuf;
use std::time::Duration;

use serde::Deserialize;

use super::problem::Problem;

/// The table as written.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
pub struct RawHistory {
    /// A directory the gateway owns (the systemd unit's `StateDirectory`).
    pub path: PathBuf,
    /// The journal never grows past this (`"64MiB"`): the oldest records go, counted.
    #[serde(default = "default_max_size")]
    pub max_size: String,
    /// Records older than this go.
    #[serde(default = "default_max_age", with = "humantime_serde")]
    pub max_age: Duration,
}

/// The checked `[history]` table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HistoryConfig {
    pub path: PathBuf,
    /// In bytes.
    pub max_size: u64,
    pub max_age: Duration,
}

/// The smallest journal worth keeping: a few segments of a few records.
pub const MIN_SIZE: u64 = 64 * 1024;

/// Checks the table; every problem is named with its place (`history.max_size`).
pub fn check(raw: &RawHistory) -> Result<HistoryConfig, Vec<Problem>> {
    let mut problems = Vec::new();
    if raw.path.as_os_str().is_empty() {
        // Whether the directory can be used is the journal's to find out, at start and
        // while it runs (`check` says it too): a path that cannot be used makes the
        // gateway unhealthy, never stops it.
        problems.push(Problem::new("history.path", "is required (a directory)"));
    }
    let max_size = match parse_size(&raw.max_size) {
        Some(size) if size >= MIN_SIZE => Some(size),
        Some(_) => {
            problems.push(Problem::new("history.max_size", "must be at least 64KiB"));
            None
        }
        None => {
            problems.push(Problem::new(
                "history.max_size",
                format!(
                    "{:?} is not a size: a number with B, KiB, MiB or GiB (\"64MiB\")",
                    raw.max_size
                ),
            ));
            None
        }
    };
    if raw.max_age < Duration::from_secs(60) {
        problems.push(Problem::new("history.max_age", "must be at least 1m"));
    }
    match max_size {
        Some(max_size) if problems.is_empty() => Ok(HistoryConfig {
            path: raw.path.clone(),
            max_size,
            max_age: raw.max_age,
        }),
        _ => Err(problems),
    }
}

/// `"64MiB"`, `"500KB"`, `"1GiB"`, `"4096"` (bytes) in bytes; None when it is not a size.
///
/// Whole numbers with these units only, never past `u64`. A size crate would take more than
/// the message names: `byte-unit` reads `"64Mb"` as megabits unless told to ignore case.
pub fn parse_size(text: &str) -> Option<u64> {
    let text = text.trim();
    let digits = text
        .find(|c: char| !c.is_ascii_digit())
        .unwrap_or(text.len());
    let number: u64 = text[..digits].parse().ok()?;
    let unit: u64 = match text[digits..].trim() {
        "" | "B" => 1,
        "KiB" => 1 << 10,
        "MiB" => 1 << 20,
        "GiB" => 1 << 30,
        "kB" | "KB" => 1_000,
        "MB" => 1_000_000,
        "GB" => 1_000_000_000,
        _ => return None,
    };
    number.checked_mul(unit)
}

fn default_max_size() -> String {
    "64MiB".to_string()
}
fn default_max_age() -> Duration {
    Duration::from_secs(7 * 24 * 3600)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_read_with_their_units() {
        assert_eq!(parse_size("64MiB"), Some(64 << 20));
        assert_eq!(parse_size("500 KB"), Some(500_000));
        assert_eq!(parse_size("4096"), Some(4096));
        assert_eq!(parse_size("1GiB"), Some(1 << 30));
        assert_eq!(parse_size("64 parsecs"), None);
        assert_eq!(parse_size("MiB"), None);
        assert_eq!(parse_size("99999999999999GiB"), None);
    }

    #[test]
    fn the_table_parses_with_defaults_and_is_checked_with_places() {
        let raw: RawHistory = toml::from_str("path = \"/var/lib/rtu2mqtt/history\"")
            .unwrap_or_else(|error| panic!("{error}"));
        assert_eq!(
            check(&raw),
            Ok(HistoryConfig {
                path: PathBuf::from("/var/lib/rtu2mqtt/history"),
                max_size: 64 << 20,
                max_age: Duration::from_secs(7 * 24 * 3600),
            })
        );
        let raw: RawHistory = toml::from_str("path = \"\"\nmax_size = \"1KiB\"\nmax_age = \"1s\"")
            .unwrap_or_else(|error| panic!("{error}"));
        let shown: Vec<String> = check(&raw)
            .err()
            .unwrap_or_default()
            .iter()
            .map(ToString::to_string)
            .collect();
        assert_eq!(
            shown,
            [
                "history.path: is required (a directory)",
                "history.max_size: must be at least 64KiB",
                "history.max_age: must be at least 1m",
            ]
        );
        let misspelt = "[mqtt]\nurl = \"mqtt://x\"\nclient_id = \"e\"\n\
                        [history]\npath = \"/x\"\nmaxsize = \"1MiB\"";
        let problems = crate::config::load::load_str(misspelt)
            .unwrap_err()
            .to_string();
        assert!(
            problems.contains("history.maxsize: unknown key, did you mean `max_size`?"),
            "{problems}"
        );
    }
}
