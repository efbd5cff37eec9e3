//! The bridge's decisions, without I/O: every handler takes one event (the MQTT link up or
//! down, an incoming message, a line event, a tick, a send the driver could not make) with the
//! time passed in, updates the state and returns the [`Action`]s to carry out (publish,
//! subscribe, hand a command to a line). Nothing here touches the network, a channel or the
//! clock; the driver in [`super`] owns those and only executes what it is told.
//!
//! The contract's rules live here: retained state and availability, republishing everything
//! on each connection, discovery on connect and after Home Assistant's birth message, removal
//! of stale discovery documents, command validation (planned once, by the device's profile),
//! the [`CommandBook`] (waiting while offline, time to live, superseding, write interval, QoS 1
//! redeliveries), results on `…/result`, clearing of retained commands once they have an
//! outcome, and results kept while MQTT is down. Commands from outside the plain topics (a
//! Sparkplug DCMD, [`Core::on_external_command`]) go through the same validation and book,
//! with their results on `…/result` too, and their end reported back ([`Action::Report`]).

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use rand::rngs::StdRng;
use rand::SeedableRng;
use rumqttc::QoS;

use super::commands::{Admission, CommandBook, TrackedCommand};
use super::discovery;
use super::guard::{TopicGuard, Verdict};
use super::json_view;
use super::metrics::{self, BridgeStats};
use super::payload::{self, decode_command, CommandPayload, CommandResult, Outcome};
use super::state::{StateCache, StateUpdate};
use crate::bus::{Command, CommandOutcome, LineEvent, LineStats};
use crate::config::{Config, GatewayOptions};
use crate::contract::{availability_word, is_ha_online, Topics, OFFLINE, ONLINE};
use crate::profile::{CommandPlan, Profile};

/// Results and clears kept while MQTT is down (older ones are dropped first).
const MAX_DEFERRED: usize = 1024;
/// Shortest time between two log lines about shed commands.
const SHED_LOG_INTERVAL: Duration = Duration::from_secs(10);

/// One message to publish.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Publish {
    pub topic: String,
    pub payload: String,
    pub qos: QoS,
    pub retain: bool,
    /// Kept until the next connection when it cannot be sent (results and clears).
    pub keep: bool,
}

/// What the driver is asked to do.
#[derive(Debug)]
pub enum Action {
    Publish(Publish),
    Subscribe {
        filter: String,
        qos: QoS,
    },
    /// Hand `command` to line number `line`; report a refusal with [`Core::on_send_failed`].
    Send {
        line: usize,
        command: Command,
    },
    /// Tell the sender of an external command how it ended.
    Report(CommandReport),
}

/// A command that did not come from a plain `…/set` topic (a Sparkplug DCMD): the field and
/// the command text as `…/set` would carry it (`ON`, `8`, `12.5`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExternalCommand {
    pub device: String,
    pub field: String,
    pub text: String,
}

/// How an [`ExternalCommand`] ended: `applied` only when the device took the value; any other
/// end (refused, superseded, expired, failed, not applied) lets the sender show the device's
/// true value again.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandReport {
    pub device: String,
    pub field: String,
    pub applied: bool,
}

/// Where a command came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Origin {
    /// `…/set`: its (possibly retained) message is cleared once it has an outcome.
    Plain,
    /// [`Core::on_external_command`]: its end is reported.
    External,
}

/// `set` or `external`: how the log says where a command came from.
impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Origin::Plain => "set",
            Origin::External => "external",
        })
    }
}

/// The one INFO line of a command's arrival. `value` as sent (bounded by
/// [`payload::echo`]), logged with `?` so control characters cannot forge log lines.
fn log_received(device: &str, field: &str, value: &str, origin: Origin) {
    tracing::info!(%device, %field, ?value, via = %origin, "command received");
}

/// The one line of a command's end, its outcome and detail as words. INFO, except for the
/// outcomes that mean a valid command was not carried out (`failed`, `expired`): the device
/// or its line needs a look, so they are warnings.
fn log_outcome(device: &str, field: &str, value: &str, outcome: Outcome, detail: &str) {
    let word = outcome.word();
    if matches!(outcome, Outcome::Failed | Outcome::Expired) {
        tracing::warn!(%device, %field, ?value, outcome = %word, ?detail, "command finished");
    } else {
        tracing::info!(%device, %field, ?value, outcome = %word, ?detail, "command finished");
    }
}

