//! What a line does next, as a pure function of time: the clock is passed in, nothing here
//! sleeps or touches a port (paused-clock and explicit-instant tests drive it).
//!
//! Rules, in order:
//! 1. Queued commands run before any poll, first come first served, as soon as their device's
//!    start-up delay has passed (a command for a device still starting up does not hold back
//!    commands for the others).
//! 2. A refresh of a device (`<prefix>/<device>/refresh`) reads each of its blocks once, after
//!    the queued commands and ahead of every poll. Its reads move no block's cadence; a
//!    refresh of an offline device is dropped (every block is read when it comes back).
//! 3. Polls are served earliest due first. Every block has its own due instant (fast blocks on
//!    the device's poll interval, slow blocks on the slow interval, a block with a period of
//!    its own on that period); after a poll the block is
//!    due again one interval after it was *due* (no drift); when the line fell behind that,
//!    one interval after the poll started, so missed periods are skipped and never caught up
//!    in a burst. Ties go to the
//!    device served least recently, which makes back-to-back polling (interval 0) round-robin.
//!    A `once` block has no period: once read it is due only when the device comes back from
//!    offline, after a write that can have changed it, or on a refresh (a read of it that
//!    fails is tried again one poll interval later).
//! 4. An offline device has no polls, only a probe (its cheapest block) on the back-off
//!    schedule of [`super::availability`]. That bounds what a dead device costs the line and it can
//!    never starve the others: its failing polls push its own due instants, not theirs.
//! 5. Exception 06 (busy) re-schedules the block a short while later without counting as a
//!    failure; other devices use the line meanwhile.
//! 6. A command slot moves no block's cadence: the blocks it read whole and the blocks its
//!    write cannot have changed stay due when they were; a block the write can have changed
//!    and the slot did not read is due at once.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use super::availability::{Availability, DeviceHealth, HealthChange, HealthPolicy};
use super::cadence::DevicePlan;

/// How long a block answered with exception 06 (busy) waits before it is read again.
pub const BUSY_RETRY_DELAY: Duration = Duration::from_millis(100);

/// Consecutive busy answers after which the block counts as failed (a device that is busy
/// forever is as good as absent).
pub const BUSY_LIMIT: u32 = 10;

/// What the line should do next.
#[derive(Debug, PartialEq, Eq)]
pub enum Due<C> {
    /// Run this command's slot now.
    Command { device: usize, command: C },
    /// Read this block now.
    Poll { device: usize, block: usize },
    /// Read this block now as the probe of an offline device (one attempt, no retries).
    Probe { device: usize, block: usize },
    /// Nothing is due before this instant (a command arriving earlier changes that).
    Wait(Instant),
    /// No devices and no commands: wait for a command.
    Idle,
}

/// How a poll ended, as far as scheduling and health care.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PollOutcome {
    /// The device answered (values, or an exception other than busy).
    Answered,
    /// Exception 06: the device is there but cannot serve now.
    Busy,
    /// No usable answer after the retries.
    Failed,
}

#[derive(Debug)]
struct DeviceSlot {
    plan: DevicePlan,
    ready_at: Instant,
    /// When each block is due; None for a `once` block that has been read.
    block_due: Vec<Option<Instant>>,
    /// Blocks a refresh asked for that have not been handed out yet.
    refresh: Vec<bool>,
    /// Refresh reads handed out whose end has not been recorded yet.
    refreshing: Vec<bool>,
    /// Consecutive busy answers per block.
    busy_count: Vec<u32>,
    /// When each block's last poll was handed out.
    started: Vec<Instant>,
    health: DeviceHealth,
    /// Serial number of the last time the device was served: the fairness tie-breaker.
    last_served: u64,
}

/// When a block polled at `started` (it was due at `due`) is due again, the poll having ended
/// at `now`: one interval after it was due, so the cadence does not drift; when the line fell
/// behind that, one interval after the poll started (missed periods are skipped, not caught up
/// in a burst), and never in the past. A device whose interval is shorter than a transaction
/// is thus polled back to back with no idle gap.
fn next_due_after(due: Instant, interval: Duration, started: Instant, now: Instant) -> Instant {
    let next = due + interval;
    if next >= now {
        return next;
    }
    (started + interval).max(now)
}

