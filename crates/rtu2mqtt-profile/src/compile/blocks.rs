//! The device side of a profile: the line's limits (`[line]`), the read blocks
//! (`[[blocks]]`) with their cadence, and the [`Layout`] the write frames and fields are
//! compiled against.

use std::collections::HashMap;
use std::time::Duration;

use super::problems::Problems;
use crate::format::{BlockSection, LineSection};
use crate::model::{BlockKind, FieldDef, Limits, PollClass, ReadBlock, WriteFrame};
use crate::register_numbers::RegisterNumbers;
use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_modbus::Request;

/// What write frames and fields are compiled against: the device's limits, its read blocks (by
/// index and by name) and the shared write frames.
pub(super) struct Layout<'f> {
    pub(super) limits: Limits,
    pub(super) blocks: Vec<ReadBlock>,
    /// Parallel to `blocks`.
    pub(super) kinds: Vec<BlockKind>,
    pub(super) block_index: HashMap<&'f str, usize>,
    /// The `[[write_frames]]` by name; empty while they are being built.
    pub(super) frames: HashMap<String, WriteFrame>,
    /// How the profile numbers its registers: write addresses are resolved with it too.
    pub(super) numbers: RegisterNumbers,
}

impl<'f> Layout<'f> {
    /// The read blocks compiled against the line's limits, with no write frames yet.
    pub(super) fn new(
        limits: Limits,
        numbers: Option<RegisterNumbers>,
        sections: &'f [BlockSection],
        problems: &mut Problems<'_>,
    ) -> Self {
        let (blocks, kinds) = build_blocks(sections, &limits, numbers, problems);
        let block_index = sections
            .iter()
            .enumerate()
            .map(|(i, b)| (b.name.as_str(), i))
            .collect();
        Self {
            limits,
            blocks,
            kinds,
            block_index,
            frames: HashMap::new(),
            numbers: numbers.unwrap_or_default(),
        }
    }

    /// The bus address of a write's `address` (in the profile's numbers) for `function`; 0
    /// with a problem at `place` when it is none.
    pub(super) fn write_address(
        &self,
        address: u32,
        function: u8,
        place: &str,
        problems: &mut Problems<'_>,
    ) -> u16 {
        bus_address(self.numbers, address, function, place, problems)
    }

    /// How many registers or bits block `block` reads.
    pub(super) fn block_len(&self, block: usize) -> u32 {
        self.blocks[block]
            .request
            .read_span()
            .map_or(0, |(_, quantity)| u32::from(quantity))
    }
}

/// The bus address of `number` in the profile's `numbers` for `function`; 0 with a problem at
/// `place` when it is none.
pub(super) fn bus_address(
    numbers: RegisterNumbers,
    number: u32,
    function: u8,
    place: &str,
    problems: &mut Problems<'_>,
) -> u16 {
    numbers
        .bus_address(number, function)
        .unwrap_or_else(|reason| {
            problems.add(place.to_string(), reason);
            0
        })
}