/// An incoming MQTT message, as much of it as the rules look at.
#[derive(Debug, Clone, Copy)]
pub struct Incoming<'m> {
    pub topic: &'m str,
    pub payload: &'m [u8],
    pub qos: QoS,
    pub pkid: u16,
    pub dup: bool,
    /// Set by the broker only for a retained message sent because we subscribed (MQTT 3.1.1
    /// clears it on live messages, retained or not).
    pub retain: bool,
}

impl<'m> Incoming<'m> {
    pub fn of(publish: &'m rumqttc::Publish) -> Self {
        Incoming {
            topic: &publish.topic,
            payload: &publish.payload,
            qos: publish.qos,
            pkid: publish.pkid,
            dup: publish.dup,
            retain: publish.retain,
        }
    }
}

/// A configured device as the bridge sees it.
#[derive(Debug, Clone)]
pub struct BridgeDevice {
    pub name: String,
    pub profile: Arc<Profile>,
    /// Index of its line in the configuration.
    pub line: usize,
}

/// What the core is built from.
#[derive(Debug, Clone)]
pub struct CoreSettings {
    pub topics: Topics,
    /// Home Assistant discovery is published.
    pub discovery: bool,
    pub options: GatewayOptions,
    pub line_names: Vec<String>,
    /// In configuration order.
    pub devices: Vec<BridgeDevice>,
}

impl CoreSettings {
    pub fn from_config(config: &Config) -> Self {
        let mut devices = Vec::new();
        for (line, spec) in config.lines.iter().enumerate() {
            for device in &spec.devices {
                devices.push(BridgeDevice {
                    name: device.name.clone(),
                    profile: device.profile.clone(),
                    line,
                });
            }
        }
        CoreSettings {
            topics: config.mqtt.topics(),
            discovery: config.mqtt.discovery,
            options: config.gateway.clone(),
            line_names: config.lines.iter().map(|line| line.name.clone()).collect(),
            devices,
        }
    }
}

/// The bridge's state and rules.
#[derive(Debug)]
pub struct Core {
    topics: Topics,
    discovery: bool,
    options: GatewayOptions,
    line_names: Vec<String>,
    devices: HashMap<String, BridgeDevice>,
    cache: StateCache,
    book: CommandBook,
    /// The plans of waiting commands, by command id (planned once, when validated).
    plans: HashMap<u64, CommandPlan>,
    /// Commands handed to a line, by id, until their [`LineEvent::CommandFinished`].
    on_bus: HashMap<u64, TrackedCommand>,
    /// Ids of booked commands that came from [`Core::on_external_command`].
    external: HashSet<u64>,
    connected: bool,
    deferred: VecDeque<Publish>,
    counters: BridgeStats,
    /// Re-announce discovery at this instant (after Home Assistant's birth message).
    reannounce_at: Option<Instant>,
    /// Last JSON view payload per topic, to skip unchanged ones.
    json_views: HashMap<String, Vec<u8>>,
    started: Instant,
    next_stats: Instant,
    /// Statistics go out on the next tick (start, reconnect, Home Assistant's birth).
    stats_due: bool,
    /// The driver cannot keep up: incoming commands are shed with a `rejected` outcome.
    overloaded: bool,
    /// Shed commands not yet reported in the log, and when the log last spoke of them.
    shed_unlogged: u64,
    shed_logged_at: Option<Instant>,
    /// The status, availability and state topics this gateway defends.
    guard: TopicGuard,
    /// Devices another gateway announces availability for under our prefix: commands for them
    /// are that gateway's business.
    foreign_devices: HashSet<String>,
    /// Actions that must not run twice, by their `…/set` topic: handed to their line only once
    /// the broker has passed on our clearing of the (possibly retained) command.
    clearing: HashMap<String, (usize, Command)>,
    rng: StdRng,
    out: Vec<Action>,
}

impl Core {
    pub fn new(settings: CoreSettings, now: Instant) -> Self {
        let order: Vec<String> = settings.devices.iter().map(|d| d.name.clone()).collect();
        let devices = settings
            .devices
            .into_iter()
            .map(|device| (device.name.clone(), device))
            .collect();
        Core {
            topics: settings.topics,
            discovery: settings.discovery,
            line_names: settings.line_names,
            devices,
            cache: StateCache::new(order.iter().map(String::as_str)),
            book: CommandBook::new(settings.options.command_ttl),
            plans: HashMap::new(),
            on_bus: HashMap::new(),
            external: HashSet::new(),
            connected: false,
            deferred: VecDeque::new(),
            counters: BridgeStats::default(),
            reannounce_at: None,
            json_views: HashMap::new(),
            started: now,
            next_stats: now + settings.options.stats_interval,
            stats_due: true,
            overloaded: false,
            shed_unlogged: 0,
            shed_logged_at: None,
            guard: TopicGuard::default(),
            foreign_devices: HashSet::new(),
            clearing: HashMap::new(),
            options: settings.options,
            rng: StdRng::from_entropy(),
            out: Vec::new(),
        }
    }

