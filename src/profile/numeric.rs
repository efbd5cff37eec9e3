//! The numeric register codecs (`u8` … `f64`): how raw registers become an exact number and
//! back. One raw count is worth `factor` units of the last shown place; `offset` is added after
//! scaling; a `scale_by` field's value is multiplied by ten to the power its exponent field
//! holds; raw values listed as `invalid` are the device's "no value" marks. Integers all the way
//! (i128), so values stay exact; only `f32`/`f64` pass through binary floating point, as the
//! device itself holds them.

use super::registers::RegisterLayout;
use super::value::Value;

/// Which byte of a register an 8-bit codec takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BytePlace {
    High,
    Low,
}

/// Register number types.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NumberType {
    U8(BytePlace),
    I8(BytePlace),
    U16,
    I16,
    U32,
    I32,
    F32,
    U64,
    I64,
    F64,
}

impl NumberType {
    /// Registers the number covers.
    pub fn registers(self) -> u16 {
        match self {
            Self::U8(_) | Self::I8(_) | Self::U16 | Self::I16 => 1,
            Self::U32 | Self::I32 | Self::F32 => 2,
            Self::U64 | Self::I64 | Self::F64 => 4,
        }
    }

    pub fn is_float(self) -> bool {
        matches!(self, Self::F32 | Self::F64)
    }

    /// Bits of the raw value.
    fn bits(self) -> u32 {
        match self {
            Self::U8(_) | Self::I8(_) => 8,
            other => 16 * u32::from(other.registers()),
        }
    }

    /// The raw integers the type holds; None for floats.
    pub fn raw_range(self) -> Option<(i128, i128)> {
        Some(match self {
            Self::U8(_) => (0, i128::from(u8::MAX)),
            Self::I8(_) => (i128::from(i8::MIN), i128::from(i8::MAX)),
            Self::U16 => (0, i128::from(u16::MAX)),
            Self::I16 => (i128::from(i16::MIN), i128::from(i16::MAX)),
            Self::U32 => (0, i128::from(u32::MAX)),
            Self::I32 => (i128::from(i32::MIN), i128::from(i32::MAX)),
            Self::U64 => (0, i128::from(u64::MAX)),
            Self::I64 => (i128::from(i64::MIN), i128::from(i64::MAX)),
            Self::F32 | Self::F64 => return None,
        })
    }

    /// The raw bits of `value` (an integer of the type's range, written signed or unsigned:
    /// `-32768` and `0x8000` are the same i16 mark). None when it fits neither way.
    pub fn raw_bits_of(self, value: i128) -> Option<u64> {
        let (min, max) = self.raw_range()?;
        let unsigned_max = (1i128 << self.bits()) - 1;
        let signed_min = -(1i128 << (self.bits() - 1));
        if !(signed_min.min(min)..=unsigned_max.max(max)).contains(&value) {
            return None;
        }
        Some((value & unsigned_max) as u64)
    }

    /// The mask of the register bits an 8-bit codec owns; the whole register otherwise.
    pub fn mask(self) -> u16 {
        match self {
            Self::U8(BytePlace::High) | Self::I8(BytePlace::High) => 0xFF00,
            Self::U8(BytePlace::Low) | Self::I8(BytePlace::Low) => 0x00FF,
            _ => 0xFFFF,
        }
    }
}

/// The exponent a `scale_by` field is read or written with, as the exponent field read it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Exponent {
    /// The field has no `scale_by`.
    None,
    /// A power of ten, -10…10.
    Power(i8),
    /// The exponent field holds one of its `invalid` marks: the value is unavailable too.
    Unavailable,
    /// The exponent was not read with the value, or is not a power -10…10: invalid data.
    Unusable(String),
}

/// Exponents a `scale_by` field may hold (SunSpec's scale factors).
pub const EXPONENTS: std::ops::RangeInclusive<i8> = -10..=10;

impl Exponent {
    /// The exponent a `scale_by` field's value is read with, from its exponent field's value.
    pub fn from_value(value: Result<&Value, String>) -> Self {
        match value {
            Ok(Value::Unavailable) => Self::Unavailable,
            Ok(Value::Int(power)) => match i8::try_from(*power) {
                Ok(power) if EXPONENTS.contains(&power) => Self::Power(power),
                _ => Self::Unusable(format!("exponent {power} is outside -10…10")),
            },
            Ok(other) => Self::Unusable(format!("exponent {other:?} is not an integer")),
            Err(why) => Self::Unusable(format!("no exponent: {why}")),
        }
    }
}

