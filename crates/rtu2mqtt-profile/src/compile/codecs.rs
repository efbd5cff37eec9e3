//! The codecs of a profile: a field's `codec` section as a [`FieldCodec`], with the number
//! codecs' scale, offset and `invalid` marks checked to stay exact.

use std::collections::HashSet;
use std::ops::RangeInclusive;

use super::problems::Problems;
use crate::codec::FieldCodec;
use crate::enumeration::EnumCodec;
use crate::format::{CodecSection, InvalidMark, NumberSection};
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
        CodecSection::Enum {
            values,
            registers,
            word_order,
            unknown,
        } => FieldCodec::Enum(build_enum(
            values,
            *registers,
            *word_order,
            *unknown,
            place,
            problems,
        )?),
    })
}

/// An `enum` codec: one or two registers, each named code a number of that width, each name a
/// lower-case word used once.
fn build_enum(
    values: &std::collections::BTreeMap<String, String>,
    registers: u16,
    word_order: Option<crate::registers::WordOrder>,
    unknown: crate::enumeration::UnknownCode,
    place: &str,
    problems: &mut Problems<'_>,
) -> Option<EnumCodec> {
    let before = problems.count();
    if !(1..=2).contains(&registers) {
        problems.add(
            format!("{place}.codec.registers"),
            "an enum code is one register (a u16) or two (a u32)",
        );
        return None;
    }
    if registers == 1 && word_order.is_some() {
        problems.add(
            format!("{place}.codec.word_order"),
            "`word_order` is for codes over two registers",
        );
    }
    if values.is_empty() {
        problems.add(
            format!("{place}.codec.values"),
            "an enum names at least one code: `values = { 0 = \"off\", 1 = \"on\" }`",
        );
    }
    let largest = if registers == 1 {
        u64::from(u16::MAX)
    } else {
        u64::from(u32::MAX)
    };
    let mut codes = Vec::new();
    for (key, name) in values {
        match parse_code(key).filter(|code| *code <= largest) {
            Some(code) => codes.push((code as u32, name.clone())),
            None => problems.add(
                format!("{place}.codec.values"),
                format!(
                    "`{key}` is not a code of {registers} register(s) (a whole number 0–{largest})"
                ),
            ),
        }
    }
    codes.sort_by_key(|(code, _)| *code);
    let names: Vec<String> = codes.iter().map(|(_, name)| name.clone()).collect();
    check_words(&names, "values", place, problems);
    (problems.count() == before).then(|| EnumCodec {
        registers,
        layout: crate::registers::RegisterLayout {
            words: word_order.unwrap_or_default(),
            bytes: crate::registers::ByteOrder::HighFirst,
        },
        codes,
        unknown,
    })
}

/// A code as a TOML key spells it: decimal, or hex with `0x`.
fn parse_code(key: &str) -> Option<u64> {
    let key = key.trim();
    match key.strip_prefix("0x").or_else(|| key.strip_prefix("0X")) {
        Some(hex) => u64::from_str_radix(hex, 16).ok(),
        None => key.parse().ok(),
    }
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
    check_words(options, "options", place, problems);
}

