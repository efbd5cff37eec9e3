//! Process health: systemd readiness and watchdog pings, the status file behind
//! `rtu2mqtt health`, and the internal watchdog that ends a stuck process.
//!
//! What enters: each line's [`LineStats`] (its `heartbeat` is refreshed on every turn of the
//! line task) and the MQTT bridge loop's heartbeat and connection state (watch channels).
//! What leaves: `READY=1` / `WATCHDOG=1` / `STOPPING=1` / `STATUS=` to systemd, a JSON
//! [`StatusReport`] written atomically every few seconds, and, when a loop has been stuck
//! longer than [`HealthSettings::stall_limit`], a shutdown followed by a non-zero exit
//! ([`EXIT_STUCK`]): plain Docker never restarts an unhealthy container, so the process must
//! end itself for `restart: unless-stopped` to act.
//!
//! The [`Watchdog`] runs on its own OS thread, not on the tokio runtime, so that it still
//! judges (and still stops pinging systemd) when the runtime itself is blocked. The judgement
//! is the pure [`assess`]; the file check of `rtu2mqtt health` is the pure [`judge_status`].

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use tokio::sync::watch;

use crate::bridge::BridgeHealth;
use crate::bus::{LineHandle, LineStats};
use crate::shutdown::ShutdownTrigger;

/// Exit status of a process ended by its own watchdog (EX_SOFTWARE): `Restart=on-failure` and
/// Docker's `restart: unless-stopped` both restart it.
pub const EXIT_STUCK: i32 = 70;

/// Default place of the status file (systemd `RuntimeDirectory=rtu2mqtt`, a tmpfs in Docker).
pub const DEFAULT_STATUS_FILE: &str = "/run/rtu2mqtt/health";

/// How often the bridge loop promises to turn: it beats every tick; four ticks leave room for
/// a busy machine.
const BRIDGE_MAX_QUIET: Duration = crate::bridge::TICK.saturating_mul(4);

/// How the health machinery behaves. Deserializable so that the configuration can carry it as
/// a `[health]` table; every key has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HealthSettings {
    /// Where the status file is written; `None` (an empty string in TOML) writes none.
    #[serde(with = "optional_path")]
    pub status_file: Option<PathBuf>,
    /// How often the status is assessed, written and (when healthy) the systemd watchdog pinged.
    /// Shortened automatically to a third of systemd's `WatchdogSec`.
    #[serde(with = "humantime_serde")]
    pub interval: Duration,
    /// A loop whose heartbeat is older than this is not alive: the status turns unhealthy and
    /// the systemd watchdog is no longer pinged.
    #[serde(with = "humantime_serde")]
    pub stale_after: Duration,
    /// A loop stuck this long ends the process with [`EXIT_STUCK`]. Zero disables the exit.
    #[serde(with = "humantime_serde")]
    pub stall_limit: Duration,
}

