//! The bridge's task: it owns the [`Core`](crate::bridge::core::Core), the outbox and the\nchannels, feeds every event to the core and carries out the actions it returns.

use super::connection;
use super::connection::{LinkEvent, LinkFlag, PacketLimit, MAX_OUTGOING_PACKET};
use super::history_stream::{is_history, HistoryStream, REPLAY_ROOM};
use super::inputs::LocalMessage;
use super::inputs::{next_external, next_local};
use super::outbox::{ClientOrder, Outbox, Urgency};
use super::oversized::SubscriptionWatch;
use super::writer::spawn_writer;
use crate::bridge::core::publisher::ANNOUNCE_BATCH;
use crate::bridge::core::{
    Action, BridgeDevice, CommandReport, Core, CoreSettings, ExternalCommand, Incoming, Publish,
};
use crate::bridge::observers::figures::BridgeFigures;
use crate::bridge::observers::plant_view::PlantView;
use crate::bridge::observers::statistics::BridgeStats;
use crate::bus::{LineEvent, LineHandle, LineStats};
use crate::config::Config;
use crate::topics::TopicKind;
use rand::rngs::StdRng;
use rand::SeedableRng;
use rumqttc::AsyncClient;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// How often waiting commands, expiries and statistics are looked at; the bridge's heartbeat
/// is refreshed at least this often.
pub const TICK: Duration = Duration::from_millis(250);
/// How long shutdown waits for commands on the bus, and then for the Disconnect to complete.
const STOP_GRACE: Duration = Duration::from_secs(3);
/// Requests handed to the writer task ahead of the client.
const WRITER_QUEUE: usize = 32;
/// Outbox entries above which incoming commands are shed.
pub const OVERLOAD_HIGH: usize = 5_000;
/// Outbox entries below which commands are taken again.
pub const OVERLOAD_LOW: usize = 1_000;
/// Outbox entries below which the next devices are announced between ticks.
const ANNOUNCE_ROOM: usize = 1_000;
/// Shortest time between two announcements between ticks: the pace is the broker's, within
/// this bound.
const ANNOUNCE_GAP: Duration = Duration::from_millis(20);
/// Shortest time between two log lines about publishes the outbox had to drop.
const DROP_LOG_INTERVAL: Duration = Duration::from_secs(10);

/// Liveness of the bridge for the watchdog and the status file.
#[derive(Debug, Clone)]
pub struct BridgeHealth {
    /// Refreshed on every turn of the bridge loop (at least every [`TICK`]).
    pub heartbeat: watch::Receiver<Instant>,
    pub connected: watch::Receiver<bool>,
    /// Why the history journal cannot be written, while it cannot (the gateway is then
    /// unhealthy); always None without `[history]`.
    pub history_problem: watch::Receiver<Option<String>>,
}

/// A configuration reload, as the bridge learns it: the devices (in configuration order, each
/// with the index of its line) and the running lines' handles in that order.
#[derive(Debug)]
pub struct Reconfiguration {
    pub devices: Vec<BridgeDevice>,
    pub lines: Vec<LineHandle>,
}

