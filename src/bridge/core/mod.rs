//! The bridge's decisions, without I/O: every handler takes one event (the MQTT link up or
//! down, an incoming message, a line event, a tick, a send the driver could not make, a
//! reload) with the time passed in, and returns the [`Action`]s to carry out (publish,
//! subscribe, hand a command to a line, report). Nothing here touches the network, a channel
//! or the clock, and its one random choice (the delay before re-announcing discovery) comes
//! from the generator it is given, so equal inputs give equal actions; the driver
//! (`bridge::driver`) owns the I/O and only executes what it is told.
//!
//! The core routes each event to its two halves: the [`CommandDesk`] (commands from arrival
//! to result) and the [`Publisher`] (the state cache and what is published from it, results
//! kept while MQTT is down, the defence of our topics). It keeps what is neither's: the
//! connection counters, the statistics document's cadence and Home Assistant's re-announcement.
//! Commands from outside the plain topics (a Sparkplug DCMD, [`Core::on_external_command`])
//! go through the same desk, with their results on `…/result` too, and their end reported
//! back ([`Action::Report`]).
//!
//! Its parts: [`command_desk`] and [`command_book`] (the commands), [`payload`] (what a `…/set` carries
//! and a result says), [`publisher`] with [`state`] and [`json_view`] (the published state),
//! [`discovery`] with [`entity_naming`], [`ha_templates`] and [`action_entities`] (Home Assistant), [`topic_guard`] (our retained topics
//! defended), [`action`] and [`bridge_device`] (what the core gives and is given).

pub(crate) mod action;
pub mod action_entities;
pub(crate) mod bridge_device;
pub(crate) mod command_book;
pub(crate) mod command_desk;
pub mod discovery;
mod entity_naming;
mod ha_templates;
pub mod json_view;
pub mod payload;
pub(crate) mod publisher;
pub mod state;
#[cfg(test)]
mod tests;
pub(crate) mod topic_guard;

use std::time::{Duration, Instant};

use rand::rngs::StdRng;
use rumqttc::QoS;

use self::command_desk::{CommandDesk, SetMessage};
use self::publisher::Publisher;
use crate::bridge::observers::statistics::{self, BridgeStats, HistoryStats};
use crate::bus::{Command, LineEvent, LineStats, Origin};
use crate::config::{Config, GatewayOptions};
use rtu2mqtt_profile::contract::{is_ha_online, Topics};

pub use self::action::{Action, CommandReport, HistoryEntry, Publish};
pub use self::bridge_device::BridgeDevice;

/// A command that did not come from a plain `…/set` topic (a Sparkplug DCMD): the field and
/// the command text as `…/set` would carry it (`ON`, `8`, `12.5`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExternalCommand {
    pub device: String,
    pub field: String,
    pub text: String,
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

/// A message on `<prefix>/<device>/refresh`. A live one (any payload but the empty clearing)
/// sends the device's line a refresh request; one from the broker's retained store is stale,
/// so it is ignored. Either is then cleared (an empty retained message), like a command: MQTT
/// 3.1.1 does not say whether a live message was retained, and a retained copy left behind
/// would be a stale request at the next subscription. Devices that are not ours are left
/// alone.
fn on_refresh(p: &mut Publisher, device: &str, message: Incoming<'_>) {
    let Some(line) = p.devices().get(device).map(|entry| entry.line) else {
        tracing::debug!(%device, "refresh for a device that is not ours");
        return;
    };
    if message.payload.is_empty() {
        return;
    }
    if message.retain {
        tracing::info!(%device, "a retained refresh request is ignored and cleared");
    } else {
        tracing::info!(%device, "refresh requested");
        p.push(Action::Refresh {
            line,
            device: device.to_string(),
        });
    }
    let topic = p.topics().refresh_topic(device);
    p.publish_or_keep(topic, String::new(), true);
}

/// What the core is built from.
#[derive(Debug, Clone)]
pub struct CoreSettings {
    pub topics: Topics,
    /// Home Assistant discovery is published.
    pub discovery: bool,
    pub options: GatewayOptions,
    /// Change sets go to the history stream (`[history]`).
    pub history: bool,
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
            history: config.history.is_some(),
            line_names: config.lines.iter().map(|line| line.name.clone()).collect(),
            devices,
        }
    }
}