/// Why a numeric field has no value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NumberError {
    /// The raw value is one of the field's `invalid` marks, or its exponent's.
    Unavailable,
    Invalid(String),
}

/// A compiled numeric codec.
#[derive(Debug, Clone, PartialEq)]
pub struct NumberCodec {
    pub ty: NumberType,
    pub layout: RegisterLayout,
    /// Places shown (before any exponent).
    pub decimals: u8,
    /// Units of the last shown place one raw count is worth (`decimals` 1, `scale` 0.5 → 5).
    pub factor: i64,
    /// Added after scaling, in units of the last shown place.
    pub offset: i128,
    /// Raw bits that mean "no value" (`0x8000`).
    pub invalid: Vec<u64>,
    /// The value is multiplied by 10^exponent, the exponent read from another field.
    pub scaled_by_exponent: bool,
}

fn pow10(places: u8) -> i128 {
    10i128.pow(u32::from(places))
}

impl NumberCodec {
    /// The most decimals a value of this codec can have: its own, plus ten for a `scale_by`
    /// field read with exponent -10.
    pub fn max_precision(&self) -> u8 {
        if self.scaled_by_exponent {
            self.decimals + EXPONENTS.start().unsigned_abs()
        } else {
            self.decimals
        }
    }

    /// The precision and multiplier of a value read with `exponent`: a negative exponent adds
    /// places, a positive one multiplies the count.
    fn shape(&self, exponent: i8) -> (u8, i128) {
        if exponent < 0 {
            (self.decimals + exponent.unsigned_abs(), 1)
        } else {
            (self.decimals, pow10(exponent.unsigned_abs()))
        }
    }

    fn power(&self, exponent: &Exponent) -> Result<i8, NumberError> {
        match (self.scaled_by_exponent, exponent) {
            (false, _) => Ok(0),
            (true, Exponent::Power(power)) => Ok(*power),
            (true, Exponent::Unavailable) => Err(NumberError::Unavailable),
            (true, Exponent::Unusable(why)) => Err(NumberError::Invalid(why.clone())),
            (true, Exponent::None) => Err(NumberError::Invalid("no exponent".to_string())),
        }
    }

    /// The raw bits of the number in `words` (the field's registers as read).
    fn raw_bits(&self, words: &[u16]) -> u64 {
        let first = words.first().copied().unwrap_or(0);
        match self.ty {
            NumberType::U8(place) | NumberType::I8(place) => match place {
                BytePlace::High => u64::from(first >> 8),
                BytePlace::Low => u64::from(first & 0xFF),
            },
            _ => self.layout.join(words),
        }
    }

    /// Decodes the field's registers; `exponent` is what its `scale_by` field read.
    pub fn decode(&self, words: &[u16], exponent: &Exponent) -> Result<Value, NumberError> {
        let bits = self.raw_bits(words);
        if self.invalid.contains(&bits) {
            return Err(NumberError::Unavailable);
        }
        let power = self.power(exponent)?;
        let counts = match self.ty {
            NumberType::U8(_) | NumberType::U16 | NumberType::U32 | NumberType::U64 => {
                i128::from(bits)
            }
            NumberType::I8(_) => i128::from(bits as u8 as i8),
            NumberType::I16 => i128::from(bits as u16 as i16),
            NumberType::I32 => i128::from(bits as u32 as i32),
            NumberType::I64 => i128::from(bits as i64),
            NumberType::F32 => {
                return self.decode_float(f64::from(f32::from_bits(bits as u32)), power)
            }
            NumberType::F64 => return self.decode_float(f64::from_bits(bits), power),
        };
        // At most 2^64 × 10^9 × 10^10 before the offset: far inside i128.
        let (precision, multiplier) = self.shape(power);
        let offset = self.offset * pow10(precision - self.decimals);
        let scaled = counts * i128::from(self.factor) * multiplier + offset;
        Ok(self.value(scaled, precision))
    }

    fn value(&self, scaled: i128, precision: u8) -> Value {
        if precision == 0 && !self.scaled_by_exponent {
            Value::Int(scaled)
        } else {
            Value::Decimal { scaled, precision }
        }
    }

