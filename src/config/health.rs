//! The `[health]` table: how the watchdog and status file behave (the machinery itself is
//! `crate::health`).

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::problem::Problem;

/// Default place of the status file (systemd `RuntimeDirectory=rtu2mqtt`, a tmpfs in Docker).
pub const DEFAULT_STATUS_FILE: &str = "/run/rtu2mqtt/health";

/// How the health machinery behaves. Deserializable so that the configuration can carry it as
/// a `[health]` table; every key has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct HealthSettings {
    /// Where the status file is written; `None` (an empty string in TOML) writes none.
    #[serde(with = "optional_path")]
    pub status_file: Option<PathBuf>,
    /// How often the status is assessed, written and (when healthy) the systemd watchdog pinged.
    /// Shortened automatically to a third of systemd's `WatchdogSec`.
    #[serde(with = "humantime_serde")]
    pub interval: Duration,
    /// A loop whose heartbeat is older than this is not alive: the status turns unhealthy and
    /// the systemd watchdog is no longer pinged.
    #[serde(with = "humantime_serde")]
    pub stale_after: Duration,
    /// A loop stuck this long ends the process with `crate::health::EXIT_STUCK`. Zero disables
    /// the exit.
    #[serde(with = "humantime_serde")]
    pub stall_limit: Duration,
}

mod optional_path {
    use std::path::PathBuf;

    use serde::{Deserialize, Deserializer, Serializer};

    pub(super) fn serialize<S: Serializer>(
        path: &Option<PathBuf>,
        s: S,
    ) -> Result<S::Ok, S::Error> {
        match path {
            Some(path) => s.serialize_str(&path.to_string_lossy()),
            None => s.serialize_str(""),
        }
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(
        d: D,
    ) -> Result<Option<PathBuf>, D::Error> {
        let text = String::deserialize(d)?;
        Ok((!text.is_empty()).then(|| PathBuf::from(text)))
    }
}

impl Default for HealthSettings {
    fn default() -> Self {
        HealthSettings {
            status_file: Some(PathBuf::from(DEFAULT_STATUS_FILE)),
            interval: Duration::from_secs(5),
            stale_after: Duration::from_secs(15),
            stall_limit: Duration::from_secs(60),
        }
    }
}

/// Checks the table; every problem is named with its place (`health.interval`).
pub(super) fn validate_health(health: &HealthSettings, problems: &mut Vec<Problem>) {
    if health.interval < Duration::from_millis(100) {
        problems.push(Problem::new(
            "health.interval",
            "must be at least 100ms".to_string(),
        ));
    }
    if health.stale_after <= health.interval {
        problems.push(Problem::new(
            "health.stale_after",
            "must be longer than health.interval".to_string(),
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_interval_and_staleness_are_refused_at_their_keys() {
        let mut problems = Vec::new();
        validate_health(&HealthSettings::default(), &mut problems);
        assert_eq!(problems, Vec::new());
        let settings = HealthSettings {
            interval: Duration::from_millis(50),
            stale_after: Duration::from_millis(50),
            ..HealthSettings::default()
        };
        validate_health(&settings, &mut problems);
        let shown: Vec<String> = problems.iter().map(ToString::to_string).collect();
        assert_eq!(
            shown,
            [
                "health.interval: must be at least 100ms",
                "health.stale_after: must be longer than health.interval",
            ]
        );
    }
}
