//! The compiled, validated form of a profile: line limits, read blocks, fields with their codecs
//! and write frames, forbidden combinations. Built only by [`super::compile`]; read by decoding
//! and command planning, which can therefore trust it without re-checking. The parts the rest of
//! the crate sees ([`ReadBlock`], [`PollClass`], [`Limits`]) are re-exported by the profile
//! module.

use std::ops::RangeInclusive;
use std::time::Duration;

use serde::Deserialize;

use super::codec::{FieldCodec, FieldError};
use super::field::FieldInfo;
use super::numeric::Exponent;
use super::value::Value;
use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_modbus::Request;

/// How often a block is read (its `poll` key).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PollClass {
    /// Every poll cycle (the device's poll interval).
    Fast,
    /// Every [`Limits::slow_interval`].
    Slow,
    /// On its own period, never shorter than [`Limits::min_poll_interval`].
    Every(Duration),
    /// At start, when the device comes back from offline, after a write into the block and on
    /// a refresh request; never in steady state.
    Once,
}

/// `fast`, `slow`, `once` or the period (`250ms`, `15s`), as the profile writes it.
impl std::fmt::Display for PollClass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PollClass::Fast => f.write_str("fast"),
            PollClass::Slow => f.write_str("slow"),
            PollClass::Every(period) => write!(f, "{}", humantime::format_duration(*period)),
            PollClass::Once => f.write_str("once"),
        }
    }
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
    /// The device answers a read of any part of this block with the items the whole block
    /// holds at those addresses, so a part may be cut from an answer to the whole.
    pub reads_linearly: bool,
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

/// How a written field behaves on the device.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Behaviour {
    /// A state: written as commanded, written back as read when another field of its frame is.
    #[default]
    State,
    /// Writing 1 flips the state; written 1 only to change it, 0 otherwise.
    Toggle,
    /// A button: written 1 once when pressed, 0 otherwise.
    Momentary,
}

/// What a block holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlockKind {
    Coils,
    DiscreteInputs,
    HoldingRegisters,
    InputRegisters,
}

impl BlockKind {
    pub fn is_bits(self) -> bool {
        matches!(self, Self::Coils | Self::DiscreteInputs)
    }

    pub fn is_writable(self) -> bool {
        matches!(self, Self::Coils | Self::HoldingRegisters)
    }
}

/// One write frame: the device addresses written and the block offsets they mirror.
#[derive(Debug, Clone, PartialEq)]
pub struct WriteFrame {
    pub function: u8,
    pub address: u16,
    pub block: usize,
    pub offset: u16,
    pub count: u16,
}

/// A compiled field.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldDef {
    pub block: usize,
    pub offset: u16,
    pub codec: FieldCodec,
    pub write: Option<WriteFrame>,
    pub behaviour: Behaviour,
    pub settle_window: Option<Duration>,
    /// (field index, value): when all hold on a read-back, the device has stopped moving and a
    /// value that still differs is final (not applied) before the settle window ends.
    pub settle_until: Vec<(usize, Value)>,
    pub overlay: bool,
    /// Integers accepted besides the range (the valve's 255 = alarm disabled).
    pub also: Vec<i64>,
    /// The profile's example command value for this field, checked at load.
    pub example: Option<String>,
    /// The field holding the power of ten this number is multiplied by (`scale_by`).
    pub scale_by: Option<usize>,
}

impl Compiled {
    /// The exponent field `index` is read or written with: [`Exponent::None`] without
    /// `scale_by`; otherwise the exponent field's value as `read` gives it (None: it was not
    /// read with the value).
    pub fn exponent_for(
        &self,
        index: usize,
        read: impl FnOnce(usize) -> Option<Result<Value, FieldError>>,
    ) -> Exponent {
        let Some(exponent) = self.defs.get(index).and_then(|def| def.scale_by) else {
            return Exponent::None;
        };
        match read(exponent) {
            None => Exponent::Unusable("the exponent was not read with the value".to_string()),
            Some(Ok(value)) => Exponent::from_value(Ok(&value)),
            Some(Err(error)) => Exponent::from_value(Err(error.to_string())),
        }
    }

    /// The exponent of field `index` from `image`, a whole image of its exponent's block, when
    /// that is `block`.
    pub fn exponent_in(
        &self,
        index: usize,
        block: usize,
        image: &super::codec::BlockImage,
    ) -> Exponent {
        self.exponent_for(index, |exponent| {
            let def = &self.defs[exponent];
            (def.block == block).then(|| def.codec.decode(image, def.offset))
        })
    }
}

/// A compiled forbidden combination.
#[derive(Debug, Clone, PartialEq)]
pub struct Forbidden {
    /// (field index, value that must hold).
    pub when: Vec<(usize, Value)>,
    pub reason: String,
}

/// The compiled, validated form of a profile.
#[derive(Debug, Clone, PartialEq)]
pub struct Compiled {
    pub name: String,
    pub manufacturer: String,
    pub model: String,
    pub description: String,
    pub default_address: Option<u8>,
    pub limits: Limits,
    pub blocks: Vec<ReadBlock>,
    pub block_kinds: Vec<BlockKind>,
    /// Parallel to `infos`.
    pub defs: Vec<FieldDef>,
    pub infos: Vec<FieldInfo>,
    pub forbidden: Vec<Forbidden>,
    /// The `[[write_frames]]` by name, in file order.
    pub named_frames: Vec<(String, WriteFrame)>,
}
