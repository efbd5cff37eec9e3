//! The task that owns one serial line. It opens the port (and reopens it with back-off,
//! 100 ms doubling to 3 s, when it is missing or disappears), asks the [`Scheduler`] what is
//! due, runs command slots ([`super::slot`]) before polls, reads blocks (falling back to a
//! block's used runs when the device refuses the merged block with exception 02, and
//! remembering that per device), decodes them with the profile and reports [`LineEvent`]s. It
//! publishes [`LineStats`] after every transaction and at least once a second.
//!
//! A path that exists but is no serial port (a file, `/dev/null`: docs/reliability.md B11) is a
//! configuration mistake that waiting does not fix. The line is then failed: its devices are
//! offline, every attempt logs an ERROR naming the path, and it looks again only after 5 s
//! doubling to 60 s (the path may be a link that gets pointed at the adapter). It does not end
//! the daemon: the gateway's other lines keep serving their devices.
//!
//! A transaction is never cancelled half-way: shutdown, commands and timers are only looked at
//! between transactions, so the line is always left with a complete frame exchange on it.
//!
//! Settle re-reads (a valve still moving after its command) run outside the command's slot:
//! the writes are done by then, so nothing can interleave with them any more, and a 60 s settle
//! window must not take the line from the other devices.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, watch};
use tracing::Instrument;

use super::health::{HealthChange, HealthPolicy};
use super::plan::{read_answer_bytes, DevicePlan};
use super::scheduler::{Due, PollOutcome, Scheduler};
use super::slot::{self, SeenReads, SlotEnd};
use super::stats::DeviceStats;
use super::transaction::{Exchange, Failure, Turnaround};
use super::{Command, CommandOutcome, DeviceSpec, LineEvent, LineHandle, LineSpec, LineStats};
use crate::profile::{CommandPlan, Profile, ReadBlock, Verification};
use crate::rtu::master::{Master, MasterOptions, WireCounters};
use crate::rtu::timing::LineTiming;
use crate::rtu::transport::{Port, TransportError};
use crate::rtu::{ExceptionCode, Request, Response};
use crate::shutdown::Shutdown;

/// Commands that may wait in a line's queue; the bridge waits when it is full.
pub const COMMAND_QUEUE: usize = 64;
/// Time a device takes to start answering on top of the answer's own wire time.
pub const DEVICE_MARGIN: Duration = Duration::from_millis(100);
/// First wait before reopening a port that is missing or failed.
pub const REOPEN_INITIAL: Duration = Duration::from_millis(100);
/// Longest wait between two attempts to open a port.
pub const REOPEN_MAX: Duration = Duration::from_secs(3);
/// First wait before looking again at a port path that is no serial port.
pub const NOT_A_PORT_RETRY_INITIAL: Duration = Duration::from_secs(5);
/// Longest wait between two looks at a port path that is no serial port.
pub const NOT_A_PORT_RETRY_MAX: Duration = Duration::from_secs(60);
/// Statistics are published at least this often (the watchdog's heartbeat).
pub const HEARTBEAT: Duration = Duration::from_secs(1);
/// Bus load is measured over this sliding window.
pub const LOAD_WINDOW: Duration = Duration::from_secs(10);
/// Pause between two read-backs of a command whose device is still moving.
pub const SETTLE_REREAD: Duration = Duration::from_millis(500);

/// Starts the task that owns `spec`'s port.
pub fn spawn_line(
    spec: LineSpec,
    events_tx: mpsc::Sender<LineEvent>,
    shutdown: Shutdown,
) -> (LineHandle, tokio::task::JoinHandle<()>) {
    let names: Vec<String> = spec.devices.iter().map(|d| d.name.clone()).collect();
    let now = Instant::now();
    let (command_tx, command_rx) = mpsc::channel(COMMAND_QUEUE);
    let (stats_tx, stats_rx) = watch::channel(LineStats::new(&spec.name, &names, now));
    let handle = LineHandle {
        name: spec.name.clone(),
        command_tx,
        stats_rx,
    };
    let span = tracing::info_span!("line", line = %spec.name);
    let line = Line::new(spec, events_tx, command_rx, stats_tx, shutdown, now);
    let task = tokio::spawn(line.run().instrument(span));
    (handle, task)
}