/// The longest a line's first polls are put off to spread the lines' polls over the second.
pub const MAX_POLL_PHASE: Duration = Duration::from_secs(1);
/// The most phases lines are spread over: lines in one phase poll together, so each wake-up
/// of the gateway still serves a group of them, while the groups leave the interval's first
/// millisecond to the few lines that share it.
pub const MAX_POLL_PHASES: u32 = 20;
/// Lines that poll together in one phase: a plant of fewer than twice this many lines has one
/// phase, and all its lines poll at once, with no phase to wait for.
pub const LINES_PER_PHASE: usize = 50;

/// The phases `lines` lines are spread over: one per [`LINES_PER_PHASE`], at least one and at
/// most [`MAX_POLL_PHASES`].
pub fn poll_phases(lines: usize) -> u32 {
    let phases = (lines / LINES_PER_PHASE).clamp(1, MAX_POLL_PHASES as usize);
    u32::try_from(phases).unwrap_or(MAX_POLL_PHASES)
}

/// Where in its poll interval a line of `name` polls: one of `phases` offsets evenly spaced
/// below both the line's shortest poll interval and [`MAX_POLL_PHASE`], drawn from its name
/// (FNV-1a), so stable; zero with one phase. The many lines of a plant of Modbus TCP devices
/// then do not all send their requests in the same millisecond of every second, which would
/// make the last of them late.
pub fn poll_phase(name: &str, shortest_interval: Duration, phases: u32) -> Duration {
    let phases = phases.clamp(1, MAX_POLL_PHASES);
    let span = shortest_interval.min(MAX_POLL_PHASE);
    let hash = name.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |hash, byte| {
        (hash ^ u64::from(byte)).wrapping_mul(0x0100_0000_01b3)
    });
    let phase = u32::try_from(hash % u64::from(phases)).unwrap_or(0);
    span / phases * phase
}

/// The scheduler of one line. `C` is whatever the line keeps per queued command.
#[derive(Debug)]
pub struct Scheduler<C> {
    devices: Vec<DeviceSlot>,
    commands: VecDeque<(usize, C)>,
    /// Devices with a refresh waiting, first asked first served.
    refreshes: VecDeque<usize>,
    serial: u64,
}

impl<C> Scheduler<C> {
    /// A scheduler for `plans` (indexed like the line's devices) started at `start`.
    pub fn new(plans: Vec<DevicePlan>, policy: HealthPolicy, start: Instant) -> Self {
        Self::phased(plans, policy, start, Duration::ZERO)
    }

    /// A scheduler whose first polls are due `phase` after each device is ready (see
    /// [`poll_phase`]); commands and refreshes do not wait for it.
    pub fn phased(
        plans: Vec<DevicePlan>,
        policy: HealthPolicy,
        start: Instant,
        phase: Duration,
    ) -> Self {
        let devices = plans
            .into_iter()
            .map(|plan| {
                let ready_at = start + plan.startup_delay;
                let first_poll = ready_at + phase;
                DeviceSlot {
                    block_due: vec![Some(first_poll); plan.blocks.len()],
                    refresh: vec![false; plan.blocks.len()],
                    refreshing: vec![false; plan.blocks.len()],
                    busy_count: vec![0; plan.blocks.len()],
                    started: vec![first_poll; plan.blocks.len()],
                    plan,
                    ready_at,
                    health: DeviceHealth::new(policy),
                    last_served: 0,
                }
            })
            .collect();
        Scheduler {
            devices,
            commands: VecDeque::new(),
            refreshes: VecDeque::new(),
            serial: 0,
        }
    }

    /// Asks for every block of `device` to be read in its next slots (after the queued
    /// commands, before any poll). False when it is not done: the device is unknown, has no
    /// blocks, or is offline (it is read whole when it comes back).
    pub fn request_refresh(&mut self, device: usize) -> bool {
        let Some(slot) = self.devices.get_mut(device) else {
            return false;
        };
        if slot.health.is_offline() || slot.refresh.is_empty() {
            return false;
        }
        slot.refresh.iter_mut().for_each(|asked| *asked = true);
        if !self.refreshes.contains(&device) {
            self.refreshes.push_back(device);
        }
        true
    }

