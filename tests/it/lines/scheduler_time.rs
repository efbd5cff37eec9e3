//! The bus scheduler as a pure function of time: explicit instants in, decisions out. Covers
//! start-up delay, intervals without drift, fast/slow classes, fairness between devices, a
//! dead device's bounded cost, commands before polls and busy answers.

use std::time::{Duration, Instant};

use rtu2mqtt::bus::availability::{Availability, HealthChange, HealthPolicy};
use rtu2mqtt::bus::cadence::{BlockPlan, DevicePlan};
use rtu2mqtt::bus::scheduler::{Due, PollOutcome, Scheduler, BUSY_LIMIT, BUSY_RETRY_DELAY};
use rtu2mqtt_profile::PollClass;

const MS: Duration = Duration::from_millis(1);

fn block(class: PollClass, answer_bytes: usize) -> BlockPlan {
    BlockPlan {
        class,
        answer_bytes,
    }
}

fn plan(blocks: Vec<BlockPlan>, interval_ms: u64, startup_ms: u64) -> DevicePlan {
    DevicePlan {
        blocks,
        poll_interval: Duration::from_millis(interval_ms),
        slow_interval: Duration::from_secs(60),
        startup_delay: Duration::from_millis(startup_ms),
    }
}

/// A device with one fast block of `answer_bytes`, the common case below.
fn fast_device(answer_bytes: usize, interval_ms: u64, startup_ms: u64) -> DevicePlan {
    plan(
        vec![block(PollClass::Fast, answer_bytes)],
        interval_ms,
        startup_ms,
    )
}

/// The scheduler of one line whose commands are numbers, started at `start`.
fn new_scheduler(devices: Vec<DevicePlan>, policy: HealthPolicy, start: Instant) -> Scheduler<u32> {
    Scheduler::new(devices, policy, start)
}

fn policy() -> HealthPolicy {
    HealthPolicy::with_offline_after(3)
}

/// Runs the scheduler as a line would, each transaction taking `cost(device, probe)`, until
/// `end`; returns (time, device, block, probe) of every poll and the final time.
fn simulate(
    scheduler: &mut Scheduler<u32>,
    start: Instant,
    end: Instant,
    mut run: impl FnMut(usize, bool) -> (Duration, PollOutcome),
) -> Vec<(Duration, usize, usize, bool)> {
    let mut now = start;
    let mut log = Vec::new();
    while now < end {
        // A probe is a poll of a device held offline: both take the line the same way.
        let (device, block, probe) = match scheduler.next_due(now) {
            Due::Poll { device, block } => (device, block, false),
            Due::Probe { device, block } => (device, block, true),
            Due::Wait(until) => {
                assert!(until > now, "Wait must point into the future");
                now = until;
                continue;
            }
            Due::Command { .. } => panic!("no commands queued"),
            Due::Idle => break,
        };
        log.push((now - start, device, block, probe));
        let (cost, outcome) = run(device, probe);
        now += cost;
        scheduler.record_poll(device, block, outcome, now);
    }
    log
}

#[test]
fn nothing_before_the_startup_delay() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(vec![fast_device(17, 1000, 3000)], policy(), start);
    assert_eq!(scheduler.next_due(start), Due::Wait(start + 3000 * MS));
    assert_eq!(
        scheduler.next_due(start + 2999 * MS),
        Due::Wait(start + 3000 * MS)
    );
    assert_eq!(
        scheduler.next_due(start + 3000 * MS),
        Due::Poll {
            device: 0,
            block: 0
        }
    );
}

#[test]
fn commands_wait_for_the_startup_delay_of_their_device_only() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(
        vec![fast_device(17, 1000, 3000), fast_device(8, 1000, 0)],
        policy(),
        start,
    );
    scheduler.push_command(0, 10);
    scheduler.push_command(1, 11);
    assert_eq!(
        scheduler.next_due(start),
        Due::Command {
            device: 1,
            command: 11
        }
    );
    // Device 1's poll is due now; the command for device 0 still waits.
    assert_eq!(
        scheduler.next_due(start),
        Due::Poll {
            device: 1,
            block: 0
        }
    );
    scheduler.record_poll(1, 0, PollOutcome::Answered, start + 10 * MS);
    assert_eq!(
        scheduler.next_due(start + 10 * MS),
        Due::Wait(start + 1000 * MS)
    );
    assert_eq!(
        scheduler.next_due(start + 3000 * MS),
        Due::Command {
            device: 0,
            command: 10
        }
    );
}

#[test]
fn commands_run_before_due_polls() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(
        vec![fast_device(17, 0, 0), fast_device(8, 0, 0)],
        policy(),
        start,
    );
    assert!(matches!(scheduler.next_due(start), Due::Poll { .. }));
    scheduler.push_command(1, 7);
    scheduler.push_command(0, 8);
    assert_eq!(
        scheduler.next_due(start),
        Due::Command {
            device: 1,
            command: 7
        }
    );
    assert_eq!(
        scheduler.next_due(start),
        Due::Command {
            device: 0,
            command: 8
        }
    );
    assert!(matches!(scheduler.next_due(start), Due::Poll { .. }));
    assert_eq!(scheduler.queued_commands(), 0);
}

