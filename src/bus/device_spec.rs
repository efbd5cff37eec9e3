//! One configured device on a line, as the bus takes it from the configuration: its name,
//! address, compiled profile, poll interval and publish rule.

use std::sync::Arc;
use std::time::Duration;

use rtu2mqtt_modbus::SlaveId;
use rtu2mqtt_profile::{Profile, PublishRule};

/// One configured device on a line.
#[derive(Debug, Clone)]
pub struct DeviceSpec {
    pub name: String,
    pub address: SlaveId,
    pub profile: Arc<Profile>,
    /// Zero: continuously, as often as the profile's minimum allows.
    pub poll_interval: Duration,
    /// When values are published, for every field whose profile leaves a key unset.
    pub publish: PublishRule,
}
