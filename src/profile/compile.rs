//! The compiler from the file format ([`super::format`]) to the validated model
//! ([`super::model`]).
//!
//! Everything a profile file can get wrong is caught here, at load, with the file and the key:
//! unknown keys and codecs (serde), duplicate names, blocks over the device's read limits, fields
//! outside their block or overlapping another field, write rules on read-only blocks or outside
//! the device's write limits, bad ranges and enumerations. What leaves this module is known to be
//! consistent, so decoding and command planning never have to re-check the profile.

use std::collections::HashMap;
use std::time::Duration;

use super::codec::FieldCodec;
use super::field::{FieldInfo, FieldKind, HaHints, Identity};
use super::format::{
    BlockSection, CodecSection, FieldSection, ForbiddenSection, IdentityKey, LineSection,
    NumberSection, ProfileFile, WriteFrameSection, WriteSection,
};
use super::model::{
    Behaviour, BlockKind, Compiled, FieldDef, Forbidden, Limits, PollClass, ReadBlock, WriteFrame,
};
use super::numeric::{BytePlace, NumberCodec, NumberType};
use super::publish::PublishRule;
use super::registers::RegisterLayout;
use super::value::Value;
use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_modbus::Request;

/// One problem in a profile, with its place (`file: fields[3] (gear).write.address`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{place}: {reason}")]
pub struct ProfileError {
    pub place: String,
    pub reason: String,
}

/// Every problem found in one profile.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub struct ProfileErrors(pub Vec<ProfileError>);

impl std::fmt::Display for ProfileErrors {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let lines: Vec<String> = self.0.iter().map(ToString::to_string).collect();
        f.write_str(&lines.join("\n"))
    }
}

/// Collects problems with their places.
struct Problems<'a> {
    source: &'a str,
    list: Vec<ProfileError>,
}

impl Problems<'_> {
    fn add(&mut self, place: impl std::fmt::Display, reason: impl Into<String>) {
        self.list.push(ProfileError {
            place: format!("{}: {place}", self.source),
            reason: reason.into(),
        });
    }
}

/// Parses and validates a profile. `source` names the file (or built-in) in error places.
pub fn compile(text: &str, source: &str) -> Result<Compiled, ProfileErrors> {
    let file: ProfileFile = toml::from_str(text).map_err(|err| {
        let place = match err.span() {
            Some(span) => {
                let before = text.get(..span.start).unwrap_or(text);
                let line = before.matches('\n').count() + 1;
                let column = before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1;
                format!("{source}:{line}:{column}")
            }
            None => source.to_string(),
        };
        ProfileErrors(vec![ProfileError {
            place,
            reason: err.message().to_string(),
        }])
    })?;
    let mut problems = Problems {
        source,
        list: Vec::new(),
    };
    let compiled = build(file, &mut problems);
    if problems.list.is_empty() {
        Ok(compiled)
    } else {
        Err(ProfileErrors(problems.list))
    }
}

/// Each device-registry entry is filled by one field at most.
fn check_identities(places: &[String], infos: &[FieldInfo], problems: &mut Problems<'_>) {
    let mut first: HashMap<Identity, &str> = HashMap::new();
    for (info, place) in infos.iter().zip(places) {
        let Some(identity) = info.identity else {
            continue;
        };
        if let Some(earlier) = first.insert(identity, &info.name) {
            problems.add(
                format!("{place}.identity"),
                format!(
                    "`{}` is already the identity of field `{earlier}`",
                    identity.key()
                ),
            );
        }
    }
}

fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_' || c == '-')
}

/// What write frames and fields are compiled against: the device's limits, its read blocks (by
/// index and by name) and the shared write frames.
struct Layout<'f> {
    limits: Limits,
    blocks: Vec<ReadBlock>,
    /// Parallel to `blocks`.
    kinds: Vec<BlockKind>,
    block_index: HashMap<&'f str, usize>,
    /// The `[[write_frames]]` by name; empty while they are being built.
    frames: HashMap<String, WriteFrame>,
}