    /// The next refresh read that may run at `now`, taken out of its request. A device still
    /// starting up keeps its request and notes in `earliest` when it can run; an offline
    /// device's request is dropped.
    fn take_refresh(
        &mut self,
        now: Instant,
        earliest: &mut Option<Instant>,
    ) -> Option<(usize, usize)> {
        let mut position = 0;
        while let Some(&device) = self.refreshes.get(position) {
            let Some(slot) = self.devices.get_mut(device) else {
                self.refreshes.remove(position);
                continue;
            };
            if slot.health.is_offline() {
                slot.refresh.iter_mut().for_each(|asked| *asked = false);
                self.refreshes.remove(position);
                continue;
            }
            if slot.ready_at > now {
                *earliest = Some(earliest.map_or(slot.ready_at, |e| e.min(slot.ready_at)));
                position += 1;
                continue;
            }
            let Some(block) = slot.refresh.iter().position(|&asked| asked) else {
                self.refreshes.remove(position);
                continue;
            };
            if let Some(asked) = slot.refresh.get_mut(block) {
                *asked = false;
            }
            if let Some(reading) = slot.refreshing.get_mut(block) {
                *reading = true;
            }
            if !slot.refresh.iter().any(|&asked| asked) {
                self.refreshes.remove(position);
            }
            return Some((device, block));
        }
        None
    }

    /// Queues a command for `device`; it runs before the next poll.
    pub fn push_command(&mut self, device: usize, command: C) {
        self.commands.push_back((device, command));
    }

    /// Commands queued and not yet handed out.
    pub fn queued_commands(&self) -> usize {
        self.commands.len()
    }

    /// Takes every queued command out (the line is shutting down and answers them itself).
    pub fn drain_commands(&mut self) -> Vec<(usize, C)> {
        self.commands.drain(..).collect()
    }

    /// What to do at `now`. A command or a poll handed out here is the line's to run; report a
    /// poll's end with [`Scheduler::record_poll`].
    pub fn next_due(&mut self, now: Instant) -> Due<C> {
        let mut earliest: Option<Instant> = None;
        if let Some(position) = self.commands.iter().position(|(device, _)| {
            self.devices
                .get(*device)
                .map_or(true, |slot| slot.ready_at <= now)
        }) {
            if let Some((device, command)) = self.commands.remove(position) {
                self.serve(device);
                return Due::Command { device, command };
            }
        }
        for (device, _) in &self.commands {
            if let Some(slot) = self.devices.get(*device) {
                earliest = Some(earliest.map_or(slot.ready_at, |e| e.min(slot.ready_at)));
            }
        }
        if let Some((device, block)) = self.take_refresh(now, &mut earliest) {
            self.serve(device);
            return Due::Poll { device, block };
        }

        // (due, last_served, device, block, probe)
        let mut best: Option<(Instant, u64, usize, usize, bool)> = None;
        for (index, slot) in self.devices.iter().enumerate() {
            let candidate = if slot.health.is_offline() {
                match (slot.health.next_probe(), slot.plan.probe_block()) {
                    (Some(at), Some(block)) => Some((at.max(slot.ready_at), block, true)),
                    _ => None,
                }
            } else {
                slot.block_due
                    .iter()
                    .enumerate()
                    .filter_map(|(block, due)| due.map(|due| (due, block)))
                    .min_by_key(|(due, _)| *due)
                    .map(|(due, block)| (due, block, false))
            };
            if let Some((due, block, probe)) = candidate {
                let key = (due, slot.last_served, index, block, probe);
                let better = best.map_or(true, |b| (key.0, key.1) < (b.0, b.1));
                if better {
                    best = Some(key);
                }
            }
        }

        match best {
            Some((due, _, device, block, probe)) if due <= now => {
                self.serve(device);
                if let Some(started) = self
                    .devices
                    .get_mut(device)
                    .and_then(|slot| slot.started.get_mut(block))
                {
                    *started = now;
                }
                if probe {
                    Due::Probe { device, block }
                } else {
                    Due::Poll { device, block }
                }
            }
            Some((due, ..)) => Due::Wait(earliest.map_or(due, |e| e.min(due))),
            None => earliest.map_or(Due::Idle, Due::Wait),
        }
    }

