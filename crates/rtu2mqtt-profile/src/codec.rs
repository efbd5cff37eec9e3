//! The closed set of field codecs: bits, bit groups with enumerations, inverted bits, numbers
//! of one byte to four registers ([`super::numeric`]), packed BCD integer + fraction pairs,
//! low-byte chars, byte strings, text ([`super::text`]), coils.
//!
//! A codec turns the raw registers or coils at a field's place into a [`Value`] and back into
//! a [`RawPatch`] (what to change in the block image). Command text is parsed here too, against
//! the field's [`FieldKind`], so that every refusal names the field and the allowed values.
//! Nothing here knows about frames, devices or time.

use serde::Deserialize;

use super::bcd::{self, BcdError};
use super::enumeration::{EnumCodec, UnknownCode};
use super::field::{FieldInfo, FieldKind};
use super::number::{self, DecimalText, ScaleError};
use super::numeric::{at_precision, Exponent, NumberCodec, NumberError, NumberType, EXPONENTS};
use super::registers::ByteOrder;
use super::rejection::Rejection;
use super::text::{self, Encoding};
use crate::value::Value;

/// Why a field has no value in a block answer.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FieldError {
    /// A `bcd` field's register (the raw word here) holds a nibble above 9.
    #[error("invalid BCD digit in {0:#06x}")]
    InvalidBcd(u16),
    /// Any other reason, as a sentence: an answer shorter than the block, text that is not
    /// valid in its `encoding`, a raw value no number of the codec stands for, a `scale_by`
    /// exponent that was not read or is out of range.
    #[error("{0}")]
    Invalid(String),
}

/// How a byte string is shown.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum ByteFormat {
    /// Two upper-case hex digits per byte (`0A1B2C`).
    #[default]
    Hex,
    /// Each byte in decimal (`0:1:30` with separator `:`).
    Decimal,
}

/// Which bytes of each register a byte string takes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum ByteSource {
    /// The low byte only (the "Char" registers of many Chinese devices).
    #[default]
    Low,
    /// High byte, then low byte.
    Both,
}

/// A compiled field codec.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum FieldCodec {
    /// One bit of a word; `invert`: ON when the bit is 0.
    Bit { bit: u8, invert: bool },
    /// `width` bits from `bit` upwards, as an integer or, with options, an enumeration
    /// (option i ⇔ raw value i).
    Bits {
        bit: u8,
        width: u8,
        options: Vec<String>,
    },
    /// One coil or discrete input.
    Coil { invert: bool },
    /// `width` coils from the field's offset (coil i is bit i of the raw value), as an integer
    /// or an enumeration.
    Coils { width: u8, options: Vec<String> },
    /// A number of one byte to four registers shown with `decimals` places; one raw count is
    /// worth `factor` units of the last place (`decimals` 2, `factor` 1: raw 1234 → 12.34;
    /// `decimals` 1, `factor` 5, i.e. scale 0.5: raw 3 → 1.5), plus an offset, times a power of
    /// ten read from another field for `scale_by`. Integers all the way, so values stay exact.
    Number(NumberCodec),
    /// Packed BCD over two registers: integer part, then fraction part.
    Bcd { int_digits: u8, frac_digits: u8 },
    /// The low byte of one register.
    Char,
    /// A read-only byte string over `registers` registers.
    Bytes {
        registers: u16,
        format: ByteFormat,
        separator: String,
        bytes: ByteSource,
    },
    /// Read-only text over `registers` registers, two characters to a register.
    Text {
        registers: u16,
        byte_order: ByteOrder,
        encoding: Encoding,
    },
    /// A code over one or two whole registers, its codes named sparsely.
    Enum(EnumCodec),
}

/// A change to a block image: at `offset` (block-relative), replace the bits in `mask` with
/// `bits`. For coil blocks `mask` is 1 and `bits` 0 or 1.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawPatch {
    /// The register or coil changed, counted from the block's start.
    pub offset: u16,
    /// The bits of that register the field owns (`0xFFFF` for a whole register, 1 for a coil).
    pub mask: u16,
    /// The new value of the bits in `mask`; bits outside `mask` are ignored.
    pub bits: u16,
}