/// The response timeout of a line when none is configured: the wire time of the longest answer
/// any of its devices' blocks can give, the end-of-frame silence, and a device margin.
pub fn default_response_timeout(spec: &LineSpec, timing: &LineTiming) -> Duration {
    let longest = spec
        .devices
        .iter()
        .flat_map(|device| device.profile.read_blocks().iter().map(read_answer_bytes))
        .max()
        .unwrap_or(8)
        .max(8);
    timing.frame_time(longest) + timing.t3_5 + DEVICE_MARGIN
}

/// A command waiting for its slot.
#[derive(Debug)]
struct Pending {
    command: Command,
    arrived: Instant,
}

/// A command whose writes are done and whose device is still moving toward the value.
struct Settle {
    device: usize,
    plan: CommandPlan,
    id: u64,
    arrived: Instant,
    deadline: Instant,
    next_read: Instant,
}

struct Line {
    spec: LineSpec,
    timing: LineTiming,
    timeout: Duration,
    scheduler: Scheduler<Pending>,
    master: Option<Master>,
    /// When to try opening the port next, and the wait after that attempt.
    reopen_at: Instant,
    reopen_delay: Duration,
    /// Per device and block: the device refused the merged block, read its runs instead.
    fallback: Vec<Vec<bool>>,
    settling: Vec<Settle>,
    events_tx: mpsc::Sender<LineEvent>,
    command_rx: mpsc::Receiver<Command>,
    commands_open: bool,
    stats_tx: watch::Sender<LineStats>,
    stats: LineStats,
    /// Counters of the masters of ports closed earlier (a reopened port starts a new master).
    closed_counters: WireCounters,
    load_samples: VecDeque<(Instant, Duration)>,
    turnaround: Turnaround,
    last_published: Instant,
    shutdown: Shutdown,
}

impl Line {
    fn new(
        spec: LineSpec,
        events_tx: mpsc::Sender<LineEvent>,
        command_rx: mpsc::Receiver<Command>,
        stats_tx: watch::Sender<LineStats>,
        shutdown: Shutdown,
        now: Instant,
    ) -> Self {
        let timing = LineTiming::new(spec.serial.baud, spec.serial.format);
        let timeout = spec
            .response_timeout
            .unwrap_or_else(|| default_response_timeout(&spec, &timing));
        let plans = spec.devices.iter().map(DevicePlan::for_device).collect();
        let scheduler = Scheduler::new(
            plans,
            HealthPolicy::with_offline_after(spec.offline_after),
            now,
        );
        let fallback = spec
            .devices
            .iter()
            .map(|d| vec![false; d.profile.read_blocks().len()])
            .collect();
        let stats = stats_tx.borrow().clone();
        tracing::info!(
            port = %spec.serial.path,
            baud = spec.serial.baud,
            devices = spec.devices.len(),
            ?timeout,
            "line starting"
        );
        Line {
            timing,
            timeout,
            scheduler,
            master: None,
            reopen_at: now,
            reopen_delay: REOPEN_INITIAL,
            fallback,
            settling: Vec::new(),
            events_tx,
            command_rx,
            commands_open: true,
            stats_tx,
            stats,
            closed_counters: WireCounters::default(),
            load_samples: VecDeque::new(),
            turnaround: Turnaround::default(),
            last_published: now,
            shutdown,
            spec,
        }
    }

    fn attempts(&self) -> u32 {
        self.spec.retries.saturating_add(1)
    }

    async fn run(mut self) {
        while !self.shutdown.is_fired() {
            let now = Instant::now();
            self.accept_commands(now).await;
            if self.master.is_none() {
                if now >= self.reopen_at {
                    self.open_port(now).await;
                } else {
                    self.fail_queued("the port is not open (reopening)").await;
                    self.wait(Some(self.reopen_at)).await;
                }
                continue;
            }
            if let Some(index) = self.settling.iter().position(|s| s.next_read <= now) {
                let settle = self.settling.swap_remove(index);
                self.run_settle(settle).await;
                self.publish_stats();
                continue;
            }
            let next_settle = self.settling.iter().map(|s| s.next_read).min();
            match self.scheduler.next_due(now) {
                Due::Command { device, command } => {
                    self.run_command(device, command).await;
                    self.publish_stats();
                }
                Due::Poll { device, block } => {
                    let attempts = self.attempts();
                    self.run_poll(device, block, attempts).await;
                    self.publish_stats();
                }
                Due::Probe { device, block } => {
                    // One small read: a dead device must cost the line as little as possible.
                    self.run_poll(device, block, 1).await;
                    self.publish_stats();
                }
                Due::Wait(until) => {
                    let until = next_settle.map_or(until, |s| s.min(until));
                    self.wait(Some(until)).await;
                }
                Due::Idle => self.wait(next_settle).await,
            }
        }
        self.finish().await;
    }