fn build(file: ProfileFile, problems: &mut Problems<'_>) -> Compiled {
    let limits = build_limits(&file.line, problems);
    if !valid_name(&file.device.name) {
        problems.add(
            "device.name",
            format!(
                "`{}` must be lower-case letters, digits, `-` or `_`",
                file.device.name
            ),
        );
    }

    let (blocks, kinds) = build_blocks(&file.blocks, &limits, problems);
    let block_index = file
        .blocks
        .iter()
        .enumerate()
        .map(|(i, b)| (b.name.as_str(), i))
        .collect();
    let mut layout = Layout {
        limits,
        blocks,
        kinds,
        block_index,
        frames: HashMap::new(),
    };
    layout.frames = build_write_frames(&file.write_frames, &layout, problems);

    let mut defs = Vec::new();
    let mut infos = Vec::new();
    let mut places = Vec::new();
    let mut built_sections = Vec::new();
    let mut seen = HashMap::new();
    for (i, field) in file.fields.iter().enumerate() {
        let place = format!("fields[{i}] ({})", field.name);
        if !valid_name(&field.name) || field.name.contains('-') {
            problems.add(
                format!("{place}.name"),
                "a field name must be lower-case letters, digits or `_`",
            );
        }
        if seen.insert(field.name.clone(), i).is_some() {
            problems.add(
                format!("{place}.name"),
                format!("duplicate field name `{}`", field.name),
            );
        }
        if let Some((def, info)) = build_field(field, &place, &layout, problems) {
            defs.push(def);
            infos.push(info);
            places.push(place);
            built_sections.push(field);
        }
    }
    check_overlaps(&places, &infos, &defs, &layout.blocks, problems);
    check_identities(&places, &infos, problems);
    for (index, (section, place)) in built_sections.iter().zip(&places).enumerate() {
        let until = resolve_settle_until(section, place, &infos, &defs, problems);
        defs[index].settle_until = until;
        defs[index].scale_by =
            resolve_scale_by(section, place, index, &infos, &defs, &layout, problems);
    }

    let mut used: Vec<Vec<(u16, u16)>> = vec![Vec::new(); layout.blocks.len()];
    for def in &defs {
        used[def.block].push((def.offset, def.codec.width()));
    }
    let blocks = layout
        .blocks
        .into_iter()
        .zip(used)
        .zip(&file.blocks)
        .map(|((mut block, spans), section)| {
            block.used_runs = merge_runs(spans);
            if section.read_whole && !block.used_runs.is_empty() {
                block.used_runs = vec![(0, section.count)];
            }
            block
        })
        .collect::<Vec<_>>();
    for (i, block) in blocks.iter().enumerate() {
        if block.used_runs.is_empty() && problems.list.is_empty() {
            problems.add(
                format!("blocks[{i}] ({})", block.name),
                "no field uses this block",
            );
        }
    }

    let forbidden = build_forbidden(&file.forbidden, &infos, &defs, problems);
    let named_frames = file
        .write_frames
        .iter()
        .filter_map(|section| {
            layout
                .frames
                .get(&section.name)
                .map(|frame| (section.name.clone(), frame.clone()))
        })
        .collect();

    Compiled {
        name: file.device.name,
        manufacturer: file.device.manufacturer,
        model: file.device.model,
        description: file.device.description,
        default_address: file.line.default_address,
        limits: layout.limits,
        blocks,
        block_kinds: layout.kinds,
        defs,
        infos,
        forbidden,
        named_frames,
    }
}

fn build_limits(line: &LineSection, problems: &mut Problems<'_>) -> Limits {
    let parity = match line.parity.as_str() {
        "none" => Parity::None,
        "even" => Parity::Even,
        "odd" => Parity::Odd,
        other => {
            problems.add(
                "line.parity",
                format!("`{other}` is not one of none, even, odd"),
            );
            Parity::None
        }
    };
    let [low, high] = line.address_range;
    if low == 0 || low > high || high > 253 {
        problems.add(
            "line.address_range",
            format!("[{low}, {high}] must be within 1–253 with the lower bound first"),
        );
    }
    if let Some(address) = line.default_address {
        if address < low || address > high {
            problems.add(
                "line.default_address",
                format!("{address} is outside the address range {low}–{high}"),
            );
        }
    }
    if line.min_poll_interval.is_zero() {
        problems.add("line.min_poll_interval", "must be more than zero");
    }
    let poll_interval = line.poll_interval.unwrap_or(line.min_poll_interval);
    if poll_interval < line.min_poll_interval {
        problems.add(
            "line.poll_interval",
            "is shorter than the line's min_poll_interval",
        );
    }
    if line.slow_interval < poll_interval {
        problems.add(
            "line.slow_interval",
            "is shorter than the fast poll interval",
        );
    }
    for (key, value, max) in [
        ("max_read_registers", line.max_read_registers, 125),
        ("max_write_registers", line.max_write_registers, 123),
        ("max_read_bits", line.max_read_bits, 2000),
        ("max_write_bits", line.max_write_bits, 1968),
    ] {
        if value == 0 || value > max {
            problems.add(
                format!("line.{key}"),
                format!("{value} must be 1–{max} (the Modbus limit)"),
            );
        }
    }
    if ![
        300u32, 600, 1200, 2400, 4800, 9600, 14400, 19200, 38400, 57600, 115200,
    ]
    .contains(&line.baud)
    {
        problems.add(
            "line.baud",
            format!("{} is not a usual serial baud rate", line.baud),
        );
    }
    Limits {
        address_range: low..=high,
        min_poll_interval: line.min_poll_interval,
        default_poll_interval: poll_interval,
        slow_interval: line.slow_interval,
        startup_delay: line.startup_delay.unwrap_or_default(),
        default_baud: line.baud,
        default_parity: parity,
        max_read_registers: line.max_read_registers,
        max_write_registers: line.max_write_registers,
        max_read_bits: line.max_read_bits,
        max_write_bits: line.max_write_bits,
    }
}

