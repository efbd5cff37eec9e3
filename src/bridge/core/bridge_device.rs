//! The configured devices as the bridge sees them: name, profile and line, looked up by name.

use std::collections::HashMap;
use std::sync::Arc;

use rtu2mqtt_profile::Profile;

/// A configured device as the bridge sees it.
#[derive(Debug, Clone)]
pub struct BridgeDevice {
    pub name: String,
    pub profile: Arc<Profile>,
    /// Index of its line in the configuration.
    pub line: usize,
}

/// The configured devices by name.
pub type Devices = HashMap<String, BridgeDevice>;

/// `devices` by name.
pub fn by_name(devices: impl IntoIterator<Item = BridgeDevice>) -> Devices {
    devices
        .into_iter()
        .map(|device| (device.name.clone(), device))
        .collect()
}