    /// Sleeps until `until` (or the next heartbeat), a command arrives, or shutdown.
    async fn wait(&mut self, until: Option<Instant>) {
        self.turnaround.idle();
        let heartbeat = self.last_published + HEARTBEAT;
        let wake = until.map_or(heartbeat, |u| u.min(heartbeat));
        let sleep = tokio::time::sleep_until(tokio::time::Instant::from_std(wake));
        let commands_open = self.commands_open;
        tokio::select! {
            () = sleep => {}
            command = self.command_rx.recv(), if commands_open => match command {
                Some(command) => self.accept(command, Instant::now()).await,
                None => self.commands_open = false,
            },
            () = self.shutdown.fired() => {}
        }
        if self.last_published.elapsed() >= HEARTBEAT {
            self.publish_stats();
        }
    }

    /// Hands an event to the bridge. Waits when the bridge is behind (nothing is dropped), but
    /// not past a shutdown; a bridge that is gone is not an error of the line.
    async fn emit(&mut self, event: LineEvent) {
        let events_tx = &self.events_tx;
        let shutdown = &mut self.shutdown;
        tokio::select! {
            // A free place in the queue always wins, even during shutdown.
            biased;
            _ = events_tx.send(event) => {}
            () = shutdown.fired() => {}
        }
    }

    async fn accept_commands(&mut self, now: Instant) {
        while self.commands_open {
            match self.command_rx.try_recv() {
                Ok(command) => self.accept(command, now).await,
                Err(mpsc::error::TryRecvError::Empty) => break,
                Err(mpsc::error::TryRecvError::Disconnected) => self.commands_open = false,
            }
        }
    }

    async fn accept(&mut self, command: Command, now: Instant) {
        match self.device_index(&command.device) {
            Some(device) => self.scheduler.push_command(
                device,
                Pending {
                    command,
                    arrived: now,
                },
            ),
            None => {
                let detail = format!("no device {:?} on line {}", command.device, self.spec.name);
                let (id, device) = (command.id, command.device);
                self.emit(LineEvent::CommandFinished {
                    id,
                    device,
                    outcome: CommandOutcome::Failed { detail },
                })
                .await;
            }
        }
    }

    fn device_index(&self, name: &str) -> Option<usize> {
        self.spec.devices.iter().position(|d| d.name == name)
    }

    async fn open_port(&mut self, now: Instant) {
        self.turnaround.idle();
        match Port::open(&self.spec.serial) {
            Ok(port) => {
                let options = MasterOptions {
                    echo: self.spec.echo,
                    broadcast_turnaround: self.spec.broadcast_turnaround,
                    ..MasterOptions::default()
                };
                let mut master = Master::new(port, self.timing, options);
                if let Some(log) = &self.spec.frame_log {
                    master.record_frames_to(Box::new(log.writer(&self.spec.name)));
                }
                self.master = Some(master);
                if self.stats.port_failures > 0 {
                    tracing::info!(port = %self.spec.serial.path, "port open again");
                } else {
                    tracing::info!(port = %self.spec.serial.path, "port open");
                }
                self.stats.port_open = true;
                self.reopen_delay = REOPEN_INITIAL;
                self.scheduler.port_restored(now);
            }
            Err(error @ TransportError::NotATerminal { .. }) => {
                self.stats.port_failures += 1;
                let delay = self.reopen_delay.max(NOT_A_PORT_RETRY_INITIAL);
                tracing::error!(
                    port = %self.spec.serial.path,
                    retry_in = ?delay,
                    "line failed, its devices stay offline: {error}; set `port` to the \
                     adapter's device (such as /dev/serial/by-id/…)"
                );
                self.reopen_at = now + delay;
                self.reopen_delay = (delay * 2).min(NOT_A_PORT_RETRY_MAX);
                self.lose_devices(now).await;
            }
            Err(error) => {
                self.stats.port_failures += 1;
                // After a spell as no serial port the path may simply be missing: wait as usual.
                let delay = self.reopen_delay.min(REOPEN_MAX);
                tracing::warn!(
                    port = %self.spec.serial.path,
                    retry_in = ?delay,
                    "cannot open the port: {error}"
                );
                self.reopen_at = now + delay;
                self.reopen_delay = (delay * 2).min(REOPEN_MAX);
                self.lose_devices(now).await;
            }
        }
        self.publish_stats();
    }

