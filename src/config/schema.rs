//! The configuration file as written: these serde structs are the one declaration of every
//! key (name, type, default, required or not); reading, the list of keys and the reference's
//! test derive from them, and [`shape_at`] says where each struct sits. Unknown keys are
//! refused by the reading (`read`), which lists them all; durations are humantime strings
//! (`"300ms"`), addresses plain integers (TOML accepts `0x81`). Nothing here is checked beyond
//! its type; `validate` turns it into the gateway's settings.

use std::path::PathBuf;
use std::time::Duration;

use serde::de::DeserializeOwned;
use serde::Deserialize;

use super::health::HealthSettings;
use super::history::RawHistory;
use super::tree::Step;
use super::web::RawWeb;
use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_profile::publish::RawPublish;

/// The keys the serde struct `T` declares, in order (`#[derive(Deserialize)]` names them).
pub fn keys_of<T: DeserializeOwned>() -> &'static [&'static str] {
    serde_aux::serde_introspection::serde_introspect::<T>()
}

/// What the file holds at a place: a table (a struct, with its keys), a list of tables (a
/// `Vec` of structs), or a value of another kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    Table(&'static [&'static str]),
    ListOfTables,
    Value,
}

/// Where each struct sits in the file. serde reads a struct from a list as well (its keys by
/// position), so the reading needs to know where a list must not be (`mqtt = ["mqtt://h", "e"]`).
pub fn shape_at(place: &[Step]) -> Shape {
    // An item of a list is `[]` whatever its index.
    let steps: Vec<&str> = place
        .iter()
        .map(|step| match step {
            Step::Key(key) => key.as_str(),
            Step::Index(_) => "[]",
        })
        .collect();
    let keys = match steps.as_slice() {
        ["lines"] | ["lines", "[]", "devices"] => return Shape::ListOfTables,
        [] => keys_of::<RawConfig>(),
        ["mqtt"] | ["sparkplug", "mqtt"] => keys_of::<RawMqtt>(),
        ["gateway"] => keys_of::<RawGateway>(),
        ["health"] => keys_of::<HealthSettings>(),
        ["lines", "[]"] => keys_of::<RawLine>(),
        ["lines", "[]", "rs485"] => keys_of::<RawRs485>(),
        ["lines", "[]", "serve"] => keys_of::<RawServe>(),
        ["lines", "[]", "devices", "[]"] => keys_of::<RawDevice>(),
        ["lines", "[]", "devices", "[]", "publish"] => keys_of::<RawPublish>(),
        ["sparkplug"] => keys_of::<SparkplugSettings>(),
        ["history"] => keys_of::<RawHistory>(),
        ["web"] => keys_of::<RawWeb>(),
        _ => return Shape::Value,
    };
    Shape::Table(keys)
}

/// The keys of the table at `place` (none where no table goes): for naming an unknown key's
/// neighbours and listing problems in the order of the declaration.
pub fn keys_at(place: &[Step]) -> &'static [&'static str] {
    match shape_at(place) {
        Shape::Table(keys) => keys,
        Shape::ListOfTables | Shape::Value => &[],
    }
}

/// The whole file.
#[derive(Debug, Clone, Deserialize)]
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
    /// The journal of measured values and the history stream (off when absent).
    #[serde(default)]
    pub history: Option<RawHistory>,
    /// The browser console (off when absent).
    #[serde(default)]
    pub web: Option<RawWeb>,
}

/// `[mqtt]`.
#[derive(Debug, Clone, Deserialize)]
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
    /// A Modbus TCP server sharing the line with other masters (off when absent).
    pub serve: Option<RawServe>,
    #[serde(default)]
    pub devices: Vec<RawDevice>,
}

/// `[sparkplug]`: the Sparkplug B edge node's identity and, optionally, a broker of its own.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct SparkplugSettings {
    /// The Sparkplug group.
    pub group_id: String,
    /// Default: the MQTT client id.
    pub edge_node_id: Option<String>,
    /// With a primary host, births wait for its STATE `online`.
    pub primary_host_id: Option<String>,
    /// A broker of its own, in the form of `[mqtt]` (validated by the same rules); default:
    /// the `[mqtt]` broker under another client id.
    pub mqtt: Option<RawMqtt>,
}

/// `[lines.rs485]`.
#[derive(Debug, Clone, Deserialize)]
pub struct RawRs485 {
    #[serde(default = "default_true")]
    pub rts_on_send: bool,
    #[serde(default, with = "humantime_serde")]
    pub delay_before_send: Duration,
    #[serde(default, with = "humantime_serde")]
    pub delay_after_send: Duration,
}

/// `[lines.serve]`.
#[derive(Debug, Clone, Deserialize)]
pub struct RawServe {
    /// `modbus-tcp://host:port` (Modbus TCP) or `tcp://host:port` (RTU frames over TCP).
    pub listen: String,
    /// `profile` | `read-only` | `raw`.
    #[serde(default = "default_serve_access")]
    pub access: String,
    /// Reads of a block polled younger than this come from the poll; `"0s"`: always the bus.
    #[serde(default, with = "humantime_serde")]
    pub cache: Duration,
    #[serde(default = "default_max_clients")]
    pub max_clients: usize,
}

/// `[[lines.devices]]`.
#[derive(Debug, Clone, Deserialize)]
pub struct RawDevice {
    pub name: String,
    /// A built-in profile name or a path to a profile file (relative to the config file).
    pub profile: String,
    /// Wide on purpose: an out-of-range address gets a message naming the profile's range.
    pub address: i64,
    /// Default: the profile's default poll interval. `"0s"`: continuously (back to back).
    #[serde(default, with = "humantime_serde")]
    pub poll_interval: Option<Duration>,
    /// When values are published: the default of every field (a field's own keys win).
    pub publish: Option<RawPublish>,
}

fn default_serve_access() -> String {
    crate::bus::serve::Access::Profile.word().to_string()
}
fn default_max_clients() -> usize {
    crate::bus::serve::DEFAULT_MAX_CLIENTS
}
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
    crate::topics::DEFAULT_DISCOVERY_PREFIX.to_string()
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
    fn the_keys_are_the_structs_declaration() {
        assert_eq!(
            keys_of::<RawDevice>(),
            ["name", "profile", "address", "poll_interval", "publish"]
        );
        assert_eq!(
            keys_of::<RawRs485>(),
            ["rts_on_send", "delay_before_send", "delay_after_send"]
        );
        assert!(keys_of::<String>().is_empty());
        let device = [
            Step::Key("lines".into()),
            Step::Index(2),
            Step::Key("devices".into()),
            Step::Index(0),
        ];
        assert_eq!(keys_at(&device), keys_of::<RawDevice>());
        assert!(keys_at(&[Step::Key("colour".into())]).is_empty());
        assert_eq!(shape_at(&device[..3]), Shape::ListOfTables);
        assert_eq!(shape_at(&[Step::Key("lines".into())]), Shape::ListOfTables);
    }
}
