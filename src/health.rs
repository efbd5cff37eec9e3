//! Process health: systemd readiness and watchdog, the status file behind `rtu2mqtt health`
//! (demo helper).

use std::path::Path;
use std::process::ExitCode;
use std::time::Duration;

pub fn check_status_file(path: &Path, max_age: Duration) -> anyhow::Result<ExitCode> {
    todo!("demo helper")
}
