//! Observability documents from the line statistics and the bridge's own counters: the
//! Prometheus text exposition (format 0.0.4), the JSON summary published on
//! `<prefix>/gateway/<client_id>/stats` and each line's JSON on `…/stats/<line>`.
//!
//! Pure: snapshots in, text or JSON out. The bridge (or a metrics endpoint) owns the timing
//! and the transport. Metric names, labels and JSON keys are a stable interface for
//! dashboards and alerts: add, never rename.

use std::fmt::Write as _;
use std::time::Duration;

use serde_json::{json, Map, Value as Json};

use crate::bus::stats::DeviceStats;
use crate::bus::LineStats;
use crate::history::JournalStats;

/// The history journal's health (`[history]`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct HistoryStats {
    pub journal: JournalStats,
    /// Journaled records still to be replayed while the broker is there.
    pub replay_backlog: u64,
    /// The journal can be written (otherwise the gateway is unhealthy).
    pub writable: bool,
}

/// The bridge's own counters, kept by the bridge and snapshotted for each document.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BridgeStats {
    /// Time since the gateway started.
    pub uptime: Duration,
    /// The MQTT session is up.
    pub mqtt_connected: bool,
    /// Successful (re)connections to the broker, the first one included.
    pub mqtt_connects: u64,
    /// Losses of the broker connection.
    pub mqtt_disconnects: u64,
    /// Messages handed to the MQTT client.
    pub published: u64,
    /// Publishes dropped because the client's queue was full.
    pub publish_failures: u64,
    /// Publishes refused because they were larger than the MQTT packet limit (the plain and
    /// the Sparkplug connection together).
    pub oversized_refused: u64,
    /// Commands waiting for an offline device or their turn on the line.
    pub waiting_commands: u64,
    /// QoS 1 redeliveries of a command recognised and not run again.
    pub redeliveries_ignored: u64,
    /// Commands for devices that are not configured.
    pub unknown_device_commands: u64,
    /// Commands refused unrun because the gateway was overloaded (counted as rejected too).
    pub commands_shed: u64,
    /// Own topics published again after another client overwrote them.
    pub topics_reasserted: u64,
    /// Messages received on `…/set` topics (empty clearing payloads excluded).
    pub commands_received: u64,
    /// Outcomes of commands, by outcome.
    pub commands_applied: u64,
    pub commands_not_applied: u64,
    pub commands_rejected: u64,
    pub commands_failed: u64,
    pub commands_expired: u64,
    pub commands_superseded: u64,
    /// Fields whose raw data was invalid (bad BCD): not published, counted here.
    pub invalid_values: u64,
    /// The history journal, with `[history]`.
    pub history: Option<HistoryStats>,
}

/// One metric family: its name, type and help, then its samples.
struct Family<'a> {
    out: &'a mut String,
    name: String,
}

impl<'a> Family<'a> {
    fn start(out: &'a mut String, name: &str, kind: &str, help: &str) -> Self {
        let _ = writeln!(out, "# HELP {name} {}", escape_help(help));
        let _ = writeln!(out, "# TYPE {name} {kind}");
        Family {
            out,
            name: name.to_string(),
        }
    }

    fn sample(&mut self, labels: &[(&str, &str)], value: f64) {
        let _ = write!(self.out, "{}", self.name);
        if !labels.is_empty() {
            let rendered: Vec<String> = labels
                .iter()
                .map(|(key, value)| format!("{key}=\"{}\"", escape_label(value)))
                .collect();
            let _ = write!(self.out, "{{{}}}", rendered.join(","));
        }
        let _ = writeln!(self.out, " {}", format_value(value));
    }
}

/// Label values escape `\`, `"` and line feeds (exposition format 0.0.4).
pub fn escape_label(value: &str) -> String {
    let mut escaped = String::with_capacity(value.len());
    for c in value.chars() {
        match c {
            '\\' => escaped.push_str("\\\\"),
            '"' => escaped.push_str("\\\""),
            '\n' => escaped.push_str("\\n"),
            other => escaped.push(other),
        }
    }
    escaped
}

/// HELP text escapes `\` and line feeds.
fn escape_help(text: &str) -> String {
    text.replace('\\', "\\\\").replace('\n', "\\n")
}

