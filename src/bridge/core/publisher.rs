//! The bridge core's publishing side, without I/O: the state cache and what the gateway
//! publishes from it (retained state, availability, JSON views, Home Assistant discovery),
//! results and clears kept while MQTT is down, the history stream's change sets, and the
//! defence of the gateway's own topics.
//! It collects the [`Action`]s of one event in order; the command desk's sends and reports
//! go into the same list, so that the driver carries them out in the order they were decided.

use std::collections::{HashMap, VecDeque};
use std::time::{Instant, SystemTime};

use rumqttc::QoS;

use super::action::{Action, HistoryEntry, Publish};
use super::bridge_device::{self, BridgeDevice, Devices};
use super::discovery;
use super::json_view::JsonView;
use super::state::{StateCache, StateUpdate};
use super::topic_guard::{GuardVerdict, TopicGuard};
use crate::history::document;
use crate::topics::{availability_word, TopicKind, Topics, OFFLINE, ONLINE};
use rtu2mqtt_profile::Value;

/// Results and clears kept while MQTT is down (older ones are dropped first).
const MAX_DEFERRED: usize = 1024;
/// Lines and devices announced at once (discovery documents; after a connect also each
/// device's availability, every state and the JSON view), and then as many on each tick
/// while the driver keeps up: a gateway with a thousand devices announces them over seconds
/// instead of building a hundred thousand messages in one turn of the loop that also serves
/// the lines.
pub(crate) const ANNOUNCE_BATCH: usize = 50;
/// Lines and devices announced between two ticks, once the driver's outbox has taken the
/// last ones ([`super::Core::on_announce_room`]).
pub(crate) const ANNOUNCE_ON_ROOM: usize = 10;

/// What is still to be announced: a line's discovery document; a device's, and with
/// `everything` its availability, every state and its JSON view.
#[derive(Debug)]
enum Announcement {
    Line(String),
    Device { device: String, everything: bool },
}

/// A topic this gateway owns and defends.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Guarded {
    Status,
    Availability(String),
    State(String, String),
}

/// Counts of what the publisher handed out and defended.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct PublishCounters {
    pub published: u64,
    pub publish_failures: u64,
    pub topics_reasserted: u64,
}

/// What the gateway publishes and keeps published.
#[derive(Debug)]
pub(crate) struct Publisher {
    topics: Topics,
    /// Home Assistant discovery is published.
    discovery: bool,
    /// Each device's JSON view is published.
    json_view: bool,
    /// Each change set goes to the history stream (`[history]`).
    history: bool,
    line_names: Vec<String>,
    /// The configured devices, by name; their order is the cache's.
    devices: Devices,
    connected: bool,
    cache: StateCache,
    /// Results and clears that wait for the next connection.
    deferred: VecDeque<Publish>,
    /// Each device's JSON view by its topic, with whether it changed since it was published.
    json_views: HashMap<String, JsonView>,
    /// Devices still to be announced, in configuration order.
    announcing: VecDeque<Announcement>,
    /// The status, availability and state topics this gateway defends.
    guard: TopicGuard,
    counters: PublishCounters,
    /// The actions of the event being handled, in order.
    out: Vec<Action>,
}

impl Publisher {
    /// A publisher for `devices` (in configuration order) on the lines named `line_names`.
    pub(crate) fn new(
        topics: Topics,
        discovery: bool,
        json_view: bool,
        history: bool,
        line_names: Vec<String>,
        devices: Vec<BridgeDevice>,
    ) -> Self {
        // The Last Will the MQTT connection registers (crate::bridge::driver::connection::options).
        let guard = TopicGuard::with_own_will(&topics.gateway_status_topic(), OFFLINE);
        Publisher {
            topics,
            discovery,
            json_view,
            history,
            line_names,
            cache: StateCache::with_profiles(devices.iter().map(|d| (d.name.as_str(), &d.profile))),
            devices: bridge_device::by_name(devices),
            connected: false,
            deferred: VecDeque::new(),
            json_views: HashMap::new(),
            announcing: VecDeque::new(),
            guard,
            counters: PublishCounters::default(),
            out: Vec::new(),
        }
    }

