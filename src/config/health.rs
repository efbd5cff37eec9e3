//! The `[health]` table: how the watchdog and status file behave (the machinery itself is
//! `crate::health`).

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// Default place of the status file (systemd `RuntimeDirectory=rtu2mqtt`, a tmpfs in Docker).
pub const DEFAULT_STATUS_FILE: &str = "/run/rtu2mqtt/health";

/// How the health machinery behaves. Deserializable so that the configuration can carry it as
/// a `[health]` table; every key has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
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