/// The bridge's state and rules: the command desk, the publisher, and the timing of what
/// goes out on its own (statistics, the re-announcement after Home Assistant's birth).
#[derive(Debug)]
pub struct Core {
    commands: CommandDesk,
    publisher: Publisher,
    /// How often the statistics document goes out.
    stats_interval: Duration,
    mqtt_connects: u64,
    mqtt_disconnects: u64,
    /// Re-announce discovery at this instant (after Home Assistant's birth message).
    reannounce_at: Option<Instant>,
    started: Instant,
    next_stats: Instant,
    /// Statistics go out on the next tick (start, reconnect, Home Assistant's birth).
    stats_due: bool,
    /// Picks the re-announcement delay; passed in so the core is deterministic.
    rng: StdRng,
    /// The history journal's health, as the driver last told it.
    history: Option<HistoryStats>,
    /// The driver does not keep up with what it is asked to publish: announcing waits.
    overloaded: bool,
    /// The documents of the last announcements have left the driver's outbox (they wait
    /// behind state and outcomes): the next may be built.
    announce_room: bool,
    /// Publishes refused for their size, as the driver last told it.
    oversized_refused: u64,
}

impl Core {
    /// A core started at `now`, drawing its random choices from `rng` (seeded from entropy
    /// in the daemon, from a fixed seed in tests).
    pub fn new(settings: CoreSettings, now: Instant, rng: StdRng) -> Self {
        let options = settings.options;
        Core {
            commands: CommandDesk::new(options.command_ttl, options.max_payload),
            publisher: Publisher::new(
                settings.topics,
                settings.discovery,
                options.json_view,
                settings.history,
                settings.line_names,
                settings.devices,
            ),
            mqtt_connects: 0,
            mqtt_disconnects: 0,
            reannounce_at: None,
            started: now,
            next_stats: now + options.stats_interval,
            stats_due: true,
            stats_interval: options.stats_interval,
            rng,
            history: None,
            overloaded: false,
            announce_room: true,
            oversized_refused: 0,
        }
    }

    pub fn topics(&self) -> &Topics {
        self.publisher.topics()
    }

    pub fn is_connected(&self) -> bool {
        self.publisher.is_connected()
    }

    /// Commands handed to a line whose end has not been reported yet.
    pub fn commands_on_bus(&self) -> usize {
        self.commands.commands_on_bus()
    }

    /// The counters as shared: uptime and connection state filled in.
    pub fn counters(&self, now: Instant) -> BridgeStats {
        let published = self.publisher.counters();
        BridgeStats {
            uptime: now.saturating_duration_since(self.started),
            mqtt_connected: self.publisher.is_connected(),
            mqtt_connects: self.mqtt_connects,
            mqtt_disconnects: self.mqtt_disconnects,
            published: published.published,
            publish_failures: published.publish_failures,
            topics_reasserted: published.topics_reasserted,
            waiting_commands: self.commands.waiting() as u64,
            history: self.history,
            oversized_refused: self.oversized_refused,
            ..self.commands.counters().clone()
        }
    }

    // ----- MQTT link -----

    /// Every ConnAck: everything is published again, then what waited, then the clearings
    /// that may not have reached the broker.
    pub fn on_connected(&mut self) -> Vec<Action> {
        self.mqtt_connects += 1;
        self.stats_due = true;
        self.publisher.connected();
        self.commands.clear_again(&mut self.publisher);
        self.publisher.take()
    }

    pub fn on_disconnected(&mut self) {
        if self.publisher.is_connected() {
            self.mqtt_disconnects += 1;
        }
        self.publisher.disconnected();
    }

    /// The driver's report on one [`Action::Publish`]: `sent` when the client queued it.
    pub fn on_published(&mut self, publish: Publish, sent: bool) {
        self.publisher.on_published(publish, sent);
    }

    /// The driver handed a publish to the client (the same as [`Core::on_published`] with
    /// `sent`, without the publish).
    pub fn on_handed(&mut self) {
        self.publisher.on_handed();
    }