/// The bridge task: the core and everything it must not touch itself.
#[derive(Debug)]
pub struct Bridge {
    core: Core,
    outbox: Outbox,
    /// To the writer task, which owns the client's sending side.
    writer_tx: mpsc::Sender<ClientOrder>,
    writer: tokio::task::JoinHandle<()>,
    /// The link is up: the outbox is fed to the writer.
    link_up: bool,
    overloaded: bool,
    dropped_unlogged: u64,
    dropped_logged_at: Option<Instant>,
    link_rx: mpsc::Receiver<LinkEvent>,
    event_loop: tokio::task::JoinHandle<()>,
    lines: Vec<LineHandle>,
    /// Shared with the metrics endpoint, refreshed every tick.
    counters_tx: watch::Sender<BridgeStats>,
    heartbeat_tx: watch::Sender<Instant>,
    connected_tx: watch::Sender<bool>,
    history_problem_tx: watch::Sender<Option<String>>,
    /// Commands from outside the plain topics, and where their ends are reported.
    external: Option<(mpsc::Receiver<ExternalCommand>, mpsc::Sender<CommandReport>)>,
    /// Messages from local clients (the console), once [`Bridge::accept_local_messages`] was
    /// called.
    local: Option<mpsc::Receiver<LocalMessage>>,
    /// Every message handed to the outbox is noted here too (the console), once asked for.
    plant_view: Option<PlantView>,
    /// Reloads, once [`Bridge::reconfigurations`] has been asked for.
    reconfigure_rx: Option<mpsc::Receiver<Reconfiguration>>,
    /// The running lines' statistics for the metrics endpoint (replaced by a reload).
    line_stats_tx: watch::Sender<Vec<watch::Receiver<LineStats>>>,
    /// The history stream's journal and replay (`[history]`).
    history: Option<HistoryStream>,
    /// Requests handed to the writer that it has not finished with.
    in_writer: Arc<AtomicUsize>,
    /// Asks the event loop task to give back what rumqttc holds and end (a stop whose
    /// Disconnect does not complete).
    give_back: watch::Sender<bool>,
    /// Refuses what rumqttc would end the connection on.
    packet_limit: PacketLimit,
    /// When devices were last announced between ticks.
    announced_at: Option<Instant>,
}

impl Bridge {
    /// The bridge for `config`'s devices on `lines` (one handle per configured line, in
    /// order), using the client made by [`connection::connect`]. Its event loop starts connecting
    /// at once; what it reports waits for [`Bridge::run`].
    pub fn new(
        config: &Config,
        lines: Vec<LineHandle>,
        (client, eventloop): (AsyncClient, rumqttc::EventLoop),
    ) -> (Bridge, BridgeHealth) {
        let (link_tx, link_rx) = mpsc::channel(256);
        let link: LinkFlag = Arc::new(AtomicBool::new(false));
        let in_writer = Arc::new(AtomicUsize::new(0));
        let subscriptions = SubscriptionWatch::default();
        let writer_link = (
            Arc::clone(&link),
            link_tx.clone(),
            Arc::clone(&in_writer),
            subscriptions.clone(),
        );
        let (give_back, give_back_rx) = watch::channel(false);
        let event_loop = connection::spawn_event_loop(
            eventloop,
            link_tx,
            config.mqtt.client_id.clone(),
            link,
            give_back_rx,
            subscriptions,
        );
        let now = Instant::now();
        let (heartbeat_tx, heartbeat) = watch::channel(now);
        let (connected_tx, connected) = watch::channel(false);
        let (history_problem_tx, history_problem) = watch::channel(None);
        let (writer_tx, writer_rx) = mpsc::channel(WRITER_QUEUE);
        let line_stats_tx = watch::channel(stats_receivers(&lines)).0;
        let bridge = Bridge {
            core: Core::new(
                CoreSettings::from_config(config),
                now,
                StdRng::from_entropy(),
            ),
            outbox: Outbox::default(),
            writer_tx,
            writer: spawn_writer(client, writer_rx, writer_link),
            link_up: false,
            overloaded: false,
            dropped_unlogged: 0,
            dropped_logged_at: None,
            link_rx,
            event_loop,
            lines,
            counters_tx: watch::channel(BridgeStats::default()).0,
            heartbeat_tx,
            connected_tx,
            history_problem_tx,
            external: None,
            local: None,
            plant_view: None,
            reconfigure_rx: None,
            line_stats_tx,
            history: config
                .history
                .as_ref()
                .map(|history| HistoryStream::open(history, config.mqtt.topics())),
            in_writer,
            give_back,
            packet_limit: PacketLimit::new(MAX_OUTGOING_PACKET, "plain"),
            announced_at: None,
        };
        (
            bridge,
            BridgeHealth {
                heartbeat,
                connected,
                history_problem,
            },
        )
    }