fn build_blocks(
    sections: &[BlockSection],
    limits: &Limits,
    problems: &mut Problems<'_>,
) -> (Vec<ReadBlock>, Vec<BlockKind>) {
    let mut blocks = Vec::new();
    let mut kinds = Vec::new();
    let mut names = HashMap::new();
    for (i, section) in sections.iter().enumerate() {
        let place = format!("blocks[{i}] ({})", section.name);
        if names.insert(section.name.as_str(), i).is_some() {
            problems.add(
                format!("{place}.name"),
                format!("duplicate block name `{}`", section.name),
            );
        }
        let (start, quantity) = (section.start, section.count);
        let (kind, request, max) = match section.function {
            1 => (
                BlockKind::Coils,
                Request::ReadCoils { start, quantity },
                limits.max_read_bits,
            ),
            2 => (
                BlockKind::DiscreteInputs,
                Request::ReadDiscreteInputs { start, quantity },
                limits.max_read_bits,
            ),
            3 => (
                BlockKind::HoldingRegisters,
                Request::ReadHoldingRegisters { start, quantity },
                limits.max_read_registers,
            ),
            4 => (
                BlockKind::InputRegisters,
                Request::ReadInputRegisters { start, quantity },
                limits.max_read_registers,
            ),
            other => {
                problems.add(
                    format!("{place}.function"),
                    format!("{other} is not a read function (1, 2, 3 or 4)"),
                );
                (
                    BlockKind::HoldingRegisters,
                    Request::ReadHoldingRegisters { start, quantity },
                    limits.max_read_registers,
                )
            }
        };
        if quantity == 0 || quantity > max {
            problems.add(
                format!("{place}.count"),
                format!("{quantity} must be 1–{max} (this device's read limit)"),
            );
        }
        if u32::from(start) + u32::from(quantity) > 0x1_0000 {
            problems.add(
                format!("{place}.count"),
                "the block runs past address 0xFFFF",
            );
        }
        let class = poll_class(&section.poll, limits).unwrap_or_else(|reason| {
            problems.add(format!("{place}.poll"), reason);
            PollClass::Fast
        });
        blocks.push(ReadBlock {
            name: section.name.clone(),
            request,
            class,
            used_runs: Vec::new(),
            reads_linearly: section.reads_linearly,
        });
        kinds.push(kind);
    }
    (blocks, kinds)
}

/// Longest period a block may be polled on: a value read less often is better read `once`.
const LONGEST_POLL_PERIOD: Duration = Duration::from_secs(24 * 3600);

/// A block's `poll` key: `fast`, `slow`, `once` or a period (`250ms`, `15s`, `1h`) no shorter
/// than the profile's `min_poll_interval`, which the device would not take (refused rather
/// than raised, so that what the profile says is what the line does).
fn poll_class(text: &str, limits: &Limits) -> Result<PollClass, String> {
    match text {
        "fast" => return Ok(PollClass::Fast),
        "slow" => return Ok(PollClass::Slow),
        "once" => return Ok(PollClass::Once),
        _ => {}
    }
    let period = humantime::parse_duration(text).map_err(|_| {
        format!(
            "`{text}` is not fast, slow, once or a duration (such as \"250ms\", \"15s\" or \"1h\")"
        )
    })?;
    if period < limits.min_poll_interval {
        return Err(format!(
            "{} is under the profile's min_poll_interval {}",
            humantime::format_duration(period),
            humantime::format_duration(limits.min_poll_interval)
        ));
    }
    if period > LONGEST_POLL_PERIOD {
        return Err("must be at most 24h (use \"once\" for data that does not change)".into());
    }
    Ok(PollClass::Every(period))
}