/// The raw data of a block: words or bits.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BlockImage {
    /// A holding- or input-register block (FC 03/04): one word per register.
    Words(Vec<u16>),
    /// A coil or discrete-input block (FC 01/02): one bool per coil, `true` when on.
    Bits(Vec<bool>),
}

impl BlockImage {
    /// Applies patches; places outside the image are ignored (validated profiles never make them).
    pub fn apply(&mut self, patches: &[RawPatch]) {
        for patch in patches {
            let index = usize::from(patch.offset);
            match self {
                Self::Words(words) => {
                    if let Some(word) = words.get_mut(index) {
                        *word = (*word & !patch.mask) | (patch.bits & patch.mask);
                    }
                }
                Self::Bits(bits) => {
                    if let Some(bit) = bits.get_mut(index) {
                        if patch.mask & 1 != 0 {
                            *bit = patch.bits & 1 != 0;
                        }
                    }
                }
            }
        }
    }
}

fn pow10(decimals: u8) -> i64 {
    10i64.pow(u32::from(decimals))
}

fn enum_or_int(raw: u16, options: &[String]) -> Result<Value, FieldError> {
    if options.is_empty() {
        return Ok(Value::Int(i128::from(raw)));
    }
    options
        .get(usize::from(raw))
        .map(|word| Value::Enum(word.clone()))
        .ok_or_else(|| FieldError::Invalid(format!("raw value {raw} has no option")))
}

fn raw_of_enum(value: &Value, options: &[String], width: u8) -> Result<u16, String> {
    let limit = (1u32 << width) - 1;
    let raw = match value {
        Value::Enum(word) if !options.is_empty() => options
            .iter()
            .position(|o| o == word)
            .ok_or_else(|| format!("unknown option `{word}`"))?,
        Value::Int(v) if options.is_empty() && *v >= 0 && *v <= i128::from(limit) => *v as usize,
        other => return Err(format!("{other:?} does not fit {width} bits")),
    };
    u16::try_from(raw).map_err(|_| "option index too large".to_string())
}

/// Decodes `digits` packed BCD digits of `word`; digits above them must be zero.
fn bcd_digits(word: u16, digits: u8) -> Result<i64, FieldError> {
    bcd::decode(word, digits)
        .map(i64::from)
        .map_err(|error| match error {
            BcdError::NotDecimal => FieldError::InvalidBcd(word),
            BcdError::TooManyDigits => FieldError::Invalid(format!(
                "BCD word {word:#06x} has more than {digits} digits"
            )),
        })
}

/// One word of a BCD pair; the caller has already bounded the value to the pair's digits.
fn to_bcd(value: i128) -> Result<u16, String> {
    u16::try_from(value)
        .ok()
        .and_then(|value| bcd::encode(value, bcd::WORD_DIGITS))
        .ok_or_else(|| format!("{value} does not fit four BCD digits"))
}

impl FieldCodec {
    /// Registers or coils the field covers.
    pub(crate) fn width(&self) -> u16 {
        match self {
            Self::Bit { .. } | Self::Bits { .. } | Self::Coil { .. } | Self::Char => 1,
            Self::Coils { width, .. } => u16::from(*width),
            Self::Number(number) => number.ty.registers(),
            Self::Bcd { .. } => 2,
            Self::Bytes { registers, .. } | Self::Text { registers, .. } => *registers,
            Self::Enum(codes) => codes.registers,
        }
    }

    /// True for codecs of coil / discrete-input blocks.
    pub(crate) fn is_bit_codec(&self) -> bool {
        matches!(self, Self::Coil { .. } | Self::Coils { .. })
    }

    pub(crate) fn is_writable(&self) -> bool {
        !matches!(self, Self::Bytes { .. } | Self::Text { .. })
    }

    /// Whether the device can report "no value" through this codec (see
    /// [`FieldInfo::may_be_unavailable`]).
    pub(crate) fn may_be_unavailable(&self) -> bool {
        match self {
            Self::Number(number) => {
                number.ty.is_float() || !number.invalid.is_empty() || number.scaled_by_exponent
            }
            Self::Text { .. } => true,
            Self::Enum(codes) => codes.unknown == UnknownCode::Invalid,
            _ => false,
        }
    }

    /// An enum publishing the codes it does not name as numbers.
    pub(crate) fn unnamed_codes_as_numbers(&self) -> bool {
        matches!(self, Self::Enum(codes) if codes.unknown == UnknownCode::PublishNumber)
    }

