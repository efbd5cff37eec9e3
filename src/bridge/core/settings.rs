//! [`CoreSettings`]: what the bridge core is built from, taken from the configuration.

use super::bridge_device::BridgeDevice;
use crate::config::{Config, GatewayOptions};
use crate::topics::Topics;

/// What the core is built from.
#[derive(Debug, Clone)]
pub struct CoreSettings {
    pub topics: Topics,
    /// Home Assistant discovery is published.
    pub discovery: bool,
    pub options: GatewayOptions,
    /// Change sets go to the history stream (`[history]`).
    pub history: bool,
    pub line_names: Vec<String>,
    /// In configuration order.
    pub devices: Vec<BridgeDevice>,
}

impl CoreSettings {
    pub fn from_config(config: &Config) -> Self {
        let mut devices = Vec::new();
        for (line, spec) in config.lines.iter().enumerate() {
            for device in &spec.devices {
                devices.push(BridgeDevice {
                    name: device.name.clone(),
                    profile: device.profile.clone(),
                    line,
                });
            }
        }
        CoreSettings {
            topics: config.mqtt.topics(),
            discovery: config.mqtt.discovery,
            options: config.gateway.clone(),
            history: config.history.is_some(),
            line_names: config.lines.iter().map(|line| line.name.clone()).collect(),
            devices,
        }
    }
}
