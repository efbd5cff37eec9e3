//! The line's task: its state ([`Line`]) and its loop, started by [`spawn_line`].

use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use tokio::sync::{mpsc, watch};
use tracing::Instrument;

use crate::bus::availability::{HealthChange, HealthPolicy};
use crate::bus::cadence::DevicePlan;
use crate::bus::command::queue::{command_queue, CommandReceiver, CommandSender};
use crate::bus::command::run::SlotLink;
use crate::bus::command::slots::{CommandSlots, Pending};
use crate::bus::command::{Command, CommandFailure};
use crate::bus::device::{Decode, DeviceRuntime, Values};
use crate::bus::event::{LineEvent, Origin};
use crate::bus::line_spec::{LineSpec, Transport};
use crate::bus::poll::{self, PollContext};
use crate::bus::port::{self, Backoff, OpenError, Reopen, MISSING_PORT, UNREACHABLE_SERVER};
use crate::bus::report::Report;
use crate::bus::reporter;
use crate::bus::scheduler::{poll_phase, Due, PollOutcome, Scheduler};
use crate::bus::serve::queue::{BlockCache, CLIENT_QUEUE};
use crate::bus::serve::served_side::ServedSide;
use crate::bus::serve::server::{self, ServeCounters};
use crate::bus::serve::ClientRequest;
use crate::bus::stats::LineStats;
use crate::bus::stats::LoadWindow;
use crate::bus::transaction::{ExchangeContext, Failure, Turnaround};
use crate::bus::write_clock::WriteClock;
use rtu2mqtt_modbus::link::Link;
use rtu2mqtt_modbus::serial::transport::TransportError;
use rtu2mqtt_modbus::timing::LineTiming;
use rtu2mqtt_modbus::{PortFault, WireCounters};
use rtu2mqtt_profile::Profile;
use tokio_util::sync::CancellationToken;

/// The bridge's handle on a running line.
#[derive(Debug, Clone)]
pub struct LineHandle {
    pub name: String,
    pub command_tx: CommandSender,
    /// Refresh requests, by device name: each of the device's blocks is read in the line's next
    /// slots and what changed is reported.
    pub refresh_tx: mpsc::Sender<String>,
    pub stats_rx: watch::Receiver<LineStats>,
    /// Requests of other masters as slots of the line (the console's commissioning reads);
    /// None unless the line was started for the console (`LineSpec::console`).
    pub requests_tx: Option<mpsc::Sender<Box<ClientRequest>>>,
}

/// Commands that may wait in a line's queue; the bridge waits when it is full.
pub(crate) const COMMAND_QUEUE: usize = 64;
/// Refresh requests that may wait to be taken by the line; more are dropped (a device's
/// refresh already waiting covers them).
pub(crate) const REFRESH_QUEUE: usize = 16;
/// Time a device takes to start answering on top of the answer's own wire time; with the
/// timing's host allowance the default timeout leaves 100 ms beyond the wire.
pub(crate) const DEVICE_MARGIN: Duration = Duration::from_millis(80);
/// Statistics are published at least this often (the watchdog's heartbeat).
pub(crate) const HEARTBEAT: Duration = Duration::from_secs(1);
/// Bus load is measured over this sliding window.
pub(crate) const LOAD_WINDOW: Duration = Duration::from_secs(10);

/// Starts the task that owns `spec`'s port, with a write clock of its own.
pub fn spawn_line(
    spec: LineSpec,
    events_tx: mpsc::Sender<LineEvent>,
    shutdown: CancellationToken,
) -> (LineHandle, tokio::task::JoinHandle<()>) {
    spawn_line_with_clock(spec, events_tx, shutdown, WriteClock::new())
}

/// Starts the task that owns `spec`'s port; the write intervals of its devices' fields run on
/// `writes`, which the gateway's other lines (and the ones a reload starts) share.
pub fn spawn_line_with_clock(
    spec: LineSpec,
    events_tx: mpsc::Sender<LineEvent>,
    shutdown: CancellationToken,
    writes: WriteClock,
) -> (LineHandle, tokio::task::JoinHandle<()>) {
    spawn_line_in_phase(spec, events_tx, shutdown, writes, 1)
}

