//! The codecs of a profile: a field's `codec` section as a [`FieldCodec`], with the number
//! codecs' scale, offset and `invalid` marks checked to stay exact.

use std::collections::HashSet;
use std::ops::RangeInclusive;

use super::problems::Problems;
use crate::codec::FieldCodec;
use crate::format::{CodecSection, NumberSection};
use crate::numeric::{BytePlace, NumberCodec, NumberType};
use crate::registers::RegisterLayout;

/// A field's codec from its `codec` section; `None` when the section is refused (the problems
/// are added).
pub(super) fn build_codec(
    section: &CodecSection,
    place: &str,
    problems: &mut Problems<'_>,
) -> Option<FieldCodec> {
    let mut number = |ty: NumberType, keys: &NumberSection| {
        build_number(ty, keys, place, problems).map(FieldCodec::Number)
    };
    Some(match section {
        CodecSection::Bit { bit, invert } => {
            if *bit > 15 {
                problems.add(
                    format!("{place}.codec.bit"),
                    format!("bit {bit} is not 0–15"),
                );
                return None;
            }
            FieldCodec::Bit {
                bit: *bit,
                invert: *invert,
            }
        }
        CodecSection::Bits {
            bit,
            width,
            options,
        } => {
            check_bit_group(*bit, *width, place, problems)?;
            check_options(options, *width, place, problems);
            FieldCodec::Bits {
                bit: *bit,
                width: *width,
                options: options.clone(),
            }
        }
        CodecSection::Coil { invert } => FieldCodec::Coil { invert: *invert },
        CodecSection::Coils { width, options } => {
            if *width == 0 || *width > 16 {
                problems.add(
                    format!("{place}.codec.width"),
                    "a coil group has 1–16 coils",
                );
                return None;
            }
            check_options(options, *width, place, problems);
            FieldCodec::Coils {
                width: *width,
                options: options.clone(),
            }
        }
        CodecSection::U8(keys) => number(NumberType::U8(byte_of(keys)), keys)?,
        CodecSection::I8(keys) => number(NumberType::I8(byte_of(keys)), keys)?,
        CodecSection::U16(keys) => number(NumberType::U16, keys)?,
        CodecSection::I16(keys) => number(NumberType::I16, keys)?,
        CodecSection::U32(keys) => number(NumberType::U32, keys)?,
        CodecSection::I32(keys) => number(NumberType::I32, keys)?,
        CodecSection::F32(keys) => number(NumberType::F32, keys)?,
        CodecSection::U64(keys) => number(NumberType::U64, keys)?,
        CodecSection::I64(keys) => number(NumberType::I64, keys)?,
        CodecSection::F64(keys) => number(NumberType::F64, keys)?,
        CodecSection::Bcd {
            int_digits,
            frac_digits,
        } => {
            check_bcd_digits(*int_digits, *frac_digits, place, problems)?;
            FieldCodec::Bcd {
                int_digits: *int_digits,
                frac_digits: *frac_digits,
            }
        }
        CodecSection::Char => FieldCodec::Char,
        CodecSection::Bytes {
            registers,
            format,
            separator,
            bytes,
        } => {
            check_register_span(*registers, "a byte string", place, problems)?;
            FieldCodec::Bytes {
                registers: *registers,
                format: *format,
                separator: separator.clone(),
                bytes: *bytes,
            }
        }
        CodecSection::String {
            registers,
            byte_order,
            encoding,
        } => {
            check_register_span(*registers, "a string", place, problems)?;
            FieldCodec::Text {
                registers: *registers,
                byte_order: *byte_order,
                encoding: *encoding,
            }
        }
    })
}

/// A `bits` group lies inside one word.
fn check_bit_group(bit: u8, width: u8, place: &str, problems: &mut Problems<'_>) -> Option<()> {
    if width == 0 || u32::from(bit) + u32::from(width) > 16 {
        problems.add(
            format!("{place}.codec.width"),
            format!(
                "bits {bit}..{} do not fit a word",
                u32::from(bit) + u32::from(width)
            ),
        );
        return None;
    }
    Some(())
}

/// A BCD pair's digits fit its two words.
fn check_bcd_digits(
    int_digits: u8,
    frac_digits: u8,
    place: &str,
    problems: &mut Problems<'_>,
) -> Option<()> {
    if int_digits == 0 || int_digits > 4 || frac_digits > 4 {
        problems.add(
            format!("{place}.codec"),
            "a BCD pair has 1–4 integer digits and 0–4 fraction digits",
        );
        return None;
    }
    Some(())
}

/// A string (`what`) spans no more registers than one read returns.
fn check_register_span(
    registers: u16,
    what: &str,
    place: &str,
    problems: &mut Problems<'_>,
) -> Option<()> {
    if registers == 0 || registers > 125 {
        problems.add(
            format!("{place}.codec.registers"),
            format!("{what} spans 1–125 registers"),
        );
        return None;
    }
    Some(())
}

