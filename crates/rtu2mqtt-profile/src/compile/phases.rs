//! A profile's compilation from end to end: the TOML read with its errors placed at their line
//! and column, then the phases in their order, each against what the ones before it built.

use super::actions::build_actions;
use super::blocks::{build_limits, check_blocks_used, mark_used_runs, Layout};
use super::fields::{build_fields, build_forbidden, check_device_name};
use super::problems::{Problems, ProfileError, ProfileErrors};
use super::writes::{build_write_frames, named_frames};
use crate::format::ProfileFile;
use crate::identification::Identification;
use crate::model::Compiled;

/// Parses and validates a profile. `source` names the file (or built-in) in error places.
pub(crate) fn compile(text: &str, source: &str) -> Result<Compiled, ProfileErrors> {
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
        let reason = match err.message() {
            "" => unreadable(text, err.span()),
            message => message.to_string(),
        };
        ProfileErrors(vec![ProfileError { place, reason }])
    })?;
    let mut problems = Problems::new(source);
    let mut compiled = build(file, &mut problems);
    compiled.warnings = problems.take_warnings();
    problems.into_result(compiled)
}

/// Why the TOML reader stopped at `span`, for the errors it gives no words for (a control
/// character in a comment).
fn unreadable(text: &str, span: Option<std::ops::Range<usize>>) -> String {
    let at = span.and_then(|span| text.get(span.start..)?.chars().next());
    match at {
        Some(c) if c.is_control() => {
            format!(
                "the control character U+{:04X} is not allowed in TOML",
                u32::from(c)
            )
        }
        Some(c) => format!("not TOML from {c:?} on"),
        None => "not TOML".to_string(),
    }
}

/// The phases in order: each one is compiled against what the ones before it built, and adds
/// its problems in the file's order.
fn build(file: ProfileFile, problems: &mut Problems<'_>) -> Compiled {
    let limits = build_limits(&file.line, problems);
    check_device_name(&file.device.name, problems);
    let mut layout = Layout::new(limits, file.device.register_numbers, &file.blocks, problems);
    layout.frames = build_write_frames(&file.write_frames, &layout, problems);
    let (defs, infos) = build_fields(&file.fields, &layout, problems);
    let blocks = mark_used_runs(layout.blocks, &file.blocks, &defs);
    check_blocks_used(&blocks, problems);
    let forbidden = build_forbidden(&file.forbidden, &infos, &defs, problems);
    let named_frames = named_frames(&file.write_frames, &layout.frames);
    let actions = build_actions(
        &file.actions,
        &infos,
        &layout.limits,
        layout.numbers,
        problems,
    );
    let identification = file.device.identification.and_then(|section| {
        Identification::from_section(section)
            .map_err(|reason| problems.add("device.identification", reason))
            .ok()
    });

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
        warnings: Vec::new(),
        actions,
        identification,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEVICE: &str = "[device]\nname = \"t\"\nmanufacturer = \"m\"\nmodel = \"x\"\n[line]\n\
        [[blocks]]\nname = \"hold\"\nfunction = 3\nstart = 0\ncount = 2\n";

    #[test]
    fn a_consistent_profile_compiles_with_the_runs_its_fields_use() {
        let text = format!(
            "{DEVICE}[[fields]]\nname = \"a\"\nblock = \"hold\"\noffset = 1\n\
             codec = {{ type = \"u16\" }}\n"
        );
        let compiled = compile(&text, "p").expect("a valid profile");
        assert_eq!(compiled.name, "t");
        assert_eq!(compiled.blocks[0].used_runs, [(1, 1)]);
        assert_eq!(compiled.infos[0].name, "a");
    }

    #[test]
    fn a_file_that_is_not_the_format_is_refused_at_its_line_and_column() {
        let errors = compile("[device]\nname = 3\n", "p.toml").unwrap_err();
        assert_eq!(errors.0.len(), 1);
        assert_eq!(errors.0[0].place, "p.toml:2:8");
    }

    /// Found by fuzzing (`fuzz/`, profile_toml): the TOML reader gives no words for a control
    /// character in a comment, and the refusal had no reason.
    #[test]
    fn a_control_character_is_refused_with_a_reason() {
        let errors = compile("# a\0b\n", "p.toml").unwrap_err();
        assert_eq!(
            errors.to_string(),
            "p.toml:1:4: the control character U+0000 is not allowed in TOML"
        );
        let errors = compile("[device]\n# x\u{1}\n", "p.toml").unwrap_err();
        assert_eq!(
            errors.to_string(),
            "p.toml:2:4: the control character U+0001 is not allowed in TOML"
        );
    }

    #[test]
    fn problems_of_every_phase_are_reported_in_the_order_of_the_phases() {
        let text = DEVICE.replace("name = \"t\"", "name = \"T\"").replace("[line]", "[line]\nbaud = 7")
            + "[[fields]]\nname = \"a\"\nblock = \"none\"\noffset = 0\ncodec = { type = \"u16\" }\n";
        let places: Vec<String> = compile(&text, "p")
            .unwrap_err()
            .0
            .into_iter()
            .map(|e| e.place)
            .collect();
        assert_eq!(
            places,
            ["p: line.baud", "p: device.name", "p: fields[0] (a).block"]
        );
    }

    #[test]
    fn an_unused_block_is_reported_only_when_nothing_else_is_wrong() {
        let errors = compile(DEVICE, "p").unwrap_err();
        assert_eq!(
            errors.to_string(),
            "p: blocks[0] (hold): no field uses this block"
        );
    }
}