    /// Also takes commands from `commands` (a Sparkplug edge node's DCMDs) through the same
    /// validation and book as `…/set`, and reports how each ended on `reports`.
    pub fn accept_external_commands(
        &mut self,
        commands: mpsc::Receiver<ExternalCommand>,
        reports: mpsc::Sender<CommandReport>,
    ) {
        self.external = Some((commands, reports));
    }

    /// Also takes messages from `messages` as if they came from the broker (QoS 0, not
    /// retained): the console's commands and refreshes.
    pub fn accept_local_messages(&mut self, messages: mpsc::Receiver<LocalMessage>) {
        self.local = Some(messages);
    }

    /// Notes every message handed to the outbox from now on in `view` as well.
    pub fn publish_into(&mut self, view: PlantView) {
        self.plant_view = Some(view);
    }

    /// Runs until `shutdown` fires, then announces `offline` and disconnects.
    pub async fn run(
        mut self,
        mut events_rx: mpsc::Receiver<LineEvent>,
        shutdown: CancellationToken,
    ) {
        let mut tick = tokio::time::interval(TICK);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            self.heartbeat_tx.send_replace(Instant::now());
            self.pump();
            self.announce_on_room();
            let feed = self.link_up && !self.outbox.is_empty();
            let writer_tx = self.writer_tx.clone();
            tokio::select! {
                _ = shutdown.cancelled() => break,
                permit = writer_tx.reserve_owned(), if feed => {
                    if let Ok(permit) = permit {
                        if let Some(request) = self.outbox.pop() {
                            self.note_handed(&request);
                            permit.send(request);
                        }
                    }
                }
                Some(event) = self.link_rx.recv() => self.on_link(event),
                Some(news) = next_reconfiguration(&mut self.reconfigure_rx) => {
                    self.on_reconfigure(news);
                }
                Some(event) = events_rx.recv() => {
                    let actions = self.core.on_line_event(event, Instant::now());
                    self.execute(actions);
                }
                message = next_local(&mut self.local) => match message {
                    Some(message) => {
                        let incoming = Incoming {
                            topic: &message.topic,
                            payload: message.payload.as_bytes(),
                            qos: rumqttc::QoS::AtMostOnce,
                            pkid: 0,
                            dup: false,
                            retain: false,
                        };
                        let actions = self.core.on_message(incoming, Instant::now());
                        self.execute(actions);
                    }
                    None => self.local = None,
                },
                command = next_external(&mut self.external) => match command {
                    Some(command) => {
                        let actions = self.core.on_external_command(command, Instant::now());
                        self.execute(actions);
                    }
                    // The sender has ended: nothing more comes.
                    None => self.external = None,
                },
                _ = tick.tick() => {
                    let now = Instant::now();
                    self.history_tick(now);
                    let lines = &self.lines;
                    self.core.set_oversized_refused(self.packet_limit.refused());
                    self.core.set_announce_room(self.outbox.resend_len() < ANNOUNCE_BATCH);
                    let actions = self.core.on_tick(now, || line_stats(lines));
                    self.execute(actions);
                    self.counters_tx.send_replace(self.core.counters(now));
                }
            }
        }
        self.stop(events_rx).await;
    }

    /// Hands every record replayed from the history journal to `replayed` as well (the
    /// Sparkplug node's store and forward); nothing without `[history]`.
    pub fn forward_replays(&mut self, replayed: mpsc::Sender<crate::history::Record>) {
        if let Some(history) = &mut self.history {
            history.forward_replays(replayed);
        }
    }

    /// A packet limit of `max` bytes for another connection to the broker (the Sparkplug
    /// node's), counting its refusals into this bridge's statistics.
    pub fn packet_limit(&self, connection: &'static str, max: usize) -> PacketLimit {
        self.packet_limit.for_connection(connection, max)
    }

    /// Where a configuration reload tells this bridge its new devices and lines.
    pub fn reconfigurations(&mut self) -> mpsc::Sender<Reconfiguration> {
        let (tx, rx) = mpsc::channel(1);
        self.reconfigure_rx = Some(rx);
        tx
    }

    fn on_reconfigure(&mut self, news: Reconfiguration) {
        let names = news.lines.iter().map(|line| line.name.clone()).collect();
        self.line_stats_tx
            .send_replace(stats_receivers(&news.lines));
        self.lines = news.lines;
        let actions = self
            .core
            .on_reconfigure(names, news.devices, Instant::now());
        self.execute(actions);
    }

    fn on_link(&mut self, event: LinkEvent) {
        match event {
            LinkEvent::Connected { .. } => {
                self.link_up = true;
                if let Some(history) = &mut self.history {
                    history.release_held();
                }
                let actions = self.core.on_connected();
                self.connected_tx.send_replace(true);
                self.execute(actions);
            }
            LinkEvent::Disconnected { unacknowledged, .. } => {
                self.link_up = false;
                if let Some(history) = &mut self.history {
                    for publish in &unacknowledged {
                        history.take_back(&publish.topic, &publish.payload);
                    }
                    // Newer than what the writer still gives back: held until it has.
                    history.hold(
                        self.outbox
                            .take_where(|publish| is_history(&publish.topic, publish.retain)),
                    );
                }
                let dropped = self.outbox.on_disconnect();
                tracing::debug!(
                    dropped,
                    "state waiting for MQTT dropped: it is republished on connect"
                );
                self.core.on_disconnected();
                self.connected_tx.send_replace(false);
            }
            LinkEvent::Message(publish) => {
                let actions = self.core.on_message(Incoming::of(&publish), Instant::now());
                self.execute(actions);
            }
            LinkEvent::Unsent(publish) => {
                if let Some(history) = &mut self.history {
                    history.take_back(&publish.topic, publish.payload.as_bytes());
                }
            }
            LinkEvent::Closed { unacknowledged } => {
                if let Some(history) = &mut self.history {
                    for publish in &unacknowledged {
                        history.take_back(&publish.topic, &publish.payload);
                    }
                }
            }
        }
    }

    /// Carries out the core's actions, reporting back what could not be done.
    fn execute(&mut self, actions: Vec<Action>) {
        let mut queue = VecDeque::from(actions);
        while let Some(action) = queue.pop_front() {
            match action {
                Action::Publish(publish) => {
                    if !self.admits(&publish) {
                        continue;
                    }
                    if let Some(view) = &self.plant_view {
                        view.note(&publish.topic, &publish.payload);
                    }
                    let urgency = self.urgency_of(&publish);
                    if let Some(dropped) = self.outbox.push(publish, urgency) {
                        self.on_dropped(dropped);
                    }
                }
                Action::Subscribe { filter, qos } => {
                    self.outbox
                        .push_control(ClientOrder::Subscribe { filter, qos });
                }
                Action::SubscribeInTurn { filter, qos } => {
                    self.outbox
                        .push_in_turn(ClientOrder::Subscribe { filter, qos });
                }
                Action::UnsubscribeInTurn { filter } => {
                    self.outbox
                        .push_in_turn(ClientOrder::Unsubscribe { filter });
                }
                Action::Send { line, command } => {
                    let refused = match self.lines.get(line) {
                        Some(handle) => match handle.command_tx.try_send(command) {
                            Ok(()) => None,
                            Err(mpsc::error::TrySendError::Full(command)) => Some((*command, true)),
                            Err(mpsc::error::TrySendError::Closed(command)) => {
                                Some((*command, false))
                            }
                        },
                        None => Some((command, false)),
                    };
                    if let Some((command, full)) = refused {
                        queue.extend(self.core.on_send_failed(command, full));
                    }
                }
                Action::Refresh { line, device } => {
                    let sent = self
                        .lines
                        .get(line)
                        .map(|handle| handle.refresh_tx.try_send(device.clone()));
                    if let Some(Err(error)) = sent {
                        // Full: refreshes already wait there; closed: the line has stopped.
                        tracing::info!(%device, %error, "refresh request not handed to the line");
                    }
                }
                Action::History(entry) => {
                    let link_up = self.link_up;
                    let publish = self
                        .history
                        .as_mut()
                        .and_then(|history| history.route(entry, link_up));
                    if let Some(publish) = publish {
                        queue.push_front(Action::Publish(publish));
                    }
                }
                Action::Report(report) => {
                    // Never waits: a full queue loses only the re-publication of a true value
                    // that the next births or data carry anyway.
                    if let Some((_, reports)) = &self.external {
                        if let Err(error) = reports.try_send(report) {
                            tracing::warn!(%error, "command report dropped");
                        }
                    }
                }
            }
        }
    }

    /// The journal's turn: synced when due, the next records of the replay handed to the
    /// outbox while it has room (behind the state a connection republishes; live change sets
    /// wait in the journal behind the replay, so the stream stays in order), and its health
    /// told to the core.
    fn history_tick(&mut self, now: Instant) {
        let Some(history) = &mut self.history else {
            return;
        };
        history.on_tick(now);
        let problem = history.problem();
        self.history_problem_tx.send_if_modified(|told| {
            let changed = told.as_deref() != problem;
            if changed {
                *told = problem.map(str::to_string);
            }
            changed
        });
        // Everything the writer had is back (and journaled): what was held follows.
        if history.is_holding()
            && self.in_writer.load(Ordering::SeqCst) == 0
            && self.link_rx.is_empty()
        {
            history.release_held();
        }
        if self.link_up {
            let room = REPLAY_ROOM.saturating_sub(self.outbox.len());
            for publish in history.replay(room) {
                let fits =
                    self.packet_limit
                        .admits(&publish.topic, publish.payload.len(), publish.qos);
                if !fits {
                    continue;
                }
                if let Some(dropped) = self.outbox.push(publish, Urgency::Urgent) {
                    self.on_dropped(dropped);
                }
            }
        }
        let stats = self
            .history
            .as_ref()
            .map(|history| history.stats(self.link_up));
        if let Some(stats) = stats {
            self.core.set_history_stats(stats);
        }
    }

    /// Whether `publish` fits in one packet; one that does not is refused here, alone, since
    /// rumqttc would end the connection on it (and send it again after every reconnect). It is
    /// not kept for a later connection: it would not fit then either.
    fn admits(&mut self, publish: &Publish) -> bool {
        self.packet_limit
            .admits(&publish.topic, publish.payload.len(), publish.qos)
    }

    /// Discovery documents and statistics are sent again anyway: they yield to outcomes.
    fn urgency_of(&self, publish: &Publish) -> Urgency {
        let topics = self.core.topics();
        let discovery = publish
            .topic
            .strip_prefix(topics.discovery_prefix.as_str())
            .is_some_and(|rest| rest.starts_with('/'));
        let own_stats = matches!(
            topics.classify(&publish.topic),
            TopicKind::GatewayStats { gateway, .. } if gateway == topics.client_id
        );
        if discovery || own_stats {
            Urgency::Resend
        } else {
            Urgency::Urgent
        }
    }

    /// Hands the writer what it has room for, and tells the core whether it keeps up.
    fn pump(&mut self) {
        while self.link_up {
            let Ok(permit) = self.writer_tx.try_reserve() else {
                break;
            };
            let Some(request) = self.outbox.pop() else {
                break;
            };
            self.in_writer.fetch_add(1, Ordering::SeqCst);
            if let ClientOrder::Publish(_) = &request {
                self.core.on_handed();
            }
            permit.send(request);
        }
        let waiting = self.outbox.len();
        let overloaded = if self.overloaded {
            waiting > OVERLOAD_LOW
        } else {
            waiting > OVERLOAD_HIGH
        };
        if overloaded != self.overloaded {
            self.overloaded = overloaded;
            self.core.set_overloaded(overloaded);
            tracing::debug!(waiting, overloaded, "MQTT outbox");
        }
    }

    /// Between ticks, the next devices are announced once the outbox holds fewer than
    /// [`ANNOUNCE_ROOM`] entries, fewer than [`ANNOUNCE_BATCH`] of them discovery documents,
    /// at most every [`ANNOUNCE_GAP`]: the
    /// republishing after a connect goes as fast as the broker takes it, and the outbox never
    /// holds much of it.
    fn announce_on_room(&mut self) {
        let room = self.link_up
            && self.outbox.len() < ANNOUNCE_ROOM
            && self.outbox.resend_len() < ANNOUNCE_BATCH;
        if !room || !self.core.is_announcing() {
            return;
        }
        let now = Instant::now();
        if self
            .announced_at
            .is_some_and(|at| now.saturating_duration_since(at) < ANNOUNCE_GAP)
        {
            return;
        }
        self.announced_at = Some(now);
        let actions = self.core.on_announce_room();
        self.execute(actions);
        self.pump();
    }

    fn note_handed(&mut self, request: &ClientOrder) {
        self.in_writer.fetch_add(1, Ordering::SeqCst);
        if let ClientOrder::Publish(_) = request {
            self.core.on_handed();
        }
    }

    /// The outbox was full: counted, reported at most once per [`DROP_LOG_INTERVAL`]; results
    /// and clears go back to the core, which keeps them for the next connection.
    fn on_dropped(&mut self, publish: Publish) {
        self.dropped_unlogged += 1;
        let now = Instant::now();
        if self.dropped_logged_at.map_or(true, |at| {
            now.saturating_duration_since(at) >= DROP_LOG_INTERVAL
        }) {
            tracing::warn!(
                dropped = self.dropped_unlogged,
                "MQTT outbox full: oldest messages dropped"
            );
            self.dropped_unlogged = 0;
            self.dropped_logged_at = Some(now);
        }
        self.core.on_published(publish, false);
    }

    /// The figures of the lines running now (reloads included) and the bridge's counters, for
    /// the metrics endpoint and the console.
    pub fn figures(&self) -> BridgeFigures {
        BridgeFigures {
            lines: self.line_stats_tx.subscribe(),
            counters: self.counters_tx.subscribe(),
        }
    }

    async fn stop(mut self, mut events_rx: mpsc::Receiver<LineEvent>) {
        // Commands already on the bus finish there (the lines complete their transaction):
        // report them if they do so quickly.
        let deadline = tokio::time::Instant::now() + STOP_GRACE;
        while self.core.commands_on_bus() > 0 {
            match tokio::time::timeout_at(deadline, events_rx.recv()).await {
                Ok(Some(event)) => {
                    let actions = self.core.on_line_event(event, Instant::now());
                    self.execute(actions);
                }
                _ => break,
            }
        }
        let actions = self.core.on_stop();
        self.execute(actions);
        if self.core.is_connected() {
            let until = tokio::time::Instant::now() + STOP_GRACE;
            self.flush(until).await;
            // Control requests jump the queue: the Disconnect only once the rest is handed on.
            self.outbox.push_control(ClientOrder::Disconnect);
            self.flush(until).await;
            // Its own bound: the event loop waits up to its close grace for the broker.
            if !self.until_closed(STOP_GRACE).await {
                tracing::warn!("MQTT disconnect did not complete in time");
                // What the client holds is taken back from it all the same.
                self.give_back.send_replace(true);
                if !self.until_closed(STOP_GRACE).await {
                    tracing::warn!("the MQTT client did not give back what it holds in time");
                }
            }
        }
        self.drain_writer(STOP_GRACE).await;
        if let Some(history) = &mut self.history {
            // What never reached the client, then what is held behind it: for the next start.
            for publish in self
                .outbox
                .take_where(|publish| is_history(&publish.topic, publish.retain))
            {
                history.take_back(&publish.topic, publish.payload.as_bytes());
            }
            history.release_held();
            history.sync();
        }
        self.event_loop.abort();
        self.writer.abort();
        tracing::info!("bridge stopped");
    }

    /// Reads link events until the event loop task has ended (true) or `within` has passed,
    /// keeping what they say about history publishes.
    async fn until_closed(&mut self, within: Duration) -> bool {
        let mut seen = Vec::new();
        let link_rx = &mut self.link_rx;
        let closed = tokio::time::timeout(within, async {
            while let Some(event) = link_rx.recv().await {
                let last = matches!(event, LinkEvent::Closed { .. });
                seen.push(event);
                if last {
                    return;
                }
            }
        })
        .await;
        for event in seen {
            self.keep_history_of(event);
        }
        closed.is_ok()
    }

    /// Lets the writer finish what it was handed: its queue is closed, and with the link down
    /// every history publish in it comes back as [`LinkEvent::Unsent`] (a broker that stopped
    /// reading can leave many behind a stuck Disconnect), to be journaled with the rest.
    async fn drain_writer(&mut self, within: Duration) {
        let (closed, _) = mpsc::channel(1);
        drop(std::mem::replace(&mut self.writer_tx, closed));
        let writer = &mut self.writer;
        let link_rx = &mut self.link_rx;
        let mut seen = Vec::new();
        let drained = tokio::time::timeout(within, async {
            loop {
                tokio::select! {
                    _ = &mut *writer => return,
                    Some(event) = link_rx.recv() => seen.push(event),
                }
            }
        })
        .await;
        if drained.is_err() {
            tracing::warn!("the MQTT writer did not finish in time");
        }
        while let Ok(event) = self.link_rx.try_recv() {
            seen.push(event);
        }
        for event in seen {
            self.keep_history_of(event);
        }
    }

    /// While stopping, only what a link event says about history publishes still matters.
    fn keep_history_of(&mut self, event: LinkEvent) {
        if matches!(
            event,
            LinkEvent::Disconnected { .. } | LinkEvent::Unsent(_) | LinkEvent::Closed { .. }
        ) {
            self.link_up = false;
            self.on_link(event);
        }
    }

    /// Hands the whole outbox to the writer, reading link events meanwhile so the event loop
    /// keeps turning.
    async fn flush(&mut self, until: tokio::time::Instant) {
        while let Some(request) = self.outbox.pop() {
            let writer_tx = self.writer_tx.clone();
            let link_rx = &mut self.link_rx;
            let mut seen = Vec::new();
            let handed = tokio::time::timeout_at(until, async {
                let mut reserve = std::pin::pin!(writer_tx.reserve_owned());
                loop {
                    tokio::select! {
                        permit = &mut reserve => return permit.ok(),
                        event = link_rx.recv() => seen.push(event?),
                    }
                }
            })
            .await;
            for event in seen {
                self.keep_history_of(event);
            }
            match handed {
                Ok(Some(permit)) => {
                    self.note_handed(&request);
                    permit.send(request);
                }
                _ => {
                    tracing::warn!(
                        left = self.outbox.len() + 1,
                        "MQTT did not take the last messages in time"
                    );
                    return;
                }
            }
        }
    }
}

/// The next reload, or never when nobody can send one.
async fn next_reconfiguration(
    rx: &mut Option<mpsc::Receiver<Reconfiguration>>,
) -> Option<Reconfiguration> {
    if let Some(receiver) = rx {
        if let Some(news) = receiver.recv().await {
            return Some(news);
        }
        *rx = None;
    }
    std::future::pending().await
}

/// Where each line's statistics can be read.
fn stats_receivers(lines: &[LineHandle]) -> Vec<watch::Receiver<LineStats>> {
    lines.iter().map(|line| line.stats_rx.clone()).collect()
}

/// The current statistics of every line.
fn line_stats(lines: &[LineHandle]) -> Vec<LineStats> {
    lines
        .iter()
        .map(|line| line.stats_rx.borrow().clone())
        .collect()
}
