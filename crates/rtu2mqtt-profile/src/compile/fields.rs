//! The fields of a profile: each `[[fields]]` section as a [`FieldDef`] (decoding, command
//! planning) and a [`FieldInfo`] (the outside world), then what fields say of each other:
//! overlapping bits, device-registry identities, `settle_until`, `scale_by` exponents and the
//! `[[forbidden]]` combinations.

use std::collections::HashMap;

use super::blocks::{polled_at_least_as_often, Layout};
use super::codecs::build_codec;
use super::problems::Problems;
use super::writes::field_write;
use crate::codec::{parse_command, FieldCodec};
use crate::field::{FieldInfo, FieldKind, HaHints, Identity};
use crate::format::{FieldSection, ForbiddenSection, IdentityKey};
use crate::model::{Behaviour, BlockKind, FieldDef, Forbidden, ReadBlock, WriteFrame};
use crate::publish::PublishRule;
use crate::value::Value;

/// The device's `name` names its topics and files.
pub(super) fn check_device_name(name: &str, problems: &mut Problems<'_>) {
    if !valid_name(name) {
        problems.add(
            "device.name",
            format!("`{name}` must be lower-case letters, digits, `-` or `_`"),
        );
    }
}

/// The `[[fields]]`, as the definitions decoding and planning use and, in parallel, the
/// fields' faces to the outside world. A field refused is left out of both; the checks across
/// fields (overlaps, identities, `settle_until`, `scale_by`) run over the fields built.
pub(super) fn build_fields(
    sections: &[FieldSection],
    layout: &Layout<'_>,
    problems: &mut Problems<'_>,
) -> (Vec<FieldDef>, Vec<FieldInfo>) {
    let mut defs = Vec::new();
    let mut infos = Vec::new();
    let mut places = Vec::new();
    let mut built_sections = Vec::new();
    let mut seen = HashMap::new();
    for (i, field) in sections.iter().enumerate() {
        let place = format!("fields[{i}] ({})", field.name);
        if !valid_name(&field.name) || field.name.contains('-') {
            problems.add(
                format!("{place}.name"),
                "a field name must be lower-case letters, digits or `_`",
            );
        }
        if let Some(reason) = crate::topic_levels::reserved_name_problem(&field.name) {
            problems.add(format!("{place}.name"), reason);
        }
        if seen.insert(field.name.clone(), i).is_some() {
            problems.add(
                format!("{place}.name"),
                format!("duplicate field name `{}`", field.name),
            );
        }
        if let Some((def, info)) = build_field(field, &place, layout, problems) {
            defs.push(def);
            infos.push(info);
            places.push(place);
            built_sections.push(field);
        }
    }
    check_overlaps(&places, &infos, &defs, &layout.blocks, problems);
    check_identities(&places, &infos, problems);
    resolve_references(
        &built_sections,
        &places,
        &infos,
        &mut defs,
        layout,
        problems,
    );
    (defs, infos)
}

