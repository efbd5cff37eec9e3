//! The configuration file as written (serde): every table denies unknown keys, durations are
//! humantime strings (`"300ms"`), addresses plain integers (TOML accepts `0x81`). Nothing here
//! is checked beyond its type; `validate` turns it into the gateway's settings.

use std::path::PathBuf;
use std::time::Duration;

use serde::Deserialize;

use super::health::HealthSettings;
use super::sparkplug::SparkplugSettings;
use crate::rtu::timing::Parity;

/// The whole file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    pub mqtt: RawMqtt,
    #[serde(default)]
    pub gateway: RawGateway,
    /// Watchdog and status file (see `crate::health`).
    #[serde(default)]
    pub health: HealthSettings,
    #[serde(default)]
    pub lines: Vec<RawLine>,
    /// The Sparkplug B edge node (off when absent).
    #[serde(default)]
    pub sparkplug: Option<SparkplugSettings>,
}

/// `[mqtt]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawMqtt {
    /// `mqtt://host:port` or `mqtts://host:port`.
    pub url: String,
    /// Unique per gateway; also the gateway's id in topics.
    pub client_id: String,
    #[serde(default = "default_prefix")]
    pub prefix: String,
    pub username: Option<String>,
    pub password: Option<String>,
    /// Read at start; must not be readable by others.
    pub password_file: Option<PathBuf>,
    pub ca_file: Option<PathBuf>,
    pub cert_file: Option<PathBuf>,
    pub key_file: Option<PathBuf>,
    #[serde(default = "default_keep_alive", with = "humantime_serde")]
    pub keep_alive: Duration,
    /// false: the broker keeps our subscription and queues QoS 1 commands while we are away.
    #[serde(default)]
    pub clean_session: bool,
    #[serde(default = "default_inflight")]
    pub inflight: u16,
    #[serde(default = "default_true")]
    pub discovery: bool,
    #[serde(default = "default_discovery_prefix")]
    pub discovery_prefix: String,
}

/// `[gateway]`: behaviour of the bridge.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawGateway {
    /// How long a command for an offline device waits before it expires.
    #[serde(default = "default_command_ttl", with = "humantime_serde")]
    pub command_ttl: Duration,
    /// Also publish every device's state as one JSON object on `<prefix>/<device>`.
    #[serde(default)]
    pub json_view: bool,
    #[serde(default = "default_stats_interval", with = "humantime_serde")]
    pub stats_interval: Duration,
    /// `127.0.0.1:9184`: serve Prometheus `/metrics` there (off when absent).
    pub metrics_listen: Option<String>,
    /// Record every frame with its timestamp to this file (off when absent).
    pub frame_log: Option<PathBuf>,
    /// Accept raw register writes over MQTT (off: only profile fields can be written).
    #[serde(default)]
    pub allow_raw_writes: bool,
    /// Largest accepted command payload in bytes.
    #[serde(default = "default_max_payload")]
    pub max_payload: usize,
}

impl Default for RawGateway {
    fn default() -> Self {
        RawGateway {
            command_ttl: default_command_ttl(),
            json_view: false,
            stats_interval: default_stats_interval(),
            metrics_listen: None,
            frame_log: None,
            allow_raw_writes: false,
            max_payload: default_max_payload(),
        }
    }
}

/// `[[lines]]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawLine {
    pub name: String,
    /// A serial port; exactly one of `port` and `url` is set.
    pub port: Option<String>,
    /// `tcp://host:port` (serial device server) or `modbus-tcp://host:port` (gateway).
    pub url: Option<String>,
    /// TCP lines: added to the default response timeout. Default 200 ms.
    #[serde(default, with = "humantime_serde")]
    pub network_allowance: Option<Duration>,
    /// TCP lines: longest wait for the connection. Default 3 s.
    #[serde(default, with = "humantime_serde")]
    pub connect_timeout: Option<Duration>,
    /// TCP lines: idle time before keepalive probes. Default 10 s.
    #[serde(default, with = "humantime_serde")]
    pub keepalive: Option<Duration>,
    /// Default: the first device's profile default.
    pub baud: Option<u32>,
    /// Default: the first device's profile default.
    pub parity: Option<Parity>,
    #[serde(default = "default_data_bits")]
    pub data_bits: u8,
    #[serde(default = "default_stop_bits")]
    pub stop_bits: u8,
    #[serde(default, with = "humantime_serde")]
    pub response_timeout: Option<Duration>,
    #[serde(default = "default_retries")]
    pub retries: u32,
    #[serde(default = "default_offline_after")]
    pub offline_after: u32,
    /// The adapter echoes what it sends.
    #[serde(default)]
    pub echo: bool,
    #[serde(default = "default_broadcast_turnaround", with = "humantime_serde")]
    pub broadcast_turnaround: Duration,
    /// Longest pause inside an answer. Default: the master's (USB adapters' latency timer).
    #[serde(default, with = "humantime_serde")]
    pub byte_timeout: Option<Duration>,
    /// Kernel RS485 mode for UARTs that drive the transceiver themselves.
    pub rs485: Option<RawRs485>,
    #[serde(default)]
    pub devices: Vec<RawDevice>,
}

