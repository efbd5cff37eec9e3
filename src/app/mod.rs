//! Wiring for the daemon: load and validate the config, start one bus task per line and the
//! MQTT bridge, run until SIGTERM/SIGINT, then stop cleanly.

pub mod check;
pub mod demo;
pub mod logging;

use std::path::Path;
use std::process::ExitCode;

/// `rtu2mqtt run`.
pub fn run(config: &Path) -> anyhow::Result<ExitCode> {
    todo!("bridge helper")
}
