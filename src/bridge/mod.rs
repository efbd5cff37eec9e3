//! The only MQTT user: state, commands, outcomes, availability, discovery and statistics.
//!
//! [`Bridge::run`] is one task that owns all bridge state and never waits on MQTT: rumqttc's
//! event loop runs in its own task ([`mqtt`]) and every send is a non-blocking `try_*`, so line
//! events are always consumed (polling never stops because MQTT is down) and the latest values
//! are kept ([`state`], bounded by the configuration). On every ConnAck it re-subscribes,
//! announces itself, sends discovery and republishes all state. Commands on `…/set` are bounded
//! ([`topics`], [`payload`]), validated by the device's profile, kept in the [`commands`] book
//! (offline devices, newest per field, time to live, write interval, QoS 1 redeliveries),
//! handed to the device's line, and answered on `…/result`; a retained command is cleared once
//! it has an outcome.

pub mod commands;
pub mod discovery;
pub mod json_view;
pub mod metrics;
pub mod mqtt;
pub mod payload;
pub mod prometheus;
pub mod state;
pub mod topics;

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use rumqttc::{AsyncClient, Publish, QoS};
use tokio::sync::{mpsc, oneshot, watch};

use self::commands::{Admission, CommandBook, TrackedCommand};
use self::discovery::DiscoveryContext;
use self::metrics::BridgeStats;
use self::mqtt::LinkEvent;
use self::payload::{decode_command, CommandPayload, CommandResult, Outcome, OFFLINE, ONLINE};
use self::state::{StateCache, StateUpdate};
use self::topics::Topics;
use crate::bus::{Command, CommandFailure, CommandOutcome, LineEvent, LineHandle, LineStats};
use crate::config::{Config, GatewayOptions, MqttSettings};
use crate::profile::Profile;
use crate::shutdown::Shutdown;

/// How often waiting commands, expiries and statistics are looked at; the bridge's heartbeat
/// is refreshed at least this often.
pub const TICK: Duration = Duration::from_millis(250);
/// Results and clears kept while MQTT is down (older ones are dropped first).
const MAX_DEFERRED: usize = 1024;
/// How long shutdown waits for commands on the bus, and then for the Disconnect to complete.
const STOP_GRACE: Duration = Duration::from_secs(3);

/// Liveness of the bridge for the watchdog and the status file.
#[derive(Debug, Clone)]
pub struct BridgeHealth {
    /// Refreshed on every turn of the bridge loop (at least every [`TICK`]).
    pub heartbeat: watch::Receiver<Instant>,
    pub connected: watch::Receiver<bool>,
}

/// A configured device as the bridge sees it.
#[derive(Debug, Clone)]
struct BridgeDevice {
    profile: Arc<Profile>,
    line: usize,
}

/// A command's end on the bus, reported by its waiter task.
#[derive(Debug)]
struct Finished {
    command: TrackedCommand,
    outcome: CommandOutcome,
}

/// The bridge task's state.
pub struct Bridge {
    settings: MqttSettings,
    options: GatewayOptions,
    topics: Topics,
    client: AsyncClient,
    link_rx: mpsc::Receiver<LinkEvent>,
    event_loop: tokio::task::JoinHandle<()>,
    lines: Vec<LineHandle>,
    devices: HashMap<String, BridgeDevice>,
    cache: StateCache,
    book: CommandBook,
    connected: bool,
    deferred: VecDeque<(String, String, bool)>,
    /// The bridge's counters (uptime and connection filled in when shared).
    counters: BridgeStats,
    /// Shared with the metrics endpoint, refreshed every tick.
    counters_tx: watch::Sender<BridgeStats>,
    discovery: DiscoveryContext,
    /// Re-announce discovery at this instant (after Home Assistant's birth message).
    reannounce_at: Option<Instant>,
    /// Last JSON view payload per device, to skip unchanged ones.
    json_views: HashMap<String, Vec<u8>>,
    finished_tx: mpsc::Sender<Finished>,
    finished_rx: mpsc::Receiver<Finished>,
    heartbeat_tx: watch::Sender<Instant>,
    connected_tx: watch::Sender<bool>,
    started: Instant,
    next_stats: Instant,
}