    pub(crate) fn topics(&self) -> &Topics {
        &self.topics
    }

    pub(crate) fn devices(&self) -> &Devices {
        &self.devices
    }

    /// The configured lines' names, in order.
    pub(crate) fn line_names(&self) -> &[String] {
        &self.line_names
    }

    pub(crate) fn cache(&self) -> &StateCache {
        &self.cache
    }

    pub(crate) fn is_connected(&self) -> bool {
        self.connected
    }

    pub(crate) fn discovery(&self) -> bool {
        self.discovery
    }

    pub(crate) fn counters(&self) -> PublishCounters {
        self.counters
    }

    /// Adds an action that is not a publication (a send to a line, a report) in its place.
    pub(crate) fn push(&mut self, action: Action) {
        self.out.push(action);
    }

    /// The actions of the event, in order.
    pub(crate) fn take(&mut self) -> Vec<Action> {
        std::mem::take(&mut self.out)
    }

    /// Every ConnAck: subscriptions are not restored by rumqttc, and a clean session has lost
    /// whatever was unacknowledged, so everything is sent again, and what waited goes out.
    /// State topics are not subscribed to: they are audited one device at a time
    /// ([`Self::audit_turn`]).
    pub(crate) fn connected(&mut self) {
        self.connected = true;
        // A persistent session keeps what an earlier connection subscribed to: the audit the
        // lost connection interrupted, and every device's topics as earlier versions watched
        // them.
        if let Some(device) = self.guard.reset() {
            self.out.push(Action::UnsubscribeInTurn {
                filter: self.topics.device_filter(&device),
            });
        }
        self.out.push(Action::UnsubscribeInTurn {
            filter: self.topics.device_topics_filter(),
        });
        self.subscribe(self.topics.command_filter());
        self.subscribe(self.topics.gateway_status_topic());
        self.subscribe(self.topics.availability_filter());
        self.subscribe(self.topics.refresh_filter());
        if self.discovery {
            // Home Assistant's birth message, and our own earlier configs (to remove those of
            // devices no longer configured).
            self.subscribe(self.topics.ha_status_topic());
            self.subscribe(self.topics.config_filter());
            self.subscribe(self.topics.line_config_filter());
        }
        self.publish(self.topics.gateway_status_topic(), ONLINE.to_string(), true);
        self.json_views.values_mut().for_each(JsonView::mark_stale);
        self.cache.forget_all_published();
        self.announce(true);
        while let Some(kept) = self.deferred.pop_front() {
            self.out.push(Action::Publish(kept));
        }
    }

    pub(crate) fn disconnected(&mut self) {
        self.connected = false;
        // The next connection announces every device again.
        self.announcing.clear();
        self.cache.clear_awaiting_turns();
    }

    /// The driver's report on one [`Action::Publish`]: `sent` when the client queued it.
    pub(crate) fn on_published(&mut self, publish: Publish, sent: bool) {
        if sent {
            self.on_handed();
            return;
        }
        self.counters.publish_failures += 1;
        if let Some(view) = self.json_views.get_mut(&publish.topic) {
            view.mark_stale();
        }
        if publish.keep {
            self.keep(publish);
        }
    }

    /// A publish handed to the client.
    pub(crate) fn on_handed(&mut self) {
        self.counters.published += 1;
    }

    fn subscribe(&mut self, filter: String) {
        self.out.push(Action::Subscribe {
            filter,
            qos: QoS::AtLeastOnce,
        });
    }