    /// True for a `scale_by` number: it is read and written with its exponent field's value.
    pub(crate) fn needs_exponent(&self) -> bool {
        matches!(self, Self::Number(number) if number.scaled_by_exponent)
    }

    /// The bits the field occupies: (block offset, mask) for each register or coil.
    pub(crate) fn footprint(&self, offset: u16) -> Vec<(u16, u16)> {
        match self {
            Self::Bit { bit, .. } => vec![(offset, 1 << bit)],
            Self::Bits { bit, width, .. } => {
                vec![(offset, (((1u32 << width) - 1) << bit) as u16)]
            }
            Self::Char => vec![(offset, 0xFFFF)],
            Self::Number(number) if number.ty.registers() == 1 => {
                vec![(offset, number.ty.mask())]
            }
            _ if self.is_bit_codec() => (0..self.width()).map(|i| (offset + i, 1)).collect(),
            _ => (0..self.width()).map(|i| (offset + i, 0xFFFF)).collect(),
        }
    }

    /// The smallest change a number of this codec can make: one raw count (`scale = 5` → 5,
    /// `decimals = 1, scale = 0.5` → 0.5, BCD with two fraction digits → 0.01). None for
    /// fields that are not numbers (booleans, enumerations, text).
    pub(crate) fn step(&self) -> Option<Value> {
        let last_place = |decimals: u8, counts: i128| {
            if decimals == 0 {
                Value::Int(counts)
            } else {
                Value::Decimal {
                    scaled: counts,
                    precision: decimals,
                }
            }
        };
        match self {
            Self::Bit { .. }
            | Self::Coil { .. }
            | Self::Bytes { .. }
            | Self::Text { .. }
            | Self::Enum(_) => None,
            Self::Bits { options, .. } | Self::Coils { options, .. } => {
                options.is_empty().then_some(Value::Int(1))
            }
            Self::Char => Some(Value::Int(1)),
            // A float holds any value: commands keep to the shown places.
            Self::Number(number) if number.ty.is_float() => Some(last_place(number.decimals, 1)),
            // A `scale_by` number's real step follows its exponent (the slot refuses what the
            // exponent read there cannot hold); shown is one raw count at exponent 0.
            Self::Number(number) => Some(last_place(number.decimals, i128::from(number.factor))),
            Self::Bcd { frac_digits, .. } => Some(last_place(*frac_digits, 1)),
        }
    }

    /// The kind and widest range the codec can represent.
    pub(crate) fn natural_kind(&self) -> FieldKind {
        match self {
            Self::Bit { .. } | Self::Coil { .. } => FieldKind::Bool,
            Self::Bits { width, options, .. } | Self::Coils { width, options } => {
                if options.is_empty() {
                    FieldKind::Integer {
                        min: 0,
                        max: (1i128 << width) - 1,
                    }
                } else {
                    FieldKind::Enum {
                        options: options.clone(),
                    }
                }
            }
            Self::Char => FieldKind::Integer { min: 0, max: 255 },
            Self::Number(number) => number_kind(number),
            Self::Bcd {
                int_digits,
                frac_digits,
            } => {
                let scaled_max = pow10(int_digits + frac_digits) - 1;
                FieldKind::Decimal {
                    min: 0.0,
                    max: scaled_max as f64 / pow10(*frac_digits) as f64,
                    precision: *frac_digits,
                }
            }
            Self::Bytes { .. } | Self::Text { .. } => FieldKind::Text,
            Self::Enum(codes) => FieldKind::Enum {
                options: codes.names(),
            },
        }
    }

    /// Decodes the field at `offset` of a block image (a `scale_by` number has no exponent
    /// this way and is invalid data: see [`FieldCodec::decode_with`]).
    pub(crate) fn decode(&self, image: &BlockImage, offset: u16) -> Result<Value, FieldError> {
        self.decode_with(image, offset, &Exponent::None)
    }