    pub fn topics(&self) -> &Topics {
        &self.topics
    }

    pub fn is_connected(&self) -> bool {
        self.connected
    }

    /// Commands handed to a line whose end has not been reported yet.
    pub fn commands_on_bus(&self) -> usize {
        self.on_bus.len()
    }

    /// The counters as shared: uptime and connection state filled in.
    pub fn counters(&self, now: Instant) -> BridgeStats {
        BridgeStats {
            uptime: now.saturating_duration_since(self.started),
            mqtt_connected: self.connected,
            waiting_commands: self.book.waiting_count() as u64,
            ..self.counters.clone()
        }
    }

    fn take(&mut self) -> Vec<Action> {
        std::mem::take(&mut self.out)
    }

    // ----- MQTT link -----

    /// Every ConnAck: subscriptions are not restored by rumqttc, and a clean session has lost
    /// whatever was unacknowledged, so everything is sent again.
    pub fn on_connected(&mut self) -> Vec<Action> {
        self.connected = true;
        self.counters.mqtt_connects += 1;
        self.stats_due = true;
        self.guard.reset();
        self.subscribe(self.topics.command_filter());
        self.subscribe_guarded();
        if self.discovery {
            // Home Assistant's birth message, and our own earlier configs (to remove those of
            // devices no longer configured).
            self.subscribe(self.topics.ha_status_topic());
            self.subscribe(self.topics.config_filter());
        }
        self.publish(self.topics.gateway_status_topic(), ONLINE.to_string(), true);
        self.publish_discovery();
        for device in self.cache.devices().to_vec() {
            let word = availability_word(self.cache.is_online(&device));
            let topic = self.topics.availability_topic(&device);
            self.publish(topic, word.to_string(), true);
        }
        let updates = self.cache.republish_all();
        self.publish_state(updates);
        if self.options.json_view {
            self.json_views.clear();
            for device in self.cache.devices().to_vec() {
                self.publish_json_view(&device);
            }
        }
        while let Some(kept) = self.deferred.pop_front() {
            self.out.push(Action::Publish(kept));
        }
        self.clear_again();
        self.take()
    }

    pub fn on_disconnected(&mut self) {
        if self.connected {
            self.counters.mqtt_disconnects += 1;
        }
        self.connected = false;
    }

    /// The driver's report on one [`Action::Publish`]: `sent` when the client queued it.
    pub fn on_published(&mut self, publish: Publish, sent: bool) {
        if sent {
            self.counters.published += 1;
            return;
        }
        self.counters.publish_failures += 1;
        self.json_views.remove(&publish.topic);
        if publish.keep {
            self.keep(publish);
        }
    }

    fn subscribe(&mut self, filter: String) {
        self.out.push(Action::Subscribe {
            filter,
            qos: QoS::AtLeastOnce,
        });
    }

    /// A QoS 1 publish when connected; false when there is no connection to send it on.
    fn publish(&mut self, topic: String, payload: String, retain: bool) -> bool {
        if !self.connected {
            return false;
        }
        if retain && self.guarded(&topic).is_some() {
            self.guard.sent(&topic, &payload);
        }
        self.out.push(Action::Publish(Publish {
            topic,
            payload,
            qos: QoS::AtLeastOnce,
            retain,
            keep: false,
        }));
        true
    }

    /// Results and clears must not be lost to a short outage: kept until the next ConnAck.
    fn publish_or_keep(&mut self, topic: String, payload: String, retain: bool) {
        let publish = Publish {
            topic,
            payload,
            qos: QoS::AtLeastOnce,
            retain,
            keep: true,
        };
        if self.connected {
            self.out.push(Action::Publish(publish));
        } else {
            self.keep(publish);
        }
    }

    fn keep(&mut self, publish: Publish) {
        if self.deferred.len() >= MAX_DEFERRED {
            self.deferred.pop_front();
        }
        self.deferred.push_back(publish);
    }

    fn publish_state(&mut self, updates: Vec<StateUpdate>) {
        for update in updates {
            let topic = self.topics.state_topic(&update.device, &update.field);
            self.publish(topic, update.text, true);
        }
    }

