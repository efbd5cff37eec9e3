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
//! `rtu2mqtt health`), [`systemd`] (readiness and watchdog notifications), [`watchdog`] (the
//! thread) and [`supervision`] (readiness after the first connect attempt, then the watchdog
//! started over a running gateway). The settings are the configuration's
//! ([`crate::config::HealthSettings`]); the MQTT loop is seen only through the [`MqttProbe`]
//! the application hands over.

pub(crate) mod assess;
pub(crate) mod status_file;
pub(crate) mod supervision;
pub(crate) mod systemd;
pub(crate) mod watchdog;

pub use crate::config::{HealthSettings, DEFAULT_STATUS_FILE};
pub use assess::{
    assess, judge_status, status_line, Assessment, HistoryStatus, LineStatus, LoopSnapshot,
    MqttStatus, StatusReport,
};
pub use status_file::{check_status_file, wall_clock_ms, write_status_file};
pub use supervision::{first_connect_attempt, supervise, FIRST_CONNECT_WAIT};
pub use systemd::{notify_ready, notify_stopping, systemd_watchdog_period, watchdog_period_from};
pub use watchdog::{ExitFn, MqttProbe, Watchdog, WatchdogHandle, EXIT_STUCK, STUCK_GRACE};

#[cfg(test)]
mod tests;
