//! The pure judgement of the loops' liveness ([`assess`]), of the history journal
//! ([`Assessment::with_history`]) and of a status file's text ([`judge_status`]), and the
//! report they speak. Clocks are passed in; no I/O.

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::bus::LineStats;
use crate::config::HealthSettings;

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
    /// Every loop alive, and the history journal (when kept) writable.
    pub healthy: bool,
    pub mqtt: MqttStatus,
    pub lines: Vec<LineStatus>,
    /// The history journal, with `[history]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub history: Option<HistoryStatus>,
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

/// The history journal's part of the report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HistoryStatus {
    pub writable: bool,
    /// Why it cannot be written, with the place.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub problem: Option<String>,
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
    /// Every loop alive: the systemd watchdog is pinged (a journal that cannot be written
    /// makes the gateway unhealthy, but is no reason to restart it).
    pub loops_alive: bool,
    /// Loops stuck longer than the stall limit: the process must end.
    pub stuck: Vec<String>,
}

impl Assessment {
    /// Adds the history journal's state: one that cannot be written (`problem`, the cause
    /// with its place) makes the gateway unhealthy until it can.
    pub fn with_history(mut self, problem: Option<&str>) -> Assessment {
        if let Some(problem) = problem {
            self.report.healthy = false;
            self.report
                .problems
                .push(format!("history journal cannot be written: {problem}"));
        }
        self.report.history = Some(HistoryStatus {
            writable: problem.is_none(),
            problem: problem.map(str::to_string),
        });
        self
    }
}

pub(crate) fn millis(duration: Duration) -> u64 {
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
            history: None,
            problems,
        },
        loops_alive: healthy,
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
        return Err(report.problems.join("; "));
    }
    if !report.mqtt.connected && report.mqtt.state_age_ms > millis(max_age) {
        return Err(format!(
            "MQTT broker not connected for {}",
            humantime::format_duration(Duration::from_secs(report.mqtt.state_age_ms / 1000))
        ));
    }
    Ok(report)
}

/// The one-line `STATUS=` shown by `systemctl status` (no secrets: names and counts only).
pub fn status_line(report: &StatusReport) -> String {
    let online: usize = report.lines.iter().map(|l| l.devices_online).sum();
    let devices: usize = report.lines.iter().map(|l| l.devices).sum();
    let journal = match &report.history {
        Some(history) if !history.writable => "; history journal not writable",
        _ => "",
    };
    format!(
        "{online}/{devices} devices online on {} line(s); MQTT {}{journal}",
        report.lines.len(),
        if report.mqtt.connected {
            "connected"
        } else {
            "disconnected"
        }
    )
}
