//! Supervision of a started gateway: readiness once the first broker connection is made or
//! its wait is over, then the watchdog over the lines, the bridge loop and the journal.

use std::time::Duration;

use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

use super::systemd::notify_ready;
use super::watchdog::{MqttProbe, Watchdog, WatchdogHandle};
use crate::bus::LineStats;
use crate::config::HealthSettings;

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