impl Bridge {
    /// The bridge for `config`'s devices on `lines` (one handle per configured line, in
    /// order), using the client made by [`mqtt::connect`]. Its event loop starts connecting
    /// at once; what it reports waits for [`Bridge::run`].
    pub fn new(
        config: &Config,
        lines: Vec<LineHandle>,
        (client, eventloop): (AsyncClient, rumqttc::EventLoop),
    ) -> (Bridge, BridgeHealth) {
        let topics = Topics::new(&config.mqtt.prefix, &config.mqtt.client_id);
        let (link_tx, link_rx) = mpsc::channel(256);
        let event_loop = mqtt::spawn_event_loop(eventloop, link_tx);
        let mut devices = HashMap::new();
        let mut order = Vec::new();
        for (line_index, line) in config.lines.iter().enumerate() {
            for device in &line.devices {
                order.push(device.name.clone());
                devices.insert(
                    device.name.clone(),
                    BridgeDevice {
                        profile: device.profile.clone(),
                        line: line_index,
                    },
                );
            }
        }
        let (finished_tx, finished_rx) = mpsc::channel(64);
        let now = Instant::now();
        let (heartbeat_tx, heartbeat) = watch::channel(now);
        let (connected_tx, connected) = watch::channel(false);
        let bridge = Bridge {
            settings: config.mqtt.clone(),
            options: config.gateway.clone(),
            topics,
            client,
            link_rx,
            event_loop,
            lines,
            devices,
            cache: StateCache::new(order.iter().map(String::as_str)),
            book: CommandBook::new(config.gateway.command_ttl),
            connected: false,
            deferred: VecDeque::new(),
            counters: BridgeStats::default(),
            counters_tx: watch::channel(BridgeStats::default()).0,
            discovery: DiscoveryContext {
                client_id: config.mqtt.client_id.clone(),
                prefix: config.mqtt.prefix.clone(),
                discovery_prefix: config.mqtt.discovery_prefix.clone(),
            },
            reannounce_at: None,
            json_views: HashMap::new(),
            finished_tx,
            finished_rx,
            heartbeat_tx,
            connected_tx,
            started: now,
            next_stats: now + config.gateway.stats_interval,
        };
        (
            bridge,
            BridgeHealth {
                heartbeat,
                connected,
            },
        )
    }