    /// A QoS 1 publish when connected; false when there is no connection to send it on.
    pub(crate) fn publish(&mut self, topic: String, payload: String, retain: bool) -> bool {
        if !self.connected {
            return false;
        }
        if retain && self.guarded(&topic).is_some_and(|g| self.is_watched(&g)) {
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
    pub(crate) fn publish_or_keep(&mut self, topic: String, payload: String, retain: bool) {
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
    /// configured device (see [`Publisher::announce`]).
    pub(crate) fn publish_discovery(&mut self) {
        self.announce(false);
    }

    /// The gateway's discovery document, then each configured device's and each line's
    /// announcement (with `everything`: the device's availability, states and JSON view too):
    /// the first [`ANNOUNCE_BATCH`] at once, the rest by [`Publisher::continue_announcing`].
    /// A device already waiting keeps what it was to get.
    fn announce(&mut self, everything: bool) {
        let mut announcing = VecDeque::new();
        if self.discovery {
            let (topic, document) = discovery::gateway_config(&self.topics);
            self.publish(topic, document.to_string(), true);
        } else if !everything {
            return;
        }
        let waiting_everything: std::collections::HashSet<&str> = self
            .announcing
            .iter()
            .filter_map(|announcement| match announcement {
                Announcement::Device {
                    device,
                    everything: true,
                } => Some(device.as_str()),
                _ => None,
            })
            .collect();
        announcing.extend(
            self.cache
                .devices()
                .iter()
                .map(|device| Announcement::Device {
                    everything: everything || waiting_everything.contains(device.as_str()),
                    device: device.clone(),
                }),
        );
        if self.discovery {
            announcing.extend(self.line_names.iter().cloned().map(Announcement::Line));
        }
        for announcement in &announcing {
            if let Announcement::Device { device, everything } = announcement {
                self.cache.set_awaiting_turn(device, *everything);
            }
        }
        self.announcing = announcing;
        self.continue_announcing();
    }

    /// The next [`ANNOUNCE_BATCH`] lines or devices still to be announced. Each discovery
    /// document is built when it is published, from the device's state then (its identity
    /// fields). A device announced with `everything` publishes nothing of its own before its
    /// turn: what it read by then goes out in the turn, each field once.
    pub(crate) fn continue_announcing(&mut self) {
        self.continue_announcing_up_to(ANNOUNCE_BATCH);
    }

    /// Lines or devices wait to be announced on the connection.
    pub(crate) fn is_announcing(&self) -> bool {
        self.connected && !self.announcing.is_empty()
    }

    /// The next `count` lines or devices still to be announced (see
    /// [`Publisher::continue_announcing`]).
    pub(crate) fn continue_announcing_up_to(&mut self, count: usize) {
        if !self.connected {
            return;
        }
        for _ in 0..count {
            let (device, everything) = match self.announcing.pop_front() {
                None => return,
                Some(Announcement::Line(line)) => {
                    let (topic, document) = discovery::line_config(&self.topics, &line);
                    self.publish(topic, document.to_string(), true);
                    continue;
                }
                Some(Announcement::Device { device, everything }) => (device, everything),
            };
            if let Some(entry) = self.devices.get(&device).filter(|_| self.discovery) {
                let (topic, document) = discovery::device_config_with_state(
                    &self.topics,
                    &device,
                    &entry.profile,
                    self.cache.state(&device).as_ref(),
                );
                self.publish(topic, document.to_string(), true);
            }
            if everything {
                let word = availability_word(self.cache.is_online(&device));
                let topic = self.topics.availability_topic(&device);
                self.publish(topic, word.to_string(), true);
                let updates = self.cache.republish(&device);
                self.publish_state(updates);
                if self.json_view {
                    self.publish_json_view(&device);
                }
            }
        }
    }

    /// Discovery and every state again (after Home Assistant's birth message).
    pub(crate) fn reannounce(&mut self) {
        self.cache.forget_all_published();
        self.announce(true);
    }

    /// The device's JSON view on `<prefix>/<device>`, when it changed.
    fn publish_json_view(&mut self, device: &str) {
        if !self.connected {
            return;
        }
        let topic = self.topics.json_view_topic(device);
        let Some(payload) = self
            .json_views
            .get_mut(&topic)
            .and_then(JsonView::take_payload)
        else {
            return;
        };
        self.publish(topic, payload, true);
    }

    /// A line's fresh values of `device`, read at `read_at`: the state that changed, the
    /// discovery document when the device's identity changed, its JSON view, and the values
    /// that changed on the history stream (connected or not: what is measured while the
    /// broker is away goes to the journal). A heartbeat (`again`) publishes its values, the
    /// JSON view and a history entry even where nothing changed.
    pub(crate) fn values(
        &mut self,
        device: &str,
        values: Vec<(String, Value)>,
        read_at: SystemTime,
        again: bool,
    ) {
        if self.history {
            self.history_entry(device, &values, read_at, again);
        }
        if let Some(known) = self.cache.known(device).filter(|_| self.json_view) {
            let view = self
                .json_views
                .entry(self.topics.json_view_topic(device))
                .or_default();
            // Only what moved is rendered again.
            for (field, value) in &values {
                if known.get(field) != Some(value) {
                    view.set(field, value);
                }
            }
            if again && self.connected {
                view.mark_stale();
            }
        }
        // A device waiting for its turn is published in full then.
        let publishing = self.connected && !self.cache.awaits_turn(device);
        if again && publishing {
            self.cache
                .forget_published(device, values.iter().map(|(field, _)| field.as_str()));
        }
        let updates = self.cache.update(device, values, self.connected);
        if let Some((topic, document)) = self
            .devices
            .get(device)
            .filter(|_| self.discovery)
            .filter(|entry| discovery::identity_changed(device, &entry.profile, &updates))
            .map(|entry| {
                discovery::device_config_with_state(
                    &self.topics,
                    device,
                    &entry.profile,
                    self.cache.state(device).as_ref(),
                )
            })
        {
            self.publish(topic, document.to_string(), true);
        }
        self.publish_state(updates);
        if self.json_view && publishing {
            self.publish_json_view(device);
        }
    }

    /// The change set of `values` against the device's known state, as a history entry.
    fn history_entry(
        &mut self,
        device: &str,
        values: &[(String, Value)],
        read_at: SystemTime,
        again: bool,
    ) {
        let known = self.cache.known(device);
        if known.is_none() && !self.devices.contains_key(device) {
            return;
        }
        let changed: Vec<(&str, &Value)> = values
            .iter()
            .filter(|(field, value)| {
                again || known.and_then(|state| state.get(field)) != Some(value)
            })
            .map(|(field, value)| (field.as_str(), value))
            .collect();
        if changed.is_empty() {
            return;
        }
        let entry = HistoryEntry {
            device: device.to_string(),
            topic: self.topics.history_topic(device),
            at_ms: document::epoch_ms(read_at),
            document: document::document(read_at, changed),
        };
        self.out.push(Action::History(entry));
    }

    /// A line's word on `device`'s availability, published when it changed.
    pub(crate) fn availability(&mut self, device: &str, online: bool) {
        if self.cache.set_online(device, online) {
            tracing::info!(%device, online, "availability");
            let topic = self.topics.availability_topic(device);
            self.publish(topic, availability_word(online).to_string(), true);
        }
    }

    /// One of our own line documents (`line`'s) as the broker holds it: removed when its
    /// line is no longer configured.
    pub(crate) fn on_line_config(&mut self, line: &str, payload: &[u8]) {
        if !payload.is_empty() && !self.line_names.iter().any(|name| name == line) {
            let topic = self.topics.line_config_topic(line);
            tracing::info!(%topic, "removing the discovery config of a line no longer configured");
            self.publish(topic, String::new(), true);
        }
    }

    /// One of our own discovery documents (`device`'s) as the broker holds it: removed when
    /// its device is no longer configured.
    pub(crate) fn on_config(&mut self, device: &str, payload: &[u8]) {
        let configured = self.cache.devices();
        if discovery::is_stale_device_config(&self.topics, device, payload, configured) {
            let topic = self.topics.config_topic(device);
            tracing::info!(%topic, "removing the discovery config of a device no longer configured");
            self.publish(topic, String::new(), true);
        }
    }

    /// A message on `<prefix>/<device>/refresh`. A live one (any payload but the empty
    /// clearing) sends the device's line a refresh request; one from the broker's retained
    /// store (`retained`) is stale, so it is ignored. Either is then cleared (an empty retained
    /// message), like a command: MQTT 3.1.1 does not say whether a live message was retained,
    /// and a retained copy left behind would be a stale request at the next subscription.
    /// Devices that are not ours are left alone.
    pub(crate) fn on_refresh(&mut self, device: &str, payload: &[u8], retained: bool) {
        let Some(line) = self.devices.get(device).map(|entry| entry.line) else {
            tracing::debug!(%device, "refresh for a device that is not ours");
            return;
        };
        if payload.is_empty() {
            return;
        }
        if retained {
            tracing::info!(%device, "a retained refresh request is ignored and cleared");
        } else {
            tracing::info!(%device, "refresh requested");
            self.push(Action::Refresh {
                line,
                device: device.to_string(),
            });
        }
        let topic = self.topics.refresh_topic(device);
        self.publish_or_keep(topic, String::new(), true);
    }

    // ----- defence of the gateway's topics -----

    /// The topic as one this gateway defends, if it is one.
    pub(crate) fn guarded(&self, topic: &str) -> Option<Guarded> {
        self.guarded_kind(self.topics.classify(topic))
    }

    /// A topic of this kind as one this gateway defends, if it is one: its status, and the
    /// availability and state of its devices' fields.
    pub(crate) fn guarded_kind(&self, kind: TopicKind<'_>) -> Option<Guarded> {
        match kind {
            TopicKind::GatewayStatus { gateway } if gateway == self.topics.client_id => {
                Some(Guarded::Status)
            }
            TopicKind::Availability { device } if self.devices.contains_key(device) => {
                Some(Guarded::Availability(device.to_string()))
            }
            TopicKind::State { device, field } => {
                self.devices.get(device)?.profile.field(field)?;
                Some(Guarded::State(device.to_string(), field.to_string()))
            }
            _ => None,
        }
    }

    /// The topic of what this gateway defends.
    fn guarded_topic(&self, guarded: &Guarded) -> String {
        match guarded {
            Guarded::Status => self.topics.gateway_status_topic(),
            Guarded::Availability(device) => self.topics.availability_topic(device),
            Guarded::State(device, field) => self.topics.state_topic(device, field),
        }
    }

    /// Whether the broker hands this gateway what is published on the topic now: the status
    /// and availability always, a state topic only while its device is audited.
    fn is_watched(&self, guarded: &Guarded) -> bool {
        match guarded {
            Guarded::Status | Guarded::Availability(_) => true,
            Guarded::State(device, _) => self.guard.audited() == Some(device.as_str()),
        }
    }

    /// The state audit's turn (every tick while connected): the audit whose window has passed
    /// ends, the next device's begins. Both go behind what is queued, so the broker hands
    /// over the device's topics as the gateway's earlier publishes left them.
    pub(crate) fn audit_turn(&mut self, now: Instant) {
        if !self.connected {
            return;
        }
        let topics = &self.topics;
        let devices = &self.devices;
        // A device's state topics, its availability and its refresh topic.
        let topics_of = |device: &str| {
            devices
                .get(device)
                .map_or(0, |entry| entry.profile.fields().len() + 2)
        };
        let turn = self
            .guard
            .audit_turn(self.cache.devices(), now, topics_of, |device, topic| {
                // Availability is watched all the time: its echoes still come.
                match topics.classify(topic) {
                    TopicKind::State { device: owner, .. }
                    | TopicKind::Refresh { device: owner }
                    | TopicKind::History { device: owner } => owner == device,
                    _ => false,
                }
            });
        if let Some(device) = turn.ended {
            self.out.push(Action::UnsubscribeInTurn {
                filter: self.topics.device_filter(&device),
            });
        }
        if let Some(device) = turn.started {
            self.out.push(Action::SubscribeInTurn {
                filter: self.topics.device_filter(&device),
                qos: QoS::AtLeastOnce,
            });
        }
    }

    /// What the topic must say now; None when there is nothing to defend yet.
    fn truth(&self, guarded: &Guarded) -> Option<String> {
        match guarded {
            Guarded::Status => self.connected.then(|| ONLINE.to_string()),
            Guarded::Availability(device) => {
                Some(availability_word(self.cache.is_online(device)).to_string())
            }
            Guarded::State(device, field) => self.cache.published_text(device, field),
        }
    }

    /// Another client wrote `payload` on a topic we defend: the truth goes back, unless it
    /// was overwritten again too soon (then later, [`Self::reassert_due`]).
    pub(crate) fn on_guarded(&mut self, guarded: Guarded, payload: &[u8], now: Instant) {
        // A state topic outside its audit: a late message of an audit that has ended, or of
        // a subscription an earlier connection left behind.
        if !self.is_watched(&guarded) {
            return;
        }
        let Some(truth) = self.truth(&guarded) else {
            return;
        };
        let topic = self.guarded_topic(&guarded);
        let seen = String::from_utf8_lossy(payload);
        if self.guard.judge(&topic, &seen, &truth, now) == GuardVerdict::Reassert {
            self.counters.topics_reasserted += 1;
            self.publish(topic, truth, true);
        }
    }

    /// Topics overwritten again too soon, now that their interval has passed.
    pub(crate) fn reassert_due(&mut self, now: Instant) {
        for topic in self.guard.due(now) {
            let truth = self.guarded(&topic).and_then(|g| self.truth(&g));
            if let Some(truth) = truth {
                self.counters.topics_reasserted += 1;
                self.publish(topic, truth, true);
            }
        }
    }

    // ----- reload and stop -----

    /// A reload kept `kept`, configured before as `before`: the state of fields its new
    /// profile no longer has is cleared.
    pub(crate) fn clear_dropped_fields(&mut self, before: &BridgeDevice, kept: &BridgeDevice) {
        for field in before.profile.fields() {
            if kept.profile.field(&field.name).is_none() {
                let topic = self.topics.state_topic(&before.name, &field.name);
                self.publish_or_keep(topic, String::new(), true);
            }
        }
    }

    /// A reload's devices (in configuration order) on the lines named `line_names`: they
    /// replace the old ones, discovery goes out again and the availability of devices that
    /// are new is published.
    pub(crate) fn reconfigure(&mut self, line_names: Vec<String>, devices: Vec<BridgeDevice>) {
        let added: Vec<String> = devices
            .iter()
            .filter(|device| !self.devices.contains_key(&device.name))
            .map(|device| device.name.clone())
            .collect();
        self.cache.reconfigure(
            devices
                .iter()
                .map(|device| (device.name.as_str(), &device.profile)),
        );
        self.devices = bridge_device::by_name(devices);
        self.line_names = line_names;
        self.publish_discovery();
        for device in added {
            tracing::info!(%device, "device added by the reload");
            let word = availability_word(self.cache.is_online(&device));
            let topic = self.topics.availability_topic(&device);
            self.publish(topic, word.to_string(), true);
        }
    }

    /// A device removed by a reload: its retained topics are cleared (state of every field,
    /// availability, JSON view, discovery document). Results are not retained, so none is
    /// left to clear.
    pub(crate) fn forget_device(&mut self, device: &BridgeDevice) {
        let name = device.name.as_str();
        // An announcement still queued for it would publish on the topics cleared here.
        self.announcing.retain(|announcement| {
            !matches!(announcement, Announcement::Device { device, .. } if device == name)
        });
        let mut cleared = Vec::new();
        for field in device.profile.fields() {
            cleared.push(self.topics.state_topic(name, &field.name));
        }
        cleared.push(self.topics.availability_topic(name));
        if self.json_view {
            let topic = self.topics.json_view_topic(name);
            self.json_views.remove(&topic);
            cleared.push(topic);
        }
        if self.discovery {
            cleared.push(self.topics.config_topic(name));
        }
        for topic in cleared {
            self.publish_or_keep(topic, String::new(), true);
        }
    }

    /// The last words: every device and the gateway `offline`.
    pub(crate) fn stop(&mut self) {
        for device in self.cache.devices().to_vec() {
            let topic = self.topics.availability_topic(&device);
            self.publish(topic, OFFLINE.to_string(), true);
        }
        self.publish(
            self.topics.gateway_status_topic(),
            OFFLINE.to_string(),
            true,
        );
    }
}