/// [`spawn_line_with_clock`] for a line among others: a TCP line polls at one of
/// `poll_phases` phases of its interval ([`poll_phase`]; see [`crate::bus::scheduler::poll_phases`]).
pub fn spawn_line_in_phase(
    spec: LineSpec,
    events_tx: mpsc::Sender<LineEvent>,
    shutdown: CancellationToken,
    writes: WriteClock,
    poll_phases: u32,
) -> (LineHandle, tokio::task::JoinHandle<()>) {
    let names: Vec<String> = spec.devices.iter().map(|d| d.name.clone()).collect();
    let now = Instant::now();
    let (command_tx, command_rx) = command_queue(COMMAND_QUEUE);
    let (refresh_tx, refresh_rx) = mpsc::channel(REFRESH_QUEUE);
    let (stats_tx, stats_rx) = watch::channel(LineStats::new(&spec.name, &names, now));
    let span = tracing::info_span!("line", line = %spec.name);
    // The server's clients and the console share the line's one queue of requests.
    let (client_tx, clients) = if spec.serve.is_some() || spec.console {
        let (client_tx, client_rx) = mpsc::channel(CLIENT_QUEUE);
        (Some(client_tx), Some(client_rx))
    } else {
        (None, None)
    };
    let counters = match (&spec.serve, &client_tx) {
        (Some(serve), Some(client_tx)) => {
            let counters = Arc::new(ServeCounters::default());
            let server = server::run(
                serve.clone(),
                spec.devices.clone(),
                client_tx.clone(),
                Arc::clone(&counters),
                shutdown.clone(),
            );
            tokio::spawn(server.instrument(span.clone()));
            Some(counters)
        }
        _ => None,
    };
    let handle = LineHandle {
        name: spec.name.clone(),
        command_tx,
        refresh_tx,
        stats_rx,
        requests_tx: client_tx.filter(|_| spec.console),
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
    let mut line = Line::new(
        spec,
        events_tx,
        command_rx,
        stats_tx,
        shutdown,
        now,
        poll_phases,
    );
    line.refreshes = Some(refresh_rx);
    line.writes = writes;
    line.served.serve(clients, counters);
    let task = tokio::spawn(Box::new(line).run().instrument(span));
    (handle, task)
}

/// The response timeout of a line when none is configured: the wire time of the longest answer
/// any of its devices' blocks can give, the end-of-frame silence, and a device margin; on a
/// TCP line also the network allowance.
pub(crate) fn default_response_timeout(spec: &LineSpec, timing: &LineTiming) -> Duration {
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
pub(super) struct Line {
    /// The line's configuration; its devices have moved into `devices`.
    pub(super) spec: LineSpec,
    pub(super) devices: Vec<DeviceRuntime>,
    pub(super) timing: LineTiming,
    pub(super) timeout: Duration,
    pub(super) scheduler: Scheduler<Pending>,
    pub(super) master: Option<Link>,
    pub(super) reopen: Reopen,
    /// The command queue and the commands whose device is still settling.
    pub(super) commands: CommandSlots,
    /// Refresh requests by device name (None once their sender is gone).
    pub(super) refreshes: Option<mpsc::Receiver<String>>,
    pub(super) events_tx: mpsc::Sender<LineEvent>,
    pub(super) stats_tx: watch::Sender<LineStats>,
    /// The line's own figures; the devices' are in `devices` until published.
    pub(super) stats: LineStats,
    /// Counters of the masters of ports closed earlier (a reopened port starts a new master).
    pub(super) closed_counters: WireCounters,
    pub(super) load: LoadWindow,
    pub(super) turnaround: Turnaround,
    pub(super) last_published: Instant,
    pub(super) shutdown: CancellationToken,
    /// What the line keeps of the clients of its server (nothing waits when not served).
    pub(super) served: ServedSide,
    /// When the fields with a write interval were last written, by any source.
    pub(super) writes: WriteClock,
}

impl Line {
    pub(super) fn new(
        mut spec: LineSpec,
        events_tx: mpsc::Sender<LineEvent>,
        command_rx: CommandReceiver,
        stats_tx: watch::Sender<LineStats>,
        shutdown: CancellationToken,
        now: Instant,
        poll_phases: u32,
    ) -> Self {
        let timing = LineTiming::new(spec.serial.baud, spec.serial.format);
        let timeout = spec
            .response_timeout
            .unwrap_or_else(|| default_response_timeout(&spec, &timing));
        let plans: Vec<DevicePlan> = spec.devices.iter().map(DevicePlan::for_device).collect();
        // A plant has Modbus TCP devices by the hundred, each on a line of its own: their
        // polls are spread over the interval. A serial port's first poll is not put off.
        let phase = match spec.transport {
            Transport::Tcp { .. } => {
                let shortest = plans.iter().map(|plan| plan.poll_interval).min();
                shortest.map_or(Duration::ZERO, |interval| {
                    poll_phase(&spec.name, interval, poll_phases)
                })
            }
            Transport::Serial => Duration::ZERO,
        };
        let scheduler = Scheduler::phased(
            plans,
            HealthPolicy::with_offline_after(spec.offline_after),
            now,
            phase,
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
            served: ServedSide::new(cache),
            writes: WriteClock::new(),
            spec,
        }
    }

    pub(super) fn attempts(&self) -> u32 {
        self.spec.retries.saturating_add(1)
    }

    /// What a command slot or a settle re-read of `device` talks through (`None` while the port
    /// is closed, or the device is unknown), beside the command slots that drive it: one borrow
    /// of the line split in two, so a slot can run while the link is held.
    pub(super) fn slot_link(&mut self, device: usize) -> (Option<SlotLink<'_>>, &mut CommandSlots) {
        let attempts = self.attempts();
        let Line {
            spec,
            devices,
            timeout,
            master,
            commands,
            turnaround,
            ..
        } = self;
        let link = devices.get_mut(device).and_then(|runtime| {
            Some(SlotLink {
                exchange: ExchangeContext::for_device(
                    &spec.name,
                    &runtime.spec,
                    *timeout,
                    turnaround,
                ),
                master: master.as_mut()?,
                stats: &mut runtime.stats,
                attempts,
            })
        });
        (link, commands)
    }

    /// The line's loop. The line is boxed: an async fn keeps its arguments in its future beside
    /// the state of each await, and a plant of a thousand lines holds a thousand of these.
    pub(super) async fn run(mut self: Box<Self>) {
        while !self.shutdown.is_cancelled() {
            let now = Instant::now();
            self.accept_commands(now).await;
            if self.master.is_none() {
                if now >= self.reopen.at() {
                    self.open_link(now).await;
                } else {
                    self.fail_queued(&CommandFailure::PortReopening).await;
                    self.served.fail_waiting();
                    self.wait(Some(self.reopen.at())).await;
                }
                continue;
            }
            // Command, settle and client slots are rare beside polls and their futures are the
            // largest: each is boxed while it runs, so that the line's own future, which a plant
            // of a thousand lines holds a thousand times, is sized for a poll.
            // What the line does next is chosen once it is free, so that a command arriving
            // during the silence goes ahead of the poll that would otherwise have been chosen
            // at its start.
            self.quiet_unless_command().await;
            let now = Instant::now();
            if let Some(settle) = self.commands.take_due_settle(now) {
                Box::pin(self.run_settle(settle)).await;
                self.publish_stats();
                continue;
            }
            if let Some((device, pending)) = self.commands.take_due_held(now) {
                Box::pin(self.run_command(device, pending)).await;
                self.publish_stats();
                continue;
            }
            // Clients after commands, before polls; a due poll between two client slots.
            let commands_queued = self.scheduler.queued_commands() > 0;
            if let Some(request) = self.served.take_turn(commands_queued) {
                Box::pin(self.run_client(*request)).await;
                self.publish_stats();
                continue;
            }
            self.accept_refreshes();
            let next_settle = self.commands.next_due();
            match self.scheduler.next_due(now) {
                Due::Command { device, command } => {
                    Box::pin(self.run_command(device, command)).await;
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
                Due::Wait(_) | Due::Idle if self.served.is_waiting() => {}
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
    pub(super) async fn quiet_unless_command(&mut self) {
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
    pub(super) async fn take_received(&mut self, received: Option<Command>) {
        match received {
            Some(command) => self.accept(command, Instant::now()).await,
            None => self.commands.closed(),
        }
    }

    /// Sleeps until `until` (or the next heartbeat), a command arrives, or shutdown.
    pub(super) async fn wait(&mut self, until: Option<Instant>) {
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
            () = self.served.arrival() => {}
            () = self.shutdown.cancelled() => {}
        }
        if self.last_published.elapsed() >= HEARTBEAT {
            self.publish_stats();
        }
    }

    /// Hands an event to the bridge. Waits when the bridge is behind (nothing is dropped), but
    /// not past a shutdown; a bridge that is gone is not an error of the line.
    pub(super) async fn emit(&mut self, event: LineEvent) {
        let events_tx = &self.events_tx;
        let shutdown = &mut self.shutdown;
        tokio::select! {
            // A free place in the queue always wins, even during shutdown.
            biased;
            _ = events_tx.send(event) => {}
            () = shutdown.cancelled() => {}
        }
    }

    /// Reports a device's freshly decoded values (nothing when there are none): the one way
    /// values of polls, command slots and settle re-reads reach the bridge.
    /// `read_at` is the wall-clock instant the answers were read.
    pub(super) async fn emit_values(
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

    pub(super) async fn open_link(&mut self, now: Instant) {
        self.turnaround.idle();
        let opened = tokio::select! {
            opened = port::open_link(&self.spec, self.timing) => Some(opened),
            () = self.shutdown.cancelled() => None,
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
    pub(super) async fn port_failed(&mut self, error: PortFault) {
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

    pub(super) async fn lose_devices(&mut self, now: Instant) {
        for device in self.scheduler.port_lost(now) {
            self.availability_changed(device, HealthChange::WentOffline)
                .await;
        }
    }

    pub(super) async fn availability_changed(&mut self, device: usize, change: HealthChange) {
        let online = change == HealthChange::CameOnline;
        let Some(runtime) = self.devices.get_mut(device) else {
            return;
        };
        runtime.stats.online = online;
        if !online {
            runtime.forget_answers();
            self.served.cache.forget(device);
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

    pub(super) async fn run_poll(&mut self, device: usize, block: usize, attempts: u32) {
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
                        self.served.cache.store(
                            device,
                            block,
                            &read.request,
                            answer,
                            Instant::now(),
                        );
                    }
                    unchanged = runtime.answer_unchanged(block, answer);
                    if !unchanged {
                        runtime.decode_into(block, answer, Decode::Changes, &mut values);
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

    pub(super) fn publish_stats(&mut self) {
        let now = Instant::now();
        let counters = match &self.master {
            Some(master) => self.closed_counters + master.counters(),
            None => self.closed_counters,
        };
        let stats = &mut self.stats;
        stats.heartbeat = now;
        stats.record_wire(&counters);
        stats.bus_load = self.load.sample(now, counters.wire_time);
        if let Some((mean, worst)) = self.turnaround.figures() {
            stats.turnaround_mean = Some(mean);
            stats.turnaround_worst = Some(worst);
        }
        stats.set_devices(self.devices.iter().map(|d| &d.stats));
        self.served.fill_stats(stats);
        self.last_published = now;
        // Copied into the published snapshot in place: no allocation per transaction.
        self.stats_tx
            .send_modify(|published| published.clone_from(stats));
    }

    /// Shutdown: answer every command still waiting, publish the last statistics.
    pub(super) async fn finish(&mut self) {
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
        let profile = rtu2mqtt_profile::registry::built_in("wuzhou-valve").unwrap();
        let spec = LineSpec {
            name: "line-x".into(),
            serial: rtu2mqtt_modbus::serial::transport::SerialSettings {
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
            recorders: Default::default(),
            console: false,
            serve: None,
            devices: vec![crate::bus::device_spec::DeviceSpec {
                name: "valve".into(),
                address: 1,
                profile: Arc::new(profile),
                poll_interval: Duration::from_secs(1),
                publish: Default::default(),
            }],
        };
        let (events_tx, mut events_rx) = mpsc::channel(16);
        let shutdown = CancellationToken::new();
        let trigger = shutdown.clone();
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
        trigger.cancel();
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