#[test]
fn intervals_do_not_drift_and_do_not_burst_after_falling_behind() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(vec![fast_device(17, 1000, 0)], policy(), start);
    assert!(matches!(scheduler.next_due(start), Due::Poll { .. }));
    // The poll took 30 ms: the next one is still due 1000 ms after the first was due.
    scheduler.record_poll(0, 0, PollOutcome::Answered, start + 30 * MS);
    assert_eq!(
        scheduler.next_due(start + 30 * MS),
        Due::Wait(start + 1000 * MS)
    );
    // The line was held up for 5 s: one poll now, then the old cadence resumes; the missed
    // periods are skipped rather than caught up in a burst.
    let late = start + 6000 * MS;
    assert!(matches!(scheduler.next_due(late), Due::Poll { .. }));
    scheduler.record_poll(0, 0, PollOutcome::Answered, late + 30 * MS);
    assert_eq!(
        scheduler.next_due(late + 30 * MS),
        Due::Wait(start + 7000 * MS)
    );
}

#[test]
fn slow_blocks_run_at_start_then_on_their_own_interval() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(
        vec![plan(
            vec![block(PollClass::Fast, 9), block(PollClass::Slow, 30)],
            1000,
            0,
        )],
        policy(),
        start,
    );
    let end = start + Duration::from_secs(125);
    let log = simulate(&mut scheduler, start, end, |_, _| {
        (20 * MS, PollOutcome::Answered)
    });
    let fast = log.iter().filter(|entry| entry.2 == 0).count();
    let slow: Vec<_> = log
        .iter()
        .filter(|entry| entry.2 == 1)
        .map(|entry| entry.0.as_secs())
        .collect();
    assert!((124..=126).contains(&fast), "fast polls: {fast}");
    assert_eq!(slow, vec![0, 60, 120]);
}

#[test]
fn back_to_back_polling_is_round_robin() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(
        vec![
            plan(
                vec![block(PollClass::Fast, 8), block(PollClass::Fast, 9)],
                0,
                0,
            ),
            fast_device(17, 0, 0),
            fast_device(8, 0, 0),
        ],
        policy(),
        start,
    );
    let log = simulate(&mut scheduler, start, start + 900 * MS, |_, _| {
        (10 * MS, PollOutcome::Answered)
    });
    let order: Vec<(usize, usize)> = log.iter().map(|entry| (entry.1, entry.2)).collect();
    // One full cycle of every device per round: device 0 has two blocks, the others one.
    assert_eq!(&order[..4], &[(0, 0), (1, 0), (2, 0), (0, 1)]);
    assert!(order.len() >= 80, "polls: {}", order.len());
    for round in order.chunks_exact(4) {
        let mut round = round.to_vec();
        round.sort_unstable();
        assert_eq!(round, vec![(0, 0), (0, 1), (1, 0), (2, 0)]);
    }
}

#[test]
fn a_dead_device_goes_offline_and_costs_only_bounded_probes() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(
        vec![
            fast_device(17, 0, 0),
            plan(
                vec![block(PollClass::Fast, 8), block(PollClass::Fast, 6)],
                0,
                0,
            ),
        ],
        policy(),
        start,
    );
    // Device 1 never answers: each attempt burns (1 + 1 retry) × 300 ms; a probe 300 ms.
    let end = start + Duration::from_secs(120);
    let log = simulate(&mut scheduler, start, end, |device, probe| match device {
        0 => (25 * MS, PollOutcome::Answered),
        _ if probe => (300 * MS, PollOutcome::Failed),
        _ => (600 * MS, PollOutcome::Failed),
    });
    assert_eq!(scheduler.availability(1), Availability::Offline);
    assert_eq!(scheduler.availability(0), Availability::Online);
    let dead_polls = log.iter().filter(|e| e.1 == 1 && !e.3).count();
    let probes: Vec<_> = log.iter().filter(|e| e.1 == 1 && e.3).collect();
    assert_eq!(dead_polls, 3, "offline after three failed polls");
    // Probes use the cheapest block and back off to at most one per 30 s.
    assert!(probes.iter().all(|e| e.2 == 1));
    assert!(probes.len() <= 9, "probes: {}", probes.len());
    for pair in probes.windows(2).skip(5) {
        assert!(pair[1].0 - pair[0].0 >= Duration::from_secs(30));
    }
    // The live device keeps the line: far more than 90 % of the time.
    let live_polls = log.iter().filter(|e| e.1 == 0).count() as f64;
    let live_share = live_polls * 0.025 / 120.0;
    assert!(live_share > 0.9, "live device share {live_share}");
}