    /// Decodes the field at `offset` of a block image; `exponent` is what the field's
    /// `scale_by` field read in the same answer.
    pub(crate) fn decode_with(
        &self,
        image: &BlockImage,
        offset: u16,
        exponent: &Exponent,
    ) -> Result<Value, FieldError> {
        let start = usize::from(offset);
        let end = start + usize::from(self.width());
        let short = || FieldError::Invalid("the answer is shorter than the block".to_string());
        match image {
            BlockImage::Words(words) => {
                let words = words.get(start..end).ok_or_else(short)?;
                self.decode_words(words, exponent)
            }
            BlockImage::Bits(bits) => {
                let bits = bits.get(start..end).ok_or_else(short)?;
                match self {
                    Self::Coil { invert } => Ok(Value::Bool(bits[0] != *invert)),
                    Self::Coils { options, .. } => {
                        let raw = bits
                            .iter()
                            .enumerate()
                            .fold(0u16, |acc, (i, b)| acc | (u16::from(*b) << i));
                        enum_or_int(raw, options)
                    }
                    _ => Err(FieldError::Invalid(
                        "register codec on a bit block".to_string(),
                    )),
                }
            }
        }
    }

    fn decode_words(&self, words: &[u16], exponent: &Exponent) -> Result<Value, FieldError> {
        let first = words[0];
        match self {
            Self::Bit { bit, invert } => Ok(Value::Bool(((first >> bit) & 1 == 1) != *invert)),
            Self::Bits {
                bit,
                width,
                options,
            } => {
                let raw = (u32::from(first) >> bit) & ((1u32 << width) - 1);
                enum_or_int(raw as u16, options)
            }
            Self::Char => Ok(Value::Int(i128::from(first & 0xFF))),
            Self::Number(number) => match number.decode(words, exponent) {
                Ok(value) => Ok(value),
                Err(NumberError::Unavailable) => Ok(Value::Unavailable),
                Err(NumberError::Invalid(why)) => Err(FieldError::Invalid(why)),
            },
            Self::Bcd {
                int_digits,
                frac_digits,
            } => {
                let integer = bcd_digits(words[0], *int_digits)?;
                let fraction = bcd_digits(words[1], *frac_digits)?;
                Ok(Value::Decimal {
                    scaled: i128::from(integer * pow10(*frac_digits) + fraction),
                    precision: *frac_digits,
                })
            }
            Self::Bytes {
                format,
                separator,
                bytes,
                ..
            } => {
                let raw: Vec<u8> = words
                    .iter()
                    .flat_map(|w| match bytes {
                        ByteSource::Low => vec![(w & 0xFF) as u8],
                        ByteSource::Both => vec![(w >> 8) as u8, (w & 0xFF) as u8],
                    })
                    .collect();
                let parts: Vec<String> = raw
                    .iter()
                    .map(|b| match format {
                        ByteFormat::Hex => format!("{b:02X}"),
                        ByteFormat::Decimal => b.to_string(),
                    })
                    .collect();
                Ok(Value::Text(parts.join(separator)))
            }
            Self::Text {
                byte_order,
                encoding,
                ..
            } => text::decode(words, *byte_order, *encoding)
                // No characters at all (SunSpec's "not implemented" string is all NULs) is no
                // value: an empty retained payload would clear the field's topic instead.
                .map(|text| {
                    if text.is_empty() {
                        Value::Unavailable
                    } else {
                        Value::Text(text)
                    }
                })
                .map_err(|error| FieldError::Invalid(error.to_string())),
            Self::Enum(codes) => Ok(codes.decode(words)),
            Self::Coil { .. } | Self::Coils { .. } => Err(FieldError::Invalid(
                "bit codec on a register block".to_string(),
            )),
        }
    }

    /// The raw change that writes `value` into the field's place (`offset` block-relative).
    /// The value must already have the field's kind (see [`parse_command`]).
    pub(crate) fn encode(&self, offset: u16, value: &Value) -> Result<Vec<RawPatch>, String> {
        self.encode_with(offset, value, &Exponent::None)
    }