    /// Tells the core the history journal's health, for the statistics.
    pub fn set_history_stats(&mut self, stats: HistoryStats) {
        self.history = Some(stats);
    }

    /// Tells the core how many publishes the packet limit has refused, for the statistics.
    pub fn set_oversized_refused(&mut self, refused: u64) {
        self.oversized_refused = refused;
    }

    /// Tells the core whether the discovery documents announced last have left the driver's
    /// outbox: announcing goes on only then, so that documents never pile up there.
    pub fn set_announce_room(&mut self, room: bool) {
        self.announce_room = room;
    }

    /// Lines or devices wait to be announced on the connection.
    pub fn is_announcing(&self) -> bool {
        self.publisher.is_announcing()
    }

    /// The driver's outbox has taken what was announced last: the next few lines or devices
    /// are announced now rather than at the next tick (unless the driver does not keep up), so
    /// that a connect's announcing goes as fast as the broker takes it while the outbox holds
    /// little of it at any time.
    pub fn on_announce_room(&mut self) -> Vec<Action> {
        if !self.overloaded {
            self.publisher
                .continue_announcing_up_to(publisher::ANNOUNCE_ON_ROOM);
        }
        self.publisher.take()
    }

    /// Tells the core whether the driver keeps up with what it is asked to publish.
    pub fn set_overloaded(&mut self, overloaded: bool) {
        self.overloaded = overloaded;
        self.commands.set_overloaded(overloaded);
    }

    // ----- line events -----

    pub fn on_line_event(&mut self, event: LineEvent, now: Instant) -> Vec<Action> {
        let p = &mut self.publisher;
        match event {
            LineEvent::Values {
                device,
                values,
                read_at,
                origin,
            } => p.values(&device, values, read_at, origin == Origin::Heartbeat),
            LineEvent::Availability { device, online } => {
                p.availability(&device, online);
                if online {
                    self.commands.dispatch_ready(p, now);
                }
            }
            LineEvent::Written { device, fields, at } => {
                self.commands.on_written(&device, &fields, at)
            }
            LineEvent::CommandFinished { id, outcome, .. } => {
                self.commands.on_finished(p, id, outcome, now)
            }
            LineEvent::ClientWriteFinished {
                device,
                field,
                value,
                client,
                outcome,
            } => self
                .commands
                .on_client_write(p, &device, &field, &value, &client, outcome),
        }
        p.take()
    }

    // ----- incoming messages -----

    pub fn on_message(&mut self, message: Incoming<'_>, now: Instant) -> Vec<Action> {
        self.route(message, now);
        self.publisher.take()
    }