    /// Runs until `shutdown` fires, then announces `offline` and disconnects.
    pub async fn run(mut self, mut events_rx: mpsc::Receiver<LineEvent>, mut shutdown: Shutdown) {
        let mut tick = tokio::time::interval(TICK);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            self.heartbeat_tx.send_replace(Instant::now());
            tokio::select! {
                _ = shutdown.fired() => break,
                Some(event) = self.link_rx.recv() => self.on_link(event),
                Some(event) = events_rx.recv() => self.on_line_event(event),
                Some(finished) = self.finished_rx.recv() => self.on_finished(finished),
                _ = tick.tick() => self.on_tick(),
            }
        }
        self.stop().await;
    }

    // ----- MQTT link -----

    fn on_link(&mut self, event: LinkEvent) {
        match event {
            LinkEvent::Connected { .. } => self.on_connected(),
            LinkEvent::Disconnected { .. } => {
                if self.connected {
                    self.counters.mqtt_disconnects += 1;
                }
                self.connected = false;
                self.connected_tx.send_replace(false);
            }
            LinkEvent::Message(publish) => self.on_message(publish),
            LinkEvent::Closed => {}
        }
    }

    /// Every ConnAck: subscriptions are not restored by rumqttc, and a clean session has lost
    /// whatever was unacknowledged, so everything is sent again.
    fn on_connected(&mut self) {
        self.connected = true;
        self.connected_tx.send_replace(true);
        self.counters.mqtt_connects += 1;
        let filter = self.topics.command_filter();
        if let Err(error) = self.client.try_subscribe(&filter, QoS::AtLeastOnce) {
            tracing::error!(%error, topic = %filter, "cannot subscribe");
        }
        if self.settings.discovery {
            // Home Assistant's birth message, and our own earlier configs (to remove those of
            // devices no longer configured).
            for filter in [
                self.discovery.ha_status_topic(),
                self.discovery.config_filter(),
            ] {
                if let Err(error) = self.client.try_subscribe(&filter, QoS::AtLeastOnce) {
                    tracing::error!(%error, topic = %filter, "cannot subscribe");
                }
            }
        }
        self.publish(self.topics.gateway_status(), ONLINE.to_string(), true);
        self.publish_discovery();
        for device in self.cache.devices().to_vec() {
            let word = if self.cache.is_online(&device) {
                ONLINE
            } else {
                OFFLINE
            };
            self.publish(self.topics.availability(&device), word.to_string(), true);
        }
        let updates = self.cache.republish_all();
        self.publish_state(updates);
        if self.options.json_view {
            self.json_views.clear();
            for device in self.cache.devices().to_vec() {
                self.publish_json_view(&device);
            }
        }
        while let Some((topic, payload, retain)) = self.deferred.pop_front() {
            self.publish(topic, payload, retain);
        }
    }

    /// Queues a QoS 1 publish when connected; false when it was not sent.
    fn publish(&mut self, topic: String, payload: String, retain: bool) -> bool {
        if !self.connected {
            return false;
        }
        match self
            .client
            .try_publish(topic.as_str(), QoS::AtLeastOnce, retain, payload)
        {
            Ok(()) => {
                self.counters.published += 1;
                true
            }
            Err(error) => {
                self.counters.publish_failures += 1;
                tracing::warn!(%error, %topic, "publish dropped");
                false
            }
        }
    }

    /// Results and clears must not be lost to a short outage: kept until the next ConnAck.
    fn publish_or_defer(&mut self, topic: String, payload: String, retain: bool) {
        if !self.publish(topic.clone(), payload.clone(), retain) {
            if self.deferred.len() >= MAX_DEFERRED {
                self.deferred.pop_front();
            }
            self.deferred.push_back((topic, payload, retain));
        }
    }

    fn publish_state(&mut self, updates: Vec<StateUpdate>) {
        for update in updates {
            let topic = self.topics.state(&update.device, &update.field);
            self.publish(topic, update.text, true);
        }
    }

    /// Home Assistant device-based discovery: the gateway's own document, then one per
    /// configured device.
    fn publish_discovery(&mut self) {
        if !self.settings.discovery {
            return;
        }
        let line_names: Vec<String> = self.lines.iter().map(|line| line.name.clone()).collect();
        let mut documents = vec![discovery::gateway_config(&self.discovery, &line_names)];
        for device in self.cache.devices() {
            if let Some(entry) = self.devices.get(device) {
                documents.push(discovery::device_config(
                    &self.discovery,
                    device,
                    &entry.profile,
                ));
            }
        }
        for (topic, document) in documents {
            self.publish(topic, document.to_string(), true);
        }
    }

    /// The device's JSON view on `<prefix>/<device>`, when it changed.
    fn publish_json_view(&mut self, device: &str) {
        let Some(state) = self.cache.state(device) else {
            return;
        };
        if state.is_empty() {
            return;
        }
        let payload = json_view::json_view_payload(state);
        if self.json_views.get(device) == Some(&payload) {
            return;
        }
        let topic = json_view::json_view_topic(&self.settings.prefix, device);
        // Retained JSON is bytes of valid UTF-8 (serde_json output).
        let text = String::from_utf8_lossy(&payload).into_owned();
        if self.publish(topic, text, true) {
            self.json_views.insert(device.to_string(), payload);
        }
    }

    // ----- line events -----

    fn on_line_event(&mut self, event: LineEvent) {
        match event {
            LineEvent::Values { device, values } => {
                let updates = self.cache.update(&device, values, self.connected);
                self.publish_state(updates);
                if self.options.json_view {
                    self.publish_json_view(&device);
                }
            }
            LineEvent::Availability { device, online } => {
                if self.cache.set_online(&device, online) {
                    tracing::info!(%device, online, "availability");
                    let word = if online { ONLINE } else { OFFLINE };
                    self.publish(self.topics.availability(&device), word.to_string(), true);
                }
                if online {
                    self.dispatch_ready();
                }
            }
        }
    }

    // ----- commands -----

    fn on_message(&mut self, publish: Publish) {
        if self.settings.discovery {
            if publish.topic == self.discovery.ha_status_topic() {
                if discovery::is_ha_online(&publish.payload) {
                    let delay = discovery::reannounce_delay(&mut rand::thread_rng());
                    tracing::info!(
                        ?delay,
                        "Home Assistant is online: discovery and state follow"
                    );
                    self.reannounce_at = Some(Instant::now() + delay);
                }
                return;
            }
            if discovery::device_of_config_topic(&self.discovery, &publish.topic).is_some() {
                let configured = self.cache.devices().to_vec();
                if discovery::is_stale_config(
                    &self.discovery,
                    &publish.topic,
                    &publish.payload,
                    &configured,
                ) {
                    tracing::info!(topic = %publish.topic, "removing the discovery config of a device no longer configured");
                    self.publish(publish.topic.clone(), String::new(), true);
                }
                return;
            }
        }
        let Some((device, field)) = self.topics.parse_command(&publish.topic) else {
            tracing::debug!(topic = %publish.topic, "not a command topic");
            return;
        };
        let (device, field) = (device.to_string(), field.to_string());
        if publish.payload.is_empty() {
            // The clearing of a retained command (often our own): not a command.
            return;
        }
        let now = Instant::now();
        if publish.qos != QoS::AtMostOnce
            && self.book.is_redelivery(
                &publish.topic,
                publish.pkid,
                &publish.payload,
                publish.dup,
                now,
            )
        {
            self.counters.redeliveries_ignored += 1;
            tracing::debug!(%device, %field, "QoS 1 redelivery ignored");
            return;
        }
        let Some(entry) = self.devices.get(&device).cloned() else {
            self.counters.unknown_device_commands += 1;
            tracing::warn!(topic = %publish.topic, "command for a device that is not configured");
            return;
        };
        self.counters.commands_received += 1;
        // Echoed in `value` exactly as sent (bounded); logged with `?` so control characters
        // and escapes cannot forge log lines.
        let value = payload::echo(&publish.payload);
        let text = match decode_command(&publish.payload, self.options.max_payload) {
            CommandPayload::Clear => return,
            CommandPayload::Refused { shown, reason } => {
                self.reject_incoming(&device, &field, &shown, reason);
                return;
            }
            CommandPayload::Text(text) => text,
        };
        let Some(info) = entry.profile.field(&field) else {
            let reason = format!(
                "unknown field {field:?} (profile {} has: {})",
                entry.profile.name(),
                entry
                    .profile
                    .fields()
                    .iter()
                    .filter(|f| f.writable)
                    .map(|f| f.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
            self.reject_incoming(&device, &field, &value, reason);
            return;
        };
        if !info.writable {
            self.reject_incoming(&device, &field, &value, format!("{field} is read-only"));
            return;
        }
        let min_write_interval = info.min_write_interval;
        let empty = Default::default();
        let state = self.cache.state(&device).unwrap_or(&empty);
        if let Err(rejection) = entry.profile.plan_command(&field, &text, state) {
            self.reject_incoming(&device, &field, &value, rejection.0);
            return;
        }
        tracing::info!(%device, %field, command = ?value, "command received");
        match self
            .book
            .submit(&device, &field, &text, &value, min_write_interval, now)
        {
            Admission::AlreadyWaiting => {}
            Admission::Queued { superseded } => {
                if let Some(older) = superseded {
                    self.supersede(older);
                }
            }
        }
        self.dispatch_ready();
    }

    /// A newer command for the same field replaced `older` before it ran. Its retained
    /// message has been replaced by the newer one too: no clear.
    fn supersede(&mut self, older: TrackedCommand) {
        self.counters.commands_superseded += 1;
        tracing::info!(device = %older.device, field = %older.field, command = ?older.value,
            "command superseded by a newer one");
        let result = CommandResult::new(
            &older.value,
            Outcome::Superseded,
            "superseded by a newer command for the same field before it was sent",
        );
        self.publish_or_defer(
            self.topics.result(&older.device, &older.field),
            result.to_json(),
            false,
        );
    }

    /// Rejects a command as it arrives. It is the newest message on its topic, so its
    /// (possibly retained) copy is cleared whatever waits for the field.
    fn reject_incoming(&mut self, device: &str, field: &str, shown: &str, reason: String) {
        self.count_rejection(device, field, shown, &reason);
        let result = CommandResult::new(shown, Outcome::Rejected, reason);
        self.publish_or_defer(self.topics.result(device, field), result.to_json(), false);
        self.publish_or_defer(self.topics.set(device, field), String::new(), true);
    }

    /// Rejects a command that waited (re-planned on fresher state).
    fn reject(&mut self, device: &str, field: &str, shown: &str, reason: String) {
        self.count_rejection(device, field, shown, &reason);
        let result = CommandResult::new(shown, Outcome::Rejected, reason);
        self.finish_with(device, field, result);
    }

    fn count_rejection(&mut self, device: &str, field: &str, shown: &str, reason: &str) {
        tracing::warn!(%device, %field, command = ?shown, %reason, "command rejected");
        self.counters.commands_rejected += 1;
    }

    /// Publishes a result, then clears the (possibly retained) command unless a newer one for
    /// the field is waiting: with MQTT 3.1.1 we cannot tell whether it was retained.
    fn finish_with(&mut self, device: &str, field: &str, result: CommandResult) {
        self.publish_or_defer(self.topics.result(device, field), result.to_json(), false);
        if !self.book.has_waiting(device, field) {
            self.publish_or_defer(self.topics.set(device, field), String::new(), true);
        }
    }

    /// Hands every command that may run now to its line.
    fn dispatch_ready(&mut self) {
        let cache = &self.cache;
        let ready = self
            .book
            .take_ready(Instant::now(), |device| cache.is_online(device));
        for command in ready {
            self.dispatch(command);
        }
    }

    fn dispatch(&mut self, command: TrackedCommand) {
        let Some(entry) = self.devices.get(&command.device).cloned() else {
            return;
        };
        let empty = Default::default();
        let state = self.cache.state(&command.device).unwrap_or(&empty);
        // Planned again on the freshest state: it may have changed while the command waited.
        let plan = match entry
            .profile
            .plan_command(&command.field, &command.text, state)
        {
            Ok(plan) => plan,
            Err(rejection) => {
                self.book
                    .finish(&command.device, &command.field, false, Instant::now());
                self.reject(&command.device, &command.field, &command.value, rejection.0);
                return;
            }
        };
        let Some(line) = self.lines.get(entry.line) else {
            return;
        };
        let (reply_tx, reply_rx) = oneshot::channel();
        let bus_command = Command {
            device: command.device.clone(),
            plan,
            reply_tx,
        };
        match line.command_tx.try_send(bus_command) {
            Ok(()) => {
                tracing::debug!(device = %command.device, field = %command.field, "command queued on the line");
                let finished_tx = self.finished_tx.clone();
                tokio::spawn(async move {
                    let outcome = reply_rx.await.unwrap_or(CommandOutcome::Failed {
                        cause: CommandFailure::LineStopped,
                    });
                    let _ = finished_tx.send(Finished { command, outcome }).await;
                });
            }
            Err(mpsc::error::TrySendError::Full(_)) => {
                // The line is busy with earlier commands: try again on the next tick.
                if let Some(older) = self.book.requeue(command) {
                    self.supersede(older);
                }
            }
            Err(mpsc::error::TrySendError::Closed(_)) => {
                self.book
                    .finish(&command.device, &command.field, false, Instant::now());
                self.counters.commands_failed += 1;
                let result =
                    CommandResult::new(&command.value, Outcome::Failed, "the line has stopped");
                self.finish_with(&command.device, &command.field, result);
            }
        }
    }

    fn on_finished(&mut self, finished: Finished) {
        let Finished { command, outcome } = finished;
        let (word, detail, wrote) = match outcome {
            CommandOutcome::Applied { detail } => (Outcome::Applied, detail, true),
            CommandOutcome::NotApplied { detail } => (Outcome::NotApplied, detail, true),
            CommandOutcome::Rejected { detail } => (Outcome::Rejected, detail, false),
            // A failed write may have reached the device: count it for the write interval.
            CommandOutcome::Failed { cause } => (Outcome::Failed, cause.to_string(), true),
        };
        match word {
            Outcome::Applied => self.counters.commands_applied += 1,
            Outcome::NotApplied => self.counters.commands_not_applied += 1,
            Outcome::Rejected => self.counters.commands_rejected += 1,
            Outcome::Failed => self.counters.commands_failed += 1,
            Outcome::Expired => self.counters.commands_expired += 1,
            Outcome::Superseded => self.counters.commands_superseded += 1,
        }
        tracing::info!(device = %command.device, field = %command.field, command = ?command.value,
            outcome = word.word(), %detail, "command finished");
        self.book
            .finish(&command.device, &command.field, wrote, Instant::now());
        let result = CommandResult::new(&command.value, word, detail);
        self.finish_with(&command.device, &command.field, result);
        self.dispatch_ready();
    }

    fn on_tick(&mut self) {
        let now = Instant::now();
        let cache = &self.cache;
        let expired = self
            .book
            .take_expired(now, |device| cache.is_online(device));
        for command in expired {
            self.counters.commands_expired += 1;
            let detail = format!(
                "device {} stayed offline for {} (the command's time to live)",
                command.device,
                humantime::format_duration(self.options.command_ttl)
            );
            tracing::warn!(device = %command.device, field = %command.field, command = ?command.value, "command expired");
            let result = CommandResult::new(&command.value, Outcome::Expired, detail);
            self.finish_with(&command.device, &command.field, result);
        }
        self.dispatch_ready();
        if self.reannounce_at.is_some_and(|at| at <= now) {
            self.reannounce_at = None;
            self.publish_discovery();
            let updates = self.cache.republish_all();
            self.publish_state(updates);
        }
        self.counters_tx.send_replace(self.counters_snapshot());
        if now >= self.next_stats {
            self.next_stats = now + self.options.stats_interval;
            self.publish_stats();
        }
    }

    /// The current statistics of every line.
    pub fn line_stats(&self) -> Vec<LineStats> {
        self.lines
            .iter()
            .map(|line| line.stats_rx.borrow().clone())
            .collect()
    }

    /// The counters as shared: uptime and connection state filled in.
    fn counters_snapshot(&self) -> BridgeStats {
        BridgeStats {
            uptime: self.started.elapsed(),
            mqtt_connected: self.connected,
            waiting_commands: self.book.waiting_count() as u64,
            ..self.counters.clone()
        }
    }

    /// Renders the Prometheus text for the metrics endpoint from live line statistics and the
    /// bridge's counters (refreshed every tick).
    pub fn metrics_renderer(&self) -> prometheus::Render {
        let lines: Vec<_> = self
            .lines
            .iter()
            .map(|line| line.stats_rx.clone())
            .collect();
        let counters = self.counters_tx.subscribe();
        Arc::new(move || {
            let stats: Vec<LineStats> = lines.iter().map(|rx| rx.borrow().clone()).collect();
            let bridge = counters.borrow().clone();
            metrics::prometheus_text(&stats, &bridge)
        })
    }

    /// Retained: the gateway's Home Assistant sensors (and any client arriving later) read the
    /// last document at once instead of waiting up to a statistics interval.
    fn publish_stats(&mut self) {
        let document = metrics::stats_json(&self.line_stats(), &self.counters_snapshot());
        self.publish(self.topics.gateway_stats(), document.to_string(), true);
    }

    // ----- stop -----

    async fn stop(mut self) {
        // Commands already on the bus finish there (the lines complete their transaction):
        // report them if they do so quickly.
        let deadline = tokio::time::Instant::now() + STOP_GRACE;
        while self.book_has_commands_on_bus() {
            match tokio::time::timeout_at(deadline, self.finished_rx.recv()).await {
                Ok(Some(finished)) => self.on_finished(finished),
                _ => break,
            }
        }
        // Waiting commands stay retained in the broker for the next start.
        let waiting = self.book.drain_waiting();
        if !waiting.is_empty() {
            tracing::info!(
                count = waiting.len(),
                "waiting commands left for the next start"
            );
        }
        for device in self.cache.devices().to_vec() {
            self.publish(self.topics.availability(&device), OFFLINE.to_string(), true);
        }
        self.publish(self.topics.gateway_status(), OFFLINE.to_string(), true);
        if self.connected {
            if let Err(error) = self.client.try_disconnect() {
                tracing::warn!(%error, "cannot queue the MQTT disconnect");
            }
            // Its own bound: the event loop waits up to its close grace for the broker.
            let closed = tokio::time::timeout(STOP_GRACE, async {
                while let Some(event) = self.link_rx.recv().await {
                    if matches!(event, LinkEvent::Closed) {
                        break;
                    }
                }
            })
            .await;
            if closed.is_err() {
                tracing::warn!("MQTT disconnect did not complete in time");
            }
        }
        self.event_loop.abort();
        tracing::info!("bridge stopped");
    }

    fn book_has_commands_on_bus(&self) -> bool {
        self.book.on_bus_count() > 0
    }
}
