//! [`Core`]: the bridge's state and rules. Each event goes to one of its two halves, the
//! [`CommandDesk`] or the [`Publisher`]; an incoming message by the kind of its topic,
//! classified once ([`Topics::classify`]).

use std::time::{Duration, Instant};

use rand::rngs::StdRng;

use super::action::{Action, Publish};
use super::bridge_device::BridgeDevice;
use super::command_desk::{CommandDesk, SetMessage};
use super::discovery;
use super::incoming::{ExternalCommand, Incoming};
use super::publisher::{Publisher, ANNOUNCE_ON_ROOM};
use super::settings::CoreSettings;
use crate::bridge::observers::statistics::{self, BridgeStats, HistoryStats};
use crate::bus::{Command, LineEvent, LineStats, Origin};
use crate::topics::{is_ha_online, TopicKind, Topics};

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
            self.publisher.continue_announcing_up_to(ANNOUNCE_ON_ROOM);
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

    /// The message's topic is classified once, and its one handler gets what the topic
    /// names. Home Assistant's topics are looked at only with discovery on; what is left may
    /// be one of the topics this gateway defends.
    fn route(&mut self, message: Incoming<'_>, now: Instant) {
        let topic = message.topic;
        let p = &mut self.publisher;
        match p.topics().classify(topic) {
            TopicKind::HaStatus if p.discovery() => {
                if is_ha_online(message.payload) {
                    let delay = discovery::reannounce_delay(&mut self.rng);
                    tracing::info!(
                        ?delay,
                        "Home Assistant is online: discovery and state follow"
                    );
                    self.reannounce_at = Some(now + delay);
                    self.stats_due = true;
                }
            }
            TopicKind::Command { device, field } => {
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
            TopicKind::Availability { device } if !p.devices().contains_key(device) => {
                if !message.payload.is_empty() {
                    self.commands.note_foreign(device);
                }
            }
            TopicKind::Refresh { device } => p.on_refresh(device, message.payload, message.retain),
            TopicKind::LineConfig { line } if p.discovery() => {
                p.on_line_config(line, message.payload)
            }
            TopicKind::DeviceConfig { device } if p.discovery() => {
                p.on_config(device, message.payload)
            }
            kind => match p.guarded_kind(kind) {
                Some(guarded) => p.on_guarded(guarded, message.payload, now),
                None => tracing::debug!(%topic, "not a command topic"),
            },
        }
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
