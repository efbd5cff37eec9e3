//! What the Sparkplug session is given and what it gives back: the namespace and node metric
//! names, its settings, the actions its driver carries out, the Will of the next connection
//! and the history it replays. Plain data; the rules are in [`super::session`].

use std::sync::Arc;

use serde_json::Value as Json;

use super::protobuf::DataType;
use rtu2mqtt_profile::Profile;

/// The Sparkplug B topic namespace.
pub const NAMESPACE: &str = "spBv1.0";
/// The node metric a host writes `true` to for a fresh set of births.
pub const REBIRTH: &str = "Node Control/Rebirth";
/// The node metric carrying the birth/death sequence number.
pub const BD_SEQ: &str = "bdSeq";
/// Node metrics with the gateway's own figures.
pub const DEVICES: &str = "Gateway/Devices";
pub const DEVICES_ONLINE: &str = "Gateway/Devices Online";
pub const VERSION: &str = "Properties/Software Version";

/// A DCMD metric turned into a command for the gateway's validated command path: the field
/// and the command text as `…/set` would carry it (`ON`, `8`, `12.5`, `opening`).
pub use crate::bridge::core::ExternalCommand;

/// MQTT delivery of a publish.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Delivery {
    AtMostOnce,
    AtLeastOnce,
}

/// What the driver must do.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    Publish {
        topic: String,
        payload: Vec<u8>,
        delivery: Delivery,
    },
    /// Subscribe at QoS 1.
    Subscribe { topic: String },
    /// End the MQTT connection gracefully (the NDEATH was published just before).
    Disconnect,
    /// Hand a command to the gateway's command path.
    Command(ExternalCommand),
    /// A host's command refused here: nothing reaches the bus (for the log and the outcome
    /// record).
    Refused {
        device: String,
        field: Option<String>,
        reason: String,
    },
}

/// Replayed change sets kept while their devices are not born; beyond this the oldest go.
pub const HISTORY_QUEUE: usize = 50_000;

/// A device's change set read while the broker was away, replayed from the history journal.
#[derive(Debug, Clone, PartialEq)]
pub struct HistoricalValues {
    pub device: String,
    /// When the answer was read, in milliseconds since the Unix epoch.
    pub read_at: u64,
    /// Field name and value as the history document types it.
    pub values: Vec<(String, Json)>,
}

/// The Will the next MQTT connection must carry.
#[derive(Debug, Clone, PartialEq)]
pub struct Will {
    pub topic: String,
    pub payload: Vec<u8>,
}

/// What the node is configured with.
#[derive(Debug, Clone)]
pub struct SessionSettings {
    pub group_id: String,
    pub edge_node_id: String,
    pub primary_host_id: Option<String>,
    /// The configured devices, in configuration order (their aliases follow it).
    pub devices: Vec<(String, Arc<Profile>)>,
    /// The gateway's software version, shown as a node property.
    pub version: String,
    /// Gateway figures published as node metrics besides the built-in ones.
    pub node_metrics: Vec<NodeMetricSpec>,
}

/// A gateway figure published as a node metric (line statistics, bus load). Declared when the
/// session is made, so it is part of every NBIRTH; its values arrive through
/// [`Session::on_node_values`](super::session::Session::on_node_values).
#[derive(Debug, Clone, PartialEq)]
pub struct NodeMetricSpec {
    pub name: String,
    pub datatype: DataType,
}
