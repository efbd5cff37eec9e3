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
pub(crate) enum BytePlace {
    High,
    Low,
}

/// Register number types.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum NumberType {
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
    pub(crate) fn registers(self) -> u16 {
        match self {
            Self::U8(_) | Self::I8(_) | Self::U16 | Self::I16 => 1,
            Self::U32 | Self::I32 | Self::F32 => 2,
            Self::U64 | Self::I64 | Self::F64 => 4,
        }
    }

    pub(crate) fn is_float(self) -> bool {
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
    pub(crate) fn raw_range(self) -> Option<(i128, i128)> {
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
    pub(crate) fn raw_bits_of(self, value: i128) -> Option<u64> {
        let (min, max) = self.raw_range()?;
        let unsigned_max = (1i128 << self.bits()) - 1;
        let signed_min = -(1i128 << (self.bits() - 1));
        if !(signed_min.min(min)..=unsigned_max.max(max)).contains(&value) {
            return None;
        }
        Some((value & unsigned_max) as u64)
    }

    /// The mask of the register bits an 8-bit codec owns; the whole register otherwise.
    pub(crate) fn mask(self) -> u16 {
        match self {
            Self::U8(BytePlace::High) | Self::I8(BytePlace::High) => 0xFF00,
            Self::U8(BytePlace::Low) | Self::I8(BytePlace::Low) => 0x00FF,
            _ => 0xFFFF,
        }
    }
}

/// The exponent a `scale_by` field is read or written with, as the exponent field read it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Exponent {
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
pub(crate) const EXPONENTS: std::ops::RangeInclusive<i8> = -10..=10;

impl Exponent {
    /// The exponent a `scale_by` field's value is read with, from its exponent field's value.
    pub(crate) fn from_value(value: Result<&Value, String>) -> Self {
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
pub(crate) enum NumberError {
    /// The raw value is one of the field's `invalid` marks, or its exponent's.
    Unavailable,
    Invalid(String),
}

/// A compiled numeric codec.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct NumberCodec {
    pub(crate) ty: NumberType,
    pub(crate) layout: RegisterLayout,
    /// Places shown (before any exponent).
    pub(crate) decimals: u8,
    /// Units of the last shown place one raw count is worth (`decimals` 1, `scale` 0.5 → 5).
    pub(crate) factor: i64,
    /// Added after scaling, in units of the last shown place.
    pub(crate) offset: i128,
    /// Raw bits that mean "no value" (`0x8000`; a float's listed values as their bits).
    pub(crate) invalid: Vec<u64>,
    /// The value is multiplied by 10^exponent, the exponent read from another field.
    pub(crate) scaled_by_exponent: bool,
}

fn pow10(places: u8) -> i128 {
    10i128.pow(u32::from(places))
}

/// `float` in units of the `places`-th decimal place, rounded from its exact decimal
/// expansion (through its text at those places).
fn exact_at_places(float: f64, places: u8) -> Option<i128> {
    let text = format!("{float:.*}", usize::from(places));
    super::number::DecimalText::parse(&text).and_then(|number| number.scaled(places).ok())
}

/// The same as [`exact_at_places`] without the text, where the product with the power of ten
/// cannot round otherwise: it is off the exact product by at most half an ulp, so only a
/// product within an ulp of a half (or too large for an ulp under one) is left to the text.
fn nearest_at_places(float: f64, places: u8) -> Option<i128> {
    const POWERS: [f64; 16] = [
        1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
    ];
    let product = float * POWERS.get(usize::from(places))?;
    let fraction = product - product.floor();
    let ulp = product.abs() * f64::EPSILON;
    if product.abs() >= 4_503_599_627_370_496.0 || (fraction - 0.5).abs() <= ulp {
        return None;
    }
    // In range of an i128 and a whole number: the cast is exact.
    Some(product.round() as i128)
}

fn pow10_checked(places: u8) -> Option<i128> {
    10i128.checked_pow(u32::from(places))
}

impl NumberCodec {
    /// The most decimals a value of this codec can have: its own, plus ten for a `scale_by`
    /// field read with exponent -10.
    pub(crate) fn max_precision(&self) -> u8 {
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
    pub(crate) fn decode(&self, words: &[u16], exponent: &Exponent) -> Result<Value, NumberError> {
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
        // A 64-bit count times a large scale and a large exponent can leave i128: such a
        // reading is out of range, never a wrapped number.
        let (precision, multiplier) = self.shape(power);
        let scaled = pow10_checked(precision - self.decimals)
            .and_then(|places| self.offset.checked_mul(places))
            .and_then(|offset| {
                counts
                    .checked_mul(i128::from(self.factor))?
                    .checked_mul(multiplier)?
                    .checked_add(offset)
            })
            .ok_or_else(|| NumberError::Invalid(format!("raw value {bits} is out of range")))?;
        Ok(self.value(scaled, precision))
    }

    fn value(&self, scaled: i128, precision: u8) -> Value {
        // A float is a decimal at any number of places, as the profile format always had it.
        if precision == 0 && !self.scaled_by_exponent && !self.ty.is_float() {
            Value::Int(scaled)
        } else {
            Value::Decimal { scaled, precision }
        }
    }

    /// A float as the nearest value at the shown places (the decimal expansion of the float
    /// itself, correctly rounded, not of a product that rounds twice).
    fn decode_float(&self, float: f64, power: i8) -> Result<Value, NumberError> {
        // NaN (IEEE 754's "not available" of most meters) and the infinities are no value,
        // whether or not the profile lists them.
        if !float.is_finite() {
            return Err(NumberError::Unavailable);
        }
        let (precision, multiplier) = self.shape(power);
        let out_of_range = || NumberError::Invalid(format!("out of range: {float}"));
        let counts = if i128::from(self.factor) == pow10(self.decimals) {
            nearest_at_places(float, self.decimals)
                .or_else(|| exact_at_places(float, self.decimals))
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
    pub(crate) fn encode(&self, value: &Value, exponent: &Exponent) -> Result<Vec<u16>, String> {
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
pub(crate) fn at_precision(value: &Value, precision: u8) -> Result<i128, String> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registers::{ByteOrder, WordOrder};
    use proptest::prelude::*;

    const LAYOUTS: [RegisterLayout; 4] = [
        RegisterLayout {
            words: WordOrder::HighFirst,
            bytes: ByteOrder::HighFirst,
        },
        RegisterLayout {
            words: WordOrder::LowFirst,
            bytes: ByteOrder::HighFirst,
        },
        RegisterLayout {
            words: WordOrder::HighFirst,
            bytes: ByteOrder::LowFirst,
        },
        RegisterLayout {
            words: WordOrder::LowFirst,
            bytes: ByteOrder::LowFirst,
        },
    ];

    fn codec(ty: NumberType, layout: RegisterLayout, decimals: u8) -> NumberCodec {
        NumberCodec {
            ty,
            layout,
            decimals,
            factor: if ty.is_float() {
                10i64.pow(u32::from(decimals))
            } else {
                1
            },
            offset: 0,
            invalid: Vec::new(),
            scaled_by_exponent: false,
        }
    }

    fn text(value: Result<Value, NumberError>) -> String {
        match value {
            Ok(value) => value.to_text(),
            Err(error) => format!("{error:?}"),
        }
    }

    /// 123.456 as `ty` decodes from and encodes to `images`, given in the order of `LAYOUTS`.
    fn decimal_in_each_layout(ty: NumberType, images: [&[u16]; 4]) {
        let value = Value::Decimal {
            scaled: 123_456,
            precision: 3,
        };
        for (layout, words) in LAYOUTS.into_iter().zip(images) {
            let float_codec = codec(ty, layout, 3);
            assert_eq!(text(float_codec.decode(words, &Exponent::None)), "123.456");
            assert_eq!(
                float_codec.encode(&value, &Exponent::None),
                Ok(words.to_vec())
            );
        }
    }

    #[test]
    fn a_float_in_its_four_layouts() {
        // 123.456 as an IEEE 754 single is 0x42F6E979 (the worked example of many vendors'
        // "float byte order" pages): ABCD, CDAB, BADC, DCBA.
        decimal_in_each_layout(
            NumberType::F32,
            [
                &[0x42F6, 0xE979],
                &[0xE979, 0x42F6],
                &[0xF642, 0x79E9],
                &[0x79E9, 0xF642],
            ],
        );
    }

    #[test]
    fn a_double_in_its_four_layouts() {
        // 123.456 as an IEEE 754 double is 0x405EDD2F1A9FBE77.
        decimal_in_each_layout(
            NumberType::F64,
            [
                &[0x405E, 0xDD2F, 0x1A9F, 0xBE77],
                &[0xBE77, 0x1A9F, 0xDD2F, 0x405E],
                &[0x5E40, 0x2FDD, 0x9F1A, 0x77BE],
                &[0x77BE, 0x9F1A, 0x2FDD, 0x5E40],
            ],
        );
    }

    #[test]
    fn sixty_four_bit_integers_keep_every_digit() {
        let abcd = LAYOUTS[0];
        let u64_codec = codec(NumberType::U64, abcd, 0);
        let words = [0xFFFF, 0xFFFF, 0xFFFF, 0xFFFE];
        assert_eq!(
            text(u64_codec.decode(&words, &Exponent::None)),
            "18446744073709551614"
        );
        let i64_codec = codec(NumberType::I64, abcd, 0);
        assert_eq!(text(i64_codec.decode(&words, &Exponent::None)), "-2");
        assert_eq!(
            i64_codec.encode(&Value::Int(i128::from(i64::MIN)), &Exponent::None),
            Ok(vec![0x8000, 0, 0, 0])
        );
        // Energy in Wh shown as kWh with three decimals, above 2^63 Wh.
        let kwh = codec(NumberType::U64, abcd, 3);
        assert_eq!(
            text(kwh.decode(&words, &Exponent::None)),
            "18446744073709551.614"
        );
        assert_eq!(
            u64_codec.encode(&Value::Int(1 << 64), &Exponent::None),
            Err("18446744073709551616 is out of the codec's range".to_string())
        );
    }

    #[test]
    fn sixteen_bit_byte_order_and_eight_bit_places() {
        let badc = LAYOUTS[2];
        assert_eq!(
            text(codec(NumberType::I16, badc, 0).decode(&[0xFEFF], &Exponent::None)),
            "-2"
        );
        let high = codec(NumberType::I8(BytePlace::High), LAYOUTS[0], 0);
        let low = codec(NumberType::U8(BytePlace::Low), LAYOUTS[0], 0);
        assert_eq!(text(high.decode(&[0xFE12], &Exponent::None)), "-2");
        assert_eq!(text(low.decode(&[0xFE12], &Exponent::None)), "18");
        assert_eq!(
            high.encode(&Value::Int(-3), &Exponent::None),
            Ok(vec![0xFD00])
        );
        assert_eq!(
            low.encode(&Value::Int(255), &Exponent::None),
            Ok(vec![0x00FF])
        );
        assert!(low.encode(&Value::Int(256), &Exponent::None).is_err());
    }

    #[test]
    fn offset_is_added_after_scaling() {
        // Temperature = raw × 0.1 − 40.0.
        let mut temperature = codec(NumberType::U16, LAYOUTS[0], 1);
        temperature.offset = -400;
        assert_eq!(text(temperature.decode(&[250], &Exponent::None)), "-15.0");
        let value = Value::Decimal {
            scaled: 215,
            precision: 1,
        };
        assert_eq!(temperature.encode(&value, &Exponent::None), Ok(vec![615]));
    }

    #[test]
    fn a_reading_beyond_i128_is_out_of_range_never_wrapped() {
        // u64::MAX counts of 1000 (shown with 9 decimals), times 10^10: past i128, so invalid
        // data.
        let mut energy = codec(NumberType::U64, LAYOUTS[0], 9);
        energy.factor = 1_000_000_000_000;
        energy.scaled_by_exponent = true;
        let all_ones = [0xFFFF; 4];
        assert!(matches!(
            energy.decode(&all_ones, &Exponent::Power(10)),
            Err(NumberError::Invalid(_))
        ));
        // The same count at exponent 0 is exact.
        assert_eq!(
            text(energy.decode(&all_ones, &Exponent::Power(0))),
            "18446744073709551615000.000000000"
        );
    }

    #[test]
    fn sunspec_scale_factors() {
        // SunSpec model 101: W = 12345 with W_SF = -1 is 1234.5 W; with W_SF = 2, 1234500 W.
        let mut watts = codec(NumberType::I16, LAYOUTS[0], 0);
        watts.scaled_by_exponent = true;
        assert_eq!(text(watts.decode(&[12345], &Exponent::Power(-1))), "1234.5");
        assert_eq!(text(watts.decode(&[12345], &Exponent::Power(2))), "1234500");
        assert_eq!(text(watts.decode(&[12345], &Exponent::Power(0))), "12345");
        assert_eq!(
            watts.decode(&[12345], &Exponent::Unavailable),
            Err(NumberError::Unavailable)
        );
        assert!(matches!(
            watts.decode(&[12345], &Exponent::None),
            Err(NumberError::Invalid(_))
        ));
        // A write takes the exponent read in its slot: 1234.5 at -1 is raw 12345.
        let value = Value::Decimal {
            scaled: 12_345,
            precision: 1,
        };
        assert_eq!(watts.encode(&value, &Exponent::Power(-1)), Ok(vec![12345]));
        assert!(watts.encode(&value, &Exponent::Power(0)).is_err());
        assert_eq!(
            watts.encode(&Value::Int(1_234_500), &Exponent::Power(2)),
            Ok(vec![12345])
        );
        // The exponent's own value decides whether it is usable.
        assert_eq!(
            Exponent::from_value(Ok(&Value::Int(-3))),
            Exponent::Power(-3)
        );
        assert_eq!(
            Exponent::from_value(Ok(&Value::Unavailable)),
            Exponent::Unavailable
        );
        assert!(matches!(
            Exponent::from_value(Ok(&Value::Int(11))),
            Exponent::Unusable(_)
        ));
    }

    #[test]
    fn invalid_marks_are_raw_values() {
        let mut current = codec(NumberType::I16, LAYOUTS[0], 2);
        current.invalid = vec![0x8000];
        assert_eq!(
            current.decode(&[0x8000], &Exponent::None),
            Err(NumberError::Unavailable)
        );
        assert_eq!(text(current.decode(&[0x8001], &Exponent::None)), "-327.67");
        assert_eq!(NumberType::I16.raw_bits_of(-32768), Some(0x8000));
        assert_eq!(NumberType::I16.raw_bits_of(0xFFFF), Some(0xFFFF));
        assert_eq!(NumberType::U16.raw_bits_of(0x1_0000), None);
        assert_eq!(NumberType::U64.raw_bits_of(-1), Some(u64::MAX));
    }

    fn integer_type() -> impl Strategy<Value = NumberType> {
        prop_oneof![
            Just(NumberType::U8(BytePlace::High)),
            Just(NumberType::U8(BytePlace::Low)),
            Just(NumberType::I8(BytePlace::High)),
            Just(NumberType::I8(BytePlace::Low)),
            Just(NumberType::U16),
            Just(NumberType::I16),
            Just(NumberType::U32),
            Just(NumberType::I32),
            Just(NumberType::U64),
            Just(NumberType::I64),
        ]
    }

    #[test]
    fn a_float_near_a_half_at_its_places_is_rounded_from_its_text() {
        // Exact halves (0.125 at two places) are left to the text's rounding.
        assert_eq!(nearest_at_places(0.125, 2), None);
        assert_eq!(nearest_at_places(-2.5, 0), None);
        assert_eq!(exact_at_places(0.125, 2), Some(12));
        assert_eq!(nearest_at_places(f64::from(123.456f32), 3), Some(123_456));
        assert_eq!(nearest_at_places(-0.1, 1), Some(-1));
        assert_eq!(nearest_at_places(1e300, 2), None);
        assert_eq!(nearest_at_places(1.0, 16), None);
    }

    proptest! {
        #[test]
        fn every_integer_codec_round_trips_its_registers(
            ty in integer_type(),
            layout in 0usize..4,
            decimals in 0u8..=6,
            factor in prop_oneof![Just(1i64), 1i64..1000],
            offset in -1_000_000i128..1_000_000,
            exponent in prop_oneof![Just(None), (-10i8..=10).prop_map(Some)],
            words in prop::array::uniform4(any::<u16>()),
        ) {
            let mut number = codec(ty, LAYOUTS[layout], decimals);
            number.factor = factor;
            number.offset = offset;
            number.scaled_by_exponent = exponent.is_some();
            let exponent = exponent.map_or(Exponent::None, Exponent::Power);
            let words = &words[..usize::from(ty.registers())];
            let value = number.decode(words, &exponent);
            prop_assert!(value.is_ok());
            let value = value.unwrap_or(Value::Unavailable);
            // The text form is exact too.
            let parsed = crate::number::DecimalText::parse(&value.to_text())
                .and_then(|text| text.scaled(number.max_precision()).ok());
            prop_assert_eq!(parsed, at_precision(&value, number.max_precision()).ok());
            let encoded = number.encode(&value, &exponent);
            let mask = ty.mask();
            let expected: Vec<u16> = words.iter().map(|word| word & mask).collect();
            prop_assert_eq!(encoded, Ok(expected));
        }

        #[test]
        fn floats_round_at_places_as_their_exact_expansion(
            bits in any::<u64>(),
            narrow in any::<u32>(),
            ordinary in -1.0e7f64..1.0e7,
            places in 0u8..=7,
        ) {
            let meter = f64::from(ordinary as f32);
            for float in [f64::from_bits(bits), f64::from(f32::from_bits(narrow)), ordinary, meter] {
                if !float.is_finite() {
                    continue;
                }
                if let Some(fast) = nearest_at_places(float, places) {
                    prop_assert_eq!(Some(fast), exact_at_places(float, places), "{} at {}", float, places);
                }
            }
        }

        #[test]
        fn floats_round_trip_their_shown_value(
            layout in 0usize..4,
            decimals in 0u8..=3,
            scaled in -99_999i128..99_999,
            wide in -99_999_999_999_999i128..99_999_999_999_999,
        ) {
            // Inside a float's exact digits: 7 for f32 at these magnitudes, 15 for f64.
            for (ty, scaled) in [(NumberType::F32, scaled), (NumberType::F64, wide)] {
                let number = codec(ty, LAYOUTS[layout], decimals);
                let value = Value::Decimal { scaled, precision: decimals };
                let words = number.encode(&value, &Exponent::None);
                prop_assert!(words.is_ok());
                let back = number.decode(&words.unwrap_or_default(), &Exponent::None);
                prop_assert_eq!(back, Ok(value));
            }
        }
    }
}
