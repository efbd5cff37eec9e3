//! systemd's notification protocol: readiness, stopping, and whether watchdog pings are asked
//! for. No-ops outside systemd.

use std::time::Duration;

/// Tells systemd the service is ready (`Type=notify`): call after the configuration is loaded
/// and the first broker connection was attempted. A no-op outside systemd.
pub fn notify_ready(status: &str) {
    if let Err(error) = sd_notify::notify(
        false,
        &[
            sd_notify::NotifyState::Ready,
            sd_notify::NotifyState::Status(status),
        ],
    ) {
        tracing::warn!(%error, "could not notify systemd of readiness");
    }
}

/// Tells systemd the service is stopping. A no-op outside systemd.
pub fn notify_stopping() {
    let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Stopping]);
}

/// systemd's watchdog period (`WatchdogSec=`), when the service manager asks for pings.
pub fn systemd_watchdog_period() -> Option<Duration> {
    watchdog_period_from(
        std::env::var("WATCHDOG_USEC").ok().as_deref(),
        std::env::var("WATCHDOG_PID").ok().as_deref(),
        std::process::id(),
    )
}

/// `sd_watchdog_enabled(3)`'s rule: `WATCHDOG_USEC` set to a positive number, and
/// `WATCHDOG_PID` either unset or our pid (the variables may have leaked to a child).
/// (sd-notify's own `watchdog_enabled` also requires `WATCHDOG_PID`, which systemd sets but a
/// bare `NOTIFY_SOCKET` harness may not.)
pub fn watchdog_period_from(
    usec: Option<&str>,
    pid: Option<&str>,
    own_pid: u32,
) -> Option<Duration> {
    let usec = usec?.trim().parse::<u64>().ok().filter(|usec| *usec > 0)?;
    match pid {
        Some(pid) if pid.trim().parse::<u32>().ok() != Some(own_pid) => None,
        _ => Some(Duration::from_micros(usec)),
    }
}