/// Each built field's `settle_until` and `scale_by`, which name other fields.
fn resolve_references(
    sections: &[&FieldSection],
    places: &[String],
    infos: &[FieldInfo],
    defs: &mut [FieldDef],
    layout: &Layout<'_>,
    problems: &mut Problems<'_>,
) {
    for (index, (section, place)) in sections.iter().zip(places).enumerate() {
        let until = resolve_settle_until(section, place, infos, defs, problems);
        defs[index].settle_until = until;
        defs[index].scale_by =
            resolve_scale_by(section, place, index, infos, defs, layout, problems);
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

/// A name for topics and files: lower-case letters, digits, `-` or `_`.
fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_' || c == '-')
}

/// One field's definition and its face to the outside world; `None` when the field is refused
/// (the problems are added).
fn build_field(
    field: &FieldSection,
    place: &str,
    layout: &Layout<'_>,
    problems: &mut Problems<'_>,
) -> Option<(FieldDef, FieldInfo)> {
    let Some(&block) = layout.block_index.get(field.block.as_str()) else {
        problems.add(
            format!("{place}.block"),
            format!("no block named `{}`", field.block),
        );
        return None;
    };
    let codec = build_codec(&field.codec, place, problems)?;
    let kind = layout.kinds[block];
    check_codec_fits_block(&codec, kind, place, problems)?;
    check_inside_block(field, &codec, block, layout, place, problems)?;
    let placed = (block, field.offset, codec.width());
    let write = field_write(
        field.write.as_ref(),
        placed,
        &field.block,
        layout,
        place,
        problems,
    )
    .ok()?;
    if write.is_some() && !kind.is_writable() {
        // Reported by check_write_function for own frames; frames of their own are checked too.
        return None;
    }
    check_write_keys(field, &codec, write.is_some(), place, problems);
    let field_kind = field_kind(field, &codec, write.is_some(), place, problems)?;
    check_also(field, &codec, &field_kind, place, problems);
    let def = field_def(field, block, codec, write);
    let publish = publish_rule(field, &field_kind, place, problems);
    let info = field_info(field, field_kind, &def, publish);
    check_info(field, &info, place, problems);
    Some((def, info))
}

/// A bit codec (`coil`, `coils`) belongs in a coil or discrete-input block, every other codec
/// in a register block.
fn check_codec_fits_block(
    codec: &FieldCodec,
    kind: BlockKind,
    place: &str,
    problems: &mut Problems<'_>,
) -> Option<()> {
    if codec.is_bit_codec() != kind.is_bits() {
        let what = if kind.is_bits() {
            "a coil or discrete-input block needs codec `coil` or `coils`"
        } else {
            "codec `coil`/`coils` needs a coil or discrete-input block"
        };
        problems.add(format!("{place}.codec"), what);
        return None;
    }
    Some(())
}

/// The field's registers or bits all lie inside its block.
fn check_inside_block(
    field: &FieldSection,
    codec: &FieldCodec,
    block: usize,
    layout: &Layout<'_>,
    place: &str,
    problems: &mut Problems<'_>,
) -> Option<()> {
    let block_len = layout.block_len(block);
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
    Some(())
}

/// The keys that only mean something on a written field (`behaviour`, `settle_window`,
/// `min_write_interval`), and a write only on a codec that can be written.
fn check_write_keys(
    field: &FieldSection,
    codec: &FieldCodec,
    writable: bool,
    place: &str,
    problems: &mut Problems<'_>,
) {
    if writable && !codec.is_writable() {
        problems.add(
            format!("{place}.write"),
            "this codec cannot be written (byte strings are read-only)",
        );
    }
    if field.behaviour != Behaviour::State {
        if !writable {
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
    if field.settle_window.is_some() && !writable {
        problems.add(
            format!("{place}.settle_window"),
            "only a writable field has a settle window",
        );
    }
    if field.min_write_interval.is_some() && !writable {
        problems.add(
            format!("{place}.min_write_interval"),
            "only a writable field has a minimum write interval",
        );
    }
}

/// `also` (values a field takes beyond its range) is for integer fields, within the codec.
fn check_also(
    field: &FieldSection,
    codec: &FieldCodec,
    field_kind: &FieldKind,
    place: &str,
    problems: &mut Problems<'_>,
) {
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
}

/// What decoding and command planning need of a field. Its references to other fields are
/// resolved once every field is built ([`resolve_references`]).
fn field_def(
    field: &FieldSection,
    block: usize,
    codec: FieldCodec,
    write: Option<WriteFrame>,
) -> FieldDef {
    FieldDef {
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
    }
}

/// The field as the outside world sees it (topics, Home Assistant, the device registry).
fn field_info(
    field: &FieldSection,
    kind: FieldKind,
    def: &FieldDef,
    publish: PublishRule,
) -> FieldInfo {
    FieldInfo {
        name: field.name.clone(),
        description: field.description.clone(),
        kind,
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
        may_be_unavailable: def.codec.may_be_unavailable(),
        unnamed_codes_as_numbers: def.codec.unnamed_codes_as_numbers(),
    }
}

/// A label that reads as words, an identity that is never written, and an example command the
/// field would take.
fn check_info(field: &FieldSection, info: &FieldInfo, place: &str, problems: &mut Problems<'_>) {
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
        } else if let Err(rejection) = parse_command(info, example) {
            problems.add(format!("{place}.example"), rejection.0);
        }
    }
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
        match parse_command(&infos[index], text) {
            Ok(value) => until.push((index, value)),
            Err(rejection) => problems.add(at, rejection.0),
        }
    }
    until
}

