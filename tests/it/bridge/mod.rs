//! The bridge between the plant and MQTT:
//!
//! - `gateway_e2e`: the gateway between the simulated seed plant and a real mosquitto, driven as
//!   a user would.
//! - `discovery`: Home Assistant discovery, the statistics document, Prometheus text, the JSON
//!   view.
//! - `acceptance`: checks found by driving the gateway as a user would.
//! - `trust_store`: `mqtts://` against the system's trust store or a `ca_file`.
//! - `plant_connection`: the MQTT connection with a thousand lines.

mod acceptance;
mod discovery;
mod gateway_e2e;
mod plant_connection;
mod trust_store;
