//! The profile file as users write it: the serde types of the TOML format, with their defaults.
//!
//! Only the shape of the file lives here (unknown keys are refused by serde); what the values mean
//! and whether they fit together is decided by [`super::compile`].

use std::collections::BTreeMap;
use std::time::Duration;

use serde::Deserialize;

use super::action::ParamType;
use super::codec::{ByteFormat, ByteSource};
use super::enumeration::UnknownCode;
use super::identification::IdentificationSection;
use super::model::Behaviour;
use super::numeric::BytePlace;
use super::publish::RawPublish;
use super::register_numbers::RegisterNumbers;
use super::registers::{ByteOrder, WordOrder};
use super::text::Encoding;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ProfileFile {
    pub(super) device: DeviceSection,
    pub(super) line: LineSection,
    #[serde(default)]
    pub(super) blocks: Vec<BlockSection>,
    #[serde(default)]
    pub(super) write_frames: Vec<WriteFrameSection>,
    #[serde(default)]
    pub(super) fields: Vec<FieldSection>,
    #[serde(default)]
    pub(super) forbidden: Vec<ForbiddenSection>,
    #[serde(default)]
    pub(super) actions: Vec<ActionSection>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct DeviceSection {
    pub(super) name: String,
    pub(super) manufacturer: String,
    pub(super) model: String,
    #[serde(default)]
    pub(super) description: String,
    /// How the `start`s and `address`es are numbered; absent: bus addresses, and a start
    /// that looks like a Modicon number is warned about.
    pub(super) register_numbers: Option<RegisterNumbers>,
    /// What the device reports when asked what it is (a scan names the profile by it).
    pub(super) identification: Option<IdentificationSection>,
}

pub(super) fn default_baud() -> u32 {
    9600
}
pub(super) fn default_parity() -> String {
    "none".into()
}
pub(super) fn default_address_range() -> [u8; 2] {
    [1, 247]
}
pub(super) fn default_min_poll() -> Duration {
    Duration::from_millis(100)
}
pub(super) fn default_slow() -> Duration {
    Duration::from_secs(60)
}
pub(super) fn default_max_registers() -> u16 {
    125
}
pub(super) fn default_max_write_registers() -> u16 {
    123
}
pub(super) fn default_max_bits() -> u16 {
    2000
}
pub(super) fn default_max_write_bits() -> u16 {
    1968
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct LineSection {
    #[serde(default = "default_baud")]
    pub(super) baud: u32,
    #[serde(default = "default_parity")]
    pub(super) parity: String,
    #[serde(default = "default_address_range")]
    pub(super) address_range: [u8; 2],
    pub(super) default_address: Option<u8>,
    #[serde(default = "default_min_poll", with = "humantime_serde")]
    pub(super) min_poll_interval: Duration,
    #[serde(default, with = "humantime_serde")]
    pub(super) poll_interval: Option<Duration>,
    #[serde(default = "default_slow", with = "humantime_serde")]
    pub(super) slow_interval: Duration,
    #[serde(default, with = "humantime_serde")]
    pub(super) startup_delay: Option<Duration>,
    #[serde(default = "default_max_registers")]
    pub(super) max_read_registers: u16,
    #[serde(default = "default_max_write_registers")]
    pub(super) max_write_registers: u16,
    #[serde(default = "default_max_bits")]
    pub(super) max_read_bits: u16,
    #[serde(default = "default_max_write_bits")]
    pub(super) max_write_bits: u16,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct BlockSection {
    pub(super) name: String,
    pub(super) function: u8,
    /// In the profile's `register_numbers`.
    pub(super) start: u32,
    pub(super) count: u16,
    #[serde(default = "default_poll")]
    pub(super) poll: String,
    /// The block is always read with exactly this request (the vendor's own example), never
    /// split into the runs its fields use: gaps are readable on this device.
    #[serde(default)]
    pub(super) read_whole: bool,
    /// Any part of the block read on its own answers the same items as the whole block holds
    /// at those addresses (the device reads by address, not by offset from the start asked).
    #[serde(default)]
    pub(super) reads_linearly: bool,
}

pub(super) fn default_poll() -> String {
    "fast".into()
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct WriteFrameSection {
    pub(super) name: String,
    pub(super) function: u8,
    /// Device address of the first coil or register written, in the profile's
    /// `register_numbers`.
    pub(super) address: u32,
    /// The block whose fresh read supplies the bits the command does not change.
    pub(super) block: String,
    /// Block offset of the first coil or register written.
    pub(super) offset: u16,
    pub(super) count: u16,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FieldSection {
    pub(super) name: String,
    pub(super) block: String,
    pub(super) offset: u16,
    pub(super) codec: CodecSection,
    #[serde(default)]
    pub(super) description: String,
    pub(super) unit: Option<String>,
    /// `[min, max]` for numbers: the allowed command range and the Home Assistant range.
    pub(super) range: Option<[f64; 2]>,
    /// Integers accepted besides the range, e.g. `[255]` where 255 means "disabled".
    #[serde(default)]
    pub(super) also: Vec<i64>,
    pub(super) write: Option<WriteSection>,
    #[serde(default)]
    pub(super) behaviour: Behaviour,
    #[serde(default, with = "humantime_serde")]
    pub(super) min_write_interval: Option<Duration>,
    #[serde(default, with = "humantime_serde")]
    pub(super) settle_window: Option<Duration>,
    /// Field name → value text: the read-back stops settling when every one of them holds
    /// (the valve's `motor = "stopped"`) and judges the value as it is then.
    #[serde(default)]
    pub(super) settle_until: BTreeMap<String, String>,
    /// A convenience view over bits that other fields own (the air shower's `wind`).
    #[serde(default)]
    pub(super) overlay: bool,
    /// A command value that shows what the field does (`gear = 8`), offered as an example by the
    /// demo; it must be a valid command for the field.
    pub(super) example: Option<String>,
    /// The name people read where the field name says too little (`PID invalid flags`).
    pub(super) label: Option<String>,
    /// The device-registry entry the field's value fills (serial number, versions).
    pub(super) identity: Option<IdentityKey>,
    #[serde(default)]
    pub(super) ha: HaSection,
    /// When the value is published (deadband, minimum and maximum interval).
    pub(super) publish: Option<RawPublish>,
}

/// The values of a field's `identity` key.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum IdentityKey {
    SerialNumber,
    HwVersion,
    SwVersion,
}

#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub(super) enum WriteSection {
    /// The name of a shared `[[write_frames]]` entry.
    Frame(String),
    /// A frame of the field's own registers or coils.
    Own(OwnWrite),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct OwnWrite {
    pub(super) function: u8,
    /// In the profile's `register_numbers`.
    pub(super) address: u32,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct HaSection {
    pub(super) component: Option<String>,
    pub(super) device_class: Option<String>,
    pub(super) state_class: Option<String>,
    pub(super) icon: Option<String>,
    pub(super) entity_category: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ForbiddenSection {
    /// Field name → value text; the combination is refused when every one of them holds.
    pub(super) when: BTreeMap<String, String>,
    pub(super) reason: String,
}

#[derive(Debug, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub(super) enum CodecSection {
    Bit {
        bit: u8,
        #[serde(default)]
        invert: bool,
    },
    Bits {
        bit: u8,
        width: u8,
        #[serde(default)]
        options: Vec<String>,
    },
    Coil {
        #[serde(default)]
        invert: bool,
    },
    Coils {
        width: u8,
        #[serde(default)]
        options: Vec<String>,
    },
    U8(NumberSection),
    I8(NumberSection),
    U16(NumberSection),
    I16(NumberSection),
    U32(NumberSection),
    I32(NumberSection),
    F32(NumberSection),
    U64(NumberSection),
    I64(NumberSection),
    F64(NumberSection),
    Bcd {
        int_digits: u8,
        frac_digits: u8,
    },
    Char,
    Bytes {
        registers: u16,
        #[serde(default)]
        format: ByteFormat,
        #[serde(default)]
        separator: String,
        #[serde(default)]
        bytes: ByteSource,
    },
    String {
        registers: u16,
        #[serde(default)]
        byte_order: ByteOrder,
        #[serde(default)]
        encoding: Encoding,
    },
    /// A whole register (or two) holding a code; `values` names the codes (keys are the codes
    /// as TOML keys: `0`, `3`, `0x10`).
    Enum {
        values: BTreeMap<String, String>,
        #[serde(default = "one_register")]
        registers: u16,
        word_order: Option<WordOrder>,
        #[serde(default)]
        unknown: UnknownCode,
    },
}

fn one_register() -> u16 {
    1
}

impl CodecSection {
    /// The field a number codec's `scale_by` names, if any.
    pub(super) fn scale_by(&self) -> Option<&str> {
        match self {
            Self::U8(keys)
            | Self::I8(keys)
            | Self::U16(keys)
            | Self::I16(keys)
            | Self::U32(keys)
            | Self::I32(keys)
            | Self::F32(keys)
            | Self::U64(keys)
            | Self::I64(keys)
            | Self::F64(keys) => keys.scale_by.as_deref(),
            _ => None,
        }
    }
}

/// One entry of a number codec's `invalid` list, as written.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(untagged)]
pub(super) enum InvalidMark {
    Integer(i64),
    Float(f64),
    Word(String),
}

/// The keys of the number codecs (`u8` … `f64`); which of them a type takes is checked by
/// the compiler (`byte` only for 8-bit codecs, `word_order` only over several registers).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct NumberSection {
    #[serde(default)]
    pub(super) decimals: u8,
    /// The value of one raw count (default one unit of the last shown place).
    pub(super) scale: Option<f64>,
    /// Added after scaling; a whole number of the last shown place.
    pub(super) offset: Option<f64>,
    /// Values that mean "no value": raw integers (`[0x8000]`, written unsigned or signed) for
    /// the integer codecs, values (`-1.0`, `"nan"`, `"inf"`, `"-inf"`) for the floats.
    #[serde(default)]
    pub(super) invalid: Vec<InvalidMark>,
    /// A field of the same device holding the power of ten the value is multiplied by.
    pub(super) scale_by: Option<String>,
    pub(super) word_order: Option<WordOrder>,
    pub(super) byte_order: Option<ByteOrder>,
    pub(super) byte: Option<BytePlace>,
}

/// A command interface: one FC16 frame of fixed words and parameters, and optionally the
/// result register read after it.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ActionSection {
    pub(super) name: String,
    /// Address of the frame's first register, in the profile's `register_numbers`.
    pub(super) address: u32,
    /// The frame's words in order: a fixed word, or the name of a parameter.
    pub(super) registers: Vec<ActionWord>,
    /// Parameter name → its type and range (a parameter not listed is a u16 of any value).
    #[serde(default)]
    pub(super) params: BTreeMap<String, ParamSection>,
    pub(super) result: Option<ResultSection>,
    #[serde(default)]
    pub(super) description: String,
}

/// One entry of an action's `registers`.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub(super) enum ActionWord {
    Fixed(i64),
    Param(String),
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ParamSection {
    #[serde(default, rename = "type")]
    pub(super) ty: ParamType,
    pub(super) range: Option<[i64; 2]>,
    pub(super) word_order: Option<WordOrder>,
    #[serde(default)]
    pub(super) description: String,
    pub(super) unit: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ResultSection {
    /// Address of the result register, in the profile's `register_numbers`.
    pub(super) address: u32,
    /// 3 (holding register) or 4 (input register).
    #[serde(default = "default_result_function")]
    pub(super) function: u8,
    /// Code (as a TOML key) → its name.
    #[serde(default)]
    pub(super) codes: BTreeMap<String, String>,
    /// The codes that mean success (default `[0]`).
    pub(super) success: Option<Vec<i64>>,
}

pub(super) fn default_result_function() -> u8 {
    3
}