fn check_write_function(
    function: u8,
    kind: BlockKind,
    count: u16,
    limits: &Limits,
    place: &str,
    problems: &mut Problems<'_>,
) {
    if !kind.is_writable() {
        problems.add(
            place,
            "a write rule on a read-only block (discrete inputs or input registers)",
        );
        return;
    }
    let ok = match (kind.is_bits(), function) {
        (true, 5) => {
            if count != 1 {
                problems.add(place, "function 5 writes exactly one coil");
            }
            true
        }
        (true, 15) => {
            if count > limits.max_write_bits {
                problems.add(
                    place,
                    format!(
                        "{count} coils exceed the device's write limit {}",
                        limits.max_write_bits
                    ),
                );
            }
            true
        }
        (false, 6) => true,
        (false, 16) => {
            if count > limits.max_write_registers {
                problems.add(
                    place,
                    format!(
                        "{count} registers exceed the device's write limit {}",
                        limits.max_write_registers
                    ),
                );
            }
            true
        }
        _ => false,
    };
    if !ok {
        let allowed = if kind.is_bits() {
            "5 or 15 for coils"
        } else {
            "6 or 16 for registers"
        };
        problems.add(
            place,
            format!("write function {function} does not fit the block (use {allowed})"),
        );
    }
}

fn build_write_frames(
    sections: &[WriteFrameSection],
    layout: &Layout<'_>,
    problems: &mut Problems<'_>,
) -> HashMap<String, WriteFrame> {
    let Layout {
        limits,
        blocks,
        kinds,
        block_index,
        ..
    } = layout;
    let mut frames = HashMap::new();
    for (i, section) in sections.iter().enumerate() {
        let place = format!("write_frames[{i}] ({})", section.name);
        let Some(&block) = block_index.get(section.block.as_str()) else {
            problems.add(
                format!("{place}.block"),
                format!("no block named `{}`", section.block),
            );
            continue;
        };
        let block_len = blocks[block]
            .request
            .read_span()
            .map_or(0, |(_, quantity)| u32::from(quantity));
        if section.count == 0 || u32::from(section.offset) + u32::from(section.count) > block_len {
            problems.add(
                format!("{place}.count"),
                format!(
                    "offsets {}..{} are not inside block `{}` of {block_len}",
                    section.offset,
                    u32::from(section.offset) + u32::from(section.count),
                    section.block
                ),
            );
        }
        check_write_function(
            section.function,
            kinds[block],
            section.count,
            limits,
            &format!("{place}.function"),
            problems,
        );
        let frame = WriteFrame {
            function: section.function,
            address: section.address,
            block,
            offset: section.offset,
            count: section.count,
        };
        if frames.insert(section.name.clone(), frame).is_some() {
            problems.add(
                format!("{place}.name"),
                format!("duplicate write frame `{}`", section.name),
            );
        }
    }
    frames
}

fn build_codec(
    section: &CodecSection,
    place: &str,
    problems: &mut Problems<'_>,
) -> Option<FieldCodec> {
    let check_options = |options: &[String], width: u8, problems: &mut Problems<'_>| {
        if options.len() > 1usize << width {
            problems.add(
                format!("{place}.codec.options"),
                format!("{} options do not fit {width} bits", options.len()),
            );
        }
        let mut seen = std::collections::HashSet::new();
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
    };
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
            if *width == 0 || u32::from(*bit) + u32::from(*width) > 16 {
                problems.add(
                    format!("{place}.codec.width"),
                    format!(
                        "bits {bit}..{} do not fit a word",
                        u32::from(*bit) + u32::from(*width)
                    ),
                );
                return None;
            }
            check_options(options, *width, problems);
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
            check_options(options, *width, problems);
            FieldCodec::Coils {
                width: *width,
                options: options.clone(),
            }
        }
        CodecSection::U8(keys) => {
            let place_of = keys.byte.unwrap_or(BytePlace::Low);
            number(NumberType::U8(place_of), keys)?
        }
        CodecSection::I8(keys) => {
            let place_of = keys.byte.unwrap_or(BytePlace::Low);
            number(NumberType::I8(place_of), keys)?
        }
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
            if *int_digits == 0 || *int_digits > 4 || *frac_digits > 4 {
                problems.add(
                    format!("{place}.codec"),
                    "a BCD pair has 1–4 integer digits and 0–4 fraction digits",
                );
                return None;
            }
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
            if *registers == 0 || *registers > 125 {
                problems.add(
                    format!("{place}.codec.registers"),
                    "a byte string spans 1–125 registers",
                );
                return None;
            }
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
            if *registers == 0 || *registers > 125 {
                problems.add(
                    format!("{place}.codec.registers"),
                    "a string spans 1–125 registers",
                );
                return None;
            }
            FieldCodec::Text {
                registers: *registers,
                byte_order: *byte_order,
                encoding: *encoding,
            }
        }
    })
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
    let before = problems.list.len();
    let decimals = keys.decimals;
    if decimals > 6 {
        problems.add(
            format!("{place}.codec.decimals"),
            format!("{decimals} decimals: at most 6"),
        );
        return None;
    }
    let last_place = 10f64.powi(i32::from(decimals));
    let whole = |value: f64| (value - value.round()).abs() <= 1e-6;
    let factor = match keys.scale {
        // Integers count the last shown place; a float is the value itself.
        None if ty.is_float() => 10i64.pow(u32::from(decimals)),
        None => 1,
        Some(scale) => {
            let counts = scale * last_place;
            if !(counts.is_finite() && (1.0..=1e9).contains(&counts) && whole(counts)) {
                problems.add(
                    format!("{place}.codec.scale"),
                    format!(
                        "scale {scale} is not a positive whole number of the last shown \
                         place with {decimals} decimals (raise `decimals`)"
                    ),
                );
            }
            counts.round() as i64
        }
    };
    let offset = match keys.offset {
        None => 0,
        Some(offset) => {
            let counts = offset * last_place;
            if !(counts.is_finite() && counts.abs() <= 1e15 && whole(counts)) {
                problems.add(
                    format!("{place}.codec.offset"),
                    format!(
                        "offset {offset} is not a whole number of the last shown place with \
                         {decimals} decimals (raise `decimals`)"
                    ),
                );
            }
            counts.round() as i128
        }
    };
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
    (problems.list.len() == before).then(|| NumberCodec {
        ty,
        layout: RegisterLayout {
            words: keys.word_order.unwrap_or_default(),
            bytes: keys.byte_order.unwrap_or_default(),
        },
        decimals,
        factor,
        offset,
        invalid,
        scaled_by_exponent: keys.scale_by.is_some(),
    })
}