mod optional_path {
    use std::path::PathBuf;

    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(path: &Option<PathBuf>, s: S) -> Result<S::Ok, S::Error> {
        match path {
            Some(path) => s.serialize_str(&path.to_string_lossy()),
            None => s.serialize_str(""),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<PathBuf>, D::Error> {
        let text = String::deserialize(d)?;
        Ok((!text.is_empty()).then(|| PathBuf::from(text)))
    }
}

impl Default for HealthSettings {
    fn default() -> Self {
        HealthSettings {
            status_file: Some(PathBuf::from(DEFAULT_STATUS_FILE)),
            interval: Duration::from_secs(5),
            stale_after: Duration::from_secs(15),
            stall_limit: Duration::from_secs(60),
        }
    }
}

/// How long readiness waits for the first broker connection: an unreachable broker must not
/// hold up the start (the daemon polls and reconnects without it).
pub const FIRST_CONNECT_WAIT: Duration = Duration::from_secs(5);

/// Waits until the bridge is connected or `limit` has passed: the first connect attempt, after
/// which the service counts as started. True when connected.
pub async fn first_connect_attempt(bridge: &BridgeHealth, limit: Duration) -> bool {
    let mut connected = bridge.connected.clone();
    let reached = matches!(
        tokio::time::timeout(limit, connected.wait_for(|connected| *connected)).await,
        Ok(Ok(_))
    );
    reached
}

/// Supervision of a started gateway: tells systemd it is ready, then starts the [`Watchdog`]
/// over its lines and its bridge loop. None (logged) if the watchdog thread cannot start.
pub fn supervise(
    settings: HealthSettings,
    lines: &[LineHandle],
    bridge: &BridgeHealth,
    shutdown: ShutdownTrigger,
) -> Option<WatchdogHandle> {
    let mut watchdog = Watchdog::new(
        settings,
        MqttProbe {
            heartbeat: bridge.heartbeat.clone(),
            connected: bridge.connected.clone(),
            max_quiet: BRIDGE_MAX_QUIET,
        },
    );
    for line in lines {
        watchdog.watch_line(line.stats_rx.clone());
    }
    let devices: usize = lines
        .iter()
        .map(|l| l.stats_rx.borrow().devices.len())
        .sum();
    let mqtt = if *bridge.connected.borrow() {
        "MQTT connected"
    } else {
        "MQTT connecting"
    };
    notify_ready(&format!(
        "{devices} devices on {} line(s); {mqtt}",
        lines.len()
    ));
    match watchdog.spawn(shutdown) {
        Ok(handle) => Some(handle),
        Err(error) => {
            tracing::error!(%error, "cannot start the watchdog thread");
            None
        }
    }
}

/// The MQTT loop's state at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoopSnapshot {
    pub last_beat: Instant,
    pub connected: bool,
    pub connection_changed: Instant,
    pub max_quiet: Duration,
}

/// The status file's content: what `rtu2mqtt health` and an operator read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StatusReport {
    /// Wall-clock time of the assessment, milliseconds since the Unix epoch.
    pub timestamp_ms: u64,
    pub pid: u32,
    /// Every loop alive.
    pub healthy: bool,
    pub mqtt: MqttStatus,
    pub lines: Vec<LineStatus>,
    /// Human-readable reasons when not healthy or degraded.
    pub problems: Vec<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MqttStatus {
    pub alive: bool,
    pub connected: bool,
    pub beat_age_ms: u64,
    /// How long the connection has been in its current state.
    pub state_age_ms: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LineStatus {
    pub name: String,
    pub alive: bool,
    pub beat_age_ms: u64,
    pub port_open: bool,
    pub devices_online: usize,
    pub devices: usize,
    pub transactions: u64,
    pub timeouts: u64,
    pub crc_errors: u64,
}

/// The outcome of one assessment.
#[derive(Debug, Clone, PartialEq)]
pub struct Assessment {
    pub report: StatusReport,
    /// Loops stuck longer than the stall limit: the process must end.
    pub stuck: Vec<String>,
}

fn millis(duration: Duration) -> u64 {
    u64::try_from(duration.as_millis()).unwrap_or(u64::MAX)
}

/// Judges the loops at `now` (pure: the clocks are passed in).
///
/// A line is alive while its heartbeat is younger than `stale_after`; the MQTT loop while its
/// beat is younger than `stale_after` plus its promised `max_quiet`. A loop older than
/// `stall_limit` (plus `max_quiet` for MQTT) is stuck, unless `stall_limit` is zero.
pub fn assess(
    now: Instant,
    wall_ms: u64,
    pid: u32,
    lines: &[LineStats],
    mqtt: &LoopSnapshot,
    settings: &HealthSettings,
) -> Assessment {
    let mut problems = Vec::new();
    let mut stuck = Vec::new();
    let stall_enabled = !settings.stall_limit.is_zero();

    let line_statuses: Vec<LineStatus> = lines
        .iter()
        .map(|stats| {
            let age = now.saturating_duration_since(stats.heartbeat);
            let alive = age <= settings.stale_after;
            if !alive {
                problems.push(format!(
                    "line {} has not turned for {}",
                    stats.line,
                    humantime::format_duration(Duration::from_secs(age.as_secs()))
                ));
            }
            if stall_enabled && age > settings.stall_limit {
                stuck.push(format!("line {}", stats.line));
            }
            if !stats.port_open {
                problems.push(format!("line {}: serial port not open", stats.line));
            }
            LineStatus {
                name: stats.line.clone(),
                alive,
                beat_age_ms: millis(age),
                port_open: stats.port_open,
                devices_online: stats.devices.iter().filter(|d| d.online).count(),
                devices: stats.devices.len(),
                transactions: stats.transactions,
                timeouts: stats.timeouts,
                crc_errors: stats.crc_errors,
            }
        })
        .collect();

    let mqtt_age = now.saturating_duration_since(mqtt.last_beat);
    let mqtt_alive = mqtt_age <= settings.stale_after + mqtt.max_quiet;
    if !mqtt_alive {
        problems.push(format!(
            "MQTT loop has not turned for {}",
            humantime::format_duration(Duration::from_secs(mqtt_age.as_secs()))
        ));
    }
    if stall_enabled && mqtt_age > settings.stall_limit + mqtt.max_quiet {
        stuck.push("MQTT loop".to_string());
    }
    let state_age = now.saturating_duration_since(mqtt.connection_changed);
    if !mqtt.connected {
        problems.push(format!(
            "MQTT broker not connected for {}",
            humantime::format_duration(Duration::from_secs(state_age.as_secs()))
        ));
    }

    let healthy = mqtt_alive && line_statuses.iter().all(|line| line.alive);
    Assessment {
        report: StatusReport {
            timestamp_ms: wall_ms,
            pid,
            healthy,
            mqtt: MqttStatus {
                alive: mqtt_alive,
                connected: mqtt.connected,
                beat_age_ms: millis(mqtt_age),
                state_age_ms: millis(state_age),
            },
            lines: line_statuses,
            problems,
        },
        stuck,
    }
}

/// The verdict of `rtu2mqtt health` on a status file's text (pure: the clock is passed in).
///
/// Healthy means: the report parses, it is at most `max_age` old, every loop is alive, and
/// the broker is connected or was lost less than `max_age` ago (a short broker outage is
/// not the gateway's illness; a long one makes the gateway useless and is reported).
pub fn judge_status(text: &str, now_ms: u64, max_age: Duration) -> Result<StatusReport, String> {
    let report: StatusReport =
        serde_json::from_str(text).map_err(|error| format!("unreadable status: {error}"))?;
    let age_ms = now_ms.saturating_sub(report.timestamp_ms);
    if age_ms > millis(max_age) {
        return Err(format!(
            "status is {} old (limit {}): the daemon is not running or is stuck",
            humantime::format_duration(Duration::from_secs(age_ms / 1000)),
            humantime::format_duration(max_age)
        ));
    }
    if !report.healthy {
        return Err(format!("unhealthy: {}", report.problems.join("; ")));
    }
    if !report.mqtt.connected && report.mqtt.state_age_ms > millis(max_age) {
        return Err(format!(
            "MQTT broker not connected for {}",
            humantime::format_duration(Duration::from_secs(report.mqtt.state_age_ms / 1000))
        ));
    }
    Ok(report)
}

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

/// The watchdog's last step when a loop is stuck (the process's exit, in production).
pub type ExitFn = Box<dyn FnOnce(i32) + Send>;

/// How long a stuck process gets for a clean stop before the watchdog ends it.
pub const STUCK_GRACE: Duration = Duration::from_secs(5);

/// The internal watchdog, before it runs: the loops it watches.
pub struct Watchdog {
    settings: HealthSettings,
    lines: Vec<watch::Receiver<LineStats>>,
    mqtt: MqttProbe,
}

/// Where the watchdog reads the MQTT loop's life.
#[derive(Debug, Clone)]
pub struct MqttProbe {
    /// Refreshed on every turn of the loop.
    pub heartbeat: watch::Receiver<Instant>,
    pub connected: watch::Receiver<bool>,
    /// The loop's promise: it turns at least this often.
    pub max_quiet: Duration,
}

/// A running [`Watchdog`]; [`WatchdogHandle::stop`] ends it and removes the status file.
pub struct WatchdogHandle {
    stop_tx: mpsc::Sender<()>,
    thread: std::thread::JoinHandle<()>,
}

impl Watchdog {
    pub fn new(settings: HealthSettings, mqtt: MqttProbe) -> Self {
        Watchdog {
            settings,
            lines: Vec::new(),
            mqtt,
        }
    }

    /// Watches one more line (its [`crate::bus::LineHandle::stats_rx`]).
    pub fn watch_line(&mut self, stats_rx: watch::Receiver<LineStats>) {
        self.lines.push(stats_rx);
    }

    /// Starts the watchdog thread. When a loop is stuck past the stall limit it fires
    /// `shutdown`, gives the tasks [`STUCK_GRACE`] to stop, then exits the process with
    /// [`EXIT_STUCK`].
    pub fn spawn(self, shutdown: ShutdownTrigger) -> std::io::Result<WatchdogHandle> {
        self.spawn_with_exit(shutdown, Box::new(|code| std::process::exit(code)))
    }

    /// [`Watchdog::spawn`] with the final step given: `exit` receives [`EXIT_STUCK`] (tests
    /// observe it instead of ending the test process).
    pub fn spawn_with_exit(
        self,
        shutdown: ShutdownTrigger,
        exit: ExitFn,
    ) -> std::io::Result<WatchdogHandle> {
        let (stop_tx, stop_rx) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("watchdog".to_string())
            .spawn(move || self.run(stop_rx, shutdown, exit))?;
        Ok(WatchdogHandle { stop_tx, thread })
    }

    fn run(self, stop_rx: mpsc::Receiver<()>, shutdown: ShutdownTrigger, exit: ExitFn) {
        let systemd_period = systemd_watchdog_period();
        let interval = match systemd_period {
            Some(period) => self.settings.interval.min(period / 3),
            None => self.settings.interval,
        }
        .max(Duration::from_millis(100));
        let pid = std::process::id();
        let mut file_warned = false;
        let mut was_healthy = true;
        // The connection state's last change, as seen by this thread (to the interval).
        let mut connected = *self.mqtt.connected.borrow();
        let mut connection_changed = Instant::now();
        loop {
            let now = Instant::now();
            let connected_now = *self.mqtt.connected.borrow();
            if connected_now != connected {
                connected = connected_now;
                connection_changed = now;
            }
            let mqtt = LoopSnapshot {
                last_beat: *self.mqtt.heartbeat.borrow(),
                connected,
                connection_changed,
                max_quiet: self.mqtt.max_quiet,
            };
            let lines: Vec<LineStats> = self.lines.iter().map(|rx| rx.borrow().clone()).collect();
            let assessment = assess(now, wall_clock_ms(), pid, &lines, &mqtt, &self.settings);
            let report = &assessment.report;
            if let Some(path) = &self.settings.status_file {
                match write_status_file(path, report) {
                    Ok(()) => file_warned = false,
                    Err(error) if !file_warned => {
                        file_warned = true;
                        tracing::warn!(path = %path.display(), %error, "cannot write the status file");
                    }
                    Err(_) => {}
                }
            }
            if report.healthy {
                if systemd_period.is_some() {
                    let status = status_line(report);
                    let _ = sd_notify::notify(
                        false,
                        &[
                            sd_notify::NotifyState::Watchdog,
                            sd_notify::NotifyState::Status(&status),
                        ],
                    );
                }
                if !was_healthy {
                    tracing::info!("all loops alive again");
                }
            } else if was_healthy {
                tracing::error!(problems = %report.problems.join("; "), "a loop is not alive: systemd watchdog pings withheld");
            }
            was_healthy = report.healthy;

            if !assessment.stuck.is_empty() {
                tracing::error!(
                    stuck = %assessment.stuck.join(", "),
                    limit = %humantime::format_duration(self.settings.stall_limit),
                    "stuck longer than the stall limit: stopping the process"
                );
                shutdown.fire();
                // The runtime may be the thing that is stuck: give a clean stop a moment, then
                // end regardless so that a supervisor restarts us.
                let _ = stop_rx.recv_timeout(STUCK_GRACE);
                exit(EXIT_STUCK);
                return;
            }

            match stop_rx.recv_timeout(interval) {
                Err(mpsc::RecvTimeoutError::Timeout) => continue,
                Ok(()) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
            }
        }
        if let Some(path) = &self.settings.status_file {
            let _ = std::fs::remove_file(path);
        }
    }
}

impl WatchdogHandle {
    /// Ends the watchdog thread and removes the status file: a stopped daemon is not healthy.
    pub fn stop(self) {
        let _ = self.stop_tx.send(());
        let _ = self.thread.join();
    }
}

/// The one-line `STATUS=` shown by `systemctl status` (no secrets: names and counts only).
pub fn status_line(report: &StatusReport) -> String {
    let online: usize = report.lines.iter().map(|l| l.devices_online).sum();
    let devices: usize = report.lines.iter().map(|l| l.devices).sum();
    format!(
        "{online}/{devices} devices online on {} line(s); MQTT {}",
        report.lines.len(),
        if report.mqtt.connected {
            "connected"
        } else {
            "disconnected"
        }
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> HealthSettings {
        HealthSettings {
            status_file: None,
            interval: Duration::from_secs(5),
            stale_after: Duration::from_secs(15),
            stall_limit: Duration::from_secs(60),
        }
    }

    fn line(name: &str, heartbeat: Instant) -> LineStats {
        let mut stats = LineStats::new(name, &["a".to_string(), "b".to_string()], heartbeat);
        stats.port_open = true;
        stats.devices[0].online = true;
        stats
    }

    fn mqtt(last_beat: Instant, connected: bool) -> LoopSnapshot {
        LoopSnapshot {
            last_beat,
            connected,
            connection_changed: last_beat,
            max_quiet: Duration::from_secs(30),
        }
    }

    #[test]
    fn fresh_loops_are_healthy() {
        let start = Instant::now();
        let now = start + Duration::from_secs(100);
        let lines = [
            line("a", now - Duration::from_secs(1)),
            line("b", now - Duration::from_secs(14)),
        ];
        let result = assess(
            now,
            1,
            2,
            &lines,
            &mqtt(now - Duration::from_secs(40), true),
            &settings(),
        );
        assert!(result.report.healthy, "{:?}", result.report.problems);
        assert!(result.stuck.is_empty());
        assert_eq!(result.report.lines[0].devices_online, 1);
        assert_eq!(result.report.lines[0].devices, 2);
        assert_eq!(result.report.lines[1].beat_age_ms, 14_000);
    }

    #[test]
    fn a_stale_line_is_unhealthy_then_stuck() {
        let start = Instant::now();
        let now = start + Duration::from_secs(200);
        let quiet = assess(
            now,
            1,
            2,
            &[line("a", now - Duration::from_secs(16))],
            &mqtt(now, true),
            &settings(),
        );
        assert!(!quiet.report.healthy);
        assert!(!quiet.report.lines[0].alive);
        assert!(quiet.stuck.is_empty());
        assert!(quiet.report.problems[0].contains("line a"));

        let stuck = assess(
            now,
            1,
            2,
            &[line("a", now - Duration::from_secs(61))],
            &mqtt(now, true),
            &settings(),
        );
        assert_eq!(stuck.stuck, vec!["line a".to_string()]);
    }

    #[test]
    fn the_mqtt_loop_gets_its_keep_alive_as_grace() {
        let start = Instant::now();
        let now = start + Duration::from_secs(500);
        let lines = [line("a", now)];
        let idle = assess(
            now,
            1,
            2,
            &lines,
            &mqtt(now - Duration::from_secs(44), true),
            &settings(),
        );
        assert!(idle.report.healthy);
        let silent = assess(
            now,
            1,
            2,
            &lines,
            &mqtt(now - Duration::from_secs(46), true),
            &settings(),
        );
        assert!(!silent.report.healthy);
        assert!(silent.stuck.is_empty());
        let stuck = assess(
            now,
            1,
            2,
            &lines,
            &mqtt(now - Duration::from_secs(91), true),
            &settings(),
        );
        assert_eq!(stuck.stuck, vec!["MQTT loop".to_string()]);
    }

    #[test]
    fn a_zero_stall_limit_never_ends_the_process() {
        let start = Instant::now();
        let now = start + Duration::from_secs(10_000);
        let mut no_exit = settings();
        no_exit.stall_limit = Duration::ZERO;
        let result = assess(now, 1, 2, &[line("a", start)], &mqtt(start, true), &no_exit);
        assert!(!result.report.healthy);
        assert!(result.stuck.is_empty());
    }

    #[test]
    fn a_closed_port_or_lost_broker_is_reported_but_alive() {
        let now = Instant::now() + Duration::from_secs(100);
        let mut unplugged = line("a", now);
        unplugged.port_open = false;
        let result = assess(now, 1, 2, &[unplugged], &mqtt(now, false), &settings());
        assert!(result.report.healthy);
        assert!(!result.report.mqtt.connected);
        assert_eq!(
            result.report.problems.len(),
            2,
            "{:?}",
            result.report.problems
        );
    }

    fn report_text(timestamp_ms: u64, healthy: bool, connected: bool, state_age_ms: u64) -> String {
        let report = StatusReport {
            timestamp_ms,
            pid: 1,
            healthy,
            mqtt: MqttStatus {
                alive: true,
                connected,
                beat_age_ms: 0,
                state_age_ms,
            },
            lines: vec![],
            problems: if healthy {
                vec![]
            } else {
                vec!["line a has not turned for 20s".to_string()]
            },
        };
        serde_json::to_string(&report).unwrap()
    }

    #[test]
    fn judge_accepts_only_fresh_healthy_reports() {
        let max_age = Duration::from_secs(30);
        let now = 1_000_000;
        assert!(judge_status(&report_text(now - 29_000, true, true, 0), now, max_age).is_ok());
        let old = judge_status(&report_text(now - 31_000, true, true, 0), now, max_age);
        assert!(old.unwrap_err().contains("old"));
        let sick = judge_status(&report_text(now, false, true, 0), now, max_age);
        assert!(sick.unwrap_err().contains("line a"));
        assert!(judge_status(&report_text(now, true, false, 10_000), now, max_age).is_ok());
        let lost = judge_status(&report_text(now, true, false, 31_000), now, max_age);
        assert!(lost.unwrap_err().contains("not connected"));
        assert!(judge_status("{not json", now, max_age).is_err());
        assert!(judge_status("", now, max_age).is_err());
    }

    #[test]
    fn status_file_round_trips_and_health_command_reads_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("health");
        let now = Instant::now();
        let report = assess(
            now,
            wall_clock_ms(),
            7,
            &[line("a", now)],
            &mqtt(now, true),
            &settings(),
        )
        .report;
        write_status_file(&path, &report).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let read: StatusReport = serde_json::from_str(&text).unwrap();
        assert_eq!(read, report);
        let code = check_status_file(&path, Duration::from_secs(30)).unwrap();
        assert_eq!(code, ExitCode::SUCCESS);
        let missing = check_status_file(&dir.path().join("nope"), Duration::from_secs(30));
        assert_eq!(missing.unwrap(), ExitCode::FAILURE);
    }

    #[test]
    fn watchdog_period_follows_sd_watchdog_enabled() {
        let period = Some(Duration::from_secs(30));
        assert_eq!(watchdog_period_from(Some("30000000"), None, 7), period);
        assert_eq!(watchdog_period_from(Some("30000000"), Some("7"), 7), period);
        assert_eq!(watchdog_period_from(Some("30000000"), Some("8"), 7), None);
        assert_eq!(watchdog_period_from(Some("0"), None, 7), None);
        assert_eq!(watchdog_period_from(Some("soon"), None, 7), None);
        assert_eq!(watchdog_period_from(None, Some("7"), 7), None);
    }

    #[tokio::test]
    async fn readiness_waits_for_the_first_connection_but_not_forever() {
        let (_heartbeat_tx, heartbeat) = watch::channel(Instant::now());
        let (connected_tx, connected) = watch::channel(false);
        let bridge = BridgeHealth {
            heartbeat,
            connected,
        };
        assert!(!first_connect_attempt(&bridge, Duration::from_millis(50)).await);
        let waiting = tokio::spawn({
            let bridge = bridge.clone();
            async move { first_connect_attempt(&bridge, Duration::from_secs(600)).await }
        });
        tokio::task::yield_now().await;
        connected_tx.send_replace(true);
        assert!(waiting.await.unwrap());
    }

    #[test]
    fn settings_deserialize_with_defaults() {
        let parsed: HealthSettings = toml::from_str("stall_limit = \"2m\"").unwrap();
        assert_eq!(parsed.stall_limit, Duration::from_secs(120));
        assert_eq!(parsed.status_file, Some(PathBuf::from(DEFAULT_STATUS_FILE)));
        let none: HealthSettings = toml::from_str("status_file = \"\"").unwrap();
        assert_eq!(none.status_file, None);
        assert!(toml::from_str::<HealthSettings>("stall = \"1s\"").is_err());
    }

    #[test]
    fn a_stuck_line_fires_the_shutdown_then_ends_the_process() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("health");
        let settings = HealthSettings {
            status_file: Some(path.clone()),
            interval: Duration::from_millis(100),
            stale_after: Duration::from_millis(200),
            stall_limit: Duration::from_millis(300),
        };
        // The MQTT loop promises an hour of quiet, so only the line can be stuck.
        let (_heartbeat_tx, heartbeat) = watch::channel(Instant::now());
        let (_connected_tx, connected) = watch::channel(true);
        let probe = MqttProbe {
            heartbeat,
            connected,
            max_quiet: Duration::from_secs(3600),
        };
        let (_stats_tx, stats_rx) = watch::channel(line("a", Instant::now()));
        let mut watchdog = Watchdog::new(settings, probe);
        watchdog.watch_line(stats_rx);
        let (trigger, token) = crate::shutdown::channel();
        let (exit_tx, exit_rx) = mpsc::channel();
        let handle = watchdog
            .spawn_with_exit(
                trigger,
                Box::new(move |code| {
                    let _ = exit_tx.send(code);
                }),
            )
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(20);
        while !token.is_fired() {
            assert!(Instant::now() < deadline, "the shutdown was never fired");
            std::thread::sleep(Duration::from_millis(20));
        }
        // A clean stop within the grace period: the process still ends, with EXIT_STUCK.
        handle.stop();
        assert_eq!(
            exit_rx.recv_timeout(Duration::from_secs(10)),
            Ok(EXIT_STUCK)
        );
        let report: StatusReport =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        assert!(!report.healthy, "the last status tells why");
        assert!(
            report.problems[0].contains("line a"),
            "{:?}",
            report.problems
        );
    }

    #[test]
    fn watchdog_writes_then_removes_the_status_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("health");
        let mut health = settings();
        health.status_file = Some(path.clone());
        health.interval = Duration::from_millis(100);
        let (_heartbeat_tx, heartbeat) = watch::channel(Instant::now());
        let (_connected_tx, connected) = watch::channel(true);
        let probe = MqttProbe {
            heartbeat,
            connected,
            max_quiet: Duration::from_secs(1),
        };
        let (_stats_tx, stats_rx) = watch::channel(line("a", Instant::now()));
        let mut watchdog = Watchdog::new(health, probe);
        watchdog.watch_line(stats_rx);
        let (trigger, _token) = crate::shutdown::channel();
        let handle = watchdog.spawn(trigger).unwrap();
        let deadline = Instant::now() + Duration::from_secs(20);
        while !path.exists() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let report = judge_status(&text, wall_clock_ms(), Duration::from_secs(30)).unwrap();
        assert_eq!(report.lines[0].name, "a");
        handle.stop();
        assert!(!path.exists());
    }
}
