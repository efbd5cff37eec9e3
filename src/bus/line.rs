//! The task that owns one line: its loop. It keeps the link open ([`super::port`]: a serial
//! port or a TCP connection, the same loop for both),
//! asks the [`Scheduler`] what is due, runs command slots and settle re-reads
//! ([`super::commands`]) before polls ([`super::poll`]), carries out what they report, turns
//! answers into values through each
//! device's runtime ([`super::device`]) and reports [`LineEvent`]s. It publishes [`LineStats`]
//! after every transaction and at least once a second.
//!
//! A served line ([`super::serve`]) takes its clients' requests when no command waits, one
//! client slot at a time and a due poll between two of them; reads a young poll answered
//! exactly (or, of a block the device reads linearly, in part) come from its cache.
//!
//! A port path that is no serial port fails the line without ending the daemon: its devices
//! are offline, every attempt logs an ERROR naming the path, and the gateway's other lines
//! keep serving their devices.
//!
//! A transaction is never cancelled half-way: shutdown, commands and timers are only looked at
//! between transactions, so the line is always left with a complete frame exchange on it.

use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use tokio::sync::{mpsc, watch};
use tracing::Instrument;

use super::commands::{CommandSlots, Finished, Pending, Settle, SlotLink, SlotReport};
use super::device::{DeviceRuntime, Values};
use super::health::{HealthChange, HealthPolicy};
use super::plan::DevicePlan;
use super::poll::{self, PollContext};
use super::port::{self, Backoff, OpenError, Reopen, MISSING_PORT, UNREACHABLE_SERVER};
use super::report::Report;
use super::reporter;
use super::scheduler::{Due, PollOutcome, Scheduler};
use super::serve::policy;
use super::serve::queue::{BlockCache, ClientQueue, CLIENT_QUEUE};
use super::serve::server::{self, ServeCounters};
use super::serve::{Access, ClientRequest};
use super::slot::SeenReads;
use super::stats::LoadWindow;
use super::transaction::{Exchange, Failure, Turnaround};
use super::{
    Command, CommandFailure, CommandOutcome, LineEvent, LineHandle, LineSpec, LineStats, Origin,
    Transport, WriteClock,
};
use crate::profile::Profile;
use crate::shutdown::Shutdown;
use rtu2mqtt_modbus::link::Link;
use rtu2mqtt_modbus::master::{PortFault, Reply, WireCounters};
use rtu2mqtt_modbus::timing::LineTiming;
use rtu2mqtt_modbus::transport::TransportError;
use rtu2mqtt_modbus::{ExceptionCode, Request, Response};

/// Commands that may wait in a line's queue; the bridge waits when it is full.
pub const COMMAND_QUEUE: usize = 64;
/// Refresh requests that may wait to be taken by the line; more are dropped (a device's
/// refresh already waiting covers them).
pub const REFRESH_QUEUE: usize = 16;
/// Time a device takes to start answering on top of the answer's own wire time; with the
/// timing's host allowance the default timeout leaves 100 ms beyond the wire.
pub const DEVICE_MARGIN: Duration = Duration::from_millis(80);
/// Statistics are published at least this often (the watchdog's heartbeat).
pub const HEARTBEAT: Duration = Duration::from_secs(1);
/// Bus load is measured over this sliding window.
pub const LOAD_WINDOW: Duration = Duration::from_secs(10);
/// Ids of the commands a client's write becomes start here, far above any the bridge uses:
/// their ends answer the client and never reach the bridge.
const CLIENT_COMMAND_IDS: u64 = 1 << 63;

/// Starts the task that owns `spec`'s port, with a write clock of its own.
pub fn spawn_line(
    spec: LineSpec,
    events_tx: mpsc::Sender<LineEvent>,
    shutdown: Shutdown,
) -> (LineHandle, tokio::task::JoinHandle<()>) {
    spawn_line_with_clock(spec, events_tx, shutdown, WriteClock::new())
}

/// Starts the task that owns `spec`'s port; the write intervals of its devices' fields run on
/// `writes`, which the gateway's other lines (and the ones a reload starts) share.
pub fn spawn_line_with_clock(
    spec: LineSpec,
    events_tx: mpsc::Sender<LineEvent>,
    shutdown: Shutdown,
    writes: WriteClock,
) -> (LineHandle, tokio::task::JoinHandle<()>) {
    let names: Vec<String> = spec.devices.iter().map(|d| d.name.clone()).collect();
    let now = Instant::now();
    let (command_tx, command_rx) = mpsc::channel(COMMAND_QUEUE);
    let (refresh_tx, refresh_rx) = mpsc::channel(REFRESH_QUEUE);
    let (stats_tx, stats_rx) = watch::channel(LineStats::new(&spec.name, &names, now));
    let handle = LineHandle {
        name: spec.name.clone(),
        command_tx,
        refresh_tx,
        stats_rx,
    };
    let span = tracing::info_span!("line", line = %spec.name);
    let (clients, counters) = match &spec.serve {
        Some(serve) => {
            let (client_tx, client_rx) = mpsc::channel(CLIENT_QUEUE);
            let counters = Arc::new(ServeCounters::default());
            let server = server::run(
                serve.clone(),
                spec.devices.clone(),
                client_tx,
                Arc::clone(&counters),
                shutdown.clone(),
            );
            tokio::spawn(server.instrument(span.clone()));
            (Some(client_rx), Some(counters))
        }
        None => (None, None),
    };
    // Fields with `publish` settings: the line's events pass its reporter on their way out.
    let report = Report::new(&spec.devices);
    let events_tx = if report.is_empty() {
        events_tx
    } else {
        let (line_tx, line_rx) = mpsc::channel(reporter::REPORTER_QUEUE);
        let reporting = reporter::run(report, line_rx, events_tx, shutdown.clone());
        tokio::spawn(reporting.instrument(span.clone()));
        line_tx
    };
    let mut line = Line::new(spec, events_tx, command_rx, stats_tx, shutdown, now);
    line.refreshes = Some(refresh_rx);
    line.writes = writes;
    line.clients = ClientQueue::new(clients);
    line.serve_counters = counters;
    let task = tokio::spawn(line.run().instrument(span));
    (handle, task)
}

