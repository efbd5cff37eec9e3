//! The write side of a profile: the shared `[[write_frames]]`, and the write of one field
//! (a frame named, or a function and address of its own), each checked against its block and
//! the device's write limits.

use std::collections::HashMap;

use super::blocks::Layout;
use super::problems::Problems;
use crate::format::{WriteFrameSection, WriteSection};
use crate::model::{BlockKind, Limits, WriteFrame};

/// A write function that fits its block (5/15 for coils, 6/16 for registers) and writes no more
/// than the device takes at once.
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
            check_write_limit(count, limits.max_write_bits, "coils", place, problems);
            true
        }
        (false, 6) => true,
        (false, 16) => {
            check_write_limit(
                count,
                limits.max_write_registers,
                "registers",
                place,
                problems,
            );
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

/// Refuses a multiple write of more `items` (coils or registers) than the device takes in one
/// frame.
fn check_write_limit(
    count: u16,
    limit: u16,
    items: &str,
    place: &str,
    problems: &mut Problems<'_>,
) {
    if count > limit {
        problems.add(
            place,
            format!("{count} {items} exceed the device's write limit {limit}"),
        );
    }
}

/// The `[[write_frames]]` by name, each checked against its block and the device's write
/// limits.
pub(super) fn build_write_frames(
    sections: &[WriteFrameSection],
    layout: &Layout<'_>,
    problems: &mut Problems<'_>,
) -> HashMap<String, WriteFrame> {
    let Layout {
        limits,
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
        let block_len = layout.block_len(block);
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
        let address = layout.write_address(
            section.address,
            section.function,
            &format!("{place}.address"),
            problems,
        );
        let frame = WriteFrame {
            function: section.function,
            address,
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

/// Where a field is written: the write frame it names or one of its own. `block`, `offset` and
/// `width` place the field; `None` when the field is not written, or its write is refused (the
/// problem is added).
pub(super) fn field_write(
    write: Option<&WriteSection>,
    (block, offset, width): (usize, u16, u16),
    block_name: &str,
    layout: &Layout<'_>,
    place: &str,
    problems: &mut Problems<'_>,
) -> Result<Option<WriteFrame>, ()> {
    let end = u32::from(offset) + u32::from(width);
    match write {
        None => Ok(None),
        Some(WriteSection::Frame(name)) => match layout.frames.get(name) {
            Some(frame) => {
                if frame.block != block {
                    problems.add(
                        format!("{place}.write"),
                        format!("write frame `{name}` mirrors another block than `{block_name}`"),
                    );
                    return Err(());
                }
                let frame_end = u32::from(frame.offset) + u32::from(frame.count);
                if offset < frame.offset || end > frame_end {
                    problems.add(
                        format!("{place}.write"),
                        format!("the field is not inside write frame `{name}`"),
                    );
                    return Err(());
                }
                Ok(Some(frame.clone()))
            }
            None => {
                problems.add(
                    format!("{place}.write"),
                    format!("no write frame named `{name}`"),
                );
                Err(())
            }
        },
        Some(WriteSection::Own(own)) => {
            check_write_function(
                own.function,
                layout.kinds[block],
                width,
                &layout.limits,
                &format!("{place}.write.function"),
                problems,
            );
            let address = layout.write_address(
                own.address,
                own.function,
                &format!("{place}.write.address"),
                problems,
            );
            Ok(Some(WriteFrame {
                function: own.function,
                address,
                block,
                offset,
                count: width,
            }))
        }
    }
}

/// The write frames by name in the file's order, for what the device exposes of them.
pub(super) fn named_frames(
    sections: &[WriteFrameSection],
    frames: &HashMap<String, WriteFrame>,
) -> Vec<(String, WriteFrame)> {
    sections
        .iter()
        .filter_map(|section| {
            frames
                .get(&section.name)
                .map(|frame| (section.name.clone(), frame.clone()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use crate::compile::compile;

    const DEVICE: &str = "[device]\nname = \"t\"\nmanufacturer = \"m\"\nmodel = \"x\"\n\
        [line]\nmax_write_registers = 4\n\
        [[blocks]]\nname = \"hold\"\nfunction = 3\nstart = 100\ncount = 8\n\
        [[blocks]]\nname = \"coils\"\nfunction = 1\nstart = 0\ncount = 8\n\
        [[fields]]\nname = \"lamp\"\nblock = \"coils\"\noffset = 0\ncodec = { type = \"coil\" }\n";

    fn problems(rest: &str) -> Vec<(String, String)> {
        match compile(&format!("{DEVICE}{rest}"), "p") {
            Ok(_) => Vec::new(),
            Err(errors) => errors.0.into_iter().map(|e| (e.place, e.reason)).collect(),
        }
    }

    #[test]
    fn a_field_written_through_a_shared_frame_gets_that_frame() {
        let compiled = compile(
            &format!(
                "{DEVICE}[[write_frames]]\nname = \"pair\"\nfunction = 16\naddress = 102\n\
                 block = \"hold\"\noffset = 2\ncount = 2\n\
                 [[fields]]\nname = \"low\"\nblock = \"hold\"\noffset = 3\n\
                 codec = {{ type = \"u16\" }}\nrange = [0, 9]\nwrite = \"pair\"\n"
            ),
            "p",
        )
        .expect("a valid profile");
        let frame = compiled.defs[1].write.as_ref().expect("a write frame");
        assert_eq!(
            (frame.function, frame.address, frame.offset, frame.count),
            (16, 102, 2, 2)
        );
        assert_eq!(compiled.named_frames.len(), 1);
        assert_eq!(compiled.named_frames[0].0, "pair");
    }

    #[test]
    fn a_frame_outside_its_block_or_over_the_write_limit_is_refused_at_its_keys() {
        assert_eq!(
            problems(
                "[[write_frames]]\nname = \"big\"\nfunction = 16\naddress = 100\n\
                 block = \"hold\"\noffset = 2\ncount = 7\n"
            ),
            [
                (
                    "p: write_frames[0] (big).count".into(),
                    "offsets 2..9 are not inside block `hold` of 8".into()
                ),
                (
                    "p: write_frames[0] (big).function".into(),
                    "7 registers exceed the device's write limit 4".into()
                ),
            ]
        );
    }

    #[test]
    fn a_write_function_must_fit_its_block() {
        assert_eq!(
            problems(
                "[[fields]]\nname = \"fan\"\nblock = \"coils\"\noffset = 1\n\
                 codec = { type = \"coil\" }\nwrite = { function = 6, address = 1 }\n"
            ),
            [(
                "p: fields[1] (fan).write.function".into(),
                "write function 6 does not fit the block (use 5 or 15 for coils)".into()
            )]
        );
    }

    #[test]
    fn a_field_naming_a_missing_or_foreign_frame_is_refused_at_its_write() {
        let found = problems(
            "[[write_frames]]\nname = \"pair\"\nfunction = 16\naddress = 100\n\
             block = \"hold\"\noffset = 0\ncount = 2\n\
             [[fields]]\nname = \"a\"\nblock = \"hold\"\noffset = 4\n\
             codec = { type = \"u16\" }\nrange = [0, 9]\nwrite = \"pair\"\n\
             [[fields]]\nname = \"b\"\nblock = \"hold\"\noffset = 5\n\
             codec = { type = \"u16\" }\nrange = [0, 9]\nwrite = \"none\"\n",
        );
        assert_eq!(
            found,
            [
                (
                    "p: fields[1] (a).write".into(),
                    "the field is not inside write frame `pair`".into()
                ),
                (
                    "p: fields[2] (b).write".into(),
                    "no write frame named `none`".into()
                ),
            ]
        );
    }
}