/// Sample values: integers without a fraction, the special values as the format spells them.
fn format_value(value: f64) -> String {
    if value.is_nan() {
        "NaN".to_string()
    } else if value.is_infinite() {
        if value > 0.0 { "+Inf" } else { "-Inf" }.to_string()
    } else if value.fract() == 0.0 && value.abs() < 1.0e15 {
        format!("{}", value as i64)
    } else {
        format!("{value}")
    }
}

fn flag(on: bool) -> f64 {
    if on {
        1.0
    } else {
        0.0
    }
}

/// A line counter: (metric suffix, help, accessor).
type LineCounter = (&'static str, &'static str, fn(&LineStats) -> u64);

const LINE_COUNTERS: &[LineCounter] = &[
    (
        "transactions_total",
        "Request/answer transactions run on the line.",
        |s| s.transactions,
    ),
    (
        "timeouts_total",
        "Transactions that got no answer in time.",
        |s| s.timeouts,
    ),
    ("crc_errors_total", "Answers dropped for a bad CRC.", |s| {
        s.crc_errors
    }),
    (
        "truncated_total",
        "Answers that stopped short of their length.",
        |s| s.truncated,
    ),
    (
        "unexpected_answers_total",
        "Answers from the wrong address or with the wrong function.",
        |s| s.unexpected_answers,
    ),
    (
        "long_gaps_total",
        "Silences longer than t1.5 inside answers, tolerated up to the byte timeout.",
        |s| s.long_gaps,
    ),
    ("exceptions_total", "Modbus exception answers.", |s| {
        s.exceptions
    }),
    (
        "late_answers_total",
        "Answers that arrived after their transaction had timed out.",
        |s| s.late_answers,
    ),
    (
        "stray_bytes_total",
        "Bytes received outside any transaction and discarded.",
        |s| s.stray_bytes,
    ),
    ("commands_total", "Commands carried out on the line.", |s| {
        s.commands
    }),
    (
        "client_requests_total",
        "Requests from the line's Modbus TCP server's clients.",
        |s| s.client_requests,
    ),
    (
        "cache_hits_total",
        "Client reads answered from a recent poll without the bus.",
        |s| s.cache_hits,
    ),
    (
        "client_refusals_total",
        "Client requests refused before the line (access, unknown unit, malformed).",
        |s| s.client_refusals,
    ),
    (
        "client_busy_total",
        "Client requests answered busy (06): their client pipelined too many, or wrote inside a write interval.",
        |s| s.client_busy,
    ),
    (
        "client_evicted_total",
        "Client connections closed to give their place to a newcomer (no completed request).",
        |s| s.client_evicted,
    ),
];

/// A device counter: (metric suffix, help, accessor).
type DeviceCounter = (&'static str, &'static str, fn(&DeviceStats) -> u64);

/// A latency gauge: (metric name, help, accessor); no sample while never measured.
type LineLatency = (
    &'static str,
    &'static str,
    fn(&LineStats) -> Option<Duration>,
);
type DeviceLatency = (
    &'static str,
    &'static str,
    fn(&DeviceStats) -> Option<Duration>,
);

const DEVICE_COUNTERS: &[DeviceCounter] = &[
    ("transactions_total", "Transactions with the device.", |d| {
        d.transactions
    }),
    (
        "timeouts_total",
        "Transactions with the device that got no answer in time.",
        |d| d.timeouts,
    ),
    (
        "crc_errors_total",
        "Answers from the device dropped for a bad CRC.",
        |d| d.crc_errors,
    ),
    (
        "exceptions_total",
        "Modbus exception answers from the device.",
        |d| d.exceptions,
    ),
    (
        "failures_total",
        "Failed transactions with the device (timeouts, CRC errors and exceptions).",
        device_failures,
    ),
    (
        "split_read_fallbacks_total",
        "Exception 02 answers to a merged block read after which the block is read in parts \
         (expected from some devices; not exceptions, not failures).",
        |d| d.split_read_fallbacks,
    ),
    (
        "unavailable_episodes_total",
        "Times a field turned unavailable (the device reported no value: a NaN, an invalid \
         mark, an unnamed code), once per episode.",
        |d| d.unavailable_episodes,
    ),
];