    /// [`FieldCodec::encode`] for a value read back with `exponent` (a `scale_by` number).
    pub(crate) fn encode_with(
        &self,
        offset: u16,
        value: &Value,
        exponent: &Exponent,
    ) -> Result<Vec<RawPatch>, String> {
        let word = |rel: u16, mask: u16, bits: u16| RawPatch {
            offset: offset + rel,
            mask,
            bits,
        };
        let number = |decimals: u8| -> Result<i128, String> { at_precision(value, decimals) };
        let fits = |raw: i128, min: i128, max: i128| {
            if raw < min || raw > max {
                Err(format!("{} is out of the codec's range", value.to_text()))
            } else {
                Ok(raw)
            }
        };
        match self {
            Self::Bit { bit, invert } => {
                let Value::Bool(on) = value else {
                    return Err(format!("{value:?} is not ON/OFF"));
                };
                let set = *on != *invert;
                Ok(vec![word(0, 1 << bit, if set { 1 << bit } else { 0 })])
            }
            Self::Bits {
                bit,
                width,
                options,
            } => {
                let raw = raw_of_enum(value, options, *width)?;
                let mask = (((1u32 << width) - 1) << bit) as u16;
                Ok(vec![word(0, mask, raw << bit)])
            }
            Self::Coil { invert } => {
                let Value::Bool(on) = value else {
                    return Err(format!("{value:?} is not ON/OFF"));
                };
                Ok(vec![word(0, 1, u16::from(*on != *invert))])
            }
            Self::Coils { width, options } => {
                let raw = raw_of_enum(value, options, *width)?;
                Ok((0..u16::from(*width))
                    .map(|i| word(i, 1, (raw >> i) & 1))
                    .collect())
            }
            Self::Char => {
                let raw = fits(number(0)?, 0, 255)?;
                Ok(vec![word(0, 0xFFFF, raw as u16)])
            }
            Self::Number(number) => {
                let mask = number.ty.mask();
                Ok(number
                    .encode(value, exponent)?
                    .into_iter()
                    .zip(0u16..)
                    .map(|(bits, rel)| word(rel, mask, bits))
                    .collect())
            }
            Self::Bcd {
                int_digits,
                frac_digits,
            } => {
                let scaled = number(*frac_digits)?;
                let scaled = fits(scaled, 0, i128::from(pow10(int_digits + frac_digits)) - 1)?;
                let divisor = i128::from(pow10(*frac_digits));
                Ok(vec![
                    word(0, 0xFFFF, to_bcd(scaled / divisor)?),
                    word(1, 0xFFFF, to_bcd(scaled % divisor)?),
                ])
            }
            Self::Enum(codes) => Ok(codes
                .encode(value)?
                .into_iter()
                .zip(0u16..)
                .map(|(bits, rel)| word(rel, 0xFFFF, bits))
                .collect()),
            Self::Bytes { .. } => Err("a byte string is read-only".to_string()),
            // The device side only (simulators seeding a model name): commands never get here,
            // a string having no write rule and no command kind.
            Self::Text {
                registers,
                byte_order,
                ..
            } => {
                let Value::Text(text) = value else {
                    return Err(format!("{value:?} is not text"));
                };
                let words = text::encode(text, *registers, *byte_order)
                    .ok_or_else(|| format!("`{text}` does not fit {registers} registers"))?;
                Ok(words
                    .into_iter()
                    .zip(0u16..)
                    .map(|(bits, rel)| word(rel, 0xFFFF, bits))
                    .collect())
            }
        }
    }
}

/// The kind and widest range of a number codec (for a `scale_by` number, with the widest
/// exponent either way).
fn number_kind(number: &NumberCodec) -> FieldKind {
    let precision = number.max_precision();
    let Some((raw_min, raw_max)) = number.ty.raw_range() else {
        let (min, max) = match number.ty {
            NumberType::F32 => (f64::from(f32::MIN), f64::from(f32::MAX)),
            _ => (f64::MIN, f64::MAX),
        };
        return FieldKind::Decimal {
            min,
            max,
            precision,
        };
    };
    let widest = if number.scaled_by_exponent {
        10i128.pow(u32::from(EXPONENTS.end().unsigned_abs()))
    } else {
        1
    };
    let factor = i128::from(number.factor) * widest;
    let (min, max) = (
        raw_min * factor + number.offset,
        raw_max * factor + number.offset,
    );
    if precision == 0 && !number.scaled_by_exponent {
        FieldKind::Integer { min, max }
    } else {
        let scale = 10f64.powi(i32::from(number.decimals));
        FieldKind::Decimal {
            min: min as f64 / scale,
            max: max as f64 / scale,
            precision,
        }
    }
}

fn format_limit(value: f64, precision: u8) -> String {
    format!("{value:.*}", usize::from(precision))
}