/// `[lines.rs485]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawRs485 {
    #[serde(default = "default_true")]
    pub rts_on_send: bool,
    #[serde(default, with = "humantime_serde")]
    pub delay_before_send: Duration,
    #[serde(default, with = "humantime_serde")]
    pub delay_after_send: Duration,
}

/// `[[lines.devices]]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawDevice {
    pub name: String,
    /// A built-in profile name or a path to a profile file (relative to the config file).
    pub profile: String,
    /// Wide on purpose: an out-of-range address gets a message naming the profile's range.
    pub address: i64,
    /// Default: the profile's default poll interval. `"0s"`: continuously (back to back).
    #[serde(default, with = "humantime_serde")]
    pub poll_interval: Option<Duration>,
}

/// What a key's value must be, for reporting every unknown key and wrongly typed value at once
/// with its place (serde stops at the first problem and words it in its own terms).
#[derive(Debug, Clone, Copy)]
pub enum Kind {
    Text,
    Bool,
    /// An integer in `min..=max` (the range of the field's Rust type).
    Integer {
        min: i64,
        max: i64,
    },
    /// A humantime duration (`"300ms"`).
    Duration,
    /// One of these words.
    OneOf(&'static [&'static str]),
    /// A table with these keys.
    Table(&'static [Key]),
    /// A list of tables with these keys (`[[lines]]`).
    Tables(&'static [Key]),
}

/// One key a table knows.
#[derive(Debug, Clone, Copy)]
pub struct Key {
    pub name: &'static str,
    pub kind: Kind,
    pub required: bool,
}

const fn required(name: &'static str, kind: Kind) -> Key {
    Key {
        name,
        kind,
        required: true,
    }
}

const fn optional(name: &'static str, kind: Kind) -> Key {
    Key {
        name,
        kind,
        required: false,
    }
}

const fn integer_up_to(max: u64) -> Kind {
    // Every bound used here fits an i64.
    Kind::Integer {
        min: 0,
        max: if max > i64::MAX as u64 {
            i64::MAX
        } else {
            max as i64
        },
    }
}

const U8: Kind = integer_up_to(u8::MAX as u64);
const U16: Kind = integer_up_to(u16::MAX as u64);
const U32: Kind = integer_up_to(u32::MAX as u64);
const USIZE: Kind = integer_up_to(usize::MAX as u64);
const I64: Kind = Kind::Integer {
    min: i64::MIN,
    max: i64::MAX,
};

/// The parity words ([`Parity`] in lower case).
pub const PARITY_WORDS: &[&str] = &["none", "even", "odd"];

/// The whole file, key by key (must agree with the serde structs above and the `*_KEYS`).
pub const TOP_SHAPE: &[Key] = &[
    required("mqtt", Kind::Table(MQTT_SHAPE)),
    optional("gateway", Kind::Table(GATEWAY_SHAPE)),
    optional("health", Kind::Table(HEALTH_SHAPE)),
    optional("lines", Kind::Tables(LINE_SHAPE)),
    optional("sparkplug", Kind::Table(SPARKPLUG_SHAPE)),
];
pub const SPARKPLUG_SHAPE: &[Key] = &[
    required("group_id", Kind::Text),
    optional("edge_node_id", Kind::Text),
    optional("primary_host_id", Kind::Text),
    optional("mqtt", Kind::Table(MQTT_SHAPE)),
];
pub const MQTT_SHAPE: &[Key] = &[
    required("url", Kind::Text),
    required("client_id", Kind::Text),
    optional("prefix", Kind::Text),
    optional("username", Kind::Text),
    optional("password", Kind::Text),
    optional("password_file", Kind::Text),
    optional("ca_file", Kind::Text),
    optional("cert_file", Kind::Text),
    optional("key_file", Kind::Text),
    optional("keep_alive", Kind::Duration),
    optional("clean_session", Kind::Bool),
    optional("inflight", U16),
    optional("discovery", Kind::Bool),
    optional("discovery_prefix", Kind::Text),
];
pub const HEALTH_SHAPE: &[Key] = &[
    optional("status_file", Kind::Text),
    optional("interval", Kind::Duration),
    optional("stale_after", Kind::Duration),
    optional("stall_limit", Kind::Duration),
];
pub const GATEWAY_SHAPE: &[Key] = &[
    optional("command_ttl", Kind::Duration),
    optional("json_view", Kind::Bool),
    optional("stats_interval", Kind::Duration),
    optional("metrics_listen", Kind::Text),
    optional("frame_log", Kind::Text),
    optional("allow_raw_writes", Kind::Bool),
    optional("max_payload", USIZE),
];
pub const LINE_SHAPE: &[Key] = &[
    required("name", Kind::Text),
    optional("port", Kind::Text),
    optional("url", Kind::Text),
    optional("network_allowance", Kind::Duration),
    optional("connect_timeout", Kind::Duration),
    optional("keepalive", Kind::Duration),
    optional("baud", U32),
    optional("parity", Kind::OneOf(PARITY_WORDS)),
    optional("data_bits", U8),
    optional("stop_bits", U8),
    optional("response_timeout", Kind::Duration),
    optional("retries", U32),
    optional("offline_after", U32),
    optional("echo", Kind::Bool),
    optional("broadcast_turnaround", Kind::Duration),
    optional("byte_timeout", Kind::Duration),
    optional("rs485", Kind::Table(RS485_SHAPE)),
    optional("devices", Kind::Tables(DEVICE_SHAPE)),
];
pub const RS485_SHAPE: &[Key] = &[
    optional("rts_on_send", Kind::Bool),
    optional("delay_before_send", Kind::Duration),
    optional("delay_after_send", Kind::Duration),
];
pub const DEVICE_SHAPE: &[Key] = &[
    required("name", Kind::Text),
    required("profile", Kind::Text),
    required("address", I64),
    optional("poll_interval", Kind::Duration),
];

/// The key names of each table (the README documents each of them).
pub const TOP_KEYS: &[&str] = &["mqtt", "gateway", "health", "lines", "sparkplug"];
pub const SPARKPLUG_KEYS: &[&str] = &["group_id", "edge_node_id", "primary_host_id", "mqtt"];
pub const MQTT_KEYS: &[&str] = &[
    "url",
    "client_id",
    "prefix",
    "username",
    "password",
    "password_file",
    "ca_file",
    "cert_file",
    "key_file",
    "keep_alive",
    "clean_session",
    "inflight",
    "discovery",
    "discovery_prefix",
];
pub const HEALTH_KEYS: &[&str] = &["status_file", "interval", "stale_after", "stall_limit"];
pub const GATEWAY_KEYS: &[&str] = &[
    "command_ttl",
    "json_view",
    "stats_interval",
    "metrics_listen",
    "frame_log",
    "allow_raw_writes",
    "max_payload",
];
pub const LINE_KEYS: &[&str] = &[
    "name",
    "port",
    "url",
    "network_allowance",
    "connect_timeout",
    "keepalive",
    "baud",
    "parity",
    "data_bits",
    "stop_bits",
    "response_timeout",
    "retries",
    "offline_after",
    "echo",
    "broadcast_turnaround",
    "byte_timeout",
    "rs485",
    "devices",
];
pub const RS485_KEYS: &[&str] = &["rts_on_send", "delay_before_send", "delay_after_send"];
pub const DEVICE_KEYS: &[&str] = &["name", "profile", "address", "poll_interval"];

fn default_prefix() -> String {
    "plant".to_string()
}
fn default_keep_alive() -> Duration {
    Duration::from_secs(30)
}
fn default_inflight() -> u16 {
    100
}
fn default_true() -> bool {
    true
}
fn default_discovery_prefix() -> String {
    crate::contract::DEFAULT_DISCOVERY_PREFIX.to_string()
}
fn default_command_ttl() -> Duration {
    Duration::from_secs(300)
}
fn default_stats_interval() -> Duration {
    Duration::from_secs(60)
}
fn default_max_payload() -> usize {
    1024
}
fn default_data_bits() -> u8 {
    8
}
fn default_stop_bits() -> u8 {
    1
}
fn default_retries() -> u32 {
    1
}
fn default_offline_after() -> u32 {
    3
}
fn default_broadcast_turnaround() -> Duration {
    Duration::from_millis(200)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_key_lists_name_the_shapes_keys() {
        let pairs: [(&[&str], &[Key]); 8] = [
            (TOP_KEYS, TOP_SHAPE),
            (MQTT_KEYS, MQTT_SHAPE),
            (HEALTH_KEYS, HEALTH_SHAPE),
            (GATEWAY_KEYS, GATEWAY_SHAPE),
            (LINE_KEYS, LINE_SHAPE),
            (RS485_KEYS, RS485_SHAPE),
            (DEVICE_KEYS, DEVICE_SHAPE),
            (SPARKPLUG_KEYS, SPARKPLUG_SHAPE),
        ];
        for (names, shape) in pairs {
            let shape_names: Vec<&str> = shape.iter().map(|key| key.name).collect();
            assert_eq!(names, shape_names.as_slice());
        }
    }
}