/// The response timeout of a line when none is configured: the wire time of the longest answer
/// any of its devices' blocks can give, the end-of-frame silence, and a device margin; on a
/// TCP line also the network allowance.
pub fn default_response_timeout(spec: &LineSpec, timing: &LineTiming) -> Duration {
    let network = match &spec.transport {
        Transport::Serial => Duration::ZERO,
        Transport::Tcp {
            network_allowance, ..
        } => *network_allowance,
    };
    let longest = spec
        .devices
        .iter()
        .flat_map(|device| device.profile.read_blocks().iter())
        .map(|block| block.request.answer_len())
        .max()
        .unwrap_or(8)
        .max(8);
    timing.default_response_timeout(longest, DEVICE_MARGIN) + network
}

/// The line task's state.
struct Line {
    /// The line's configuration; its devices have moved into `devices`.
    spec: LineSpec,
    devices: Vec<DeviceRuntime>,
    timing: LineTiming,
    timeout: Duration,
    scheduler: Scheduler<Pending>,
    master: Option<Link>,
    reopen: Reopen,
    /// The command queue and the commands whose device is still settling.
    commands: CommandSlots,
    /// Refresh requests by device name (None once their sender is gone).
    refreshes: Option<mpsc::Receiver<String>>,
    events_tx: mpsc::Sender<LineEvent>,
    stats_tx: watch::Sender<LineStats>,
    /// The line's own figures; the devices' are in `devices` until published.
    stats: LineStats,
    /// Counters of the masters of ports closed earlier (a reopened port starts a new master).
    closed_counters: WireCounters,
    load: LoadWindow,
    turnaround: Turnaround,
    last_published: Instant,
    shutdown: Shutdown,
    /// Requests from the line's server (none when the line is not served).
    clients: ClientQueue,
    /// The last slot was a client's: a due poll goes before the next one.
    client_went_last: bool,
    /// Polled blocks that clients' reads are answered from.
    cache: BlockCache,
    serve_counters: Option<Arc<ServeCounters>>,
    next_client_command: u64,
    /// Clients' writes still settling on their device, by command id: their end is published
    /// when the read-back settles.
    settling_client_writes: std::collections::HashMap<u64, ClientWrite>,
    /// When the fields with a write interval were last written, by any source.
    writes: WriteClock,
}

/// A client's write as its outcome is published.
#[derive(Debug)]
struct ClientWrite {
    device: String,
    field: String,
    value: String,
    client: String,
}