    /// The port failed under a transaction: close it, take the devices offline, reopen later.
    async fn port_failed(&mut self, error: std::io::Error) {
        let now = Instant::now();
        if let Some(master) = self.master.take() {
            self.closed_counters = add_counters(self.closed_counters, master.counters());
        }
        self.stats.port_open = false;
        self.stats.port_failures += 1;
        self.reopen_delay = REOPEN_INITIAL;
        tracing::warn!(
            port = %self.spec.serial.path,
            retry_in = ?self.reopen_delay,
            "port failed, closing it: {error}"
        );
        self.reopen_at = now + self.reopen_delay;
        self.reopen_delay = (self.reopen_delay * 2).min(REOPEN_MAX);
        for settle in std::mem::take(&mut self.settling) {
            self.reply(
                settle.device,
                settle.id,
                settle.arrived,
                CommandOutcome::Failed {
                    detail: format!("the port failed before the read-back settled: {error}"),
                },
            )
            .await;
        }
        self.lose_devices(now).await;
        self.publish_stats();
    }

    async fn lose_devices(&mut self, now: Instant) {
        for device in self.scheduler.port_lost(now) {
            self.availability_changed(device, HealthChange::WentOffline)
                .await;
        }
    }

    async fn availability_changed(&mut self, device: usize, change: HealthChange) {
        let online = change == HealthChange::CameOnline;
        if let Some(stats) = self.stats.devices.get_mut(device) {
            stats.online = online;
        }
        let Some(spec) = self.spec.devices.get(device) else {
            return;
        };
        if online {
            tracing::info!(device = %spec.name, "device online");
        } else {
            tracing::warn!(device = %spec.name, "device offline");
        }
        let event = LineEvent::Availability {
            device: spec.name.clone(),
            online,
        };
        self.emit(event).await;
    }

    async fn run_poll(&mut self, device: usize, block: usize, attempts: u32) {
        let Some(spec) = self.spec.devices.get(device) else {
            return;
        };
        let profile: Arc<Profile> = spec.profile.clone();
        let Some(read) = profile.read_blocks().get(block) else {
            return;
        };
        let (Some(master), Some(stats)) =
            (self.master.as_mut(), self.stats.devices.get_mut(device))
        else {
            return;
        };
        let exchange = device_exchange(&self.spec.name, spec, self.timeout, &self.turnaround);
        let use_runs = self
            .fallback
            .get(device)
            .and_then(|blocks| blocks.get(block))
            .copied()
            .unwrap_or(false);
        let mut result = if use_runs {
            read_runs(&exchange, master, stats, read, attempts).await
        } else {
            exchange.run(master, stats, &read.request, attempts).await
        };
        if !use_runs && read.used_runs.len() > 1 {
            if let Err(Failure::Exception(ExceptionCode::IllegalDataAddress)) = result {
                tracing::info!(
                    device = %spec.name,
                    block = %read.name,
                    "device refuses the merged block (exception 02): reading its parts one by one from now on"
                );
                if let Some(flag) = self.fallback.get_mut(device).and_then(|b| b.get_mut(block)) {
                    *flag = true;
                }
                result = read_runs(&exchange, master, stats, read, attempts).await;
            }
        }

        let mut values = Vec::new();
        let outcome = match result {
            Ok(response) => {
                for reading in profile.decode_block(block, &response) {
                    match reading.value {
                        Ok(value) => values.push((reading.field, value)),
                        Err(error) => {
                            stats.field_errors += 1;
                            tracing::warn!(
                                device = %spec.name,
                                field = %reading.field,
                                "invalid field data, not published: {error}"
                            );
                        }
                    }
                }
                PollOutcome::Answered
            }
            Err(Failure::Exception(ExceptionCode::ServerDeviceBusy)) => PollOutcome::Busy,
            Err(Failure::Exception(
                code @ (ExceptionCode::ServerDeviceFailure
                | ExceptionCode::GatewayTargetFailedToRespond),
            )) => {
                tracing::warn!(device = %spec.name, block = %read.name, "poll failed: {code}");
                PollOutcome::Failed
            }
            Err(Failure::Exception(code)) => {
                // The device is there and refuses this read: a profile problem, not an outage.
                tracing::warn!(device = %spec.name, block = %read.name, "poll refused: {code}");
                PollOutcome::Answered
            }
            Err(Failure::NoAnswer(problem)) => {
                tracing::debug!(device = %spec.name, block = %read.name, "poll failed: {problem}");
                PollOutcome::Failed
            }
            Err(Failure::PortGone(error)) => {
                self.port_failed(error).await;
                return;
            }
        };
        match outcome {
            PollOutcome::Answered if !values.is_empty() => stats.polls_ok += 1,
            PollOutcome::Failed => stats.polls_failed += 1,
            _ => {}
        }
        let name = spec.name.clone();
        let now = Instant::now();
        let change = self.scheduler.record_poll(device, block, outcome, now);
        if let Some(stats) = self.stats.devices.get_mut(device) {
            stats.consecutive_failures = self.scheduler.consecutive_failures(device);
        }
        if let Some(change) = change {
            self.availability_changed(device, change).await;
        }
        if !values.is_empty() {
            let event = LineEvent::Values {
                device: name,
                values,
            };
            self.emit(event).await;
        }
    }

