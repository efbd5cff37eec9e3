//! The Prometheus text exposition (format 0.0.4) of the line statistics and the bridge's own
//! counters, served by [`super::prometheus`]. (The same figures as JSON on
//! `<prefix>/gateway/<client_id>/stats` are [`super::stats::gateway_stats_json`].)
//!
//! Pure: snapshots in, text out. Metric names and labels are a stable interface for dashboards
//! and alerts: add, never rename.

use std::fmt::Write as _;
use std::time::Duration;

use super::stats::BridgeCounters;
use crate::bus::stats::DeviceStats;
use crate::bus::LineStats;

/// What the exposition needs from the bridge besides the lines' statistics.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BridgeSnapshot {
    /// Time since the gateway started.
    pub uptime: Duration,
    /// The MQTT session is up.
    pub mqtt_connected: bool,
    /// Commands waiting for an offline device or their turn on the line.
    pub waiting_commands: usize,
    pub counters: BridgeCounters,
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
pub fn prometheus_text(lines: &[LineStats], bridge: &BridgeSnapshot) -> String {
    let mut out = String::new();
    let counters = &bridge.counters;

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

    let bridge_counters: [(&str, &str, u64); 8] = [
        (
            "rtu2mqtt_mqtt_connects_total",
            "Successful connections to the broker, the first one included.",
            counters.connects,
        ),
        (
            "rtu2mqtt_mqtt_disconnects_total",
            "Losses of the broker connection.",
            counters.disconnects,
        ),
        (
            "rtu2mqtt_mqtt_published_total",
            "Messages handed to the MQTT client.",
            counters.published,
        ),
        (
            "rtu2mqtt_mqtt_publish_failures_total",
            "Publishes dropped because the client's queue was full.",
            counters.publish_failures,
        ),
        (
            "rtu2mqtt_commands_received_total",
            "Commands received on set topics for configured devices.",
            counters.commands_received,
        ),
        (
            "rtu2mqtt_command_redeliveries_ignored_total",
            "QoS 1 redeliveries of a command recognised and not run again.",
            counters.redeliveries_ignored,
        ),
        (
            "rtu2mqtt_unknown_device_commands_total",
            "Commands for devices that are not configured.",
            counters.unknown_device_commands,
        ),
        (
            "rtu2mqtt_commands_finished_total",
            "Commands with an outcome, all outcomes together.",
            counters
                .commands_applied
                .saturating_add(counters.commands_not_applied)
                .saturating_add(counters.commands_rejected)
                .saturating_add(counters.commands_failed)
                .saturating_add(counters.commands_expired),
        ),
    ];
    for (name, help, value) in bridge_counters {
        let mut family = Family::start(&mut out, name, "counter", help);
        family.sample(&[], value as f64);
    }

    let mut family = Family::start(
        &mut out,
        "rtu2mqtt_command_outcomes_total",
        "counter",
        "Command outcomes, by outcome.",
    );
    for (outcome, value) in [
        ("applied", counters.commands_applied),
        ("not_applied", counters.commands_not_applied),
        ("rejected", counters.commands_rejected),
        ("failed", counters.commands_failed),
        ("expired", counters.commands_expired),
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
