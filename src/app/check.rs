//! `rtu2mqtt check`: validates config and profiles and prints each line's poll plan.

use std::path::Path;
use std::process::ExitCode;

pub fn check(config: &Path) -> anyhow::Result<ExitCode> {
    todo!("bridge helper")
}