    async fn run_command(&mut self, device: usize, pending: Pending) {
        let Pending { command, arrived } = pending;
        let attempts = self.attempts();
        let (Some(spec), Some(master), Some(stats)) = (
            self.spec.devices.get(device),
            self.master.as_mut(),
            self.stats.devices.get_mut(device),
        ) else {
            let detail = "the port is not open".to_string();
            let outcome = CommandOutcome::Failed { detail };
            self.reply(device, command.id, arrived, outcome).await;
            return;
        };
        let exchange = device_exchange(&self.spec.name, spec, self.timeout, &self.turnaround);
        let span =
            tracing::info_span!("command", device = %spec.name, field = command.plan.field());
        let mut seen = SeenReads::new();
        let end = slot::run_slot(&exchange, master, stats, &command.plan, attempts, &mut seen)
            .instrument(span)
            .await;
        let now = Instant::now();
        match end {
            SlotEnd::Done(outcome) => {
                let answered = matches!(
                    outcome,
                    CommandOutcome::Applied { .. } | CommandOutcome::NotApplied { .. }
                );
                tracing::info!(device = %spec.name, field = command.plan.field(), ?outcome, "command done");
                if answered {
                    self.contact(device, now).await;
                }
                self.publish_reads(device, seen, now).await;
                self.reply(device, command.id, arrived, outcome).await;
            }
            SlotEnd::Settling { deadline } => {
                self.settling.push(Settle {
                    device,
                    plan: command.plan,
                    id: command.id,
                    arrived,
                    deadline,
                    next_read: now + SETTLE_REREAD,
                });
                self.contact(device, now).await;
                self.publish_reads(device, seen, now).await;
            }
            SlotEnd::PortGone(error) => {
                let detail = format!("the port failed: {error}");
                let outcome = CommandOutcome::Failed { detail };
                self.reply(device, command.id, arrived, outcome).await;
                self.port_failed(error).await;
            }
        }
    }

    async fn run_settle(&mut self, mut settle: Settle) {
        let attempts = self.attempts();
        let (Some(spec), Some(master), Some(stats)) = (
            self.spec.devices.get(settle.device),
            self.master.as_mut(),
            self.stats.devices.get_mut(settle.device),
        ) else {
            let detail = "the port is not open".to_string();
            let outcome = CommandOutcome::Failed { detail };
            self.reply(settle.device, settle.id, settle.arrived, outcome)
                .await;
            return;
        };
        let exchange = device_exchange(&self.spec.name, spec, self.timeout, &self.turnaround);
        let mut seen = SeenReads::new();
        let result =
            slot::reread(&exchange, master, stats, &settle.plan, attempts, &mut seen).await;
        let now = Instant::now();
        let outcome = match result {
            Ok(Verification::Applied) => CommandOutcome::Applied {
                detail: "read-back confirms the value after settling".into(),
            },
            Ok(Verification::NotApplied(detail)) => CommandOutcome::NotApplied { detail },
            Ok(Verification::Settling) if now < settle.deadline => {
                settle.next_read = now + SETTLE_REREAD;
                self.settling.push(settle);
                return;
            }
            Ok(Verification::Settling) => CommandOutcome::NotApplied {
                detail: "the device was still moving when the settle window ended".into(),
            },
            Err(Failure::PortGone(error)) => {
                let detail = format!("the port failed: {error}");
                let outcome = CommandOutcome::Failed { detail };
                self.reply(settle.device, settle.id, settle.arrived, outcome)
                    .await;
                self.port_failed(error).await;
                return;
            }
            Err(failure) => match slot::failed(failure) {
                SlotEnd::Done(outcome) => outcome,
                _ => CommandOutcome::Failed {
                    detail: "read-back failed".into(),
                },
            },
        };
        let device = settle.device;
        self.publish_reads(device, seen, now).await;
        self.reply(device, settle.id, settle.arrived, outcome).await;
    }