impl Line {
    fn new(
        mut spec: LineSpec,
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
        let devices: Vec<DeviceRuntime> = std::mem::take(&mut spec.devices)
            .into_iter()
            .map(DeviceRuntime::new)
            .collect();
        let stats = stats_tx.borrow().clone();
        let cache_age = spec
            .serve
            .as_ref()
            .map_or(Duration::ZERO, |serve| serve.cache);
        let cache = BlockCache::new(
            cache_age,
            devices.iter().map(|d| {
                let blocks = d.spec.profile.read_blocks().iter();
                blocks.map(|block| block.reads_linearly).collect()
            }),
        );
        tracing::info!(
            link = %spec.transport.describe(&spec.serial),
            baud = spec.serial.baud,
            devices = devices.len(),
            ?timeout,
            "line starting"
        );
        Line {
            timing,
            timeout,
            scheduler,
            master: None,
            reopen: Reopen::new(now),
            devices,
            commands: CommandSlots::new(command_rx),
            refreshes: None,
            events_tx,
            stats_tx,
            stats,
            closed_counters: WireCounters::default(),
            load: LoadWindow::new(LOAD_WINDOW),
            turnaround: Turnaround::default(),
            last_published: now,
            shutdown,
            clients: ClientQueue::new(None),
            client_went_last: false,
            cache,
            serve_counters: None,
            next_client_command: CLIENT_COMMAND_IDS,
            settling_client_writes: std::collections::HashMap::new(),
            writes: WriteClock::new(),
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
                if now >= self.reopen.at() {
                    self.open_link(now).await;
                } else {
                    self.fail_queued(&CommandFailure::PortReopening).await;
                    self.fail_client_requests();
                    self.wait(Some(self.reopen.at())).await;
                }
                continue;
            }
            // What the line does next is chosen once it is free, so that a command arriving
            // during the silence goes ahead of the poll that would otherwise have been chosen
            // at its start.
            self.quiet_unless_command().await;
            let now = Instant::now();
            if let Some(settle) = self.commands.take_due_settle(now) {
                self.run_settle(settle).await;
                self.publish_stats();
                continue;
            }
            if let Some((device, pending)) = self.commands.take_due_held(now) {
                self.run_command(device, pending).await;
                self.publish_stats();
                continue;
            }
            // Clients after commands, before polls; a due poll between two client slots.
            if self.scheduler.queued_commands() == 0 && !self.client_went_last {
                if let Some(request) = self.clients.try_take() {
                    self.client_went_last = true;
                    self.run_client(request).await;
                    self.publish_stats();
                    continue;
                }
            }
            self.client_went_last = false;
            self.accept_refreshes();
            let next_settle = self.commands.next_due();
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
                Due::Wait(_) | Due::Idle if self.clients.is_waiting() => {}
                Due::Wait(until) => {
                    let until = next_settle.map_or(until, |s| s.min(until));
                    self.wait(Some(until)).await;
                }
                Due::Idle => self.wait(next_settle).await,
            }
        }
        self.finish().await;
    }

    /// Waits until the link could take the next request, or until a command arrives (it is
    /// queued, and commands go ahead of polls). A link that fails here is left to the next
    /// transaction to report.
    async fn quiet_unless_command(&mut self) {
        let Some(master) = self.master.as_mut() else {
            return;
        };
        let patience = self.timeout;
        let commands_open = self.commands.is_open();
        let arrived = tokio::select! {
            biased;
            command = self.commands.next(), if commands_open => Some(command),
            _ = master.wait_until_quiet(patience) => None,
        };
        match arrived {
            Some(received) => {
                // A command's transaction waits out the rest of the silence itself: that gap
                // is the wire's, not the line's own time.
                self.turnaround.idle();
                self.take_received(received).await;
            }
            None => self.turnaround.silence_over(),
        }
    }

    /// What the command queue gave while the line waited: a command is queued; the end of
    /// the queue (the bridge is gone) stops the line listening to it.
    async fn take_received(&mut self, received: Option<Command>) {
        match received {
            Some(command) => self.accept(command, Instant::now()).await,
            None => self.commands.closed(),
        }
    }

    /// Sleeps until `until` (or the next heartbeat), a command arrives, or shutdown.
    async fn wait(&mut self, until: Option<Instant>) {
        self.turnaround.idle();
        let heartbeat = self.last_published + HEARTBEAT;
        let wake = until.map_or(heartbeat, |u| u.min(heartbeat));
        let sleep = tokio::time::sleep_until(tokio::time::Instant::from_std(wake));
        let commands_open = self.commands.is_open();
        let refreshes = self.refreshes.as_mut();
        let refreshes_open = refreshes.is_some();
        let refresh = async move {
            match refreshes {
                Some(refreshes) => refreshes.recv().await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            () = sleep => {}
            received = self.commands.next(), if commands_open => {
                self.take_received(received).await;
            }
            asked = refresh, if refreshes_open => self.refresh(asked),
            () = self.clients.arrival() => {}
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

    /// Reports a device's freshly decoded values (nothing when there are none): the one way
    /// values of polls, command slots and settle re-reads reach the bridge.
    /// `read_at` is the wall-clock instant the answers were read.
    async fn emit_values(
        &mut self,
        device: usize,
        values: Values,
        read_at: SystemTime,
        origin: Origin,
    ) {
        let Some(runtime) = self.devices.get(device) else {
            return;
        };
        if values.is_empty() {
            return;
        }
        let event = LineEvent::Values {
            device: runtime.spec.name.clone(),
            values,
            read_at,
            origin,
        };
        self.emit(event).await;
    }

    async fn open_link(&mut self, now: Instant) {
        self.turnaround.idle();
        let opened = tokio::select! {
            opened = port::open_link(&self.spec, self.timing) => Some(opened),
            () = self.shutdown.fired() => None,
        };
        let Some(opened) = opened else {
            return;
        };
        match opened {
            Ok(link) => {
                self.master = Some(link);
                if self.stats.port_failures > 0 {
                    tracing::info!(port = %self.spec.serial.path, "port open again");
                } else {
                    tracing::info!(port = %self.spec.serial.path, "port open");
                }
                self.stats.port_open = true;
                self.reopen.opened();
                self.scheduler.port_restored(now);
            }
            Err(error) => {
                self.stats.port_failures += 1;
                let backoff = Backoff::after(&error);
                let delay = self.reopen.failed(Instant::now(), backoff);
                if let OpenError::Serial(TransportError::NotATerminal { .. }) = error {
                    tracing::error!(
                        port = %self.spec.serial.path,
                        retry_in = ?delay,
                        "line failed, its devices stay offline: {error}; set `port` to the \
                         adapter's device (such as /dev/serial/by-id/…)"
                    );
                } else {
                    tracing::warn!(
                        port = %self.spec.serial.path,
                        retry_in = ?delay,
                        "cannot open the port: {error}"
                    );
                }
                self.lose_devices(now).await;
            }
        }
        self.publish_stats();
    }

    /// The port failed under a transaction: close it, take the devices offline, reopen later.
    async fn port_failed(&mut self, error: PortFault) {
        let now = Instant::now();
        if let Some(master) = self.master.take() {
            self.closed_counters += master.counters();
        }
        self.stats.port_open = false;
        self.stats.port_failures += 1;
        self.reopen.opened();
        let backoff = match self.spec.transport {
            Transport::Serial => MISSING_PORT,
            Transport::Tcp { .. } => UNREACHABLE_SERVER,
        };
        let delay = self.reopen.failed(now, backoff);
        tracing::warn!(
            port = %self.spec.serial.path,
            retry_in = ?delay,
            "port failed, closing it: {error}"
        );
        for (device, finished) in self.commands.fail_settling(&error) {
            self.reply(device, finished).await;
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
        let Some(runtime) = self.devices.get_mut(device) else {
            return;
        };
        runtime.stats.online = online;
        if !online {
            runtime.forget_answers();
            self.cache.forget(device);
        }
        if online {
            tracing::info!(device = %runtime.spec.name, "device online");
        } else {
            tracing::warn!(device = %runtime.spec.name, "device offline");
        }
        let event = LineEvent::Availability {
            device: runtime.spec.name.clone(),
            online,
        };
        self.emit(event).await;
    }

    async fn run_poll(&mut self, device: usize, block: usize, attempts: u32) {
        let Some(runtime) = self.devices.get_mut(device) else {
            return;
        };
        let profile: Arc<Profile> = runtime.spec.profile.clone();
        let Some(read) = profile.read_blocks().get(block) else {
            return;
        };
        let Some(master) = self.master.as_mut() else {
            return;
        };
        let context = PollContext {
            line: &self.spec.name,
            timeout: self.timeout,
            turnaround: &self.turnaround,
            attempts,
        };
        let result = poll::read_block(context, master, runtime, block, read).await;
        let mut values = Values::new();
        let mut unchanged = false;
        let outcome = match result {
            Ok(reply) => {
                if let Ok(answer) = &reply {
                    let whole = !runtime.read_by_parts.get(block).copied().unwrap_or(false);
                    if whole {
                        // Only what the device itself answered may answer a client.
                        self.cache
                            .store(device, block, &read.request, answer, Instant::now());
                    }
                    unchanged = runtime.answer_unchanged(block, answer);
                    if !unchanged {
                        runtime.decode_into(block, answer, &mut values);
                    }
                }
                poll::outcome(&reply, &runtime.spec.name, &read.name)
            }
            Err(Failure::NoAnswer(problem)) => {
                tracing::debug!(device = %runtime.spec.name, block = %read.name, "poll failed: {problem}");
                PollOutcome::Failed
            }
            Err(Failure::PortGone(error)) => {
                self.port_failed(error).await;
                return;
            }
        };
        match outcome {
            PollOutcome::Answered if unchanged || !values.is_empty() => runtime.stats.polls_ok += 1,
            PollOutcome::Failed => runtime.stats.polls_failed += 1,
            _ => {}
        }
        let now = Instant::now();
        let read_at = SystemTime::now();
        let change = self.scheduler.record_poll(device, block, outcome, now);
        runtime.stats.consecutive_failures = self.scheduler.consecutive_failures(device);
        if let Some(change) = change {
            self.availability_changed(device, change).await;
        }
        self.emit_values(device, values, read_at, Origin::Poll)
            .await;
    }

    fn publish_stats(&mut self) {
        let now = Instant::now();
        let counters = match &self.master {
            Some(master) => self.closed_counters + master.counters(),
            None => self.closed_counters,
        };
        let stats = &mut self.stats;
        stats.heartbeat = now;
        stats.record_wire(&counters);
        if let Some(load) = self.load.sample(now, counters.wire_time) {
            stats.bus_load = load;
        }
        if let Some((mean, worst)) = self.turnaround.figures() {
            stats.turnaround_mean = Some(mean);
            stats.turnaround_worst = Some(worst);
        }
        stats.set_devices(self.devices.iter().map(|d| &d.stats));
        if let Some(counters) = &self.serve_counters {
            use std::sync::atomic::Ordering::Relaxed;
            stats.client_requests = counters.requests.load(Relaxed);
            stats.cache_hits = counters.cache_hits.load(Relaxed);
            stats.client_refusals = counters.refusals.load(Relaxed);
            stats.client_busy = counters.busy.load(Relaxed);
            stats.client_evicted = counters.evicted.load(Relaxed);
        }
        self.last_published = now;
        // Copied into the published snapshot in place: no allocation per transaction.
        self.stats_tx
            .send_modify(|published| published.clone_from(stats));
    }

    /// Shutdown: answer every command still waiting, publish the last statistics.
    async fn finish(&mut self) {
        self.fail_queued(&CommandFailure::ShuttingDown).await;
        for (device, pending) in self.commands.drain_held() {
            let finished = pending.failed(CommandFailure::ShuttingDown);
            self.reply(device, finished).await;
        }
        for (device, finished) in self.commands.abandon_settling() {
            self.reply(device, finished).await;
        }
        self.publish_stats();
        tracing::info!("line stopped");
    }
}

/// Commands: taking them in, running their slots and carrying out what the slots report.
impl Line {
    async fn accept_commands(&mut self, now: Instant) {
        while let Some(command) = self.commands.try_take() {
            self.accept(command, now).await;
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
                let cause = CommandFailure::UnknownDevice {
                    device: command.device.clone(),
                    line: self.spec.name.clone(),
                };
                let (id, device) = (command.id, command.device);
                self.emit(LineEvent::CommandFinished {
                    id,
                    device,
                    outcome: CommandOutcome::Failed { cause },
                })
                .await;
            }
        }
    }

    /// Takes every refresh request already waiting, without waiting.
    fn accept_refreshes(&mut self) {
        while let Some(refreshes) = self.refreshes.as_mut() {
            match refreshes.try_recv() {
                Ok(device) => self.refresh(Some(device)),
                Err(mpsc::error::TryRecvError::Empty) => return,
                Err(mpsc::error::TryRecvError::Disconnected) => self.refresh(None),
            }
        }
    }

    /// A refresh request for `device` (None: their sender is gone, the line stops listening).
    fn refresh(&mut self, device: Option<String>) {
        let Some(name) = device else {
            self.refreshes = None;
            return;
        };
        let refreshed = self
            .device_index(&name)
            .is_some_and(|device| self.scheduler.request_refresh(device));
        if refreshed {
            tracing::debug!(device = %name, "refresh: every block is read next");
        } else {
            tracing::info!(device = %name, "refresh not done: the device is offline or not on this line");
        }
    }

    fn device_index(&self, name: &str) -> Option<usize> {
        self.devices.iter().position(|d| d.spec.name == name)
    }

    async fn run_command(&mut self, device: usize, pending: Pending) {
        // A client wrote one of the command's fields after the bridge sent it: the command
        // waits out the field's interval like any command for it.
        let now = Instant::now();
        if let Some(runtime) = self.devices.get(device) {
            let plan = &pending.command.plan;
            let fields = plan.targets().into_iter().map(|(field, _)| field);
            let busy =
                self.writes
                    .busy_until(&runtime.spec.name, &runtime.spec.profile, fields, now);
            if let Some(until) = busy {
                tracing::debug!(device = %runtime.spec.name, field = plan.field(), wait = ?until - now,
                    "command held: the field's write interval runs");
                self.commands.hold(device, pending, until);
                return;
            }
        }
        let fields: Vec<String> = pending
            .command
            .plan
            .targets()
            .into_iter()
            .map(|(field, _)| field.to_string())
            .collect();
        let attempts = self.attempts();
        let Some(link) = slot_link(
            &mut self.devices,
            self.master.as_mut(),
            &self.spec.name,
            self.timeout,
            &self.turnaround,
            device,
            attempts,
        ) else {
            let finished = pending.failed(CommandFailure::PortNotOpen);
            self.reply(device, finished).await;
            return;
        };
        let report = self.commands.run(link, device, pending).await;
        if report.wrote {
            self.note_write(device, &fields).await;
        }
        self.carry_out(report).await;
    }

    /// A slot that wrote `fields` of `device` has ended: their write intervals start now, and
    /// the bridge learns it before the slot's values and end.
    async fn note_write(&mut self, device: usize, fields: &[String]) {
        let Some(runtime) = self.devices.get(device) else {
            return;
        };
        let at = Instant::now();
        let name = runtime.spec.name.clone();
        let fields = fields.iter().map(String::as_str);
        let noted = self.writes.wrote(&name, &runtime.spec.profile, fields, at);
        if !noted.is_empty() {
            self.emit(LineEvent::Written {
                device: name,
                fields: noted,
                at,
            })
            .await;
        }
    }

    async fn run_settle(&mut self, settle: Settle) {
        let attempts = self.attempts();
        let device = settle.device();
        let Some(link) = slot_link(
            &mut self.devices,
            self.master.as_mut(),
            &self.spec.name,
            self.timeout,
            &self.turnaround,
            device,
            attempts,
        ) else {
            let finished = settle.finish(CommandOutcome::Failed {
                cause: CommandFailure::PortNotOpen,
            });
            self.reply(device, finished).await;
            return;
        };
        let report = self.commands.reread(link, settle).await;
        self.carry_out(report).await;
    }

    /// What a slot or a settle re-read reported, in its order: the device's contact, its
    /// reads, the command's end, and last the port's failure.
    async fn carry_out(&mut self, report: SlotReport) {
        let SlotReport {
            device,
            contact,
            reads,
            changed,
            finished,
            port_gone,
            wrote: _,
        } = report;
        let now = Instant::now();
        // The command can have changed what a poll read: clients read the device again.
        self.cache.forget(device);
        if contact {
            if let Some(change) = self.scheduler.record_contact(device, now) {
                self.availability_changed(device, change).await;
            }
        }
        if let Some(seen) = reads {
            self.publish_reads(device, seen, &changed, now).await;
        }
        if let Some(finished) = finished {
            self.reply(device, finished).await;
        }
        if let Some(error) = port_gone {
            self.port_failed(error).await;
        }
    }

    /// Sends the values of the reads a command slot made that are poll blocks of the device.
    /// A block in `changed` (the command can have changed it) that the slot did not read whole
    /// is polled at once, so that what the command changed is reported without waiting for a
    /// poll interval; no block's cadence moves ([`Scheduler::after_command`]).
    async fn publish_reads(
        &mut self,
        device: usize,
        seen: SeenReads,
        changed: &[usize],
        now: Instant,
    ) {
        let Some(runtime) = self.devices.get_mut(device) else {
            return;
        };
        let read_at = SystemTime::now();
        let profile = runtime.spec.profile.clone();
        let mut values = Values::new();
        let blocks = profile.read_blocks().len();
        let mut covered = vec![false; blocks];
        for (request, answer) in &seen {
            let Some(block) = profile
                .read_blocks()
                .iter()
                .position(|b| &b.request == request)
            else {
                continue;
            };
            runtime.decode_into(block, answer, &mut values);
            if let Some(flag) = covered.get_mut(block) {
                *flag = true;
            }
        }
        let mut changeable = vec![false; blocks];
        for &block in changed {
            if let Some(flag) = changeable.get_mut(block) {
                *flag = true;
            }
        }
        let change = self
            .scheduler
            .after_command(device, &changeable, &covered, now);
        if let Some(change) = change {
            self.availability_changed(device, change).await;
        }
        self.emit_values(device, values, read_at, Origin::Command)
            .await;
    }

    /// Counts a command's end and reports it on the events channel (after any `Values` of
    /// its slot, so that a command's state is out before its result).
    async fn reply(&mut self, device: usize, finished: Finished) {
        let Finished {
            id,
            arrived,
            outcome,
        } = finished;
        if id >= CLIENT_COMMAND_IDS {
            // A client's write whose device settled after its client was answered.
            if let Some(write) = self.settling_client_writes.remove(&id) {
                self.client_write_finished(write, outcome).await;
            }
            return;
        }
        let latency = arrived.elapsed();
        self.stats.commands += 1;
        self.stats.last_command_latency = Some(latency);
        self.stats.worst_command_latency = Some(
            self.stats
                .worst_command_latency
                .map_or(latency, |w| w.max(latency)),
        );
        let device = self
            .devices
            .get(device)
            .map(|runtime| runtime.spec.name.clone())
            .unwrap_or_default();
        self.emit(LineEvent::CommandFinished {
            id,
            device,
            outcome,
        })
        .await;
    }

    async fn fail_queued(&mut self, why: &CommandFailure) {
        if self.scheduler.queued_commands() == 0 {
            return;
        }
        for (device, pending) in self.scheduler.drain_commands() {
            let finished = pending.failed(why.clone());
            self.reply(device, finished).await;
        }
    }
}

/// Client requests: the cache, the profile's write planning, and the exchange on the line.
impl Line {
    async fn run_client(&mut self, slot: ClientRequest) {
        let ClientRequest {
            client,
            unit,
            request,
            reply,
        } = slot;
        let device = self.devices.iter().position(|d| d.spec.address == unit);
        let access = self.spec.serve.as_ref().map_or(Access::Raw, |s| s.access);
        if let Some(device) = device {
            if let Some(answer) = self.cache.lookup(device, &request, Instant::now()) {
                if let Some(counters) = &self.serve_counters {
                    counters
                        .cache_hits
                        .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
                let _ = reply.send(Ok(answer));
                return;
            }
            if !request.is_read() {
                self.cache.forget(device);
                if access == Access::Profile {
                    let answer = self.run_client_write(device, &client, &request).await;
                    let _ = reply.send(answer);
                    return;
                }
            }
        }
        // A raw write passes as it came, but not inside a write interval of a field it covers.
        let raw_write = match device.and_then(|d| self.devices.get(d).map(|r| (d, r))) {
            Some((device, runtime)) if !request.is_read() => {
                // By address through each field's own write, and as the profile's shared frames
                // read it (the dust collector's gear at 0x1001 of its settings frame).
                let profile = &runtime.spec.profile;
                let mut fields = profile.fields_touched(&request);
                for reading in profile.decode_write(&request).unwrap_or_default() {
                    if !fields.contains(&reading.field) {
                        fields.push(reading.field);
                    }
                }
                if let Err(code) = self.client_write_allowed(device, &client, &fields) {
                    let _ = reply.send(Err(code));
                    return;
                }
                Some((device, fields))
            }
            _ => None,
        };
        let attempts = self.attempts();
        let Some(master) = self.master.as_mut() else {
            let _ = reply.send(Err(ExceptionCode::GatewayTargetFailedToRespond));
            return;
        };
        let mut passer_by = super::stats::DeviceStats::new(&format!("unit {unit}"));
        let unknown = format!("unit {unit}");
        let (name, stats) = match device.and_then(|d| self.devices.get_mut(d)) {
            Some(runtime) => (runtime.spec.name.as_str(), &mut runtime.stats),
            None => (unknown.as_str(), &mut passer_by),
        };
        let exchange = Exchange {
            line: &self.spec.name,
            device: name,
            slave: unit,
            timeout: self.timeout,
            turnaround: &self.turnaround,
        };
        let result = exchange.run(master, stats, &request, attempts).await;
        tracing::debug!(%client, unit, ?request, ?result, "client request on the line");
        if let Some((device, fields)) = raw_write {
            self.note_write(device, &fields).await;
        }
        match result {
            Ok(answer) => {
                if let (Some(device), Ok(_)) = (device, &answer) {
                    self.after_raw_write(device, &request);
                }
                let _ = reply.send(answer);
            }
            Err(Failure::NoAnswer(_)) => {
                let _ = reply.send(Err(ExceptionCode::GatewayTargetFailedToRespond));
            }
            Err(Failure::PortGone(error)) => {
                let _ = reply.send(Err(ExceptionCode::GatewayTargetFailedToRespond));
                self.port_failed(error).await;
            }
        }
    }

    /// A client's write went to `device` as it was sent (`raw` access): the device's blocks
    /// of the table it wrote, at the addresses it wrote, are read again at once (a `once`
    /// block included), like after a command.
    fn after_raw_write(&mut self, device: usize, write: &Request) {
        let Some(runtime) = self.devices.get(device) else {
            return;
        };
        let written = written_span(write);
        let changed: Vec<bool> = runtime
            .spec
            .profile
            .read_blocks()
            .iter()
            .map(|block| written.is_some_and(|span| block_overlaps(&block.request, span)))
            .collect();
        if changed.iter().any(|&changed| changed) {
            let none = vec![false; changed.len()];
            self.scheduler
                .after_command(device, &changed, &none, Instant::now());
        }
    }

    /// The port is closed: waiting clients are told the device cannot be reached rather than
    /// left to time out.
    fn fail_client_requests(&mut self) {
        while let Some(request) = self.clients.try_take() {
            let _ = request
                .reply
                .send(Err(ExceptionCode::GatewayTargetFailedToRespond));
        }
    }

    /// A client's write under `profile` access: planned by the device's profile on its known
    /// state (a refusal sends nothing), then run as a command slot whose reads are published.
    async fn run_client_write(&mut self, device: usize, client: &str, write: &Request) -> Reply {
        let Some(runtime) = self.devices.get(device) else {
            return Err(ExceptionCode::GatewayPathUnavailable);
        };
        let name = runtime.spec.name.clone();
        let planned = policy::plan_write(&runtime.spec.profile, write, &runtime.known_state());
        let planned = match planned {
            Ok(planned) => planned,
            Err(code) => {
                tracing::info!(%client, device = %name, ?write, "client write refused: {code}");
                if let Some(counters) = &self.serve_counters {
                    counters
                        .refusals
                        .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
                return Err(code);
            }
        };
        self.client_write_allowed(device, client, &planned.covered)?;
        let Some(plan) = planned.plan else {
            // Only zeros on buttons and toggles: the device itself would do nothing.
            tracing::debug!(%client, device = %name, ?write, "client write leaves the device as it is");
            return echo(write).ok_or(ExceptionCode::IllegalFunction);
        };
        let field = plan.field().to_string();
        let write_record = ClientWrite {
            device: name.clone(),
            field: field.clone(),
            value: plan
                .targets()
                .iter()
                .map(|(_, value)| value.to_text())
                .collect::<Vec<_>>()
                .join(","),
            client: client.to_string(),
        };
        let id = self.next_client_command;
        self.next_client_command += 1;
        let pending = Pending {
            command: Command {
                id,
                device: name.clone(),
                plan,
            },
            arrived: Instant::now(),
        };
        let attempts = self.attempts();
        let (Some(DeviceRuntime { spec, stats, .. }), Some(master)) =
            (self.devices.get_mut(device), self.master.as_mut())
        else {
            return Err(ExceptionCode::GatewayTargetFailedToRespond);
        };
        let link = SlotLink {
            exchange: Exchange::for_device(&self.spec.name, spec, self.timeout, &self.turnaround),
            master,
            stats,
            attempts,
        };
        let mut report = self.commands.run(link, device, pending).await;
        if report.wrote {
            self.note_write(device, &planned.covered).await;
        }
        let finished = report.finished.take();
        let answer = match &finished {
            Some(finished) => {
                tracing::info!(%client, device = %name, %field, outcome = %finished.outcome, "client write");
                client_answer(&finished.outcome, write)
            }
            // Written; the device is still moving toward the value.
            None if report.port_gone.is_none() => {
                tracing::info!(%client, device = %name, %field, "client write applied, settling");
                echo(write).ok_or(ExceptionCode::IllegalFunction)
            }
            None => Err(ExceptionCode::GatewayTargetFailedToRespond),
        };
        self.carry_out(report).await;
        match finished {
            Some(finished) => {
                self.client_write_finished(write_record, finished.outcome)
                    .await;
            }
            None => {
                self.settling_client_writes.insert(id, write_record);
            }
        }
        answer
    }

    /// The write-interval rule for a client's write covering `fields` of `device`: refused at
    /// once with 06 (server device busy) while the interval of any of them runs, whoever
    /// wrote last; the client may send it again later.
    fn client_write_allowed(
        &self,
        device: usize,
        client: &str,
        fields: &[String],
    ) -> Result<(), ExceptionCode> {
        let Some(runtime) = self.devices.get(device) else {
            return Ok(());
        };
        let now = Instant::now();
        let covered = fields.iter().map(String::as_str);
        let name = &runtime.spec.name;
        let Some(until) = self
            .writes
            .busy_until(name, &runtime.spec.profile, covered, now)
        else {
            return Ok(());
        };
        tracing::info!(%client, device = %name, ?fields, wait = ?until - now,
            "client write refused: the write interval runs (06, busy)");
        if let Some(counters) = &self.serve_counters {
            counters
                .busy
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        Err(ExceptionCode::ServerDeviceBusy)
    }

    /// Reports a client's write's end to the bridge (after the values of its reads).
    async fn client_write_finished(&mut self, write: ClientWrite, outcome: CommandOutcome) {
        let ClientWrite {
            device,
            field,
            value,
            client,
        } = write;
        self.emit(LineEvent::ClientWriteFinished {
            device,
            field,
            value,
            client,
            outcome,
        })
        .await;
    }
}

/// What the client of a write is answered for its command's outcome.
fn client_answer(outcome: &CommandOutcome, write: &Request) -> Reply {
    match outcome {
        CommandOutcome::Applied { .. } | CommandOutcome::NotApplied { .. } => {
            echo(write).ok_or(ExceptionCode::IllegalFunction)
        }
        CommandOutcome::Rejected { .. } => Err(ExceptionCode::IllegalDataValue),
        CommandOutcome::Failed {
            cause: CommandFailure::Exception(code),
        } => Err(*code),
        CommandOutcome::Failed { .. } => Err(ExceptionCode::GatewayTargetFailedToRespond),
    }
}

/// Where a write lands: (holding registers rather than coils, first address, count).
fn written_span(write: &Request) -> Option<(bool, u16, u16)> {
    let count = |len: usize| u16::try_from(len).ok();
    match write {
        Request::WriteSingleCoil { address, .. } => Some((false, *address, 1)),
        Request::WriteSingleRegister { address, .. } => Some((true, *address, 1)),
        Request::WriteMultipleCoils { start, values } => {
            Some((false, *start, count(values.len())?))
        }
        Request::WriteMultipleRegisters { start, values } => {
            Some((true, *start, count(values.len())?))
        }
        _ => None,
    }
}

/// Whether the read `block` reads any item of `(registers, start, count)`.
fn block_overlaps(block: &Request, (registers, start, count): (bool, u16, u16)) -> bool {
    let same_table = match block {
        Request::ReadHoldingRegisters { .. } => registers,
        Request::ReadCoils { .. } => !registers,
        _ => false,
    };
    let Some((first, len)) = block.read_span() else {
        return false;
    };
    let (first, end) = (u32::from(first), u32::from(first) + u32::from(len));
    let (start, stop) = (u32::from(start), u32::from(start) + u32::from(count));
    same_table && start < end && first < stop
}

/// The normal answer to a write: the device echoes what it was asked.
fn echo(write: &Request) -> Option<Response> {
    Some(match write {
        Request::WriteSingleRegister { address, value } => Response::WriteSingleRegister {
            address: *address,
            value: *value,
        },
        Request::WriteSingleCoil { address, value } => Response::WriteSingleCoil {
            address: *address,
            value: *value,
        },
        Request::WriteMultipleRegisters { start, values } => Response::WriteMultipleRegisters {
            start: *start,
            quantity: u16::try_from(values.len()).ok()?,
        },
        Request::WriteMultipleCoils { start, values } => Response::WriteMultipleCoils {
            start: *start,
            quantity: u16::try_from(values.len()).ok()?,
        },
        _ => return None,
    })
}

/// What a command slot or a settle re-read of `device` talks through; `None` while the port is
/// closed (or the device is unknown).
fn slot_link<'a>(
    devices: &'a mut [DeviceRuntime],
    master: Option<&'a mut Link>,
    line: &'a str,
    timeout: Duration,
    turnaround: &'a Turnaround,
    device: usize,
    attempts: u32,
) -> Option<SlotLink<'a>> {
    let DeviceRuntime { spec, stats, .. } = devices.get_mut(device)?;
    Some(SlotLink {
        exchange: Exchange::for_device(line, spec, timeout, turnaround),
        master: master?,
        stats,
        attempts,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
            serial: rtu2mqtt_modbus::transport::SerialSettings {
                path: path.display().to_string(),
                baud: 9600,
                format: rtu2mqtt_modbus::timing::CharFormat {
                    data_bits: 8,
                    parity: rtu2mqtt_modbus::timing::Parity::Even,
                    stop_bits: 1,
                },
                rs485: None,
            },
            transport: Transport::Serial,
            response_timeout: None,
            retries: 1,
            offline_after: 2,
            echo: false,
            broadcast_turnaround: Duration::from_millis(200),
            byte_timeout: None,
            frame_log: None,
            serve: None,
            devices: vec![super::super::DeviceSpec {
                name: "valve".into(),
                address: 1,
                profile: Arc::new(profile),
                poll_interval: Duration::from_secs(1),
                publish: Default::default(),
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