fn build_field(
    field: &FieldSection,
    place: &str,
    layout: &Layout<'_>,
    problems: &mut Problems<'_>,
) -> Option<(FieldDef, FieldInfo)> {
    let Layout {
        limits,
        blocks,
        kinds,
        block_index,
        frames,
    } = layout;
    let Some(&block) = block_index.get(field.block.as_str()) else {
        problems.add(
            format!("{place}.block"),
            format!("no block named `{}`", field.block),
        );
        return None;
    };
    let codec = build_codec(&field.codec, place, problems)?;
    let kind = kinds[block];
    if codec.is_bit_codec() != kind.is_bits() {
        let what = if kind.is_bits() {
            "a coil or discrete-input block needs codec `coil` or `coils`"
        } else {
            "codec `coil`/`coils` needs a coil or discrete-input block"
        };
        problems.add(format!("{place}.codec"), what);
        return None;
    }
    let block_len = blocks[block]
        .request
        .read_span()
        .map_or(0, |(_, quantity)| u32::from(quantity));
    let end = u32::from(field.offset) + u32::from(codec.width());
    if end > block_len {
        problems.add(
            format!("{place}.offset"),
            format!(
                "the field covers offsets {}..{end}, outside block `{}` of {block_len}",
                field.offset, field.block
            ),
        );
        return None;
    }

    let write = match &field.write {
        None => None,
        Some(WriteSection::Frame(name)) => match frames.get(name) {
            Some(frame) => {
                if frame.block != block {
                    problems.add(
                        format!("{place}.write"),
                        format!(
                            "write frame `{name}` mirrors another block than `{}`",
                            field.block
                        ),
                    );
                    return None;
                }
                let frame_end = u32::from(frame.offset) + u32::from(frame.count);
                if field.offset < frame.offset || end > frame_end {
                    problems.add(
                        format!("{place}.write"),
                        format!("the field is not inside write frame `{name}`"),
                    );
                    return None;
                }
                Some(frame.clone())
            }
            None => {
                problems.add(
                    format!("{place}.write"),
                    format!("no write frame named `{name}`"),
                );
                return None;
            }
        },
        Some(WriteSection::Own(own)) => {
            let count = codec.width();
            check_write_function(
                own.function,
                kind,
                count,
                limits,
                &format!("{place}.write.function"),
                problems,
            );
            Some(WriteFrame {
                function: own.function,
                address: own.address,
                block,
                offset: field.offset,
                count,
            })
        }
    };
    if write.is_some() && !kind.is_writable() {
        // Reported by check_write_function for own frames; frames of their own are checked too.
        return None;
    }
    if write.is_some() && !codec.is_writable() {
        problems.add(
            format!("{place}.write"),
            "this codec cannot be written (byte strings are read-only)",
        );
    }
    if field.behaviour != Behaviour::State {
        if write.is_none() {
            problems.add(
                format!("{place}.behaviour"),
                "toggle and momentary fields must be writable",
            );
        }
        if !matches!(codec, FieldCodec::Bit { .. } | FieldCodec::Coil { .. }) {
            problems.add(
                format!("{place}.behaviour"),
                "toggle and momentary need a single bit or coil",
            );
        }
    }
    if field.settle_window.is_some() && write.is_none() {
        problems.add(
            format!("{place}.settle_window"),
            "only a writable field has a settle window",
        );
    }
    if field.min_write_interval.is_some() && write.is_none() {
        problems.add(
            format!("{place}.min_write_interval"),
            "only a writable field has a minimum write interval",
        );
    }

    let field_kind = field_kind(field, &codec, write.is_some(), place, problems)?;
    if !field.also.is_empty() {
        match codec.natural_kind() {
            FieldKind::Integer { min, max } if matches!(field_kind, FieldKind::Integer { .. }) => {
                for value in &field.also {
                    if i128::from(*value) < min || i128::from(*value) > max {
                        problems.add(
                            format!("{place}.also"),
                            format!("{value} is outside the codec's {min}–{max}"),
                        );
                    }
                }
            }
            _ => problems.add(format!("{place}.also"), "only integer fields take `also`"),
        }
    }
    let def = FieldDef {
        block,
        offset: field.offset,
        codec,
        write,
        behaviour: field.behaviour,
        settle_window: field.settle_window,
        // Field names resolve once every field is built (`resolve_settle_until`).
        settle_until: Vec::new(),
        // Resolved with the other fields' names too (`resolve_scale_by`).
        scale_by: None,
        overlay: field.overlay,
        also: field.also.clone(),
        example: field.example.clone(),
    };
    let publish = publish_rule(field, &field_kind, place, problems);
    let info = FieldInfo {
        name: field.name.clone(),
        description: field.description.clone(),
        kind: field_kind,
        writable: def.write.is_some(),
        unit: field.unit.clone(),
        step: def.codec.step(),
        also: field.also.clone(),
        ha: HaHints {
            component: field.ha.component.clone(),
            device_class: field.ha.device_class.clone(),
            state_class: field.ha.state_class.clone(),
            unit: field.unit.clone(),
            icon: field.ha.icon.clone(),
            entity_category: field.ha.entity_category.clone(),
        },
        label: field.label.clone(),
        identity: field.identity.map(|key| match key {
            IdentityKey::SerialNumber => Identity::SerialNumber,
            IdentityKey::HwVersion => Identity::HardwareVersion,
            IdentityKey::SwVersion => Identity::SoftwareVersion,
        }),
        min_write_interval: field.min_write_interval,
        publish,
        scaled_by: field.codec.scale_by().map(str::to_string),
    };
    if let Some(label) = &field.label {
        if label.trim().is_empty() || label.trim() != label || label.chars().any(char::is_control) {
            problems.add(
                format!("{place}.label"),
                "a label is words without leading or trailing spaces or control characters",
            );
        }
    }
    if info.identity.is_some() && info.writable {
        problems.add(
            format!("{place}.identity"),
            "an identity field is read from the device, never written",
        );
    }
    if let Some(example) = &field.example {
        if !info.writable {
            problems.add(
                format!("{place}.example"),
                "only a writable field has an example command",
            );
        } else if let Err(rejection) = super::codec::parse_command(&info, example) {
            problems.add(format!("{place}.example"), rejection.0);
        }
    }
    Some((def, info))
}