fn device_failures(device: &DeviceStats) -> u64 {
    device
        .timeouts
        .saturating_add(device.crc_errors)
        .saturating_add(device.exceptions)
}

/// The Prometheus text exposition (version 0.0.4) of the gateway: per line its counters, bus
/// load and command latency; per device whether it is online, its counters and latency; the
/// bridge's MQTT and command counters. Samples of one family are contiguous, as the format
/// requires; a latency never measured has no sample.
pub fn prometheus_text(lines: &[LineStats], bridge: &BridgeStats) -> String {
    let mut out = String::new();

    let mut family = Family::start(
        &mut out,
        "rtu2mqtt_build_info",
        "gauge",
        "Always 1; the version is a label.",
    );
    family.sample(&[("version", env!("CARGO_PKG_VERSION"))], 1.0);

    let mut family = Family::start(
        &mut out,
        "rtu2mqtt_uptime_seconds",
        "gauge",
        "Seconds since the gateway started.",
    );
    family.sample(&[], bridge.uptime.as_secs_f64());

    let mut family = Family::start(
        &mut out,
        "rtu2mqtt_mqtt_connected",
        "gauge",
        "1 while the MQTT session is up.",
    );
    family.sample(&[], flag(bridge.mqtt_connected));

    let mut family = Family::start(
        &mut out,
        "rtu2mqtt_commands_waiting",
        "gauge",
        "Commands waiting for their device or their turn on the line.",
    );
    family.sample(&[], bridge.waiting_commands as f64);

    let bridge_counters: [(&str, &str, u64); 11] = [
        (
            "rtu2mqtt_mqtt_connects_total",
            "Successful connections to the broker, the first one included.",
            bridge.mqtt_connects,
        ),
        (
            "rtu2mqtt_mqtt_disconnects_total",
            "Losses of the broker connection.",
            bridge.mqtt_disconnects,
        ),
        (
            "rtu2mqtt_mqtt_published_total",
            "Messages handed to the MQTT client.",
            bridge.published,
        ),
        (
            "rtu2mqtt_mqtt_publish_failures_total",
            "Publishes dropped because the client's queue was full.",
            bridge.publish_failures,
        ),
        (
            "rtu2mqtt_mqtt_oversized_refused_total",
            "Messages not sent because they were larger than the MQTT packet limit.",
            bridge.oversized_refused,
        ),
        (
            "rtu2mqtt_command_redeliveries_ignored_total",
            "QoS 1 redeliveries of a command recognised and not run again.",
            bridge.redeliveries_ignored,
        ),
        (
            "rtu2mqtt_unknown_device_commands_total",
            "Commands for devices that are not configured.",
            bridge.unknown_device_commands,
        ),
        (
            "rtu2mqtt_commands_shed_total",
            "Commands refused unrun because the gateway was overloaded.",
            bridge.commands_shed,
        ),
        (
            "rtu2mqtt_topics_reasserted_total",
            "Own topics published again after another client overwrote them.",
            bridge.topics_reasserted,
        ),
        (
            "rtu2mqtt_commands_received_total",
            "Commands received on set topics.",
            bridge.commands_received,
        ),
        (
            "rtu2mqtt_invalid_values_total",
            "Field values not published because their raw data was invalid.",
            bridge.invalid_values,
        ),
    ];
    for (name, help, value) in bridge_counters {
        let mut family = Family::start(&mut out, name, "counter", help);
        family.sample(&[], value as f64);
    }
    if let Some(history) = &bridge.history {
        history_families(&mut out, history);
    }

    let mut family = Family::start(
        &mut out,
        "rtu2mqtt_command_outcomes_total",
        "counter",
        "Command outcomes, by outcome.",
    );
    for (outcome, value) in [
        ("applied", bridge.commands_applied),
        ("not_applied", bridge.commands_not_applied),
        ("rejected", bridge.commands_rejected),
        ("failed", bridge.commands_failed),
        ("expired", bridge.commands_expired),
        ("superseded", bridge.commands_superseded),
    ] {
        family.sample(&[("outcome", outcome)], value as f64);
    }

    let mut family = Family::start(
        &mut out,
        "rtu2mqtt_line_port_open",
        "gauge",
        "1 while the line's serial port is open.",
    );
    for line in lines {
        family.sample(&[("line", &line.line)], flag(line.port_open));
    }

    for (suffix, help, counter) in LINE_COUNTERS {
        let name = format!("rtu2mqtt_line_{suffix}");
        let mut family = Family::start(&mut out, &name, "counter", help);
        for line in lines {
            family.sample(&[("line", &line.line)], counter(line) as f64);
        }
    }

    let mut family = Family::start(
        &mut out,
        "rtu2mqtt_line_bus_load_ratio",
        "gauge",
        "Share of wall time the line carried frames and mandatory silences (0 to 1).",
    );
    for line in lines {
        family.sample(&[("line", &line.line)], line.bus_load);
    }

    let latencies: [LineLatency; 2] = [
        (
            "rtu2mqtt_line_command_latency_seconds",
            "Time from the last command's arrival on the line to its outcome.",
            |l| l.last_command_latency,
        ),
        (
            "rtu2mqtt_line_command_latency_worst_seconds",
            "Longest time from a command's arrival on the line to its outcome.",
            |l| l.worst_command_latency,
        ),
    ];
    for (name, help, latency) in latencies {
        let mut family = Family::start(&mut out, name, "gauge", help);
        for line in lines {
            if let Some(latency) = latency(line) {
                family.sample(&[("line", &line.line)], latency.as_secs_f64());
            }
        }
    }

    let devices = || {
        lines
            .iter()
            .flat_map(|line| line.devices.iter().map(move |device| (line, device)))
    };

    let mut family = Family::start(
        &mut out,
        "rtu2mqtt_device_online",
        "gauge",
        "1 while the device answers.",
    );
    for (line, device) in devices() {
        family.sample(
            &[("line", &line.line), ("device", &device.name)],
            flag(device.online),
        );
    }

    for (suffix, help, counter) in DEVICE_COUNTERS {
        let name = format!("rtu2mqtt_device_{suffix}");
        let mut family = Family::start(&mut out, &name, "counter", help);
        for (line, device) in devices() {
            family.sample(
                &[("line", &line.line), ("device", &device.name)],
                counter(device) as f64,
            );
        }
    }

    let mut family = Family::start(
        &mut out,
        "rtu2mqtt_device_consecutive_failures",
        "gauge",
        "Failed polls of the device since its last good answer.",
    );
    for (line, device) in devices() {
        family.sample(
            &[("line", &line.line), ("device", &device.name)],
            f64::from(device.consecutive_failures),
        );
    }

    let device_latencies: [DeviceLatency; 2] = [
        (
            "rtu2mqtt_device_latency_seconds",
            "Duration of the device's last transaction, request to answer.",
            |d| d.last_latency,
        ),
        (
            "rtu2mqtt_device_latency_worst_seconds",
            "Longest transaction with the device, request to answer.",
            |d| d.worst_latency,
        ),
    ];
    for (name, help, latency) in device_latencies {
        let mut family = Family::start(&mut out, name, "gauge", help);
        for (line, device) in devices() {
            if let Some(latency) = latency(device) {
                family.sample(
                    &[("line", &line.line), ("device", &device.name)],
                    latency.as_secs_f64(),
                );
            }
        }
    }

    out
}

