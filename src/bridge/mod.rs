//! The only MQTT user: state, commands, outcomes, availability, discovery and statistics.

pub mod discovery;