/// The field's own `publish` keys, checked: a deadband only on a number.
fn publish_rule(
    field: &FieldSection,
    kind: &FieldKind,
    place: &str,
    problems: &mut Problems<'_>,
) -> PublishRule {
    let Some(raw) = &field.publish else {
        return PublishRule::default();
    };
    let rule = match PublishRule::from_raw(raw) {
        Ok(rule) => rule,
        Err(found) => {
            for (key, reason) in found {
                problems.add(format!("{place}.publish.{key}"), reason);
            }
            return PublishRule::default();
        }
    };
    let numeric = matches!(kind, FieldKind::Integer { .. } | FieldKind::Decimal { .. });
    if !numeric {
        for (key, set) in [
            ("deadband", rule.deadband.is_some()),
            ("deadband_percent", rule.deadband_percent.is_some()),
        ] {
            if set {
                problems.add(
                    format!("{place}.publish.{key}"),
                    "a deadband needs a number; ON/OFF, enumerations and text are published on \
                     any change",
                );
            }
        }
    }
    rule
}

fn field_kind(
    field: &FieldSection,
    codec: &FieldCodec,
    writable: bool,
    place: &str,
    problems: &mut Problems<'_>,
) -> Option<FieldKind> {
    let natural = codec.natural_kind();
    let kind = match (natural, field.range) {
        (FieldKind::Integer { min, max }, Some([low, high])) => {
            if low.fract() != 0.0 || high.fract() != 0.0 {
                problems.add(
                    format!("{place}.range"),
                    "an integer field needs an integer range",
                );
                return None;
            }
            // A bound written as the codec's own limit means that limit, though a 64-bit one
            // has no exact spelling in a TOML float (`1.8446744073709552e19` is u64::MAX).
            let exact = |bound: f64, limit: i128| {
                if bound == limit as f64 {
                    limit
                } else {
                    bound as i128
                }
            };
            let (low, high) = (exact(low, min), exact(high, max));
            if low > high || low < min || high > max {
                problems.add(
                    format!("{place}.range"),
                    format!("[{low}, {high}] must be ordered and within the codec's {min}–{max}"),
                );
                return None;
            }
            FieldKind::Integer {
                min: low,
                max: high,
            }
        }
        (
            FieldKind::Decimal {
                min,
                max,
                precision,
            },
            Some([low, high]),
        ) => {
            if !(low.is_finite() && high.is_finite()) || low > high || low < min || high > max {
                problems.add(
                    format!("{place}.range"),
                    format!("[{low}, {high}] must be ordered and within the codec's {min}–{max}"),
                );
                return None;
            }
            FieldKind::Decimal {
                min: low,
                max: high,
                precision,
            }
        }
        (kind, Some(_)) => {
            problems.add(format!("{place}.range"), "only numbers have a range");
            kind
        }
        (kind, None) => kind,
    };
    let kind = match (kind, field.behaviour) {
        (FieldKind::Bool, Behaviour::Momentary) => FieldKind::Momentary,
        (kind, _) => kind,
    };
    if writable && field.range.is_none() && matches!(codec, FieldCodec::Number { .. }) {
        problems.add(
            format!("{place}.range"),
            "a writable number needs a range [min, max]",
        );
    }
    if matches!(kind, FieldKind::Enum { ref options } if options.is_empty()) {
        problems.add(
            format!("{place}.codec.options"),
            "an enumeration needs options",
        );
    }
    Some(kind)
}

