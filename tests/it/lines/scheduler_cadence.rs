//! Per-block cadence in the pure scheduler (explicit instants in, decisions out): many periods
//! on one line keep their exact timing and share it fairly, a `once` block is read at start,
//! when its device comes back from offline and after a write into it and never in steady
//! state, and a refresh reads every block of a device next, after commands and ahead of polls,
//! without moving any block's cadence.

use std::time::{Duration, Instant};

use rtu2mqtt::bus::availability::{Availability, HealthPolicy};
use rtu2mqtt::bus::cadence::{BlockPlan, DevicePlan};
use rtu2mqtt::bus::scheduler::{Due, PollOutcome, Scheduler};
use rtu2mqtt_profile::PollClass;

const MS: Duration = Duration::from_millis(1);
/// What one poll takes on the line in these tests.
const POLL: Duration = Duration::from_millis(10);

fn device(classes: &[PollClass], interval_ms: u32) -> DevicePlan {
    DevicePlan {
        blocks: classes
            .iter()
            .map(|&class| BlockPlan {
                class,
                answer_bytes: 9,
            })
            .collect(),
        poll_interval: interval_ms * MS,
        slow_interval: Duration::from_secs(60),
        startup_delay: Duration::ZERO,
    }
}

/// A line as the line task drives it: every poll takes [`POLL`], its outcome chosen by the
/// test; every decision is logged.
struct Line {
    scheduler: Scheduler<u32>,
    start: Instant,
    now: Instant,
    /// (offset from start, device, block) of every poll and probe handed out.
    polls: Vec<(Duration, usize, usize)>,
    /// (offset from start, command) of every command handed out.
    commands: Vec<(Duration, u32)>,
}

impl Line {
    fn new(devices: Vec<DevicePlan>) -> Line {
        let start = Instant::now();
        Line {
            scheduler: Scheduler::new(devices, HealthPolicy::with_offline_after(3), start),
            start,
            now: start,
            polls: Vec::new(),
            commands: Vec::new(),
        }
    }

    /// Runs until `until` (from start), `outcome` deciding how each poll ends.
    fn run(&mut self, until: Duration, outcome: impl Fn(usize, usize) -> PollOutcome) {
        let end = self.start + until;
        while self.now < end {
            match self.scheduler.next_due(self.now) {
                Due::Poll { device, block } | Due::Probe { device, block } => {
                    self.polls.push((self.now - self.start, device, block));
                    self.now += POLL;
                    let result = outcome(device, block);
                    self.scheduler.record_poll(device, block, result, self.now);
                }
                Due::Command { command, .. } => {
                    self.commands.push((self.now - self.start, command));
                    self.now += POLL;
                }
                Due::Wait(at) => {
                    assert!(at > self.now, "Wait must point into the future");
                    self.now = at.min(end);
                }
                Due::Idle => self.now = end,
            }
        }
    }

    /// The instants `block` of `device` was read at.
    fn reads(&self, device: usize, block: usize) -> Vec<Duration> {
        self.polls
            .iter()
            .filter(|(_, d, b)| (*d, *b) == (device, block))
            .map(|(at, ..)| *at)
            .collect()
    }

    /// The (device, block) of the next `n` polls from `from` on.
    fn polls_from(&self, from: Duration, n: usize) -> Vec<(usize, usize)> {
        self.polls
            .iter()
            .filter(|(at, ..)| *at >= from)
            .take(n)
            .map(|(_, d, b)| (*d, *b))
            .collect()
    }
}

fn answered(_: usize, _: usize) -> PollOutcome {
    PollOutcome::Answered
}