pub(super) fn build_limits(line: &LineSection, problems: &mut Problems<'_>) -> Limits {
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
    numbers: Option<RegisterNumbers>,
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
        let quantity = section.count;
        let start = numbers
            .unwrap_or_default()
            .bus_address(section.start, section.function)
            .unwrap_or_else(|reason| {
                problems.add(format!("{place}.start"), reason);
                0
            });
        if let Some(address) = numbers
            .is_none()
            .then(|| RegisterNumbers::Bus.looks_like_modicon(start, section.function))
            .flatten()
        {
            problems.warn(
                format!("{place}.start"),
                format!(
                    "{start} looks like a Modicon number (register {} of its table, bus \
                     address {address}); a manual's numbers are copied with \
                     `register_numbers = \"modicon\"` in [device], and `register_numbers = \
                     \"bus\"` says that {start} is meant",
                    u32::from(address) + 1
                ),
            );
        }
        let (kind, request, max) = read_request(section, start, limits).unwrap_or_else(|other| {
            problems.add(
                format!("{place}.function"),
                format!("{other} is not a read function (1, 2, 3 or 4)"),
            );
            (
                BlockKind::HoldingRegisters,
                Request::ReadHoldingRegisters { start, quantity },
                limits.max_read_registers,
            )
        });
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

/// A block's read request from its `function`, with its kind and the device's limit on its
/// count; the function number itself when it is not a read function.
fn read_request(
    section: &BlockSection,
    start: u16,
    limits: &Limits,
) -> Result<(BlockKind, Request, u16), u8> {
    let quantity = section.count;
    Ok(match section.function {
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
        other => return Err(other),
    })
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

/// Each block's `used_runs`: the spans its fields cover, merged, or the whole block when it is
/// `read_whole` and any field uses it.
pub(super) fn mark_used_runs(
    blocks: Vec<ReadBlock>,
    sections: &[BlockSection],
    defs: &[FieldDef],
) -> Vec<ReadBlock> {
    let mut used: Vec<Vec<(u16, u16)>> = vec![Vec::new(); blocks.len()];
    for def in defs {
        used[def.block].push((def.offset, def.codec.width()));
    }
    blocks
        .into_iter()
        .zip(used)
        .zip(sections)
        .map(|((mut block, spans), section)| {
            block.used_runs = merge_runs(spans);
            if section.read_whole && !block.used_runs.is_empty() {
                block.used_runs = vec![(0, section.count)];
            }
            block
        })
        .collect()
}

/// A block no field uses is a mistake, reported only when nothing else is wrong (a field
/// refused for another reason would leave its block unused too).
pub(super) fn check_blocks_used(blocks: &[ReadBlock], problems: &mut Problems<'_>) {
    for (i, block) in blocks.iter().enumerate() {
        if block.used_runs.is_empty() && problems.is_empty() {
            problems.add(
                format!("blocks[{i}] ({})", block.name),
                "no field uses this block",
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
pub(crate) fn polled_at_least_as_often(
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

#[cfg(test)]
mod tests {
    use super::*;

    fn line(text: &str) -> LineSection {
        toml::from_str(text).expect("a line section")
    }

    fn block(text: &str) -> BlockSection {
        toml::from_str(text).expect("a block section")
    }

    fn places(problems: Problems<'_>) -> Vec<String> {
        match problems.into_result(()) {
            Ok(()) => Vec::new(),
            Err(errors) => errors.0.into_iter().map(|e| e.place).collect(),
        }
    }

    #[test]
    fn the_default_line_is_accepted_with_its_defaults() {
        let mut problems = Problems::new("p");
        let limits = build_limits(&line(""), &mut problems);
        assert!(problems.is_empty());
        assert_eq!(limits.address_range, 1..=247);
        assert_eq!(limits.default_poll_interval, Duration::from_millis(100));
        assert_eq!(limits.max_read_registers, 125);
    }

    #[test]
    fn a_line_over_the_modbus_limits_is_refused_at_its_keys() {
        let mut problems = Problems::new("p");
        build_limits(
            &line("parity = \"mark\"\nmax_read_registers = 126\nbaud = 1000"),
            &mut problems,
        );
        assert_eq!(
            places(problems),
            [
                "p: line.parity",
                "p: line.max_read_registers",
                "p: line.baud"
            ]
        );
    }

    #[test]
    fn poll_takes_the_classes_and_periods_within_the_line() {
        let limits = build_limits(&line(""), &mut Problems::new("p"));
        assert_eq!(poll_class("once", &limits), Ok(PollClass::Once));
        assert_eq!(
            poll_class("15s", &limits),
            Ok(PollClass::Every(Duration::from_secs(15)))
        );
        assert!(poll_class("50ms", &limits).is_err_and(|r| r.contains("min_poll_interval")));
        assert!(poll_class("25h", &limits).is_err_and(|r| r.contains("24h")));
        assert!(poll_class("soon", &limits).is_err());
    }

    #[test]
    fn a_block_is_refused_at_its_function_count_and_name() {
        let limits = build_limits(&line(""), &mut Problems::new("p"));
        let sections = [
            block("name = \"a\"\nfunction = 5\nstart = 0\ncount = 2"),
            block("name = \"a\"\nfunction = 4\nstart = 65535\ncount = 126"),
        ];
        let mut problems = Problems::new("p");
        let (blocks, kinds) = build_blocks(&sections, &limits, None, &mut problems);
        assert_eq!(
            kinds,
            [BlockKind::HoldingRegisters, BlockKind::InputRegisters]
        );
        assert_eq!(
            blocks[1].request,
            Request::ReadInputRegisters {
                start: 65535,
                quantity: 126
            }
        );
        assert_eq!(
            places(problems),
            [
                "p: blocks[0] (a).function",
                "p: blocks[1] (a).name",
                "p: blocks[1] (a).count",
                "p: blocks[1] (a).count",
            ]
        );
    }

    #[test]
    fn used_spans_merge_into_runs() {
        assert_eq!(
            merge_runs(vec![(6, 2), (0, 2), (2, 1), (7, 3)]),
            [(0, 3), (6, 4)]
        );
        assert!(merge_runs(Vec::new()).is_empty());
    }

    #[test]
    fn a_once_block_is_never_outlasted_and_outlasts_every_period() {
        let limits = build_limits(&line(""), &mut Problems::new("p"));
        let fast = limits.default_poll_interval;
        let every = |s| PollClass::Every(Duration::from_secs(s));
        assert!(polled_at_least_as_often(
            PollClass::Fast,
            PollClass::Slow,
            &limits,
            fast
        ));
        assert!(polled_at_least_as_often(
            every(60),
            PollClass::Once,
            &limits,
            fast
        ));
        assert!(!polled_at_least_as_often(
            PollClass::Once,
            every(60),
            &limits,
            fast
        ));
        assert!(!polled_at_least_as_often(
            PollClass::Slow,
            PollClass::Fast,
            &limits,
            fast
        ));
        assert!(polled_at_least_as_often(every(5), every(10), &limits, fast));
    }

    #[test]
    fn starts_are_read_in_the_profiles_register_numbers_and_a_modicon_look_is_warned_about() {
        let limits = build_limits(&line(""), &mut Problems::new("p"));
        let sections = [block(
            "name = \"a\"\nfunction = 3\nstart = 43204\ncount = 2",
        )];
        let mut problems = Problems::new("p");
        let (blocks, _) = build_blocks(
            &sections,
            &limits,
            Some(RegisterNumbers::Modicon),
            &mut problems,
        );
        assert_eq!(blocks[0].request.read_span(), Some((3203, 2)));
        assert!(problems.is_empty() && problems.take_warnings().is_empty());

        // Unsaid, 43204 is read as a bus address, with a warning naming the rule.
        let (blocks, _) = build_blocks(&sections, &limits, None, &mut problems);
        assert_eq!(blocks[0].request.read_span(), Some((43204, 2)));
        let warnings = problems.take_warnings();
        assert_eq!(warnings.len(), 1);
        assert_eq!(warnings[0].place, "p: blocks[0] (a).start");
        assert!(
            warnings[0]
                .reason
                .contains("register 3204 of its table, bus address 3203"),
            "{}",
            warnings[0].reason
        );
        // Said to be a bus address, it is one, silently.
        build_blocks(
            &sections,
            &limits,
            Some(RegisterNumbers::Bus),
            &mut problems,
        );
        assert!(problems.is_empty() && problems.take_warnings().is_empty());

        // A number of another table is refused at the block's start.
        let input = [block(
            "name = \"i\"\nfunction = 4\nstart = 43204\ncount = 2",
        )];
        build_blocks(
            &input,
            &limits,
            Some(RegisterNumbers::Modicon),
            &mut problems,
        );
        assert_eq!(places(problems), ["p: blocks[0] (i).start"]);
    }
}
