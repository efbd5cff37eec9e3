//! Wiring for the daemon: load and validate the config, start one bus task per line, the
//! MQTT bridge and (with `[sparkplug]`) the Sparkplug edge node, reload the configuration on
//! SIGHUP ([`reload`]), run until SIGTERM/SIGINT, then stop cleanly. [`run_gateway`] is the
//! library entry point that `run`, the demo and the end-to-end tests share.
//!
//! Its modules: [`check`] (`rtu2mqtt check`: the configuration and its poll plan),
//! [`profiles`] (`rtu2mqtt profiles`), [`reload`], [`signals`] (SIGHUP, SIGTERM, SIGINT) and
//! [`logging`]; the wiring itself is [`gateway`]. The commissioning tools are
//! `crate::commissioning`'s.

pub mod check;
mod gateway;
pub mod logging;
pub mod profiles;
pub mod reload;
pub mod signals;

pub use gateway::{run, run_gateway, Hooks, Running};
