//! `rtu2mqtt simulate`.

use std::path::Path;
use std::process::ExitCode;

pub fn simulate(
    profile: &str,
    port: &Path,
    address: Option<u8>,
    baud: u32,
    parity: &str,
    pace: bool,
) -> anyhow::Result<ExitCode> {
    todo!("sim helper")
}
