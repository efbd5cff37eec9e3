//! The gateway as a Sparkplug B 3.0 edge node, beside the plain topics, in two parts as the
//! bridge is:
//!
//! - [`core`]: the node's rules: the protobuf payload, profile fields as typed metrics, line
//!   statistics as node metrics, the edge node state machine, and the bdSeq kept across
//!   restarts.
//! - [`driver`]: the one task that runs the session on the node's own MQTT connection.
//!
//! The core never names the driver; the driver runs the core.

pub mod core;
pub mod driver;

pub use self::core::session::{
    Action, ExternalCommand, HistoricalValues, NodeMetricSpec, Session, SessionSettings,
};
pub use crate::config::sparkplug::{
    shared_broker, SparkplugConfig, SparkplugIdentity, CLIENT_ID_SUFFIX,
};
pub use crate::config::SparkplugSettings;
pub use driver::{now_millis, run, session_for, CommandReport, NodeLinks, MAX_OUTGOING_PACKET};
