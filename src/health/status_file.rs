//! The status file: written atomically by the watchdog, read by `rtu2mqtt health`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use super::assess::{judge_status, millis, StatusReport};

/// `rtu2mqtt health`: exit 0 iff the status file is fresh and healthy; one line of why.
pub fn check_status_file(path: &Path, max_age: Duration) -> anyhow::Result<ExitCode> {
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(error) => {
            println!("unhealthy: cannot read {}: {error}", path.display());
            return Ok(ExitCode::FAILURE);
        }
    };
    match judge_status(&text, wall_clock_ms(), max_age) {
        Ok(report) => {
            let online: usize = report.lines.iter().map(|l| l.devices_online).sum();
            let devices: usize = report.lines.iter().map(|l| l.devices).sum();
            println!(
                "healthy: {} line(s) alive, {online}/{devices} devices online, MQTT {}",
                report.lines.len(),
                if report.mqtt.connected {
                    "connected"
                } else {
                    "reconnecting"
                }
            );
            Ok(ExitCode::SUCCESS)
        }
        Err(reason) => {
            println!("unhealthy: {reason}");
            Ok(ExitCode::FAILURE)
        }
    }
}

/// Milliseconds since the Unix epoch (0 if the clock is before 1970).
pub fn wall_clock_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(millis)
        .unwrap_or(0)
}

/// Writes the report so that a reader never sees half a file: a temporary file in the same
/// directory, then a rename over the old one.
pub fn write_status_file(path: &Path, report: &StatusReport) -> std::io::Result<()> {
    let json = serde_json::to_vec_pretty(report).map_err(std::io::Error::other)?;
    let mut temporary = path.as_os_str().to_owned();
    temporary.push(".tmp");
    let temporary = PathBuf::from(temporary);
    std::fs::write(&temporary, json)?;
    std::fs::rename(&temporary, path)
}