    /// The device answered a command: it is there.
    async fn contact(&mut self, device: usize, now: Instant) {
        if let Some(change) = self.scheduler.record_contact(device, now) {
            self.availability_changed(device, change).await;
        }
    }

    /// Sends the values of the reads a command slot made that are poll blocks of the device
    /// (they count as that block's poll); every other block is polled at once, so that what
    /// the command changed is reported without waiting for a poll interval.
    async fn publish_reads(&mut self, device: usize, seen: SeenReads, now: Instant) {
        let Some(spec) = self.spec.devices.get(device) else {
            return;
        };
        let profile = spec.profile.clone();
        let name = spec.name.clone();
        let mut values = Vec::new();
        let mut covered = vec![false; profile.read_blocks().len()];
        for (request, answer) in &seen {
            let Some(block) = profile
                .read_blocks()
                .iter()
                .position(|b| &b.request == request)
            else {
                continue;
            };
            for reading in profile.decode_block(block, answer) {
                match reading.value {
                    Ok(value) => values.push((reading.field, value)),
                    Err(error) => {
                        if let Some(stats) = self.stats.devices.get_mut(device) {
                            stats.field_errors += 1;
                        }
                        tracing::warn!(device = %name, field = %reading.field, "invalid field data, not published: {error}");
                    }
                }
            }
            if let Some(flag) = covered.get_mut(block) {
                *flag = true;
            }
            self.scheduler
                .record_poll(device, block, PollOutcome::Answered, now);
        }
        self.scheduler.refresh_except(device, &covered, now);
        if !values.is_empty() {
            let event = LineEvent::Values {
                device: name,
                values,
            };
            self.emit(event).await;
        }
    }

    /// Counts a command's end and reports it on the events channel (after any `Values` of
    /// its slot, so that a command's state is out before its result).
    async fn reply(&mut self, device: usize, id: u64, arrived: Instant, outcome: CommandOutcome) {
        let latency = arrived.elapsed();
        self.stats.commands += 1;
        self.stats.last_command_latency = Some(latency);
        self.stats.worst_command_latency = Some(
            self.stats
                .worst_command_latency
                .map_or(latency, |w| w.max(latency)),
        );
        let device = self
            .spec
            .devices
            .get(device)
            .map(|spec| spec.name.clone())
            .unwrap_or_default();
        self.emit(LineEvent::CommandFinished {
            id,
            device,
            outcome,
        })
        .await;
    }

    async fn fail_queued(&mut self, why: &str) {
        if self.scheduler.queued_commands() == 0 {
            return;
        }
        for (device, pending) in self.scheduler.drain_commands() {
            let outcome = CommandOutcome::Failed {
                detail: why.to_string(),
            };
            self.reply(device, pending.command.id, pending.arrived, outcome)
                .await;
        }
    }

    fn publish_stats(&mut self) {
        let now = Instant::now();
        let counters = match &self.master {
            Some(master) => add_counters(self.closed_counters, master.counters()),
            None => self.closed_counters,
        };
        let stats = &mut self.stats;
        stats.heartbeat = now;
        stats.transactions = counters.requests;
        stats.timeouts = counters.timeouts;
        stats.crc_errors = counters.crc_errors;
        stats.truncated = counters.truncated;
        stats.unexpected_answers = counters.unexpected;
        stats.exceptions = counters.exceptions;
        stats.late_answers = counters.late_answers;
        stats.stray_bytes = counters.stray_bytes;
        stats.wrong_address = counters.wrong_address;
        stats.wire_time = counters.wire_time;
        self.load_samples.push_back((now, counters.wire_time));
        while self
            .load_samples
            .get(1)
            .is_some_and(|(at, _)| now.duration_since(*at) >= LOAD_WINDOW)
        {
            self.load_samples.pop_front();
        }
        if let Some((since, wire_then)) = self.load_samples.front() {
            let wall = now.duration_since(*since).as_secs_f64();
            if wall > 0.0 {
                let wire = counters.wire_time.saturating_sub(*wire_then).as_secs_f64();
                stats.bus_load = (wire / wall).min(1.0);
            }
        }
        if let Some((mean, worst)) = self.turnaround.figures() {
            stats.turnaround_mean = Some(mean);
            stats.turnaround_worst = Some(worst);
        }
        self.last_published = now;
        self.stats_tx.send_replace(stats.clone());
    }