/// `decimal` or `decimals`, as a count calls for.
pub(crate) fn decimals_word(precision: u8) -> &'static str {
    if precision == 1 {
        "decimal"
    } else {
        "decimals"
    }
}

/// Parses command text for a field against its kind and range. The accepted words:
/// booleans `ON`/`OFF`, `true`/`false`, `1`/`0` (any case, surrounding blanks ignored);
/// momentary fields `PRESS` or `ON` (also `true`, `1`); enumerations by their word (any case).
/// Integers and decimals are numbers as [`super::number`] defines them, read exactly: an
/// integer takes no decimals other than zeros (`8.0`), a decimal at most the field's precision
/// (`12.340` for two decimals, never `12.345`, at any magnitude).
pub(crate) fn parse_command(info: &FieldInfo, text: &str) -> Result<Value, Rejection> {
    let name = &info.name;
    let trimmed = text.trim();
    // Numbers are shown as sent (`got 11`), anything else quoted (`got "abc"`), shortened.
    let short: String = trimmed.chars().take(40).collect();
    let shown = if number::is_number(trimmed) {
        short
    } else {
        format!("\"{short}\"")
    };
    let lower = trimmed.to_ascii_lowercase();
    match &info.kind {
        FieldKind::Bool => match lower.as_str() {
            "on" | "true" | "1" => Ok(Value::Bool(true)),
            "off" | "false" | "0" => Ok(Value::Bool(false)),
            _ => Err(Rejection(format!(
                "{name} must be ON or OFF (also on/off, true/false, 1/0), got {shown}"
            ))),
        },
        FieldKind::Momentary => match lower.as_str() {
            "press" | "on" | "true" | "1" => Ok(Value::Bool(true)),
            _ => Err(Rejection(format!(
                "{name} is a button: send PRESS (or ON), got {shown}"
            ))),
        },
        FieldKind::Integer { min, max } => match number::wide_integer(trimmed) {
            Some(value) if (*min..=*max).contains(&value) => Ok(Value::Int(value)),
            _ => Err(Rejection(format!(
                "{name} must be an integer {min}–{max}, got {shown}"
            ))),
        },
        FieldKind::Decimal {
            min,
            max,
            precision,
        } => {
            let range = format!(
                "{}–{}",
                format_limit(*min, *precision),
                format_limit(*max, *precision)
            );
            let places = decimals_word(*precision);
            let refuse = || {
                Rejection(format!(
                    "{name} must be a number {range} with at most {precision} {places}, got {shown}"
                ))
            };
            let parsed = DecimalText::parse(trimmed).ok_or_else(refuse)?;
            let scaled = match parsed.scaled(*precision) {
                Ok(scaled) => scaled,
                Err(ScaleError::TooPrecise) => {
                    return Err(Rejection(format!(
                        "{name} takes at most {precision} {places} ({range}), got {shown}"
                    )))
                }
                Err(ScaleError::TooLarge) => return Err(refuse()),
            };
            // The limits are exact at the field's precision (they come from its raw range).
            let factor = pow10(*precision) as f64;
            let (low, high) = ((min * factor).round(), (max * factor).round());
            let value = scaled;
            if (value as f64) < low || (value as f64) > high {
                return Err(refuse());
            }
            Ok(Value::Decimal {
                scaled: value,
                precision: *precision,
            })
        }
        FieldKind::Enum { options } => options
            .iter()
            .find(|o| **o == lower)
            .map(|o| Value::Enum(o.clone()))
            .ok_or_else(|| {
                Rejection(format!(
                    "{name} must be one of {}, got {shown}",
                    options.join(", ")
                ))
            }),
        FieldKind::Text => Err(Rejection(format!("{name} is read-only text"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_string_of_no_characters_is_unavailable_not_an_empty_payload() {
        let model = FieldCodec::Text {
            registers: 2,
            byte_order: ByteOrder::HighFirst,
            encoding: Encoding::Ascii,
        };
        let decode = |words: Vec<u16>| model.decode(&BlockImage::Words(words), 0);
        assert_eq!(decode(vec![0, 0]), Ok(Value::Unavailable));
        assert_eq!(decode(vec![0x2020, 0x2000]), Ok(Value::Unavailable));
        assert_eq!(
            decode(vec![0x5344, 0x4D00]),
            Ok(Value::Text("SDM".to_string()))
        );
    }
}