    fn route(&mut self, message: Incoming<'_>, now: Instant) {
        let topic = message.topic;
        let p = &mut self.publisher;
        if p.discovery() {
            if topic == p.topics().ha_status_topic() {
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
            if p.topics().device_of_config_topic(topic).is_some() {
                p.on_config(topic, message.payload);
                return;
            }
            if let Some(line) = p.topics().line_of_config_topic(topic) {
                p.on_line_config(topic, line, message.payload);
                return;
            }
        }
        if let Some(guarded) = p.guarded(topic) {
            p.on_guarded(guarded, topic, message.payload, now);
            return;
        }
        if let Some(device) = p.topics().device_of_availability_topic(topic) {
            if !p.devices().contains_key(device) && !message.payload.is_empty() {
                self.commands.note_foreign(device);
            }
            return;
        }
        if let Some(device) = p.topics().device_of_refresh_topic(topic) {
            on_refresh(p, device, message);
            return;
        }
        let Some((device, field)) = p.topics().parse_command(topic) else {
            tracing::debug!(%topic, "not a command topic");
            return;
        };
        let set = SetMessage {
            topic,
            device,
            field,
            payload: message.payload,
            qos: message.qos,
            pkid: message.pkid,
            dup: message.dup,
            retain: message.retain,
        };
        self.commands.on_set(p, set, now);
    }

    /// A command from outside the plain topics (a Sparkplug DCMD metric turned into command
    /// text): the same validation, book and results as `…/set`, and its end is reported with
    /// an [`Action::Report`] so the sender can show the device's true value after a refusal.
    pub fn on_external_command(&mut self, command: ExternalCommand, now: Instant) -> Vec<Action> {
        let p = &mut self.publisher;
        self.commands
            .on_external(p, &command.device, &command.field, &command.text, now);
        p.take()
    }

    /// The driver could not hand `command` to its line: the line's queue is `full` (try again
    /// on the next tick), or the line has stopped.
    pub fn on_send_failed(&mut self, command: Command, full: bool) -> Vec<Action> {
        let p = &mut self.publisher;
        self.commands.on_send_failed(p, command, full);
        p.take()
    }

    // ----- time -----

    /// Expiries, waiting commands, the re-announcement after Home Assistant's birth and the
    /// statistics document. `line_stats` is asked only when statistics are due.
    pub fn on_tick(
        &mut self,
        now: Instant,
        line_stats: impl FnOnce() -> Vec<LineStats>,
    ) -> Vec<Action> {
        self.commands.on_tick(&mut self.publisher, now);
        if self.reannounce_at.is_some_and(|at| at <= now) {
            self.reannounce_at = None;
            self.publisher.reannounce();
        } else if !self.overloaded && self.announce_room {
            self.publisher.continue_announcing();
        }
        self.publisher.reassert_due(now);
        self.publisher.audit_turn(now);
        if self.publisher.is_connected() && (self.stats_due || now >= self.next_stats) {
            self.stats_due = false;
            self.next_stats = now + self.stats_interval;
            // Retained: the gateway's Home Assistant sensors (and any client arriving later)
            // read the last documents at once instead of waiting up to a statistics interval.
            // One document per line, so that none grows with the number of lines.
            let lines = line_stats();
            let summary = statistics::stats_json(&lines, &self.counters(now));
            let topic = self.publisher.topics().gateway_stats_topic();
            self.publisher.publish(topic, summary.to_string(), true);
            for line in &lines {
                let document = statistics::line_stats_json(line);
                let topic = self.publisher.topics().line_stats_topic(&line.line);
                self.publisher.publish(topic, document.to_string(), true);
            }
        }
        self.publisher.take()
    }

    // ----- reload -----

    /// The configuration was reloaded: `devices` (in configuration order) on the lines named
    /// `line_names` (in the order the driver's line handles now have). Removed devices are
    /// forgotten (their waiting commands fail, their retained topics are cleared), kept ones
    /// keep their waiting commands, new ones are announced. The topics and gateway options
    /// stay those of the start.
    pub fn on_reconfigure(
        &mut self,
        line_names: Vec<String>,
        devices: Vec<BridgeDevice>,
        now: Instant,
    ) -> Vec<Action> {
        let p = &mut self.publisher;
        let gone_lines: Vec<String> = p
            .line_names()
            .iter()
            .filter(|old| !line_names.contains(old))
            .cloned()
            .collect();
        for gone in gone_lines {
            tracing::info!(line = %gone, "line removed by the reload: clearing its statistics");
            let topic = p.topics().line_stats_topic(&gone);
            p.publish_or_keep(topic, String::new(), true);
            if p.discovery() {
                let topic = p.topics().line_config_topic(&gone);
                p.publish_or_keep(topic, String::new(), true);
            }
        }
        for name in p.cache().devices().to_vec() {
            let Some(old) = p.devices().get(&name).cloned() else {
                continue;
            };
            match devices.iter().find(|device| device.name == name) {
                None => {
                    tracing::info!(device = %name, "device removed by the reload: clearing its retained topics");
                    self.commands.forget_device(p, &name);
                    p.forget_device(&old);
                }
                Some(kept) => p.clear_dropped_fields(&old, kept),
            }
        }
        p.reconfigure(line_names, devices);
        self.commands.dispatch_ready(p, now);
        p.take()
    }

    // ----- stop -----

    /// The last words: every device and the gateway `offline`. Waiting commands stay retained
    /// in the broker for the next start.
    pub fn on_stop(&mut self) -> Vec<Action> {
        self.commands.stop(&mut self.publisher);
        self.publisher.stop();
        self.publisher.take()
    }
}