/// Checks that no two fields share a bit, except overlay fields, which are views by design.
fn check_overlaps(
    places: &[String],
    infos: &[FieldInfo],
    defs: &[FieldDef],
    blocks: &[ReadBlock],
    problems: &mut Problems<'_>,
) {
    // (block, offset) → (mask, owning field index)
    let mut owners: HashMap<(usize, u16), Vec<(u16, usize)>> = HashMap::new();
    for (i, def) in defs.iter().enumerate() {
        if def.overlay {
            continue;
        }
        for (offset, mask) in def.codec.footprint(def.offset) {
            let slot = owners.entry((def.block, offset)).or_default();
            if let Some(&(_, other)) = slot.iter().find(|(m, _)| m & mask != 0) {
                problems.add(
                    places[i].clone(),
                    format!(
                        "overlaps field `{}` at offset {offset} of block `{}`",
                        infos[other].name, blocks[def.block].name
                    ),
                );
            } else {
                slot.push((mask, i));
            }
        }
    }
    for (i, def) in defs.iter().enumerate() {
        if !def.overlay {
            continue;
        }
        let covered = def
            .codec
            .footprint(def.offset)
            .into_iter()
            .all(|(offset, mask)| {
                owners.get(&(def.block, offset)).is_some_and(|slot| {
                    slot.iter().fold(0u16, |acc, (m, _)| acc | m) & mask == mask
                })
            });
        if !covered {
            problems.add(
                format!("{}.overlay", places[i]),
                "an overlay field must only cover bits that other fields own",
            );
        }
    }
}

fn merge_runs(mut spans: Vec<(u16, u16)>) -> Vec<(u16, u16)> {
    spans.sort_unstable();
    let mut runs: Vec<(u16, u16)> = Vec::new();
    for (offset, len) in spans {
        match runs.last_mut() {
            Some((start, run_len))
                if u32::from(offset) <= u32::from(*start) + u32::from(*run_len) =>
            {
                let end = (u32::from(offset) + u32::from(len))
                    .max(u32::from(*start) + u32::from(*run_len));
                *run_len = (end - u32::from(*start)) as u16;
            }
            _ => runs.push((offset, len)),
        }
    }
    runs
}

/// True when a block of class `exponent` is read at least as often as one of class `user`: an
/// exponent is then never older than the values it scales. `fast` is the period of the fast
/// blocks (the profile's default poll interval, or a device's own).
pub(super) fn polled_at_least_as_often(
    exponent: PollClass,
    user: PollClass,
    limits: &Limits,
    fast: Duration,
) -> bool {
    // A period per class; `None` is a block read only once (at start, after a write into it,
    // on refresh), which no exponent outlasts.
    let period = |class: PollClass| match class {
        PollClass::Fast => Some(fast),
        PollClass::Slow => Some(limits.slow_interval.max(fast)),
        PollClass::Every(period) => Some(period),
        PollClass::Once => None,
    };
    match (exponent, user) {
        // Fast follows the device's poll interval, which slow never undercuts.
        (PollClass::Fast, PollClass::Fast | PollClass::Slow) => true,
        _ => match (period(exponent), period(user)) {
            (_, None) => true,
            (None, Some(_)) => false,
            (Some(exponent), Some(user)) => exponent <= user,
        },
    }
}