    /// Shutdown: answer every command still waiting, publish the last statistics.
    async fn finish(&mut self) {
        self.fail_queued("the gateway is shutting down").await;
        for settle in std::mem::take(&mut self.settling) {
            let detail = "the gateway shut down before the read-back settled".to_string();
            let outcome = CommandOutcome::NotApplied { detail };
            self.reply(settle.device, settle.id, settle.arrived, outcome)
                .await;
        }
        self.publish_stats();
        tracing::info!("line stopped");
    }
}

/// What one exchange with `device` on the line named `line` needs. A free function over the
/// line's fields rather than a method, so that the master and the device's counters can be
/// borrowed mutably beside it.
fn device_exchange<'a>(
    line: &'a str,
    device: &'a DeviceSpec,
    timeout: Duration,
    turnaround: &'a Turnaround,
) -> Exchange<'a> {
    Exchange {
        line,
        device: &device.name,
        slave: device.address,
        timeout,
        turnaround,
    }
}

/// Reads a block's used runs one by one and assembles the block's answer with zeros in the
/// places no field uses.
async fn read_runs(
    exchange: &Exchange<'_>,
    master: &mut Master,
    stats: &mut DeviceStats,
    block: &ReadBlock,
    attempts: u32,
) -> Result<Response, Failure> {
    let mut answer = empty_answer(&block.request);
    for &(offset, length) in &block.used_runs {
        let Some(request) = run_request(&block.request, offset, length) else {
            continue;
        };
        let part = exchange.run(master, stats, &request, attempts).await?;
        place(&mut answer, offset, &part);
    }
    Ok(answer)
}

/// The read request for `length` items at `offset` inside `block`.
pub fn run_request(block: &Request, offset: u16, length: u16) -> Option<Request> {
    let at = |start: u16| start.checked_add(offset);
    Some(match block {
        Request::ReadCoils { start, .. } => Request::ReadCoils {
            start: at(*start)?,
            quantity: length,
        },
        Request::ReadDiscreteInputs { start, .. } => Request::ReadDiscreteInputs {
            start: at(*start)?,
            quantity: length,
        },
        Request::ReadHoldingRegisters { start, .. } => Request::ReadHoldingRegisters {
            start: at(*start)?,
            quantity: length,
        },
        Request::ReadInputRegisters { start, .. } => Request::ReadInputRegisters {
            start: at(*start)?,
            quantity: length,
        },
        _ => return None,
    })
}

/// An all-zero answer of the shape `block` would get.
pub fn empty_answer(block: &Request) -> Response {
    match block {
        Request::ReadCoils { quantity, .. } => Response::Coils(vec![false; usize::from(*quantity)]),
        Request::ReadDiscreteInputs { quantity, .. } => {
            Response::DiscreteInputs(vec![false; usize::from(*quantity)])
        }
        Request::ReadInputRegisters { quantity, .. } => {
            Response::InputRegisters(vec![0; usize::from(*quantity)])
        }
        Request::ReadHoldingRegisters { quantity, .. } => {
            Response::HoldingRegisters(vec![0; usize::from(*quantity)])
        }
        _ => Response::HoldingRegisters(Vec::new()),
    }
}

/// Copies a run's answer into the block answer at `offset` (ignoring anything out of range).
pub fn place(answer: &mut Response, offset: u16, part: &Response) {
    let offset = usize::from(offset);
    match answer {
        Response::Coils(bits) | Response::DiscreteInputs(bits) => {
            if let Some(part) = part.bits() {
                for (slot, bit) in bits.iter_mut().skip(offset).zip(part) {
                    *slot = *bit;
                }
            }
        }
        Response::HoldingRegisters(words) | Response::InputRegisters(words) => {
            if let Some(part) = part.registers() {
                for (slot, word) in words.iter_mut().skip(offset).zip(part) {
                    *slot = *word;
                }
            }
        }
        _ => {}
    }
}

