//! The MQTT topics of one gateway, built and read back in one place so that the two cannot
//! drift apart: the configuration check, the bridge, the console and the demo all use them.
//!
//! - [`names`]: [`Topics`], every topic, subscription filter and Home Assistant identifier
//!   the gateway builds.
//! - [`kind`]: [`Topics::classify`], what a topic is ([`TopicKind`], with the device, field,
//!   line or gateway it names).
//! - [`words`]: the payload words `online`/`offline`, the default discovery prefix and the
//!   longest topic looked at.
//!
//! The levels the topics reserve (`availability`, `set`, `result`, …), which no device or
//! field may be named, are the profile crate's ([`rtu2mqtt_profile::topic_levels`]): a
//! profile is checked against them when it is read.

pub mod kind;
pub mod names;
pub mod words;

pub use kind::TopicKind;
pub use names::{json_view_topic, Topics};
pub use words::{
    availability_word, is_ha_online, DEFAULT_DISCOVERY_PREFIX, MAX_TOPIC_LEN, OFFLINE, ONLINE,
};