/// The `[[forbidden]]` combinations: values of two or more fields of one block that are never
/// written together.
pub(super) fn build_forbidden(
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
            match parse_command(&infos[index], text) {
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

#[cfg(test)]
mod tests {
    use crate::compile::compile;

    const DEVICE: &str = "[device]\nname = \"t\"\nmanufacturer = \"m\"\nmodel = \"x\"\n[line]\n\
        [[blocks]]\nname = \"hold\"\nfunction = 3\nstart = 0\ncount = 8\n\
        [[blocks]]\nname = \"info\"\nfunction = 4\nstart = 0\ncount = 8\npoll = \"once\"\n";

    fn places(fields: &str) -> Vec<String> {
        match compile(&format!("{DEVICE}{fields}"), "p") {
            Ok(_) => Vec::new(),
            Err(errors) => errors.0.into_iter().map(|e| e.place).collect(),
        }
    }

    fn field(name: &str, block: &str, offset: u16, extra: &str) -> String {
        format!(
            "[[fields]]\nname = \"{name}\"\nblock = \"{block}\"\noffset = {offset}\n\
             codec = {{ type = \"u16\" }}\n{extra}"
        )
    }

    #[test]
    fn fields_that_name_each_other_are_resolved() {
        let text = format!(
            "{DEVICE}{}{}{}{}",
            field("exponent", "hold", 0, ""),
            "[[fields]]\nname = \"power\"\nblock = \"hold\"\noffset = 1\n\
             codec = { type = \"u16\", scale_by = \"exponent\" }\n",
            field(
                "setpoint",
                "hold",
                2,
                "range = [0, 9]\nwrite = { function = 6, address = 2 }\n\
                 settle_window = \"2s\"\nsettle_until = { exponent = \"1\" }\n"
            ),
            field("serial", "info", 0, ""),
        );
        let compiled = compile(&text, "p").expect("a valid profile");
        assert_eq!(compiled.defs[1].scale_by, Some(0));
        assert_eq!(compiled.defs[2].settle_until.len(), 1);
        assert_eq!(compiled.defs[2].settle_until[0].0, 0);
        assert_eq!(compiled.infos[1].scaled_by.as_deref(), Some("exponent"));
    }

    #[test]
    fn names_are_lower_case_and_once_only() {
        let fields = format!(
            "{}{}",
            field("Bad", "hold", 0, ""),
            field("Bad", "hold", 1, "")
        );
        assert_eq!(
            places(&fields),
            [
                "p: fields[0] (Bad).name",
                "p: fields[1] (Bad).name",
                "p: fields[1] (Bad).name"
            ]
        );
    }

    #[test]
    fn a_field_outside_its_block_or_over_another_is_refused() {
        let fields = format!(
            "{}{}{}",
            "[[fields]]\nname = \"a\"\nblock = \"hold\"\noffset = 7\n\
             codec = { type = \"u32\" }\n",
            field("b", "hold", 0, ""),
            field("c", "hold", 0, ""),
        );
        assert_eq!(
            places(&fields),
            ["p: fields[0] (a).offset", "p: fields[2] (c)"]
        );
    }

    #[test]
    fn keys_of_written_fields_are_refused_on_a_read_only_one() {
        let fields = field(
            "a",
            "hold",
            0,
            "settle_window = \"1s\"\nmin_write_interval = \"1s\"\n",
        );
        assert_eq!(
            places(&fields),
            [
                "p: fields[0] (a).settle_window",
                "p: fields[0] (a).min_write_interval"
            ]
        );
    }

    #[test]
    fn references_to_other_fields_are_refused_at_their_key() {
        let fields = format!(
            "{}{}{}",
            field("slow", "info", 0, ""),
            "[[fields]]\nname = \"power\"\nblock = \"hold\"\noffset = 0\n\
             codec = { type = \"u16\", scale_by = \"slow\" }\n",
            "[[fields]]\nname = \"self\"\nblock = \"hold\"\noffset = 1\n\
             codec = { type = \"u16\", scale_by = \"self\" }\n",
        );
        assert_eq!(
            places(&fields),
            [
                "p: fields[1] (power).codec.scale_by",
                "p: fields[2] (self).codec.scale_by"
            ]
        );
    }

    #[test]
    fn an_identity_is_filled_once_and_a_forbidden_combination_names_two_fields() {
        let fields = format!(
            "{}{}[[forbidden]]\nwhen = {{ a = \"1\" }}\nreason = \"r\"\n",
            field("a", "hold", 0, "identity = \"serial_number\"\n"),
            field("b", "hold", 1, "identity = \"serial_number\"\n"),
        );
        assert_eq!(
            places(&fields),
            ["p: fields[1] (b).identity", "p: forbidden[0].when"]
        );
    }
}