/// The byte an 8-bit codec takes (the low one when unnamed, which [`build_number`] refuses).
fn byte_of(keys: &NumberSection) -> BytePlace {
    keys.byte.unwrap_or(BytePlace::Low)
}

/// The `options` of a `bits` or `coils` enumeration: lower-case words, no two alike, no more
/// than `width` bits can tell apart.
fn check_options(options: &[String], width: u8, place: &str, problems: &mut Problems<'_>) {
    if options.len() > 1usize << width {
        problems.add(
            format!("{place}.codec.options"),
            format!("{} options do not fit {width} bits", options.len()),
        );
    }
    let mut seen = HashSet::new();
    for option in options {
        if option.is_empty()
            || !option
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
        {
            problems.add(
                format!("{place}.codec.options"),
                format!("option `{option}` must be a lower-case word"),
            );
        }
        if !seen.insert(option) {
            problems.add(
                format!("{place}.codec.options"),
                format!("duplicate option `{option}`"),
            );
        }
    }
}

/// A number codec from its keys. `decimals` places are shown; `scale` is the value of one raw
/// count (default 10^-decimals) and `offset` is added after scaling: both must be whole numbers
/// of the last shown place, so values stay exact.
fn build_number(
    ty: NumberType,
    keys: &NumberSection,
    place: &str,
    problems: &mut Problems<'_>,
) -> Option<NumberCodec> {
    let before = problems.count();
    let decimals = keys.decimals;
    if decimals > 6 {
        problems.add(
            format!("{place}.codec.decimals"),
            format!("{decimals} decimals: at most 6"),
        );
        return None;
    }
    let factor = match keys.scale {
        // Integers count the last shown place; a float is the value itself.
        None if ty.is_float() => 10i64.pow(u32::from(decimals)),
        None => 1,
        Some(scale) => last_place_counts(scale, decimals, 1.0..=1e9).unwrap_or_else(|| {
            problems.add(
                format!("{place}.codec.scale"),
                format!(
                    "scale {scale} is not a positive whole number of the last shown place with \
                     {decimals} decimals (raise `decimals`)"
                ),
            );
            0
        }),
    };
    let offset = match keys.offset {
        None => 0,
        Some(offset) => last_place_counts(offset, decimals, -1e15..=1e15).unwrap_or_else(|| {
            problems.add(
                format!("{place}.codec.offset"),
                format!(
                    "offset {offset} is not a whole number of the last shown place with \
                     {decimals} decimals (raise `decimals`)"
                ),
            );
            0
        }),
    };
    let invalid = invalid_marks(ty, keys, place, problems);
    check_register_keys(ty, keys, place, problems);
    (problems.count() == before).then(|| NumberCodec {
        ty,
        layout: RegisterLayout {
            words: keys.word_order.unwrap_or_default(),
            bytes: keys.byte_order.unwrap_or_default(),
        },
        decimals,
        factor,
        offset: i128::from(offset),
        invalid,
        scaled_by_exponent: keys.scale_by.is_some(),
    })
}

/// `value` in units of the last place shown with `decimals` decimals, when that is a whole
/// number within `counts` (to a millionth: `0.1` times ten is not exactly 1 in a float).
fn last_place_counts(value: f64, decimals: u8, counts: RangeInclusive<f64>) -> Option<i64> {
    let scaled = value * 10f64.powi(i32::from(decimals));
    let whole = (scaled - scaled.round()).abs() <= 1e-6;
    (scaled.is_finite() && counts.contains(&scaled) && whole).then(|| scaled.round() as i64)
}

/// The raw values of `invalid`, as the codec's raw bits: only integer codecs have them.
fn invalid_marks(
    ty: NumberType,
    keys: &NumberSection,
    place: &str,
    problems: &mut Problems<'_>,
) -> Vec<u64> {
    let mut invalid = Vec::new();
    for mark in &keys.invalid {
        match ty.raw_bits_of(i128::from(*mark)) {
            Some(bits) => invalid.push(bits),
            None if ty.is_float() => {
                problems.add(
                    format!("{place}.codec.invalid"),
                    "only integer codecs have invalid raw values (a float's is NaN)",
                );
                break;
            }
            None => problems.add(
                format!("{place}.codec.invalid"),
                format!("{mark} is not a raw value of this codec"),
            ),
        }
    }
    invalid
}