fn millis(latency: Option<Duration>) -> Json {
    latency.map_or(Json::Null, |latency| {
        json!((latency.as_secs_f64() * 1000.0 * 1000.0).round() / 1000.0)
    })
}

fn device_json(device: &DeviceStats) -> Json {
    json!({
        "online": device.online,
        "transactions": device.transactions,
        "timeouts": device.timeouts,
        "crc_errors": device.crc_errors,
        "exceptions": device.exceptions,
        "failures": device_failures(device),
        "consecutive_failures": device.consecutive_failures,
        "split_read_fallbacks": device.split_read_fallbacks,
        "unavailable_episodes": device.unavailable_episodes,
        "latency_ms": millis(device.last_latency),
        "worst_latency_ms": millis(device.worst_latency),
    })
}

/// One line's statistics document for `<prefix>/gateway/<client_id>/stats/<line>`: `line`
/// (its name), its counters, `bus_load_percent`, latencies in milliseconds and
/// `devices.<device>`. Latencies never measured are `null`. Its size depends on the line's
/// devices alone (at most 247), never on the number of lines. The gateway's Home Assistant
/// line sensors read these keys (see [`crate::bridge::core::discovery::gateway_config`]).
pub fn line_stats_json(line: &LineStats) -> Json {
    let devices: Map<String, Json> = line
        .devices
        .iter()
        .map(|device| (device.name.clone(), device_json(device)))
        .collect();
    json!({
        "line": line.line,
        "port_open": line.port_open,
        "transactions": line.transactions,
        "timeouts": line.timeouts,
        "crc_errors": line.crc_errors,
        "truncated": line.truncated,
        "unexpected_answers": line.unexpected_answers,
        "exceptions": line.exceptions,
        "late_answers": line.late_answers,
        "stray_bytes": line.stray_bytes,
        "long_gaps": line.long_gaps,
        // Percent with one decimal: what a person reads on a dashboard.
        "bus_load_percent": (line.bus_load * 1000.0).round() / 10.0,
        "commands": line.commands,
        "command_latency_ms": millis(line.last_command_latency),
        "worst_command_latency_ms": millis(line.worst_command_latency),
        "client_requests": line.client_requests,
        "cache_hits": line.cache_hits,
        "client_refusals": line.client_refusals,
        "client_busy": line.client_busy,
        "client_evicted": line.client_evicted,
        "devices": devices,
    })
}

