//! The only MQTT user: state, commands, outcomes, availability, discovery and statistics.

pub mod discovery;
pub mod json_view;
pub mod metrics;
