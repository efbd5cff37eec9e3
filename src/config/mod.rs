//! The gateway configuration: serde structs ([`schema`], the one declaration of every key),
//! `config` layering (file < `RTU2MQTT__*` environment, [`load`](mod@load)) into one typed [`tree`], read
//! by serde strictly with every problem placed ([`deserialize`]), and complete validation
//! ([`validate`]) that runs every section's checks and names the place of every problem before
//! anything is opened. Each section is
//! checked in its own file: [`mqtt`] (`[mqtt]` and the broker URL), [`gateway`], [`health`],
//! [`lines`] (lines, their ports or URLs and `[lines.serve]`), [`devices`]
//! (`[[lines.devices]]`), [`sparkplug`], [`history`] and [`web`]; [`names`] holds the name rules and
//! the quoting they share, [`problem`] what a problem is. [`poll_plan`] computes each line's
//! poll plan and bus load from the wire timing, for validation and `rtu2mqtt check`;
//! [`suggestion`] writes a configuration to copy from what a scan found.
//!
//! What leaves this module is a [`Config`] (declared beside the validation that builds it):
//! the bus's [`LineSpec`](crate::bus::LineSpec)s with their resolved profiles, and the MQTT
//! ([`MqttSettings`], in [`mqtt`]) and gateway ([`GatewayOptions`], in [`gateway`]) settings,
//! all checked.

pub(crate) mod deserialize;
pub(crate) mod devices;
pub(crate) mod gateway;
pub(crate) mod health;
pub mod history;
pub(crate) mod lines;
pub mod load;
pub mod mqtt;
pub(crate) mod names;
pub mod poll_plan;
pub(crate) mod problem;
pub mod schema;
pub(crate) mod sparkplug;
pub mod suggestion;
pub(crate) mod tree;
pub(crate) mod validate;
pub mod web;

use std::path::Path;

pub use gateway::GatewayOptions;
pub use health::{HealthSettings, DEFAULT_STATUS_FILE};
pub use history::HistoryConfig;
pub use mqtt::{MqttSettings, TlsSettings};
pub use problem::{Problem, Problems};
pub use schema::keys_of;
pub use schema::SparkplugSettings;
pub use sparkplug::{SparkplugConfig, SparkplugIdentity};
pub use validate::Config;
pub use web::WebSettings;

/// Reads, overrides from the environment and validates the configuration at `path`.
/// A problem in a value set from the environment names its variable, not the file.
pub fn load(path: &Path) -> Result<Config, Problems> {
    load_with_env(path, load::process_environment()?)
}

/// Like [`load()`] with an explicit environment (tests).
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
