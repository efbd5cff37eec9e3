//! The gateway statistics document on `<prefix>/gateway/<client_id>/stats`: per line the
//! counters of [`LineStats`] (transactions, timeouts, CRC errors, exceptions, late answers, bus
//! load, command latency, per device), plus the bridge's own counters. Pure.

use std::time::Duration;

use serde::Serialize;
use serde_json::{json, Value as Json};

use crate::bus::LineStats;

/// What the bridge counts itself.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct BridgeCounters {
    pub connects: u64,
    pub disconnects: u64,
    pub published: u64,
    /// Publishes that could not be queued (the request queue was full).
    pub publish_failures: u64,
    pub commands_received: u64,
    pub commands_applied: u64,
    pub commands_not_applied: u64,
    pub commands_rejected: u64,
    pub commands_failed: u64,
    pub commands_expired: u64,
    /// QoS 1 redeliveries recognised and not run again.
    pub redeliveries_ignored: u64,
    /// Commands for devices that are not configured (dropped, logged).
    pub unknown_device_commands: u64,
}

fn millis(duration: Option<Duration>) -> Json {
    match duration {
        Some(duration) => json!((duration.as_secs_f64() * 1000.0 * 10.0).round() / 10.0),
        None => Json::Null,
    }
}

/// One line's statistics as JSON.
pub fn line_json(stats: &LineStats) -> Json {
    let devices: Vec<Json> = stats
        .devices
        .iter()
        .map(|device| {
            json!({
                "name": device.name,
                "online": device.online,
                "transactions": device.transactions,
                "timeouts": device.timeouts,
                "crc_errors": device.crc_errors,
                "exceptions": device.exceptions,
                "consecutive_failures": device.consecutive_failures,
                "last_latency_ms": millis(device.last_latency),
                "worst_latency_ms": millis(device.worst_latency),
            })
        })
        .collect();
    json!({
        "name": stats.line,
        "port_open": stats.port_open,
        "transactions": stats.transactions,
        "timeouts": stats.timeouts,
        "crc_errors": stats.crc_errors,
        "truncated": stats.truncated,
        "unexpected_answers": stats.unexpected_answers,
        "exceptions": stats.exceptions,
        "late_answers": stats.late_answers,
        "stray_bytes": stats.stray_bytes,
        "bus_load": (stats.bus_load * 1000.0).round() / 1000.0,
        "commands": stats.commands,
        "last_command_latency_ms": millis(stats.last_command_latency),
        "worst_command_latency_ms": millis(stats.worst_command_latency),
        "devices": devices,
    })
}

/// The whole statistics document.
pub fn gateway_stats_json(
    client_id: &str,
    uptime: Duration,
    connected: bool,
    counters: &BridgeCounters,
    waiting_commands: usize,
    lines: &[LineStats],
) -> Json {
    json!({
        "client_id": client_id,
        "version": env!("CARGO_PKG_VERSION"),
        "uptime_s": uptime.as_secs(),
        "mqtt": {
            "connected": connected,
            "counters": counters,
            "waiting_commands": waiting_commands,
        },
        "lines": lines.iter().map(line_json).collect::<Vec<_>>(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn carries_line_and_device_counters() {
        let mut stats = LineStats::new("line-a", &["dust".to_string()], std::time::Instant::now());
        stats.transactions = 42;
        stats.crc_errors = 2;
        stats.bus_load = 0.12345;
        stats.last_command_latency = Some(Duration::from_micros(12_340));
        stats.devices[0].timeouts = 3;
        let counters = BridgeCounters {
            commands_rejected: 4,
            ..BridgeCounters::default()
        };
        let doc = gateway_stats_json(
            "edge1",
            Duration::from_secs(9),
            true,
            &counters,
            1,
            &[stats],
        );
        assert_eq!(doc["lines"][0]["transactions"], 42);
        assert_eq!(doc["lines"][0]["crc_errors"], 2);
        assert_eq!(doc["lines"][0]["bus_load"], 0.123);
        assert_eq!(doc["lines"][0]["last_command_latency_ms"], 12.3);
        assert_eq!(doc["lines"][0]["devices"][0]["timeouts"], 3);
        assert_eq!(doc["mqtt"]["counters"]["commands_rejected"], 4);
        assert_eq!(doc["mqtt"]["waiting_commands"], 1);
        assert_eq!(doc["uptime_s"], 9);
    }
}