/// The names of an enumeration (its `key`): lower-case words, no two alike.
fn check_words(options: &[String], key: &str, place: &str, problems: &mut Problems<'_>) {
    let mut seen = HashSet::new();
    for option in options {
        if option.is_empty()
            || !option
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
        {
            problems.add(
                format!("{place}.codec.{key}"),
                format!("option `{option}` must be a lower-case word"),
            );
        }
        if !seen.insert(option) {
            problems.add(
                format!("{place}.codec.{key}"),
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

/// The raw bits the `invalid` marks stand for: an integer codec's raw values, a float's values
/// (NaN and the infinities are "no value" whether listed or not).
fn invalid_marks(
    ty: NumberType,
    keys: &NumberSection,
    place: &str,
    problems: &mut Problems<'_>,
) -> Vec<u64> {
    let mut invalid = Vec::new();
    for mark in &keys.invalid {
        let bits = match (mark, ty) {
            (InvalidMark::Word(word), _) if ty.is_float() && is_non_finite_word(word) => {
                continue;
            }
            (InvalidMark::Integer(value), NumberType::F32) => float_bits_f32(*value as f64),
            (InvalidMark::Float(value), NumberType::F32) => float_bits_f32(*value),
            (InvalidMark::Integer(value), NumberType::F64) => float_bits_f64(*value as f64),
            (InvalidMark::Float(value), NumberType::F64) => float_bits_f64(*value),
            (InvalidMark::Integer(value), _) => {
                ty.raw_bits_of(i128::from(*value)).map(|bits| vec![bits])
            }
            (InvalidMark::Float(_), _) => None,
            (InvalidMark::Word(_), _) => None,
        };
        match bits {
            Some(bits) => invalid.extend(bits),
            None if ty.is_float() => problems.add(
                format!("{place}.codec.invalid"),
                format!(
                    "{} is not a value of this float (a number, \"nan\", \"inf\" or \"-inf\")",
                    mark_text(mark)
                ),
            ),
            None => problems.add(
                format!("{place}.codec.invalid"),
                format!("{} is not a raw value of this codec", mark_text(mark)),
            ),
        }
    }
    invalid
}

fn is_non_finite_word(word: &str) -> bool {
    matches!(
        word.to_ascii_lowercase().as_str(),
        "nan" | "inf" | "+inf" | "-inf"
    )
}

fn mark_text(mark: &InvalidMark) -> String {
    match mark {
        InvalidMark::Integer(value) => value.to_string(),
        InvalidMark::Float(value) => value.to_string(),
        InvalidMark::Word(word) => format!("`{word}`"),
    }
}

/// The bits of an f32 mark, the nearest f32 to it (both zeros for a zero); None when it is
/// beyond the f32's range.
fn float_bits_f32(value: f64) -> Option<Vec<u64>> {
    let single = value as f32;
    if !single.is_finite() {
        return None;
    }
    let mut bits = vec![u64::from(single.to_bits())];
    if single == 0.0 {
        bits.push(u64::from((-single).to_bits()));
    }
    Some(bits)
}

/// The bits of an f64 mark (both zeros for a zero).
fn float_bits_f64(value: f64) -> Option<Vec<u64>> {
    if !value.is_finite() {
        return None;
    }
    let mut bits = vec![value.to_bits()];
    if value == 0.0 {
        bits.push((-value).to_bits());
    }
    Some(bits)
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
            refused_at("type = \"f32\"\ninvalid = [1e40, \"none\"]"),
            [
                "p: fields[0] (f).codec.invalid",
                "p: fields[0] (f).codec.invalid"
            ]
        );
        assert_eq!(
            refused_at("type = \"i16\"\ninvalid = [0.5, \"nan\"]"),
            [
                "p: fields[0] (f).codec.invalid",
                "p: fields[0] (f).codec.invalid"
            ]
        );
        assert_eq!(
            refused_at("type = \"i32\"\ndecimals = 7"),
            ["p: fields[0] (f).codec.decimals"]
        );
    }

    #[test]
    fn a_float_lists_values_and_words_as_no_value_marks() {
        let (codec, found) = codec("type = \"f32\"\ninvalid = [\"nan\", -1.0, 0, 0.1, \"-inf\"]");
        assert!(found.is_empty(), "{found:?}");
        let Some(FieldCodec::Number(number)) = codec else {
            panic!("not a number: {codec:?}");
        };
        let bits = |value: f32| u64::from(value.to_bits());
        assert_eq!(
            number.invalid,
            [bits(-1.0), bits(0.0), bits(-0.0), bits(0.1)]
        );
    }

    #[test]
    fn an_enum_names_sparse_codes_of_one_or_two_registers() {
        let (sparse, found) = codec(
            "type = \"enum\"\nvalues = { 0 = \"waiting\", 1 = \"normal\", 0x10 = \"fault\" }\n\
             unknown = \"publish_number\"",
        );
        assert!(found.is_empty(), "{found:?}");
        let Some(FieldCodec::Enum(codes)) = sparse else {
            panic!("not an enum: {sparse:?}");
        };
        assert_eq!(codes.registers, 1);
        assert_eq!(
            codes.codes,
            [
                (0, "waiting".to_string()),
                (1, "normal".to_string()),
                (16, "fault".to_string())
            ]
        );
        assert_eq!(
            codes.unknown,
            crate::enumeration::UnknownCode::PublishNumber
        );
        let (wide, found) = codec(
            "type = \"enum\"\nregisters = 2\nword_order = \"low_first\"\nvalues = { 70000 = \"far\" }",
        );
        assert!(found.is_empty(), "{found:?}");
        assert!(matches!(wide, Some(FieldCodec::Enum(codes)) if codes.registers == 2));
    }

    #[test]
    fn an_enum_refuses_codes_past_its_registers_and_names_used_twice() {
        let (_, found) =
            codec("type = \"enum\"\nvalues = { 70000 = \"far\", 1 = \"a\", 2 = \"a\", x = \"b\" }");
        let reasons: Vec<&str> = found.iter().map(|(_, reason)| reason.as_str()).collect();
        assert_eq!(
            reasons,
            [
                "`70000` is not a code of 1 register(s) (a whole number 0–65535)",
                "`x` is not a code of 1 register(s) (a whole number 0–65535)",
                "duplicate option `a`",
            ]
        );
        assert_eq!(
            refused_at("type = \"enum\"\nregisters = 3\nvalues = { 0 = \"a\" }"),
            ["p: fields[0] (f).codec.registers"]
        );
        assert_eq!(
            refused_at("type = \"enum\"\nword_order = \"low_first\"\nvalues = { 0 = \"a\" }"),
            ["p: fields[0] (f).codec.word_order"]
        );
    }
}
