//! The gateway configuration: serde structs ([`schema`], the one declaration of every key),
//! `config` layering (file < `RTU2MQTT__*` environment, [`load`]) into one typed [`tree`], read
//! by serde strictly with every problem placed ([`deserialize`]), and complete validation
//! ([`validate`]) that runs every section's checks and names the place of every problem before
//! anything is opened. Each section is
//! checked in its own file: [`mqtt`] (`[mqtt]` and the broker URL), [`gateway`], [`health`],
//! [`lines`] (lines, their ports or URLs and `[lines.serve]`), [`devices`]
//! (`[[lines.devices]]`), [`sparkplug`] and [`history`]; [`names`] holds the name rules and
//! the quoting they share. [`poll_plan`] computes each line's poll plan and bus load from the wire
//! timing, for validation and `rtu2mqtt check`.
//!
//! What leaves this module is a [`Config`]: the bus's [`LineSpec`]s with their resolved
//! profiles, and the MQTT and gateway settings, all checked.

pub mod deserialize;
pub mod devices;
pub mod gateway;
pub mod health;
pub mod history;
pub mod lines;
pub mod load;
pub mod mqtt;
pub mod names;
pub mod poll_plan;
pub mod schema;
pub mod sparkplug;
pub mod tree;
pub mod validate;

use std::fmt;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::bus::LineSpec;
use rtu2mqtt_profile::contract::Topics;

pub use health::{HealthSettings, DEFAULT_STATUS_FILE};
pub use history::HistoryConfig;
pub use schema::keys_of;
pub use schema::SparkplugSettings;
pub use sparkplug::{SparkplugConfig, SparkplugIdentity};

/// A validated gateway configuration.
#[derive(Debug, Clone)]
pub struct Config {
    pub mqtt: MqttSettings,
    pub gateway: GatewayOptions,
    pub health: HealthSettings,
    pub lines: Vec<LineSpec>,
    /// The Sparkplug B edge node, when `[sparkplug]` is present.
    pub sparkplug: Option<SparkplugConfig>,
    /// The journal and the history stream, when `[history]` is present.
    pub history: Option<HistoryConfig>,
    /// Things that work but deserve attention (a `/dev/ttyUSB0` path, a pty ignoring parity).
    pub warnings: Vec<Problem>,
}

/// How to reach the broker, checked.
#[derive(Debug, Clone, PartialEq)]
pub struct MqttSettings {
    pub host: String,
    pub port: u16,
    /// Present for `mqtts://`.
    pub tls: Option<TlsSettings>,
    pub client_id: String,
    /// Topic prefix (`plant`).
    pub prefix: String,
    pub username: Option<String>,
    /// From the file, the environment or `password_file`.
    pub password: Option<String>,
    pub keep_alive: Duration,
    pub clean_session: bool,
    pub inflight: u16,
    pub discovery: bool,
    pub discovery_prefix: String,
}

impl MqttSettings {
    /// The topics and Home Assistant names of this gateway.
    pub fn topics(&self) -> Topics {
        Topics::new(&self.client_id, &self.prefix).with_discovery_prefix(&self.discovery_prefix)
    }
}

/// TLS files (checked to exist; read when connecting).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsSettings {
    /// The CA bundle the broker's certificate is verified against; None: the system's trust
    /// store.
    pub ca_file: Option<PathBuf>,
    /// Client certificate and key.
    pub client_auth: Option<(PathBuf, PathBuf)>,
}

/// Per-gateway behaviour of the bridge.
#[derive(Debug, Clone, PartialEq)]
pub struct GatewayOptions {
    pub command_ttl: Duration,
    pub json_view: bool,
    pub stats_interval: Duration,
    pub metrics_listen: Option<SocketAddr>,
    pub frame_log: Option<PathBuf>,
    pub allow_raw_writes: bool,
    pub max_payload: usize,
}

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

/// Reads, overrides from the environment and validates the configuration at `path`.
/// A problem in a value set from the environment names its variable, not the file.
pub fn load(path: &Path) -> Result<Config, Problems> {
    load_with_env(path, load::process_environment()?)
}

/// Like [`load`] with an explicit environment (tests).
pub fn load_with_env(
    path: &Path,
    env: std::collections::HashMap<String, String>,
) -> Result<Config, Problems> {
    let overrides = load::env_overrides(&env);
    let loaded = load::load_file_lenient(path, Some(env))?;
    let base = path.parent().unwrap_or_else(|| Path::new("."));
    validate_loaded(loaded, base)
        .map_err(|problems| load::blame_overrides(problems, &overrides, false))
}

/// Parses and validates configuration text (profile paths relative to `base`).
pub fn from_str(text: &str, base: &Path) -> Result<Config, Problems> {
    validate_loaded(load::load_str_lenient(text)?, base)
}

/// Validates what reading found. Problems of the reading stage come first; validation of the
/// rest follows, leaving out problems at a place the reading stage already reported.
fn validate_loaded(loaded: deserialize::Loaded, base: &Path) -> Result<Config, Problems> {
    let Some(raw) = &loaded.raw else {
        return Err(Problems(loaded.problems));
    };
    let validated = validate::validate(raw, base);
    if loaded.problems.is_empty() {
        return validated;
    }
    let mut problems = loaded.problems;
    if let Err(Problems(found)) = validated {
        let reported: Vec<String> = problems.iter().map(|p| p.place.clone()).collect();
        problems.extend(found.into_iter().filter(|problem| {
            !reported
                .iter()
                .any(|place| !place.is_empty() && load::is_within(&problem.place, place))
        }));
    }
    Err(Problems(problems))
}