    /// Records how a poll or probe of `block` ended at `now`; returns an availability change.
    pub fn record_poll(
        &mut self,
        device: usize,
        block: usize,
        outcome: PollOutcome,
        now: Instant,
    ) -> Option<HealthChange> {
        let slot = self.devices.get_mut(device)?;
        let interval = slot.plan.interval_of(block);
        let period = slot.plan.period_of(block);
        let refresh_read = slot.refreshing.get_mut(block).is_some_and(std::mem::take);
        let was_offline = slot.health.is_offline();
        let outcome = match outcome {
            // A refresh read the device is too busy for: the block's own polls read it.
            PollOutcome::Busy if refresh_read => return None,
            PollOutcome::Busy => {
                let count = slot.busy_count.get_mut(block)?;
                *count += 1;
                if *count < BUSY_LIMIT {
                    if let Some(due) = slot.block_due.get_mut(block) {
                        *due = Some(now + BUSY_RETRY_DELAY);
                    }
                    return None;
                }
                PollOutcome::Failed
            }
            other => other,
        };
        if let Some(count) = slot.busy_count.get_mut(block) {
            *count = 0;
        }
        let started = slot.started.get(block).copied().unwrap_or(now);
        // A refresh read moves no cadence: the block stays due when it was.
        if let Some(due) = slot.block_due.get_mut(block).filter(|_| !refresh_read) {
            *due = match (period, outcome) {
                (Some(period), _) => {
                    Some(next_due_after(due.unwrap_or(started), period, started, now))
                }
                // A `once` block is read: nothing more until something asks for it.
                (None, PollOutcome::Answered) => None,
                (None, _) => Some(now + interval),
            };
        }
        match outcome {
            PollOutcome::Answered => {
                let change = slot.health.record_success();
                if was_offline {
                    // Back from the dead: read everything at once so every value is re-sent.
                    slot.block_due.iter_mut().for_each(|due| *due = Some(now));
                }
                change
            }
            _ => slot.health.record_failure(now),
        }
    }

    /// The device answered outside a poll (a command slot): that proves it is there.
    pub fn record_contact(&mut self, device: usize, now: Instant) -> Option<HealthChange> {
        let slot = self.devices.get_mut(device)?;
        let was_offline = slot.health.is_offline();
        let change = slot.health.record_success();
        if was_offline {
            slot.block_due.iter_mut().for_each(|due| *due = Some(now));
        }
        change
    }

    /// A command slot on `device` ended at `now`. It read the blocks marked in `read` whole
    /// (their values are out, which proves the device is there); its write can have changed
    /// the blocks marked in `changed`. Those of them it did not read are due at `now` (never
    /// before the device's start-up delay); every other block keeps its due instant, so the
    /// command moves no block's cadence. Returns an availability change.
    pub fn after_command(
        &mut self,
        device: usize,
        changed: &[bool],
        read: &[bool],
        now: Instant,
    ) -> Option<HealthChange> {
        let slot = self.devices.get_mut(device)?;
        let at = now.max(slot.ready_at);
        let marked = |marks: &[bool], block: usize| marks.get(block).copied().unwrap_or(false);
        for (block, due) in slot.block_due.iter_mut().enumerate() {
            if marked(changed, block) && !marked(read, block) {
                *due = Some(due.map_or(at, |due| due.min(at)));
            }
        }
        if !read.iter().any(|&whole| whole) {
            return None;
        }
        let was_offline = slot.health.is_offline();
        let change = slot.health.record_success();
        if was_offline {
            slot.block_due.iter_mut().for_each(|due| *due = Some(now));
        }
        change
    }