#[test]
fn many_periods_on_one_line_keep_their_exact_timing_and_once_is_read_once() {
    let mut line = Line::new(vec![
        device(
            &[
                PollClass::Fast,
                PollClass::Every(250 * MS),
                PollClass::Every(1500 * MS),
                PollClass::Slow,
                PollClass::Once,
            ],
            500,
        ),
        device(&[PollClass::Every(300 * MS), PollClass::Fast], 700),
    ]);
    line.run(6000 * MS, answered);
    // At most every other block ahead of a block's turn: its read is never later than that.
    let late = 6 * POLL;
    for (device, block, period) in [
        (0, 0, 500 * MS),
        (0, 1, 250 * MS),
        (0, 2, 1500 * MS),
        (1, 0, 300 * MS),
        (1, 1, 700 * MS),
    ] {
        let reads = line.reads(device, block);
        // Every period in the 6 s is served, none twice and none skipped: no drift.
        let periods = (6000 * MS).as_millis() / period.as_millis();
        let expected = periods as usize + usize::from(6000 % period.as_millis() != 0);
        assert_eq!(reads.len(), expected, "{device}/{block}: {reads:?}");
        for (k, at) in reads.iter().enumerate() {
            let slot = period * k as u32;
            assert!(
                *at >= slot && *at <= slot + late,
                "{device}/{block} read {k} at {at:?}, due {slot:?}: {reads:?}"
            );
        }
    }
    // Slow (60 s) and once blocks are read at start only.
    assert_eq!(line.reads(0, 3).len(), 1, "{:?}", line.reads(0, 3));
    assert_eq!(line.reads(0, 4), vec![line.reads(0, 4)[0]]);
    assert!(line.reads(0, 4)[0] <= late);
}

#[test]
fn a_line_of_once_blocks_only_is_idle_after_start() {
    let mut line = Line::new(vec![device(&[PollClass::Once, PollClass::Once], 1000)]);
    line.run(100 * MS, answered);
    assert_eq!(line.polls.len(), 2, "{:?}", line.polls);
    assert_eq!(line.scheduler.next_due(line.now), Due::Idle);
}

#[test]
fn a_once_block_is_read_again_when_its_device_comes_back_from_offline() {
    let mut line = Line::new(vec![device(&[PollClass::Fast, PollClass::Once], 200)]);
    line.run(1000 * MS, answered);
    assert_eq!(line.reads(0, 1), vec![10 * MS]);
    // The device stops answering: offline after three failed polls, then probed.
    line.run(3000 * MS, |_, _| PollOutcome::Failed);
    assert_eq!(line.scheduler.availability(0), Availability::Offline);
    assert_eq!(line.reads(0, 1).len(), 1, "{:?}", line.reads(0, 1));
    // It answers again: the probe brings it back and every block is read at once.
    let back = line.now - line.start;
    line.run(6000 * MS, answered);
    assert_eq!(line.scheduler.availability(0), Availability::Online);
    let once = line.reads(0, 1);
    assert_eq!(once.len(), 2, "read at start and when back: {once:?}");
    assert!(once[1] > back && once[1] <= back + 10_000 * MS, "{once:?}");
    assert!(
        line.reads(0, 0).iter().any(|at| *at > once[1]),
        "polled again"
    );
}

#[test]
fn a_once_block_is_read_again_after_a_write_into_it_unless_the_slot_read_it() {
    let mut line = Line::new(vec![device(&[PollClass::Fast, PollClass::Once], 500)]);
    line.run(1000 * MS, answered);
    assert_eq!(line.reads(0, 1), vec![10 * MS]);
    // A command writing into the once block whose slot did not read it whole.
    let at = line.now;
    line.scheduler
        .after_command(0, &[false, true], &[false, false], at);
    line.run(3000 * MS, answered);
    let reads = line.reads(0, 1);
    assert_eq!(reads.len(), 2, "{reads:?}");
    let after = at - line.start;
    assert!(
        reads[1] >= after && reads[1] <= after + POLL,
        "read right after the slot (a fast poll due then may go first): {reads:?}"
    );
    // A write into it read back whole by its slot: the values are out, nothing more to read.
    let at = line.now;
    line.scheduler
        .after_command(0, &[false, true], &[false, true], at);
    line.run(5000 * MS, answered);
    assert_eq!(line.reads(0, 1).len(), 2);
    // A write into the fast block only leaves the once block alone.
    let at = line.now;
    line.scheduler
        .after_command(0, &[true, false], &[false, false], at);
    line.run(6000 * MS, answered);
    assert_eq!(line.reads(0, 1).len(), 2);
}

