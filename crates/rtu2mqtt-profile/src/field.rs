//! What a field is to the outside world: its kind (for payloads, commands and Home Assistant),
//! its Home Assistant hints and its public description. No codec, block or frame knowledge here.

use std::time::Duration;

use super::publish::PublishRule;
use super::Value;

/// What a field is, for payloads, commands and Home Assistant.
#[derive(Debug, Clone, PartialEq)]
pub enum FieldKind {
    Bool,
    /// A button: written once when pressed, never a state to hold.
    Momentary,
    /// Wide enough for every 64-bit register value, signed or not.
    Integer {
        min: i128,
        max: i128,
    },
    /// A fixed-point number with `precision` decimals.
    Decimal {
        min: f64,
        max: f64,
        precision: u8,
    },
    Enum {
        options: Vec<String>,
    },
    Text,
}

/// Home Assistant hints, all optional.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct HaHints {
    pub component: Option<String>,
    pub device_class: Option<String>,
    pub state_class: Option<String>,
    pub unit: Option<String>,
    pub icon: Option<String>,
    /// `config` or `diagnostic`.
    pub entity_category: Option<String>,
}

/// Which entry of the device registry a field fills (Home Assistant's `serial_number`,
/// `hw_version`, `sw_version`): a profile's `identity` key.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Identity {
    SerialNumber,
    HardwareVersion,
    SoftwareVersion,
}

impl Identity {
    /// The key in a profile (`identity = "serial_number"`) and in Home Assistant's `dev` block.
    pub fn key(self) -> &'static str {
        match self {
            Identity::SerialNumber => "serial_number",
            Identity::HardwareVersion => "hw_version",
            Identity::SoftwareVersion => "sw_version",
        }
    }
}

/// A field as the outside world sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldInfo {
    pub name: String,
    pub description: String,
    pub kind: FieldKind,
    pub writable: bool,
    pub unit: Option<String>,
    /// For numbers, the smallest change the device can hold (one raw count: `0.01` for two
    /// decimals, `5` for `scale = 5`); commands off this step are refused. None otherwise.
    pub step: Option<Value>,
    /// Integers a command may carry and the device may report besides the range (the valve's
    /// `255` = alarm disabled); empty for most fields.
    pub also: Vec<i64>,
    pub ha: HaHints,
    /// The name people read (`PID invalid flags`); None derives one from `name`.
    pub label: Option<String>,
    /// The device-registry entry this field's value fills, if any.
    pub identity: Option<Identity>,
    /// Minimum time between two writes of this field (protects device EEPROM).
    pub min_write_interval: Option<Duration>,
    /// When its value is published (its own `publish` keys; the device's fill the others).
    pub publish: PublishRule,
    /// The field holding the power of ten this number is multiplied by (`scale_by`): its
    /// places follow the device, up to those of [`FieldKind::Decimal`]'s precision.
    pub scaled_by: Option<String>,
}