/// The statistics summary for `<prefix>/gateway/<client_id>/stats`: the gateway-wide figures
/// (`uptime_seconds`, `devices_online`, `devices_total`, `lines_total`, `lines_open`, `mqtt`,
/// `commands`, `history`). Each line's figures are in their own document
/// ([`line_stats_json`]), so this one stays the same size at any scale. The gateway's Home
/// Assistant sensors read these keys (see [`crate::bridge::core::discovery::gateway_config`]).
pub fn stats_json(lines: &[LineStats], bridge: &BridgeStats) -> Json {
    let all_devices = lines.iter().flat_map(|line| line.devices.iter());
    let devices_total = all_devices.clone().count();
    let devices_online = all_devices.filter(|device| device.online).count();
    json!({
        "version": env!("CARGO_PKG_VERSION"),
        "uptime_seconds": bridge.uptime.as_secs(),
        "devices_online": devices_online,
        "devices_total": devices_total,
        "lines_total": lines.len(),
        "lines_open": lines.iter().filter(|line| line.port_open).count(),
        "mqtt": {
            "connected": bridge.mqtt_connected,
            "connects": bridge.mqtt_connects,
            "disconnects": bridge.mqtt_disconnects,
            "published": bridge.published,
            "publish_failures": bridge.publish_failures,
            "oversized_refused": bridge.oversized_refused,
        },
        "commands": {
            "waiting": bridge.waiting_commands,
            "received": bridge.commands_received,
            "redeliveries_ignored": bridge.redeliveries_ignored,
            "unknown_device": bridge.unknown_device_commands,
            "shed": bridge.commands_shed,
            "topics_reasserted": bridge.topics_reasserted,
            "applied": bridge.commands_applied,
            "not_applied": bridge.commands_not_applied,
            "rejected": bridge.commands_rejected,
            "failed": bridge.commands_failed,
            "expired": bridge.commands_expired,
            "superseded": bridge.commands_superseded,
        },
        "invalid_values": bridge.invalid_values,
        "history": bridge.history.as_ref().map(history_json),
    })
}

