//! What a field is to the outside world: its kind (for payloads, commands and Home Assistant),
//! its Home Assistant hints and its public description. No codec, block or frame knowledge here.

use std::time::Duration;

use super::publish::PublishRule;
use crate::value::Value;

/// What a field is, for payloads, commands and Home Assistant.
#[derive(Debug, Clone, PartialEq)]
pub enum FieldKind {
    /// On or off: a `bit` or `coil` field; commands `ON`/`OFF` (also `true`/`false`, `1`/`0`).
    Bool,
    /// A button: written once when pressed, never a state to hold.
    Momentary,
    /// Wide enough for every 64-bit register value, signed or not.
    Integer {
        /// The smallest value: the field's `range` low end, else the codec's smallest.
        min: i128,
        /// The largest value: the field's `range` high end, else the codec's largest.
        max: i128,
    },
    /// A fixed-point number with `precision` decimals.
    Decimal {
        /// The smallest value: the field's `range` low end, else the codec's smallest.
        min: f64,
        /// The largest value: the field's `range` high end, else the codec's largest.
        max: f64,
        /// Decimals shown and accepted in a command: the codec's `decimals` (a `bcd` field's
        /// `frac_digits`).
        precision: u8,
    },
    /// One word of a list: the codec's `options`, option i standing for raw value i.
    Enum {
        /// The words in raw-value order; commands take them in any case.
        options: Vec<String>,
    },
    /// Read-only text: a `string` or `bytes` field.
    Text,
}

/// Home Assistant hints, all optional.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct HaHints {
    /// `ha.component`: the platform to expose the field as (`sensor`, `number`, `select`, …)
    /// instead of the one its kind and access call for.
    pub component: Option<String>,
    /// `ha.device_class` (`temperature`, `duration`, `problem`, …).
    pub device_class: Option<String>,
    /// `ha.state_class` (`measurement`, `total_increasing`).
    pub state_class: Option<String>,
    /// The field's `unit`, Home Assistant's `unit_of_measurement`.
    pub unit: Option<String>,
    /// `ha.icon` (`mdi:fan`).
    pub icon: Option<String>,
    /// `ha.entity_category`: `config` or `diagnostic`; None for a primary entity.
    pub entity_category: Option<String>,
}

/// Which entry of the device registry a field fills (Home Assistant's `serial_number`,
/// `hw_version`, `sw_version`): a profile's `identity` key.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Identity {
    /// `identity = "serial_number"`: Home Assistant's `serial_number`.
    SerialNumber,
    /// `identity = "hw_version"`: the hardware revision.
    HardwareVersion,
    /// `identity = "sw_version"`: the firmware version.
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
    /// The field's `name`: lower-case letters, digits and `_`, the last level of its MQTT
    /// topic (`plant/<device>/<name>`).
    pub name: String,
    /// The field's `description`; empty when the profile gives none.
    pub description: String,
    /// What values it takes, from its codec narrowed by its `range` and `behaviour`.
    pub kind: FieldKind,
    /// The field has a `write`: commands on `…/<name>/set` are planned for it.
    pub writable: bool,
    /// The field's `unit` (`°C`, `Pa`, `s`); None for values without one.
    pub unit: Option<String>,
    /// For numbers, the smallest change the device can hold (one raw count: `0.01` for two
    /// decimals, `5` for `scale = 5`); commands off this step are refused. None otherwise.
    pub step: Option<Value>,
    /// Integers a command may carry and the device may report besides the range (the valve's
    /// `255` = alarm disabled); empty for most fields.
    pub also: Vec<i64>,
    /// The field's `ha` table, with `unit` copied in.
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
    /// The device can report "no value" here (a float's NaN, an `invalid` mark, an enum code
    /// the profile does not name, an empty string): the field is then published as
    /// unavailable.
    pub may_be_unavailable: bool,
    /// An enum whose codes the profile does not name are published as numbers
    /// (`unknown = "publish_number"`): its values are not only its options.
    pub unnamed_codes_as_numbers: bool,
}
