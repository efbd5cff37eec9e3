//! The compiled, validated form of a profile: line limits, read blocks, fields with their codecs
//! and write frames, forbidden combinations. Built only by the crate's compiler (`compile`); read by decoding
//! and command planning, which can therefore trust it without re-checking. The parts users see
//! ([`ReadBlock`], [`PollClass`], [`Limits`], [`Behaviour`]) are public and re-exported at the
//! crate's root; the rest is the crate's own.

use std::ops::RangeInclusive;
use std::time::Duration;

use serde::Deserialize;

use super::action::ActionDef;
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
    /// The block's `name`, which fields and write frames refer to.
    pub name: String,
    /// A read request (FC 01–04) from the block's `function`, `start` and `count`.
    pub request: Request,
    /// How often it is read, from its `poll` key (default `fast`).
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
    /// `line.address_range`: the station addresses the device can be set to (default 1–247).
    pub address_range: RangeInclusive<u8>,
    /// `line.min_poll_interval`: the device's shortest poll interval; a device configured
    /// faster is refused (default 100 ms).
    pub min_poll_interval: Duration,
    /// `line.poll_interval`: the poll interval when the configuration gives none (default
    /// `min_poll_interval`).
    pub default_poll_interval: Duration,
    /// `line.slow_interval`: the period of `poll = "slow"` blocks (default 60 s).
    pub slow_interval: Duration,
    /// `line.startup_delay`: quiet time after power-up (gateway start) before the first
    /// transaction (default none).
    pub startup_delay: Duration,
    /// `line.baud`: the baud rate (bit/s) of a line whose configuration gives none (default
    /// 9600).
    pub default_baud: u32,
    /// `line.parity`: the parity of a line whose configuration gives none (default none; 8
    /// data bits and 1 stop bit always).
    pub default_parity: Parity,
    /// `line.max_read_registers`: most registers one FC 03/04 read may ask (default 125).
    pub max_read_registers: u16,
    /// `line.max_write_registers`: most registers one FC 10 write may carry (default 123).
    pub max_write_registers: u16,
    /// `line.max_read_bits`: most coils or inputs one FC 01/02 read may ask (default 2000).
    pub max_read_bits: u16,
    /// `line.max_write_bits`: most coils one FC 0F write may carry (default 1968).
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
pub(crate) enum BlockKind {
    Coils,
    DiscreteInputs,
    HoldingRegisters,
    InputRegisters,
}

impl BlockKind {
    pub(crate) fn is_bits(self) -> bool {
        matches!(self, Self::Coils | Self::DiscreteInputs)
    }

    pub(crate) fn is_writable(self) -> bool {
        matches!(self, Self::Coils | Self::HoldingRegisters)
    }
}

/// One write frame: the device addresses written and the block offsets they mirror.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct WriteFrame {
    pub(crate) function: u8,
    pub(crate) address: u16,
    pub(crate) block: usize,
    pub(crate) offset: u16,
    pub(crate) count: u16,
}

/// A compiled field.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct FieldDef {
    pub(crate) block: usize,
    pub(crate) offset: u16,
    pub(crate) codec: FieldCodec,
    pub(crate) write: Option<WriteFrame>,
    pub(crate) behaviour: Behaviour,
    pub(crate) settle_window: Option<Duration>,
    /// (field index, value): when all hold on a read-back, the device has stopped moving and a
    /// value that still differs is final (not applied) before the settle window ends.
    pub(crate) settle_until: Vec<(usize, Value)>,
    pub(crate) overlay: bool,
    /// Integers accepted besides the range (the valve's 255 = alarm disabled).
    pub(crate) also: Vec<i64>,
    /// The profile's example command value for this field, checked at load.
    pub(crate) example: Option<String>,
    /// The field holding the power of ten this number is multiplied by (`scale_by`).
    pub(crate) scale_by: Option<usize>,
}

impl Compiled {
    /// The exponent field `index` is read or written with: [`Exponent::None`] without
    /// `scale_by`; otherwise the exponent field's value as `read` gives it (None: it was not
    /// read with the value).
    pub(crate) fn exponent_for(
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
}

/// A compiled forbidden combination.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Forbidden {
    /// (field index, value that must hold).
    pub(crate) when: Vec<(usize, Value)>,
    pub(crate) reason: String,
}

/// The compiled, validated form of a profile.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Compiled {
    pub(crate) name: String,
    pub(crate) manufacturer: String,
    pub(crate) model: String,
    pub(crate) description: String,
    pub(crate) default_address: Option<u8>,
    pub(crate) limits: Limits,
    pub(crate) blocks: Vec<ReadBlock>,
    pub(crate) block_kinds: Vec<BlockKind>,
    /// Parallel to `infos`.
    pub(crate) defs: Vec<FieldDef>,
    pub(crate) infos: Vec<FieldInfo>,
    pub(crate) forbidden: Vec<Forbidden>,
    /// The `[[write_frames]]` by name, in file order.
    pub(crate) named_frames: Vec<(String, WriteFrame)>,
    /// What loads but is likely a mistake (a start that looks like a Modicon number).
    pub(crate) warnings: Vec<super::compile::ProfileError>,
    /// The `[[actions]]`, in file order.
    pub(crate) actions: Vec<ActionDef>,
    /// What the device reports when asked what it is.
    pub(crate) identification: Option<super::identification::Identification>,
}