#[test]
fn an_offline_device_comes_back_on_the_first_answered_probe_and_rereads_everything() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(
        vec![plan(
            vec![block(PollClass::Fast, 17), block(PollClass::Slow, 8)],
            1000,
            0,
        )],
        HealthPolicy::with_offline_after(1),
        start,
    );
    let Due::Poll { device, block } = scheduler.next_due(start) else {
        panic!("first poll expected");
    };
    assert_eq!(
        scheduler.record_poll(device, block, PollOutcome::Failed, start + 300 * MS),
        Some(HealthChange::WentOffline)
    );
    let now = start + 300 * MS;
    assert_eq!(scheduler.next_due(now), Due::Wait(now + 1000 * MS));
    let probe_at = now + 1000 * MS;
    assert_eq!(
        scheduler.next_due(probe_at),
        Due::Probe {
            device: 0,
            block: 1
        }
    );
    let back = probe_at + 20 * MS;
    assert_eq!(
        scheduler.record_poll(0, 1, PollOutcome::Answered, back),
        Some(HealthChange::CameOnline)
    );
    // Both blocks (the slow one too) are read at once so every value is sent again.
    let mut blocks = Vec::new();
    for _ in 0..2 {
        match scheduler.next_due(back) {
            Due::Poll { block, .. } => {
                blocks.push(block);
                scheduler.record_poll(0, block, PollOutcome::Answered, back);
            }
            other => panic!("expected a poll, got {other:?}"),
        }
    }
    blocks.sort_unstable();
    assert_eq!(blocks, vec![0, 1]);
}

#[test]
fn busy_answers_are_retried_soon_without_counting_as_failures() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(
        vec![fast_device(17, 1000, 0), fast_device(8, 1000, 0)],
        HealthPolicy::with_offline_after(1),
        start,
    );
    let Due::Poll { device, block } = scheduler.next_due(start) else {
        panic!("poll expected");
    };
    let now = start + 20 * MS;
    assert_eq!(
        scheduler.record_poll(device, block, PollOutcome::Busy, now),
        None
    );
    assert_eq!(scheduler.availability(device), Availability::Unknown);
    // The other device uses the line in the meantime.
    let Due::Poll { device: other, .. } = scheduler.next_due(now) else {
        panic!("poll expected");
    };
    assert_ne!(other, device);
    scheduler.record_poll(other, 0, PollOutcome::Answered, now + 20 * MS);
    assert_eq!(
        scheduler.next_due(now + 20 * MS),
        Due::Wait(now + BUSY_RETRY_DELAY)
    );
    assert_eq!(
        scheduler.next_due(now + BUSY_RETRY_DELAY),
        Due::Poll { device, block }
    );
}

#[test]
fn losing_the_port_takes_every_device_offline_and_restoring_probes_at_once() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(
        vec![fast_device(17, 1000, 0), fast_device(8, 1000, 0)],
        policy(),
        start,
    );
    for _ in 0..2 {
        if let Due::Poll { device, block } = scheduler.next_due(start) {
            scheduler.record_poll(device, block, PollOutcome::Answered, start);
        }
    }
    let lost = start + 100 * MS;
    assert_eq!(scheduler.port_lost(lost), vec![0, 1]);
    assert_eq!(scheduler.port_lost(lost), Vec::<usize>::new());
    let back = start + 10_000 * MS;
    scheduler.port_restored(back);
    assert!(matches!(scheduler.next_due(back), Due::Probe { .. }));
}

#[test]
fn a_block_busy_beyond_the_limit_counts_as_failed_and_an_answer_resets_the_count() {
    let start = Instant::now();
    let mut scheduler = new_scheduler(
        vec![fast_device(17, 1000, 0)],
        HealthPolicy::with_offline_after(1),
        start,
    );
    let mut now = start;
    let poll_busy = |scheduler: &mut Scheduler<u32>, times: u32, now: &mut Instant| {
        for _ in 0..times {
            assert_eq!(
                scheduler.next_due(*now),
                Due::Poll {
                    device: 0,
                    block: 0
                }
            );
            *now += 20 * MS;
            let change = scheduler.record_poll(0, 0, PollOutcome::Busy, *now);
            *now += BUSY_RETRY_DELAY;
            if change.is_some() {
                return change;
            }
        }
        None
    };
    assert_eq!(poll_busy(&mut scheduler, BUSY_LIMIT - 1, &mut now), None);
    assert_eq!(
        scheduler.next_due(now),
        Due::Poll {
            device: 0,
            block: 0
        }
    );
    assert_eq!(
        scheduler.record_poll(0, 0, PollOutcome::Answered, now + 20 * MS),
        Some(HealthChange::CameOnline)
    );
    now += 1000 * MS;
    // The answer started the count again: another streak one short of the limit is harmless.
    assert_eq!(poll_busy(&mut scheduler, BUSY_LIMIT - 1, &mut now), None);
    assert_eq!(scheduler.availability(0), Availability::Online);
    // One more busy answer reaches the limit: as good as absent.
    assert_eq!(
        poll_busy(&mut scheduler, 1, &mut now),
        Some(HealthChange::WentOffline)
    );
}