    /// A float as the nearest value at the shown places (the decimal expansion of the float
    /// itself, correctly rounded, not of a product that rounds twice).
    fn decode_float(&self, float: f64, power: i8) -> Result<Value, NumberError> {
        if !float.is_finite() {
            return Err(NumberError::Invalid(format!("not a number: {float}")));
        }
        let (precision, multiplier) = self.shape(power);
        let out_of_range = || NumberError::Invalid(format!("out of range: {float}"));
        let counts = if i128::from(self.factor) == pow10(self.decimals) {
            let text = format!("{float:.*}", usize::from(self.decimals));
            super::number::DecimalText::parse(&text)
                .and_then(|number| number.scaled(self.decimals).ok())
                .ok_or_else(out_of_range)?
        } else {
            let product = (float * self.factor as f64).round();
            if product.abs() > 1e30 {
                return Err(out_of_range());
            }
            product as i128
        };
        let offset = self.offset * pow10(precision - self.decimals);
        let scaled = counts
            .checked_mul(multiplier)
            .and_then(|scaled| scaled.checked_add(offset))
            .ok_or_else(out_of_range)?;
        Ok(self.value(scaled, precision))
    }

    /// The registers (in the order written) that hold `value`, read back with `exponent`.
    pub fn encode(&self, value: &Value, exponent: &Exponent) -> Result<Vec<u16>, String> {
        let power = self.power(exponent).map_err(|error| match error {
            NumberError::Unavailable => "the exponent field reads unavailable".to_string(),
            NumberError::Invalid(why) => why,
        })?;
        let (precision, multiplier) = self.shape(power);
        let scaled = at_precision(value, precision)?;
        let offset = self.offset * pow10(precision - self.decimals);
        let unscaled = scaled - offset;
        let divisor = i128::from(self.factor) * multiplier;
        if self.ty.is_float() {
            // The float is `unscaled / divisor`; with the default scale that is an exact
            // decimal, parsed to the nearest float in one rounding.
            let text = if i128::from(self.factor) == pow10(self.decimals) {
                Value::Decimal {
                    scaled: unscaled,
                    precision: self.decimals + (power.max(0).unsigned_abs()),
                }
                .to_text()
            } else {
                (unscaled as f64 / divisor as f64).to_string()
            };
            return self.encode_float(&text);
        }
        if unscaled % divisor != 0 {
            return Err(format!(
                "{} is not a multiple of the step {}",
                value.to_text(),
                Value::Decimal {
                    scaled: divisor,
                    precision
                }
                .to_text()
            ));
        }
        let counts = unscaled / divisor;
        let bits = self
            .ty
            .raw_range()
            .filter(|(min, max)| (*min..=*max).contains(&counts))
            .and_then(|_| self.ty.raw_bits_of(counts))
            .ok_or_else(|| format!("{} is out of the codec's range", value.to_text()))?;
        Ok(match self.ty {
            NumberType::U8(BytePlace::High) | NumberType::I8(BytePlace::High) => {
                vec![(bits as u16) << 8]
            }
            NumberType::U8(BytePlace::Low) | NumberType::I8(BytePlace::Low) => vec![bits as u16],
            ty => self.layout.split(bits, ty.registers()),
        })
    }

    fn encode_float(&self, text: &str) -> Result<Vec<u16>, String> {
        let bits = match self.ty {
            NumberType::F32 => text
                .parse::<f32>()
                .ok()
                .filter(|float| float.is_finite())
                .map(|float| u64::from(float.to_bits())),
            _ => text
                .parse::<f64>()
                .ok()
                .filter(|float| float.is_finite())
                .map(f64::to_bits),
        }
        .ok_or_else(|| format!("{text} does not fit the float"))?;
        Ok(self.layout.split(bits, self.ty.registers()))
    }
}

/// `value` in units of 10^-`precision`, exactly; refused when it has more places.
pub fn at_precision(value: &Value, precision: u8) -> Result<i128, String> {
    let too_large = || "number too large".to_string();
    match value {
        Value::Int(v) => v.checked_mul(pow10(precision)).ok_or_else(too_large),
        Value::Decimal {
            scaled,
            precision: places,
        } if *places <= precision => scaled
            .checked_mul(pow10(precision - places))
            .ok_or_else(too_large),
        Value::Decimal {
            scaled,
            precision: places,
        } => {
            let divisor = pow10(places - precision);
            if scaled % divisor != 0 {
                return Err(format!("{} has too many decimals", value.to_text()));
            }
            Ok(scaled / divisor)
        }
        other => Err(format!("{other:?} is not a number")),
    }
}
