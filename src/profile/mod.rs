//! Device knowledge as data. A [`Profile`] is loaded from TOML (`config/profiles/*.toml`, or
//! one of the built-in copies), validated completely at load, and then answers every question
//! the rest of the gateway has about a device: which blocks to poll, how raw words become field
//! values, which fields exist and how they are exposed, and how a command on a field becomes the
//! frames of one bus slot. Everything here is pure: no I/O, no clock, no tokio.

pub mod codec;
pub mod command;
pub mod registry;
pub mod schema;
pub mod value;

use std::collections::HashMap;
use std::ops::RangeInclusive;
use std::time::Duration;

use crate::rtu::timing::Parity;
use crate::rtu::{Request, Response};

pub use command::{CommandPlan, Rejection, Verification};
pub use value::Value;

/// Last known decoded values of one device, by field name.
pub type DeviceState = HashMap<String, Value>;

/// A validated device profile.
#[derive(Debug, Clone)]
pub struct Profile {
    // Filled in by `schema` loading; private to this module tree.
    pub(crate) inner: schema::Compiled,
}

/// How often a block is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PollClass {
    /// Every poll cycle (the device's poll interval).
    Fast,
    /// Every [`Limits::slow_interval`].
    Slow,
}

/// One read request the device is polled with.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReadBlock {
    pub name: String,
    /// A read request (FC 01–04).
    pub request: Request,
    pub class: PollClass,
    /// The (offset, length) runs of the block that fields use, in coils or registers. When the
    /// device refuses the merged block (exception 02), the line reads these runs one by one and
    /// assembles a block answer with zeros in the unused places.
    pub used_runs: Vec<(u16, u16)>,
}

/// Line defaults and device limits from the profile.
#[derive(Debug, Clone, PartialEq)]
pub struct Limits {
    pub address_range: RangeInclusive<u8>,
    pub min_poll_interval: Duration,
    pub default_poll_interval: Duration,
    pub slow_interval: Duration,
    /// Quiet time after power-up (gateway start) before the first transaction.
    pub startup_delay: Duration,
    pub default_baud: u32,
    pub default_parity: Parity,
    pub max_read_registers: u16,
    pub max_write_registers: u16,
    pub max_read_bits: u16,
    pub max_write_bits: u16,
}

/// What a field is, for payloads, commands and Home Assistant.
#[derive(Debug, Clone, PartialEq)]
pub enum FieldKind {
    Bool,
    /// A button: written once when pressed, never a state to hold.
    Momentary,
    Integer {
        min: i64,
        max: i64,
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

/// A field as the outside world sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldInfo {
    pub name: String,
    pub description: String,
    pub kind: FieldKind,
    pub writable: bool,
    pub unit: Option<String>,
    pub ha: HaHints,
    /// Minimum time between two writes of this field (protects device EEPROM).
    pub min_write_interval: Option<Duration>,
}

/// One field's value from a block, or why it has none.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldReading {
    pub field: String,
    pub value: Result<Value, codec::FieldError>,
}

impl Profile {
    /// The profile's name (`ruiwan-dust-collector`).
    pub fn name(&self) -> &str {
        todo!("profile helper")
    }

    pub fn manufacturer(&self) -> &str {
        todo!("profile helper")
    }

    pub fn model(&self) -> &str {
        todo!("profile helper")
    }

    pub fn limits(&self) -> &Limits {
        todo!("profile helper")
    }

    pub fn fields(&self) -> &[FieldInfo] {
        todo!("profile helper")
    }

    pub fn field(&self, name: &str) -> Option<&FieldInfo> {
        self.fields().iter().find(|f| f.name == name)
    }

    pub fn read_blocks(&self) -> &[ReadBlock] {
        todo!("profile helper")
    }

    /// Decodes the answer to `read_blocks()[block]` into its fields' values.
    pub fn decode_block(&self, block: usize, answer: &Response) -> Vec<FieldReading> {
        todo!("profile helper")
    }

    /// Validates a command (`text` as received on `…/set`) against the field's rules and the
    /// last known state, and plans the bus slot that carries it out.
    pub fn plan_command(
        &self,
        field: &str,
        text: &str,
        state: &DeviceState,
    ) -> Result<CommandPlan, Rejection> {
        todo!("profile helper")
    }
}
