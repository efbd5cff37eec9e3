//! The gateway configuration: serde structs ([`schema`], the one declaration of every key),
//! `config` layering (file < `RTU2MQTT__*` environment, [`load`](mod@load)) into one typed [`tree`], read
//! by serde strictly with every problem placed ([`deserialize`]), and complete validation
//! ([`validate`]) that runs every section's checks and names the place of every problem before
//! anything is opened. Each section is
//! checked in its own file: [`mqtt`] (`[mqtt]` and the broker URL), [`gateway`], [`health`],
//! [`lines`] (lines, their ports or URLs and `[lines.serve]`), [`devices`]
//! (`[[lines.devices]]`), [`sparkplug`], [`history`] and [`web`]; [`names`] holds the name rules and
//! the quoting they share, [`files`] the paths and password files a configuration names, [`problem`] what a problem is. [`poll_plan`] computes each line's
//! poll plan and bus load from the wire timing, for validation and `rtu2mqtt check`;
//! [`suggestion`] writes a configuration to copy from what a scan found.
//!
//! What leaves this module is a [`Config`] (declared beside the validation that builds it):
//! the bus's [`LineSpec`](crate::bus::LineSpec)s with their resolved profiles, and the MQTT
//! ([`MqttSettings`], in [`mqtt`]) and gateway ([`GatewayOptions`], in [`gateway`]) settings,
//! all checked.

pub(crate) mod deserialize;
pub(crate) mod devices;
pub(crate) mod files;
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

pub use gateway::GatewayOptions;
pub use health::{HealthSettings, DEFAULT_STATUS_FILE};
pub use history::HistoryConfig;
pub use mqtt::{MqttSettings, TlsSettings};
pub use problem::{Problem, Problems};
pub use schema::keys_of;
pub use schema::SparkplugSettings;
pub use sparkplug::{SparkplugConfig, SparkplugIdentity};
pub use validate::{from_str, load, load_with_env, Config};
pub use web::WebSettings;