/// The index of the field a `scale_by` number takes its exponent from: a whole-number field of
/// the same device (no decimals, scale, offset or exponent of its own) in a block read at
/// least as often as the number's.
fn resolve_scale_by(
    section: &FieldSection,
    place: &str,
    index: usize,
    infos: &[FieldInfo],
    defs: &[FieldDef],
    layout: &Layout<'_>,
    problems: &mut Problems<'_>,
) -> Option<usize> {
    let name = section.codec.scale_by()?;
    let at = format!("{place}.codec.scale_by");
    let Some(exponent) = infos.iter().position(|info| info.name == name) else {
        problems.add(at, format!("no field named `{name}`"));
        return None;
    };
    if exponent == index {
        problems.add(at, "a field cannot scale itself");
        return None;
    }
    let plain_integer = match &defs[exponent].codec {
        FieldCodec::Number(number) => {
            !number.ty.is_float()
                && !number.scaled_by_exponent
                && number.decimals == 0
                && number.factor == 1
                && number.offset == 0
        }
        _ => false,
    };
    if !plain_integer {
        problems.add(
            at,
            format!("`{name}` must be a whole-number field (an integer codec without decimals, scale, offset or scale_by)"),
        );
        return None;
    }
    let blocks = &layout.blocks;
    let (user, held) = (&blocks[defs[index].block], &blocks[defs[exponent].block]);
    let limits = &layout.limits;
    if !polled_at_least_as_often(held.class, user.class, limits, limits.default_poll_interval) {
        problems.add(
            at,
            format!(
                "`{name}` is in block `{}`, polled less often than this field's block `{}`",
                held.name, user.name
            ),
        );
        return None;
    }
    Some(exponent)
}

/// The `settle_until` conditions of a field as (field index, value).
fn resolve_settle_until(
    section: &FieldSection,
    place: &str,
    infos: &[FieldInfo],
    defs: &[FieldDef],
    problems: &mut Problems<'_>,
) -> Vec<(usize, Value)> {
    if !section.settle_until.is_empty() && section.settle_window.is_none() {
        problems.add(
            format!("{place}.settle_until"),
            "settle_until needs a settle_window",
        );
    }
    let mut until = Vec::new();
    for (name, text) in &section.settle_until {
        let at = format!("{place}.settle_until.{name}");
        let Some(index) = infos.iter().position(|info| &info.name == name) else {
            problems.add(at, format!("no field named `{name}`"));
            continue;
        };
        if name == &section.name {
            problems.add(at, "a field cannot settle until its own value");
            continue;
        }
        if defs[index].behaviour == Behaviour::Momentary {
            problems.add(at, "a button has no state to wait for");
            continue;
        }
        match super::codec::parse_command(&infos[index], text) {
            Ok(value) => until.push((index, value)),
            Err(rejection) => problems.add(at, rejection.0),
        }
    }
    until
}

fn build_forbidden(
    sections: &[ForbiddenSection],
    infos: &[FieldInfo],
    defs: &[FieldDef],
    problems: &mut Problems<'_>,
) -> Vec<Forbidden> {
    let mut out = Vec::new();
    for (i, section) in sections.iter().enumerate() {
        let place = format!("forbidden[{i}]");
        let mut when = Vec::new();
        for (name, text) in &section.when {
            let Some(index) = infos.iter().position(|info| &info.name == name) else {
                problems.add(
                    format!("{place}.when.{name}"),
                    format!("no field named `{name}`"),
                );
                continue;
            };
            if defs[index].overlay {
                problems.add(
                    format!("{place}.when.{name}"),
                    "name the fields that own the bits, not an overlay",
                );
            }
            match super::codec::parse_command(&infos[index], text) {
                Ok(value) => when.push((index, value)),
                Err(rejection) => problems.add(format!("{place}.when.{name}"), rejection.0),
            }
        }
        if when.len() < 2 {
            problems.add(
                format!("{place}.when"),
                "a forbidden combination names at least two fields",
            );
        }
        if let Some(&(first, _)) = when.first() {
            if when
                .iter()
                .any(|(f, _)| defs[*f].block != defs[first].block)
            {
                problems.add(
                    format!("{place}.when"),
                    "the fields of a forbidden combination must share one block",
                );
            }
        }
        out.push(Forbidden {
            when,
            reason: section.reason.clone(),
        });
    }
    out
}