/// The journal's families: gauges of what it holds, counters of what it lost.
fn history_families(out: &mut String, history: &HistoryStats) {
    let journal = &history.journal;
    let families: [(&str, &str, &str, u64); 6] = [
        (
            "rtu2mqtt_history_journal_bytes",
            "gauge",
            "Bytes of the history journal on disk.",
            journal.bytes,
        ),
        (
            "rtu2mqtt_history_records_waiting",
            "gauge",
            "Records in the history journal waiting for their replay.",
            journal.waiting,
        ),
        (
            "rtu2mqtt_history_replay_backlog",
            "gauge",
            "Journaled records still to be replayed while the broker is connected.",
            history.replay_backlog,
        ),
        (
            "rtu2mqtt_history_records_dropped_total",
            "counter",
            "History records dropped by max_size or max_age.",
            journal.dropped,
        ),
        (
            "rtu2mqtt_history_damaged_total",
            "counter",
            "Damaged parts of the history journal found and skipped.",
            journal.damaged,
        ),
        (
            "rtu2mqtt_history_write_failures_total",
            "counter",
            "History records that could not be written to the journal.",
            journal.write_failures,
        ),
    ];
    for (name, kind, help, value) in families {
        let mut family = Family::start(out, name, kind, help);
        family.sample(&[], value as f64);
    }
    let mut family = Family::start(
        out,
        "rtu2mqtt_history_writable",
        "gauge",
        "1 while the history journal can be written; 0 makes the gateway unhealthy.",
    );
    family.sample(&[], if history.writable { 1.0 } else { 0.0 });
}

/// `history` in the statistics document.
fn history_json(history: &HistoryStats) -> Json {
    let journal = &history.journal;
    json!({
        "journal_bytes": journal.bytes,
        "records_waiting": journal.waiting,
        "replay_backlog": history.replay_backlog,
        "records_dropped": journal.dropped,
        "damaged": journal.damaged,
        "write_failures": journal.write_failures,
        "writable": history.writable,
    })
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use super::*;

    #[test]
    fn split_read_fallbacks_are_shown_on_their_own_and_are_no_failures() {
        let mut line = LineStats::new("line-b", &["valve".to_string()], Instant::now());
        if let Some(valve) = line.devices.first_mut() {
            valve.transactions = 9;
            valve.split_read_fallbacks = 2;
            valve.timeouts = 1;
        }
        let lines = [line];
        let bridge = BridgeStats::default();

        let document = line_stats_json(&lines[0]);
        let valve = &document["devices"]["valve"];
        assert_eq!(valve["split_read_fallbacks"], 2, "{valve}");
        assert_eq!(valve["exceptions"], 0, "{valve}");
        assert_eq!(valve["failures"], 1, "only the timeout fails: {valve}");

        let text = prometheus_text(&lines, &bridge);
        assert!(
            text.contains(
                "rtu2mqtt_device_split_read_fallbacks_total{line=\"line-b\",device=\"valve\"} 2"
            ),
            "{text}"
        );
        assert!(
            text.contains("rtu2mqtt_device_failures_total{line=\"line-b\",device=\"valve\"} 1"),
            "{text}"
        );
    }

    #[test]
    fn the_history_journal_is_in_both_documents_only_when_kept() {
        let without = BridgeStats::default();
        assert!(stats_json(&[], &without)["history"].is_null());
        assert!(!prometheus_text(&[], &without).contains("rtu2mqtt_history_"));
        let with = BridgeStats {
            history: Some(HistoryStats {
                journal: JournalStats {
                    bytes: 4096,
                    waiting: 40,
                    dropped: 3,
                    damaged: 1,
                    write_failures: 2,
                },
                replay_backlog: 40,
                writable: false,
            }),
            ..BridgeStats::default()
        };
        assert_eq!(
            stats_json(&[], &with)["history"],
            json!({
                "journal_bytes": 4096,
                "records_waiting": 40,
                "replay_backlog": 40,
                "records_dropped": 3,
                "damaged": 1,
                "write_failures": 2,
                "writable": false,
            })
        );
        let text = prometheus_text(&[], &with);
        for sample in [
            "rtu2mqtt_history_journal_bytes 4096",
            "rtu2mqtt_history_records_waiting 40",
            "rtu2mqtt_history_replay_backlog 40",
            "rtu2mqtt_history_records_dropped_total 3",
            "rtu2mqtt_history_damaged_total 1",
            "rtu2mqtt_history_write_failures_total 2",
            "rtu2mqtt_history_writable 0",
            "# TYPE rtu2mqtt_history_records_dropped_total counter",
            "# TYPE rtu2mqtt_history_journal_bytes gauge",
        ] {
            assert!(
                text.lines().any(|line| line == sample),
                "{sample} missing:\n{text}"
            );
        }
    }
}