fn add_counters(a: WireCounters, b: WireCounters) -> WireCounters {
    WireCounters {
        requests: a.requests + b.requests,
        timeouts: a.timeouts + b.timeouts,
        crc_errors: a.crc_errors + b.crc_errors,
        truncated: a.truncated + b.truncated,
        unexpected: a.unexpected + b.unexpected,
        exceptions: a.exceptions + b.exceptions,
        late_answers: a.late_answers + b.late_answers,
        stray_bytes: a.stray_bytes + b.stray_bytes,
        wrong_address: a.wrong_address + b.wrong_address,
        wire_time: a.wire_time + b.wire_time,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_are_assembled_with_zeros_in_unread_places() {
        let block = Request::ReadHoldingRegisters {
            start: 0x70,
            quantity: 8,
        };
        let mut answer = empty_answer(&block);
        assert_eq!(
            run_request(&block, 4, 2),
            Some(Request::ReadHoldingRegisters {
                start: 0x74,
                quantity: 2
            })
        );
        place(
            &mut answer,
            4,
            &Response::HoldingRegisters(vec![0x64, 0x12]),
        );
        place(&mut answer, 7, &Response::HoldingRegisters(vec![9, 9, 9]));
        assert_eq!(
            answer,
            Response::HoldingRegisters(vec![0, 0, 0, 0, 0x64, 0x12, 0, 9])
        );
        let coils = Request::ReadCoils {
            start: 0,
            quantity: 4,
        };
        let mut bits = empty_answer(&coils);
        place(&mut bits, 2, &Response::Coils(vec![true, true]));
        assert_eq!(bits, Response::Coils(vec![false, false, true, true]));
    }

    /// Collects what the test's tracing subscriber writes.
    #[derive(Clone, Default)]
    struct CapturedLog(Arc<std::sync::Mutex<Vec<u8>>>);

    impl std::io::Write for CapturedLog {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for CapturedLog {
        type Writer = CapturedLog;
        fn make_writer(&'a self) -> Self::Writer {
            self.clone()
        }
    }

    // Current-thread runtime: the line task runs on this thread, under the test's subscriber.
    #[tokio::test]
    async fn a_port_path_that_is_no_serial_port_fails_the_line_with_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("passwd");
        std::fs::write(&path, "root:x:0:0::/root:/bin/sh\n").unwrap();
        let log = CapturedLog::default();
        let subscriber = tracing_subscriber::fmt()
            .with_writer(log.clone())
            .with_ansi(false)
            .with_max_level(tracing::Level::INFO)
            .finish();
        let _default = tracing::subscriber::set_default(subscriber);
        let profile = crate::profile::registry::built_in("wuzhou-valve").unwrap();
        let spec = LineSpec {
            name: "line-x".into(),
            serial: crate::rtu::transport::SerialSettings {
                path: path.display().to_string(),
                baud: 9600,
                format: crate::rtu::timing::CharFormat {
                    data_bits: 8,
                    parity: crate::rtu::timing::Parity::Even,
                    stop_bits: 1,
                },
                rs485: None,
            },
            response_timeout: None,
            retries: 1,
            offline_after: 2,
            echo: false,
            broadcast_turnaround: Duration::from_millis(200),
            frame_log: None,
            devices: vec![super::super::DeviceSpec {
                name: "valve".into(),
                address: 1,
                profile: Arc::new(profile),
                poll_interval: Duration::from_secs(1),
            }],
        };
        let (events_tx, mut events_rx) = mpsc::channel(16);
        let (trigger, shutdown) = crate::shutdown::channel();
        let (handle, task) = spawn_line(spec, events_tx, shutdown);

        let event = tokio::time::timeout(Duration::from_secs(15), events_rx.recv())
            .await
            .unwrap();
        assert_eq!(
            event,
            Some(LineEvent::Availability {
                device: "valve".into(),
                online: false
            })
        );
        let mut stats = handle.stats_rx.clone();
        // `matches!` drops the watch's read guard at once: the line publishes stats meanwhile.
        let failed = matches!(
            tokio::time::timeout(
                Duration::from_secs(15),
                stats.wait_for(|stats| stats.port_failures >= 1 && !stats.port_open),
            )
            .await,
            Ok(Ok(_))
        );
        assert!(failed);
        trigger.fire();
        task.await.unwrap();

        let text = String::from_utf8(log.0.lock().unwrap().clone()).unwrap();
        let failure = text
            .lines()
            .find(|line| line.contains("is not a serial port"))
            .unwrap_or_else(|| panic!("no line failure logged:\n{text}"));
        assert!(failure.contains("ERROR"), "{failure}");
        assert!(failure.contains(&path.display().to_string()), "{failure}");
        assert!(failure.contains("retry_in=5s"), "{failure}");
        assert!(!text.contains("cannot open the port"), "{text}");
    }
}