/// The keys that place a number in its registers: `byte` for the 8-bit codecs alone,
/// `byte_order` for the others, `word_order` for those over several registers.
fn check_register_keys(
    ty: NumberType,
    keys: &NumberSection,
    place: &str,
    problems: &mut Problems<'_>,
) {
    let eight_bits = matches!(ty, NumberType::U8(_) | NumberType::I8(_));
    if eight_bits && keys.byte.is_none() {
        problems.add(
            format!("{place}.codec.byte"),
            "an 8-bit codec names its byte: `byte = \"high\"` or `\"low\"`",
        );
    }
    if !eight_bits && keys.byte.is_some() {
        problems.add(
            format!("{place}.codec.byte"),
            "`byte` is for the 8-bit codecs u8 and i8",
        );
    }
    if eight_bits && keys.byte_order.is_some() {
        problems.add(
            format!("{place}.codec.byte_order"),
            "an 8-bit codec takes `byte`, not `byte_order`",
        );
    }
    if ty.registers() == 1 && keys.word_order.is_some() {
        problems.add(
            format!("{place}.codec.word_order"),
            "`word_order` is for codecs over several registers",
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn codec(text: &str) -> (Option<FieldCodec>, Vec<(String, String)>) {
        let section: CodecSection = toml::from_str(text).expect("a codec section");
        let mut problems = Problems::new("p");
        let codec = build_codec(&section, "fields[0] (f)", &mut problems);
        let found = match problems.into_result(()) {
            Ok(()) => Vec::new(),
            Err(errors) => errors.0.into_iter().map(|e| (e.place, e.reason)).collect(),
        };
        (codec, found)
    }

    fn refused_at(text: &str) -> Vec<String> {
        let (codec, found) = codec(text);
        assert!(codec.is_none(), "{text} was accepted");
        found.into_iter().map(|(place, _)| place).collect()
    }

    #[test]
    fn a_number_keeps_its_scale_as_counts_of_the_last_place() {
        let (codec, found) = codec("type = \"u16\"\ndecimals = 1\nscale = 0.5\noffset = -40");
        assert!(found.is_empty(), "{found:?}");
        let Some(FieldCodec::Number(number)) = codec else {
            panic!("not a number: {codec:?}");
        };
        assert_eq!((number.factor, number.offset), (5, -400));
    }

    #[test]
    fn a_bit_group_with_its_options_is_accepted() {
        let (codec, found) =
            codec("type = \"bits\"\nbit = 4\nwidth = 2\noptions = [\"off\", \"low\"]");
        assert!(found.is_empty(), "{found:?}");
        assert!(matches!(
            codec,
            Some(FieldCodec::Bits {
                bit: 4,
                width: 2,
                ..
            })
        ));
    }

    #[test]
    fn codecs_outside_their_word_are_refused_at_their_key() {
        assert_eq!(
            refused_at("type = \"bit\"\nbit = 16"),
            ["p: fields[0] (f).codec.bit"]
        );
        assert_eq!(
            refused_at("type = \"bits\"\nbit = 12\nwidth = 5"),
            ["p: fields[0] (f).codec.width"]
        );
        assert_eq!(
            refused_at("type = \"bcd\"\nint_digits = 5\nfrac_digits = 0"),
            ["p: fields[0] (f).codec"]
        );
        assert_eq!(
            refused_at("type = \"string\"\nregisters = 126"),
            ["p: fields[0] (f).codec.registers"]
        );
    }

    #[test]
    fn options_are_distinct_lower_case_words_that_fit_their_bits() {
        let (_, found) = codec("type = \"coils\"\nwidth = 1\noptions = [\"a\", \"B\", \"a\"]");
        let reasons: Vec<&str> = found.iter().map(|(_, reason)| reason.as_str()).collect();
        assert_eq!(
            reasons,
            [
                "3 options do not fit 1 bits",
                "option `B` must be a lower-case word",
                "duplicate option `a`",
            ]
        );
        assert!(found
            .iter()
            .all(|(place, _)| place == "p: fields[0] (f).codec.options"));
    }

    #[test]
    fn number_keys_that_cannot_stay_exact_or_do_not_fit_the_type_are_refused() {
        assert_eq!(
            refused_at("type = \"u16\"\ndecimals = 1\nscale = 0.15"),
            ["p: fields[0] (f).codec.scale"]
        );
        assert_eq!(refused_at("type = \"u8\""), ["p: fields[0] (f).codec.byte"]);
        assert_eq!(
            refused_at("type = \"u16\"\nword_order = \"low_first\"\ninvalid = [70000]"),
            [
                "p: fields[0] (f).codec.invalid",
                "p: fields[0] (f).codec.word_order"
            ]
        );
        assert_eq!(
            refused_at("type = \"f32\"\ninvalid = [1]"),
            ["p: fields[0] (f).codec.invalid"]
        );
        assert_eq!(
            refused_at("type = \"i32\"\ndecimals = 7"),
            ["p: fields[0] (f).codec.decimals"]
        );
    }
}