    /// The port is gone: every device is offline. Returns the devices that changed.
    /// A refresh read cut short by it is not recorded: it is forgotten with the refreshes.
    pub fn port_lost(&mut self, now: Instant) -> Vec<usize> {
        self.refreshes.clear();
        self.devices
            .iter_mut()
            .enumerate()
            .filter_map(|(index, slot)| {
                slot.refresh.iter_mut().for_each(|asked| *asked = false);
                slot.refreshing
                    .iter_mut()
                    .for_each(|reading| *reading = false);
                slot.health.force_offline(now).map(|_| index)
            })
            .collect()
    }

    /// The port is back: probe every offline device at once.
    pub fn port_restored(&mut self, now: Instant) {
        for slot in &mut self.devices {
            slot.health.probe_soon(now);
        }
    }

    pub fn availability(&self, device: usize) -> Availability {
        self.devices
            .get(device)
            .map_or(Availability::Unknown, |slot| slot.health.availability())
    }

    pub fn consecutive_failures(&self, device: usize) -> u32 {
        self.devices
            .get(device)
            .map_or(0, |slot| slot.health.consecutive_failures())
    }

    fn serve(&mut self, device: usize) {
        self.serial += 1;
        if let Some(slot) = self.devices.get_mut(device) {
            slot.last_served = self.serial;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::cadence::BlockPlan;
    use rtu2mqtt_profile::PollClass;

    const MS: Duration = Duration::from_millis(1);

    /// One device: block 0 fast (every 500 ms), block 1 slow (every 2 s), block 2 fast.
    fn scheduler(start: Instant) -> Scheduler<u32> {
        let block = |class| BlockPlan {
            class,
            answer_bytes: 9,
        };
        let plan = DevicePlan {
            blocks: vec![
                block(PollClass::Fast),
                block(PollClass::Slow),
                block(PollClass::Fast),
            ],
            poll_interval: 500 * MS,
            slow_interval: 2000 * MS,
            startup_delay: Duration::ZERO,
        };
        Scheduler::new(vec![plan], HealthPolicy::with_offline_after(3), start)
    }

    /// Runs the scheduler as a line would until `end`, each poll taking 20 ms and a command
    /// slot being run at each instant of `commands` (as its offset from `start`, with the
    /// blocks its write can change and the blocks it reads whole). Returns the instants of
    /// every poll, by block.
    fn run(
        scheduler: &mut Scheduler<u32>,
        start: Instant,
        end: Duration,
        commands: &[(Duration, [bool; 3], [bool; 3])],
    ) -> Vec<Vec<Duration>> {
        let mut polls = vec![Vec::new(); 3];
        let mut now = start;
        let mut pending = commands.iter().peekable();
        while now < start + end {
            if let Some((at, changed, read)) = pending.peek() {
                if start + *at <= now {
                    // The slot: read before, write, read back: 60 ms on the line.
                    now += 60 * MS;
                    scheduler.after_command(0, changed, read, now);
                    pending.next();
                    continue;
                }
            }
            match scheduler.next_due(now) {
                Due::Poll { block, .. } => {
                    polls[block].push(now - start);
                    now += 20 * MS;
                    scheduler.record_poll(0, block, PollOutcome::Answered, now);
                }
                Due::Wait(until) => {
                    let next_command = pending.peek().map(|(at, ..)| start + *at);
                    now = next_command.map_or(until, |c| c.min(until));
                }
                other => panic!("unexpected {other:?}"),
            }
        }
        polls
    }

    /// The gaps between consecutive instants.
    fn gaps(instants: &[Duration]) -> Vec<Duration> {
        instants.windows(2).map(|pair| pair[1] - pair[0]).collect()
    }

    #[test]
    fn every_block_keeps_its_interval_after_writes_read_back_whole() {
        let start = Instant::now();
        let mut scheduler = scheduler(start);
        // Two writes to block 0, 90 ms apart, each read back with a read of the whole block.
        let write = ([true, false, false], [true, false, false]);
        let commands = [(1230 * MS, write.0, write.1), (1320 * MS, write.0, write.1)];
        let polls = run(&mut scheduler, start, 6000 * MS, &commands);
        for gap in gaps(&polls[0]).into_iter().chain(gaps(&polls[2])) {
            assert!(
                gap <= 500 * MS + 60 * MS,
                "a fast block came late: {polls:?}"
            );
        }
        for gap in gaps(&polls[1]) {
            assert!(
                gap <= 2000 * MS + 60 * MS,
                "the slow block came late: {polls:?}"
            );
        }
        assert_eq!(
            polls[1].len(),
            3,
            "the slow block kept its own cadence: {polls:?}"
        );
        assert!(polls[0].len() >= 11, "{polls:?}");
    }

    #[test]
    fn a_phased_line_polls_first_at_its_phase_and_keeps_its_interval_after() {
        let start = Instant::now();
        let block = BlockPlan {
            class: PollClass::Fast,
            answer_bytes: 9,
        };
        let plan = DevicePlan {
            blocks: vec![block.clone(), block.clone(), block],
            poll_interval: 500 * MS,
            slow_interval: 500 * MS,
            startup_delay: Duration::ZERO,
        };
        let policy = HealthPolicy::with_offline_after(3);
        let mut scheduler = Scheduler::phased(vec![plan], policy, start, 130 * MS);
        assert_eq!(scheduler.next_due(start), Due::Wait(start + 130 * MS));
        // A command does not wait for the phase.
        scheduler.push_command(0, 7);
        assert_eq!(
            scheduler.next_due(start),
            Due::Command {
                device: 0,
                command: 7
            }
        );
        let polls = run(&mut scheduler, start, 1200 * MS, &[]);
        assert_eq!(polls[0], vec![130 * MS, 630 * MS, 1130 * MS], "{polls:?}");
    }

    #[test]
    fn poll_phases_are_stable_within_their_bound_and_spread() {
        let second = Duration::from_secs(1);
        let twenty = poll_phases(1000);
        assert_eq!(twenty, 20);
        assert_eq!(poll_phases(10), 1);
        assert_eq!(poll_phases(100), 2);
        assert_eq!(poll_phases(100_000), MAX_POLL_PHASES);
        assert_eq!(poll_phase("m0001", second, 1), Duration::ZERO);
        assert_eq!(
            poll_phase("m0001", second, twenty),
            poll_phase("m0001", second, twenty)
        );
        assert_eq!(poll_phase("m0001", Duration::ZERO, twenty), Duration::ZERO);
        assert!(poll_phase("m0001", 20 * MS, twenty) < 20 * MS);
        assert!(poll_phase("m0001", Duration::from_secs(60), twenty) < MAX_POLL_PHASE);
        assert_eq!(poll_phase("m0001", second, twenty).as_millis() % 50, 0);
        // A thousand lines named alike: every phase holds between half and twice its share.
        let mut phases = [0usize; MAX_POLL_PHASES as usize];
        for n in 0..1000 {
            let phase = poll_phase(&format!("m{n:04}"), second, twenty);
            phases[(phase.as_millis() / 50) as usize] += 1;
        }
        assert!(
            phases.iter().all(|&count| (25..=100).contains(&count)),
            "{phases:?}"
        );
    }

    #[test]
    fn only_a_block_the_write_can_have_changed_and_not_read_is_polled_at_once() {
        let start = Instant::now();
        let mut scheduler = scheduler(start);
        // The write can change blocks 0 and 1; the read-back reads only block 0 whole.
        let commands = [(700 * MS, [true, true, false], [true, false, false])];
        let polls = run(&mut scheduler, start, 2000 * MS, &commands);
        // Block 1 (slow, last read at 20 ms) is read right after the slot; block 2 is not
        // read again early, and block 0 stays on its cadence.
        assert_eq!(polls[1], vec![20 * MS, 760 * MS], "{polls:?}");
        assert!(
            polls[2].iter().all(|at| *at < 700 * MS || *at > 900 * MS),
            "{polls:?}"
        );
        assert!(polls[0].contains(&(1000 * MS)), "{polls:?}");
    }
}