#[test]
fn a_failed_read_of_a_once_block_is_tried_again_one_poll_interval_later() {
    let mut line = Line::new(vec![device(&[PollClass::Fast, PollClass::Once], 400)]);
    // The once block fails once (not enough to take the device offline), then answers.
    let failed = std::cell::Cell::new(false);
    line.run(3000 * MS, |_, block| {
        if block == 1 && !failed.replace(true) {
            PollOutcome::Failed
        } else {
            PollOutcome::Answered
        }
    });
    let reads = line.reads(0, 1);
    assert_eq!(reads.len(), 2, "{reads:?}");
    assert!(reads[1] >= reads[0] + 400 * MS && reads[1] <= reads[0] + 400 * MS + 3 * POLL);
}

#[test]
fn a_refresh_reads_every_block_after_the_commands_ahead_of_polls_and_moves_no_cadence() {
    let mut line = Line::new(vec![
        device(
            &[
                PollClass::Fast,
                PollClass::Every(5000 * MS),
                PollClass::Once,
            ],
            1000,
        ),
        // A busy neighbour: always about due.
        device(&[PollClass::Fast], 100),
    ]);
    line.run(2300 * MS, answered);
    let asked = line.now - line.start;
    line.scheduler.push_command(1, 7);
    assert!(line.scheduler.request_refresh(0));
    // Asked again before it ran: still one read of each block.
    assert!(line.scheduler.request_refresh(0));
    line.run(6000 * MS, answered);
    assert_eq!(line.commands, vec![(asked, 7)], "the command first");
    assert_eq!(
        line.polls_from(asked, 3),
        vec![(0, 0), (0, 1), (0, 2)],
        "then every block of the device, ahead of the neighbour's due polls"
    );
    // Each block read once more, and the cadence of each is what it was.
    let fast = line.reads(0, 0);
    let own = line.reads(0, 1);
    let once = line.reads(0, 2);
    assert_eq!(once.len(), 2, "{once:?}");
    assert_eq!(own.len(), 3, "at start, on refresh, at 5 s: {own:?}");
    assert!(
        own[2] >= 5000 * MS && own[2] <= 5000 * MS + 3 * POLL,
        "{own:?}"
    );
    for second in [3, 4, 5] {
        let due = second * 1000 * MS;
        assert!(
            fast.iter().any(|at| *at >= due && *at <= due + 3 * POLL),
            "the fast block kept its 1 s grid: {fast:?}"
        );
    }
}

#[test]
fn a_refresh_waits_for_the_startup_delay_and_is_dropped_for_an_offline_device() {
    let start_up = DevicePlan {
        startup_delay: 2000 * MS,
        ..device(&[PollClass::Once], 1000)
    };
    let mut line = Line::new(vec![start_up, device(&[PollClass::Fast], 500)]);
    assert!(line.scheduler.request_refresh(0));
    line.run(1900 * MS, answered);
    assert!(line.reads(0, 0).is_empty(), "{:?}", line.polls);
    line.run(2500 * MS, answered);
    // The start-up read and the refresh read.
    assert_eq!(line.reads(0, 0).len(), 2, "{:?}", line.polls);

    // Device 1 goes offline: a refresh of it is not done.
    line.run(6000 * MS, |device, _| {
        if device == 1 {
            PollOutcome::Failed
        } else {
            PollOutcome::Answered
        }
    });
    assert_eq!(line.scheduler.availability(1), Availability::Offline);
    assert!(!line.scheduler.request_refresh(1));
    assert!(!line.scheduler.request_refresh(7), "no such device");
}
