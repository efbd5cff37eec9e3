//! Process health: systemd readiness and watchdog pings, the status file behind
//! `rtu2mqtt health`, and the internal watchdog that ends a stuck process.
//!
//! What enters: each line's [`crate::bus::LineStats`] (its `heartbeat` is refreshed
//! on every turn of the line task), the MQTT loop's heartbeat and connection state (watch
//! channels, handed over as an [`MqttProbe`]) and, with `[history]`, why the journal cannot be
//! written while it cannot (a watch channel: the gateway is unhealthy meanwhile, but the
//! systemd watchdog is still pinged, since a restart would not help).
//! What leaves: `READY=1` / `WATCHDOG=1` / `STOPPING=1` / `STATUS=` to systemd, a JSON
//! [`StatusReport`] written atomically every few seconds, and, when a loop has been stuck
//! longer than [`HealthSettings::stall_limit`], a shutdown followed by a non-zero exit
//! ([`EXIT_STUCK`]): plain Docker never restarts an unhealthy container, so the process must
//! end itself for `restart: unless-stopped` to act.
//!
//! The [`Watchdog`] runs on its own OS thread, not on the tokio runtime, so that it still
//! judges (and still stops pinging systemd) when the runtime itself is blocked. The judgement
//! is the pure [`assess()`]; the file check of `rtu2mqtt health` is the pure [`judge_status`].
//!
//! One concern per file: [`mod@assess`] (the pure judgement), [`status_file`] (the file and
//! `rtu2mqtt health`), [`systemd`] (readiness and watchdog notifications) and [`watchdog`]
//! (the thread). The settings are the configuration's ([`crate::config::HealthSettings`]);
//! the MQTT loop is seen only through the [`MqttProbe`] the application hands over.

pub(crate) mod assess;
pub(crate) mod status_file;
pub(crate) mod systemd;
pub(crate) mod watchdog;

use std::time::Duration;

use tokio::sync::watch;

use crate::bus::LineStats;
use tokio_util::sync::CancellationToken;

pub use crate::config::{HealthSettings, DEFAULT_STATUS_FILE};
pub use assess::{
    assess, judge_status, status_line, Assessment, HistoryStatus, LineStatus, LoopSnapshot,
    MqttStatus, StatusReport,
};
pub use status_file::{check_status_file, wall_clock_ms, write_status_file};
pub use systemd::{notify_ready, notify_stopping, systemd_watchdog_period, watchdog_period_from};
pub use watchdog::{ExitFn, MqttProbe, Watchdog, WatchdogHandle, EXIT_STUCK, STUCK_GRACE};

/// How long readiness waits for the first broker connection: an unreachable broker must not
/// hold up the start (the daemon polls and reconnects without it).
pub const FIRST_CONNECT_WAIT: Duration = Duration::from_secs(5);

/// Waits until the bridge is connected or `limit` has passed: the first connect attempt, after
/// which the service counts as started. True when connected.
pub async fn first_connect_attempt(connected: &watch::Receiver<bool>, limit: Duration) -> bool {
    let mut connected = connected.clone();
    let reached = matches!(
        tokio::time::timeout(limit, connected.wait_for(|connected| *connected)).await,
        Ok(Ok(_))
    );
    reached
}

/// Supervision of a started gateway: tells systemd it is ready, then starts the [`Watchdog`]
/// over its lines, its bridge loop and (with `[history]`) its journal. None (logged) if the
/// watchdog thread cannot start.
pub fn supervise(
    settings: HealthSettings,
    lines: watch::Receiver<Vec<watch::Receiver<LineStats>>>,
    mqtt: MqttProbe,
    history_problem: Option<watch::Receiver<Option<String>>>,
    shutdown: CancellationToken,
) -> Option<WatchdogHandle> {
    let connected = *mqtt.connected.borrow();
    let mut watchdog = Watchdog::new(settings, mqtt);
    if let Some(problem) = history_problem {
        watchdog.watch_history(problem);
    }
    let (count, devices) = {
        let lines = lines.borrow();
        let devices: usize = lines.iter().map(|l| l.borrow().devices.len()).sum();
        (lines.len(), devices)
    };
    watchdog.follow_lines(lines);
    let mqtt = if connected {
        "MQTT connected"
    } else {
        "MQTT connecting"
    };
    notify_ready(&format!("{devices} devices on {count} line(s); {mqtt}"));
    match watchdog.spawn(shutdown) {
        Ok(handle) => Some(handle),
        Err(error) => {
            tracing::error!(%error, "cannot start the watchdog thread");
            None
        }
    }
}

#[cfg(test)]
mod tests;