    /// Home Assistant device-based discovery: the gateway's own document, then one per
    /// configured device.
    fn publish_discovery(&mut self) {
        if !self.discovery {
            return;
        }
        let mut documents = vec![discovery::gateway_config(&self.topics, &self.line_names)];
        for device in self.cache.devices() {
            if let Some(entry) = self.devices.get(device) {
                documents.push(discovery::device_config_with_state(
                    &self.topics,
                    device,
                    &entry.profile,
                    self.cache.state(device),
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
        let topic = self.topics.json_view_topic(device);
        if self.json_views.get(&topic) == Some(&payload) {
            return;
        }
        // Retained JSON is bytes of valid UTF-8 (serde_json output).
        let text = String::from_utf8_lossy(&payload).into_owned();
        if self.publish(topic.clone(), text, true) {
            self.json_views.insert(topic, payload);
        }
    }

    // ----- line events -----

    pub fn on_line_event(&mut self, event: LineEvent, now: Instant) -> Vec<Action> {
        match event {
            LineEvent::Values { device, values } => {
                let updates = self.cache.update(&device, values, self.connected);
                if let Some((topic, document)) = self
                    .devices
                    .get(&device)
                    .filter(|_| self.discovery)
                    .and_then(|entry| {
                        discovery::identity_update(
                            &self.topics,
                            &device,
                            &entry.profile,
                            self.cache.state(&device),
                            &updates,
                        )
                    })
                {
                    self.publish(topic, document.to_string(), true);
                }
                self.publish_state(updates);
                if self.options.json_view {
                    self.publish_json_view(&device);
                }
            }
            LineEvent::Availability { device, online } => {
                if self.cache.set_online(&device, online) {
                    tracing::info!(%device, online, "availability");
                    let topic = self.topics.availability_topic(&device);
                    self.publish(topic, availability_word(online).to_string(), true);
                }
                if online {
                    self.dispatch_ready(now);
                }
            }
            LineEvent::CommandFinished { id, outcome, .. } => self.on_finished(id, outcome, now),
        }
        self.take()
    }

    // ----- incoming messages -----

    pub fn on_message(&mut self, message: Incoming<'_>, now: Instant) -> Vec<Action> {
        self.handle_message(message, now);
        self.take()
    }

    fn handle_message(&mut self, message: Incoming<'_>, now: Instant) {
        let topic = message.topic;
        if self.discovery {
            if topic == self.topics.ha_status_topic() {
                if is_ha_online(message.payload) {
                    let delay = discovery::reannounce_delay(&mut self.rng);
                    tracing::info!(
                        ?delay,
                        "Home Assistant is online: discovery and state follow"
                    );
                    self.reannounce_at = Some(now + delay);
                    self.stats_due = true;
                }
                return;
            }
            if self.topics.device_of_config_topic(topic).is_some() {
                let configured = self.cache.devices();
                if discovery::is_stale_config(&self.topics, topic, message.payload, configured) {
                    tracing::info!(%topic, "removing the discovery config of a device no longer configured");
                    self.publish(topic.to_string(), String::new(), true);
                }
                return;
            }
        }
        if let Some(guarded) = self.guarded(topic) {
            self.on_guarded(guarded, topic, message.payload, now);
            return;
        }
        if let Some(device) = self.topics.device_of_availability_topic(topic) {
            if !self.devices.contains_key(device) && !message.payload.is_empty() {
                self.foreign_devices.insert(device.to_string());
            }
            return;
        }
        let Some((device, field)) = self.topics.parse_command(topic) else {
            tracing::debug!(%topic, "not a command topic");
            return;
        };
        if message.payload.is_empty() {
            // The clearing of a retained command (often our own): not a command. When an
            // action waits for it, the retained command is gone from the broker now.
            self.on_cleared(topic);
            return;
        }
        if message.qos != QoS::AtMostOnce
            && self
                .book
                .is_redelivery(topic, message.pkid, message.payload, message.dup, now)
        {
            self.counters.redeliveries_ignored += 1;
            tracing::debug!(%device, %field, "QoS 1 redelivery ignored");
            return;
        }
        if !self.devices.contains_key(device) {
            self.reject_unknown_device(device, field, message.payload);
            return;
        }
        if self.overloaded {
            self.shed(device, field, message.payload, now);
            return;
        }
        // Echoed in `value` exactly as sent (bounded); logged with `?` so control characters
        // and escapes cannot forge log lines.
        let value = payload::echo(message.payload);
        let text = match decode_command(message.payload, self.options.max_payload) {
            CommandPayload::Clear => return,
            CommandPayload::Refused { shown, reason } => {
                if self.devices.contains_key(device) {
                    self.counters.commands_received += 1;
                    self.reject_incoming(device, field, &shown, reason, Origin::Plain);
                } else {
                    self.note_unknown_device(device, topic);
                }
                return;
            }
            CommandPayload::Text(text) => text,
        };
        self.admit(
            device,
            field,
            &text,
            &value,
            Origin::Plain,
            message.retain,
            now,
        );
    }

    /// A command from outside the plain topics (a Sparkplug DCMD metric turned into command
    /// text): the same validation, book and results as `…/set`, and its end is reported with
    /// an [`Action::Report`] so the sender can show the device's true value after a refusal.
    pub fn on_external_command(&mut self, command: ExternalCommand, now: Instant) -> Vec<Action> {
        let ExternalCommand {
            device,
            field,
            text,
        } = command;
        let value = payload::shortened(&text);
        let (shown, reason) = match decode_command(text.as_bytes(), self.options.max_payload) {
            CommandPayload::Text(text) => {
                self.admit(&device, &field, &text, &value, Origin::External, false, now);
                return self.take();
            }
            CommandPayload::Clear => (value, "the command is empty".to_string()),
            CommandPayload::Refused { shown, reason } => (shown, reason),
        };
        if self.devices.contains_key(&device) {
            self.counters.commands_received += 1;
            self.reject_incoming(&device, &field, &shown, reason, Origin::External);
        } else {
            self.note_unknown_device(&device, "an external command");
            self.report(&device, &field, false);
        }
        self.take()
    }

    fn note_unknown_device(&mut self, device: &str, via: &str) {
        self.counters.unknown_device_commands += 1;
        tracing::warn!(%device, %via, "command for a device that is not configured");
    }

    /// Validates a decoded command (`text` as planned, `value` as sent) and books it.
    /// `from_store`: the broker sent it from its retained store (the MQTT retain flag).
    #[allow(clippy::too_many_arguments)]
    fn admit(
        &mut self,
        device: &str,
        field: &str,
        text: &str,
        value: &str,
        origin: Origin,
        from_store: bool,
        now: Instant,
    ) {
        let Some(entry) = self.devices.get(device).cloned() else {
            let topic = self.topics.command_topic(device, field);
            self.note_unknown_device(device, &topic);
            if origin == Origin::External {
                self.report(device, field, false);
            }
            return;
        };
        self.counters.commands_received += 1;
        // The one plan of the command: the profile refuses unknown and read-only fields and
        // values its rules forbid on the last known state. The line's slot recomputes the
        // writes from its fresh reads.
        let empty = Default::default();
        let state = self.cache.state(device).unwrap_or(&empty);
        let plan = match entry.profile.plan_command(field, text, state) {
            Ok(plan) => plan,
            Err(rejection) => {
                self.reject_incoming(device, field, value, rejection.0, origin);
                return;
            }
        };
        let min_write_interval = entry
            .profile
            .field(field)
            .and_then(|info| info.min_write_interval);
        let admission = if from_store {
            // From the broker's retained store: the same command again when it is the one
            // waiting or running (a re-subscription), so it gets no second run or outcome.
            self.book
                .submit(device, field, text, value, min_write_interval, now)
        } else {
            self.book
                .queue(device, field, text, value, min_write_interval, now)
        };
        match admission {
            Admission::AlreadyWaiting => {
                tracing::debug!(%device, %field, "the broker sent the waiting command again");
                if let Some(id) = self.book.waiting_id(device, field) {
                    if origin == Origin::External {
                        self.external.insert(id);
                    }
                }
            }
            Admission::Queued { superseded } => {
                log_received(device, field, value, origin);
                if let Some(id) = self.book.waiting_id(device, field) {
                    self.plans.insert(id, plan);
                    if origin == Origin::External {
                        self.external.insert(id);
                    }
                }
                if let Some(older) = superseded {
                    let older_was_plain = !self.external.contains(&older.id);
                    self.supersede(older);
                    if origin == Origin::External && older_was_plain {
                        // Its retained message is still on `…/set`: it must not run again
                        // at the next start.
                        let set = self.topics.command_topic(device, field);
                        self.publish_or_keep(set, String::new(), true);
                    }
                }
            }
        }
        self.dispatch_ready(now);
    }

    /// Tells the sender of an external command how it ended (nothing for plain commands).
    fn report_end(&mut self, command: &TrackedCommand, applied: bool) {
        if self.external.remove(&command.id) {
            self.report(&command.device, &command.field, applied);
        }
    }

    fn report(&mut self, device: &str, field: &str, applied: bool) {
        self.out.push(Action::Report(CommandReport {
            device: device.to_string(),
            field: field.to_string(),
            applied,
        }));
    }

    // ----- commands -----

    /// A newer command for the same field replaced `older` before it ran. Its retained
    /// message has been replaced by the newer one too: no clear.
    fn supersede(&mut self, older: TrackedCommand) {
        self.plans.remove(&older.id);
        self.report_end(&older, false);
        self.counters.commands_superseded += 1;
        let detail = "superseded by a newer command for the same field before it was sent";
        log_outcome(
            &older.device,
            &older.field,
            &older.value,
            Outcome::Superseded,
            detail,
        );
        let result = CommandResult::new(&older.value, Outcome::Superseded, detail);
        let topic = self.topics.result_topic(&older.device, &older.field);
        self.publish_or_keep(topic, result.to_json(), false);
    }

    /// Rejects a command as it arrives. It is the newest message on its topic, so its
    /// (possibly retained) copy is cleared whatever waits for the field.
    fn reject_incoming(
        &mut self,
        device: &str,
        field: &str,
        shown: &str,
        reason: String,
        origin: Origin,
    ) {
        log_received(device, field, shown, origin);
        log_outcome(device, field, shown, Outcome::Rejected, &reason);
        self.counters.commands_rejected += 1;
        let result = CommandResult::new(shown, Outcome::Rejected, reason);
        let topic = self.topics.result_topic(device, field);
        self.publish_or_keep(topic, result.to_json(), false);
        match origin {
            Origin::Plain => {
                let set = self.topics.command_topic(device, field);
                self.publish_or_keep(set, String::new(), true);
            }
            Origin::External => self.report(device, field, false),
        }
    }

    /// Publishes a result, then clears the (possibly retained) command unless a newer one for
    /// the field is waiting: with MQTT 3.1.1 we cannot tell whether it was retained.
    fn finish_with(&mut self, device: &str, field: &str, result: CommandResult) {
        let topic = self.topics.result_topic(device, field);
        self.publish_or_keep(topic, result.to_json(), false);
        if !self.book.has_waiting(device, field) {
            let set = self.topics.command_topic(device, field);
            self.publish_or_keep(set, String::new(), true);
        }
    }

    /// Hands every command that may run now to its line.
    fn dispatch_ready(&mut self, now: Instant) {
        let cache = &self.cache;
        let ready = self.book.take_ready(now, |device| cache.is_online(device));
        for command in ready {
            let plan = self.plans.remove(&command.id);
            let line = self.devices.get(&command.device).map(|entry| entry.line);
            let (Some(plan), Some(line)) = (plan, line) else {
                self.fail(command, "the command has no line to run on", now);
                continue;
            };
            tracing::debug!(device = %command.device, field = %command.field, "command handed to the line");
            let bus_command = Command {
                id: command.id,
                device: command.device.clone(),
                plan,
            };
            if !bus_command.plan.is_idempotent() {
                self.clear_then_send(line, bus_command, command);
                continue;
            }
            self.on_bus.insert(command.id, command);
            self.out.push(Action::Send {
                line,
                command: bus_command,
            });
        }
    }

    /// The driver could not hand `command` to its line: the line's queue is `full` (try again
    /// on the next tick), or the line has stopped.
    pub fn on_send_failed(&mut self, command: Command, full: bool, now: Instant) -> Vec<Action> {
        let Some(tracked) = self.on_bus.remove(&command.id) else {
            return self.take();
        };
        if full {
            self.plans.insert(command.id, command.plan);
            if let Some(older) = self.book.requeue(tracked) {
                self.supersede(older);
            }
        } else {
            self.fail(tracked, "the line has stopped", now);
        }
        self.take()
    }

    fn fail(&mut self, command: TrackedCommand, detail: &str, now: Instant) {
        self.book
            .finish(&command.device, &command.field, false, now);
        self.report_end(&command, false);
        self.counters.commands_failed += 1;
        log_outcome(
            &command.device,
            &command.field,
            &command.value,
            Outcome::Failed,
            detail,
        );
        let result = CommandResult::new(&command.value, Outcome::Failed, detail);
        self.finish_with(&command.device, &command.field, result);
    }

    fn on_finished(&mut self, id: u64, outcome: CommandOutcome, now: Instant) {
        let Some(command) = self.on_bus.remove(&id) else {
            tracing::warn!(id, "outcome of a command the bridge did not send");
            return;
        };
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
        log_outcome(
            &command.device,
            &command.field,
            &command.value,
            word,
            &detail,
        );
        self.book
            .finish(&command.device, &command.field, wrote, now);
        self.report_end(&command, word == Outcome::Applied);
        let result = CommandResult::new(&command.value, word, detail);
        self.finish_with(&command.device, &command.field, result);
        self.dispatch_ready(now);
    }

    // ----- time -----

    /// Expiries, waiting commands, the re-announcement after Home Assistant's birth and the
    /// statistics document. `line_stats` is asked only when statistics are due.
    pub fn on_tick(
        &mut self,
        now: Instant,
        line_stats: impl FnOnce() -> Vec<LineStats>,
    ) -> Vec<Action> {
        let cache = &self.cache;
        let expired = self
            .book
            .take_expired(now, |device| cache.is_online(device));
        for command in expired {
            self.plans.remove(&command.id);
            self.report_end(&command, false);
            self.counters.commands_expired += 1;
            let detail = format!(
                "device {} stayed offline for {} (the command's time to live)",
                command.device,
                humantime::format_duration(self.options.command_ttl)
            );
            log_outcome(
                &command.device,
                &command.field,
                &command.value,
                Outcome::Expired,
                &detail,
            );
            let result = CommandResult::new(&command.value, Outcome::Expired, detail);
            self.finish_with(&command.device, &command.field, result);
        }
        self.dispatch_ready(now);
        if self.reannounce_at.is_some_and(|at| at <= now) {
            self.reannounce_at = None;
            self.publish_discovery();
            let updates = self.cache.republish_all();
            self.publish_state(updates);
        }
        self.reassert_due(now);
        if self.connected && (self.stats_due || now >= self.next_stats) {
            self.stats_due = false;
            self.next_stats = now + self.options.stats_interval;
            // Retained: the gateway's Home Assistant sensors (and any client arriving later)
            // read the last document at once instead of waiting up to a statistics interval.
            let document = metrics::stats_json(&line_stats(), &self.counters(now));
            self.publish(
                self.topics.gateway_stats_topic(),
                document.to_string(),
                true,
            );
        }
        self.take()
    }

    // ----- stop -----

    /// The last words: every device and the gateway `offline`. Waiting commands stay retained
    /// in the broker for the next start.
    pub fn on_stop(&mut self) -> Vec<Action> {
        self.drop_uncleared();
        let waiting = self.book.drain_waiting();
        self.plans.clear();
        self.external.clear();
        if !waiting.is_empty() {
            tracing::info!(
                count = waiting.len(),
                "waiting commands left for the next start"
            );
        }
        for device in self.cache.devices().to_vec() {
            let topic = self.topics.availability_topic(&device);
            self.publish(topic, OFFLINE.to_string(), true);
        }
        self.publish(
            self.topics.gateway_status_topic(),
            OFFLINE.to_string(),
            true,
        );
        self.take()
    }
}

/// A topic this gateway owns and defends.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Guarded {
    Status,
    Availability(String),
    State(String, String),
}

/// Defence of the gateway's topics, unknown devices, load shedding and at-most-once actions.
impl Core {
    /// Tells the core whether the driver keeps up with what it is asked to publish.
    pub fn set_overloaded(&mut self, overloaded: bool) {
        self.overloaded = overloaded;
    }

    fn subscribe_guarded(&mut self) {
        self.subscribe(self.topics.gateway_status_topic());
        self.subscribe(self.topics.device_topics_filter());
    }

    fn guarded(&self, topic: &str) -> Option<Guarded> {
        if topic == self.topics.gateway_status_topic() {
            return Some(Guarded::Status);
        }
        let (device, level) = self.topics.parse_device_topic(topic)?;
        let entry = self.devices.get(device)?;
        if level == crate::contract::AVAILABILITY {
            return Some(Guarded::Availability(device.to_string()));
        }
        entry.profile.field(level)?;
        Some(Guarded::State(device.to_string(), level.to_string()))
    }

    /// What the topic must say now; None when there is nothing to defend yet.
    fn truth(&self, guarded: &Guarded) -> Option<String> {
        match guarded {
            Guarded::Status => self.connected.then(|| ONLINE.to_string()),
            Guarded::Availability(device) => {
                Some(availability_word(self.cache.is_online(device)).to_string())
            }
            Guarded::State(device, field) => {
                self.cache.published_text(device, field).map(str::to_string)
            }
        }
    }

    fn on_guarded(&mut self, guarded: Guarded, topic: &str, payload: &[u8], now: Instant) {
        let Some(truth) = self.truth(&guarded) else {
            return;
        };
        let seen = String::from_utf8_lossy(payload);
        if self.guard.judge(topic, &seen, &truth, now) == Verdict::Reassert {
            self.counters.topics_reasserted += 1;
            self.publish(topic.to_string(), truth, true);
        }
    }

    /// Topics overwritten again too soon, now that their interval has passed.
    fn reassert_due(&mut self, now: Instant) {
        for topic in self.guard.due(now) {
            let truth = self.guarded(&topic).and_then(|g| self.truth(&g));
            if let Some(truth) = truth {
                self.counters.topics_reasserted += 1;
                self.publish(topic, truth, true);
            }
        }
    }

    /// A command on our topic shape for a device that is not configured: rejected, naming the
    /// configured devices, unless another gateway announces that device under our prefix. Its
    /// retained copy is left alone (it may be meant for a gateway that is not running now).
    fn reject_unknown_device(&mut self, device: &str, field: &str, payload: &[u8]) {
        self.counters.unknown_device_commands += 1;
        if self.foreign_devices.contains(device) || payload.is_empty() {
            tracing::debug!(%device, "command for another gateway's device");
            return;
        }
        let shown = payload::echo(payload);
        let reason = format!(
            "unknown device {device:?}: this gateway has {}",
            self.cache.devices().join(", ")
        );
        // Not configured here: a typo in the topic or a device missing from the configuration.
        tracing::warn!(%device, %field, value = ?shown, detail = ?reason, "command for a device that is not configured: rejected");
        self.counters.commands_rejected += 1;
        let result = CommandResult::new(&shown, Outcome::Rejected, reason);
        let topic = self.topics.result_topic(device, field);
        self.publish_or_keep(topic, result.to_json(), false);
    }

    /// Load shedding: the command is refused at once, with its outcome, and the log says so at
    /// most once per [`SHED_LOG_INTERVAL`] with the count.
    fn shed(&mut self, device: &str, field: &str, payload: &[u8], now: Instant) {
        self.counters.commands_shed += 1;
        self.shed_unlogged += 1;
        if self.shed_logged_at.map_or(true, |at| {
            now.saturating_duration_since(at) >= SHED_LOG_INTERVAL
        }) {
            tracing::warn!(
                shed = self.shed_unlogged,
                "overloaded: commands refused until the MQTT link catches up"
            );
            self.shed_logged_at = Some(now);
            self.shed_unlogged = 0;
        }
        let shown = payload::echo(payload);
        self.counters.commands_rejected += 1;
        let result = CommandResult::new(
            &shown,
            Outcome::Rejected,
            "gateway overloaded: the command was not run; send it again later",
        );
        let topic = self.topics.result_topic(device, field);
        self.publish_or_keep(topic, result.to_json(), false);
        let set = self.topics.command_topic(device, field);
        self.publish_or_keep(set, String::new(), true);
    }

    /// An action that must not run twice: its (possibly retained) command is cleared first, and
    /// the command goes to the line only when the broker passes that clearing back to us. A
    /// crash before then loses the action (at most once); a crash after cannot replay it.
    fn clear_then_send(&mut self, line: usize, command: Command, tracked: TrackedCommand) {
        let set = self.topics.command_topic(&tracked.device, &tracked.field);
        tracing::debug!(device = %tracked.device, field = %tracked.field,
            "clearing the command before the action runs");
        self.on_bus.insert(tracked.id, tracked);
        self.clearing.insert(set.clone(), (line, command));
        self.publish_or_keep(set, String::new(), true);
    }

    /// An empty message on `set`: an action waiting for its clearing may run now. The broker
    /// delivers one topic's messages in order, so it was published after the command.
    fn on_cleared(&mut self, set: &str) {
        if let Some((line, command)) = self.clearing.remove(set) {
            tracing::debug!(device = %command.device, "command cleared: handed to the line");
            self.out.push(Action::Send { line, command });
        }
    }

    /// After a reconnect, clear again what may not have reached the broker.
    fn clear_again(&mut self) {
        let topics: Vec<String> = self.clearing.keys().cloned().collect();
        for set in topics {
            self.publish_or_keep(set, String::new(), true);
        }
    }

    /// Stopping: actions still waiting for their clearing never ran.
    fn drop_uncleared(&mut self) {
        let waiting: Vec<(String, (usize, Command))> = self.clearing.drain().collect();
        for (_, (_, command)) in waiting {
            if let Some(tracked) = self.on_bus.remove(&command.id) {
                self.counters.commands_failed += 1;
                let result = CommandResult::new(
                    &tracked.value,
                    Outcome::Failed,
                    "the gateway stopped before the action was sent",
                );
                let topic = self.topics.result_topic(&tracked.device, &tracked.field);
                self.publish_or_keep(topic, result.to_json(), false);
            }
        }
    }
}
#[path = "core_reconfigure.rs"]
mod reconfigure;

#[cfg(test)]
#[path = "core_tests.rs"]
mod tests;
