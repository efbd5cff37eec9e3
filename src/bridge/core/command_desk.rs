//! The bridge core's command desk, without I/O: command validation (planned once, by the
//! device's profile), the [`CommandBook`] (waiting while offline, time to live, superseding,
//! write interval, QoS 1 redeliveries), the plans of waiting commands, the commands on the bus,
//! results on `…/result`, clearing of retained commands once they have an outcome (and before
//! an action that must not run twice), load shedding, and the ends of external commands. What
//! it publishes goes through the [`Publisher`], in the order it is decided.

use std::collections::{HashMap, HashSet};
use std::time::{Duration, Instant};

use rumqttc::QoS;

use super::action::{Action, CommandReport};
use super::command_book::{Admission, CommandBook, TrackedCommand};
use super::payload::{self, decode_command, CommandPayload, CommandResult, Outcome};
use super::publisher::Publisher;
use crate::bridge::observers::statistics::BridgeStats;
use crate::bus::{Command, CommandOutcome};
use rtu2mqtt_profile::CommandPlan;

/// Shortest time between two log lines about shed commands.
const SHED_LOG_INTERVAL: Duration = Duration::from_secs(10);

/// Where a command came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum CommandSource {
    /// `…/set`: its (possibly retained) message is cleared once it has an outcome.
    Plain,
    /// An external command (a Sparkplug DCMD): its end is reported.
    External,
}

/// `set` or `external`: how the log says where a command came from.
impl std::fmt::Display for CommandSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            CommandSource::Plain => "set",
            CommandSource::External => "external",
        })
    }
}

/// A command message on `…/set`, as much of it as the desk looks at.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SetMessage<'m> {
    pub topic: &'m str,
    pub device: &'m str,
    pub field: &'m str,
    pub payload: &'m [u8],
    pub qos: QoS,
    pub pkid: u16,
    pub dup: bool,
    /// Sent from the broker's retained store.
    pub retain: bool,
}

/// Load shedding: commands are refused while the driver cannot keep up.
#[derive(Debug, Default)]
struct Shedding {
    overloaded: bool,
    /// Shed commands not yet reported in the log, and when the log last spoke of them.
    unlogged: u64,
    logged_at: Option<Instant>,
}

/// The one INFO line of a command's arrival. `value` as sent (bounded by
/// [`payload::echo`]), logged with `?` so control characters cannot forge log lines.
fn log_received(device: &str, field: &str, value: &str, origin: CommandSource) {
    tracing::info!(%device, %field, ?value, via = %origin, "command received");
}

/// The one line of a command's end, its outcome and detail as words. INFO, except for the
/// outcomes that mean a valid command was not carried out (`failed`, `expired`): the device
/// or its line needs a look, so they are warnings.
/// The result word and detail of a command's end on the bus.
fn outcome_word(outcome: CommandOutcome) -> (Outcome, String) {
    match outcome {
        CommandOutcome::Applied { detail } => (Outcome::Applied, detail),
        CommandOutcome::NotApplied { detail } => (Outcome::NotApplied, detail),
        CommandOutcome::Rejected { detail } => (Outcome::Rejected, detail),
        CommandOutcome::Failed { cause } => (Outcome::Failed, cause.to_string()),
    }
}

fn log_outcome(device: &str, field: &str, value: &str, outcome: Outcome, detail: &str) {
    let word = outcome.word();
    if matches!(outcome, Outcome::Failed | Outcome::Expired) {
        tracing::warn!(%device, %field, ?value, outcome = %word, ?detail, "command finished");
    } else {
        tracing::info!(%device, %field, ?value, outcome = %word, ?detail, "command finished");
    }
}

/// Every command from its arrival to its result.
#[derive(Debug)]
pub(crate) struct CommandDesk {
    book: CommandBook,
    /// The plans of waiting commands, by command id (planned once, when validated).
    plans: HashMap<u64, CommandPlan>,
    /// Commands handed to a line, by id, until their end.
    on_bus: HashMap<u64, TrackedCommand>,
    /// Ids of booked commands that came from outside the plain topics.
    external: HashSet<u64>,
    /// Actions that must not run twice, by their `…/set` topic: handed to their line only once
    /// the broker has passed on our clearing of the (possibly retained) command.
    clearing: HashMap<String, (usize, Command)>,
    /// Devices another gateway announces availability for under our prefix: commands for them
    /// are that gateway's business.
    foreign_devices: HashSet<String>,
    shedding: Shedding,
    /// A command's time to live, for the words of its expiry.
    ttl: Duration,
    max_payload: usize,
    /// The command counters of [`BridgeStats`]; the other fields stay zero here.
    counters: BridgeStats,
}

impl CommandDesk {
    pub(crate) fn new(ttl: Duration, max_payload: usize) -> Self {
        CommandDesk {
            book: CommandBook::new(ttl),
            plans: HashMap::new(),
            on_bus: HashMap::new(),
            external: HashSet::new(),
            clearing: HashMap::new(),
            foreign_devices: HashSet::new(),
            shedding: Shedding::default(),
            ttl,
            max_payload,
            counters: BridgeStats::default(),
        }
    }

    /// Commands handed to a line whose end has not been reported yet.
    pub(crate) fn commands_on_bus(&self) -> usize {
        self.on_bus.len()
    }

    /// Commands waiting for an offline device or their turn on the line.
    pub(crate) fn waiting(&self) -> usize {
        self.book.waiting_count()
    }

    /// The command counters (every other field zero).
    pub(crate) fn counters(&self) -> &BridgeStats {
        &self.counters
    }

    /// Tells the desk whether the driver keeps up with what it is asked to publish.
    pub(crate) fn set_overloaded(&mut self, overloaded: bool) {
        self.shedding.overloaded = overloaded;
    }

    /// Another gateway announces `device` under our prefix.
    pub(crate) fn note_foreign(&mut self, device: &str) {
        self.foreign_devices.insert(device.to_string());
    }

    /// A message on a `…/set` topic.
    pub(crate) fn on_set(&mut self, p: &mut Publisher, message: SetMessage<'_>, now: Instant) {
        let SetMessage {
            topic,
            device,
            field,
            payload,
            ..
        } = message;
        if payload.is_empty() {
            // The clearing of a retained command (often our own): not a command. When an
            // action waits for it, the retained command is gone from the broker now.
            self.on_cleared(p, topic);
            return;
        }
        if message.qos != QoS::AtMostOnce
            && self
                .book
                .is_redelivery(topic, message.pkid, payload, message.dup, now)
        {
            self.counters.redeliveries_ignored += 1;
            tracing::debug!(%device, %field, "QoS 1 redelivery ignored");
            return;
        }
        if !p.devices().contains_key(device) {
            self.reject_unknown_device(p, device, field, payload);
            return;
        }
        if self.shedding.overloaded {
            self.shed(p, device, field, payload, now);
            return;
        }
        // Echoed in `value` exactly as sent (bounded); logged with `?` so control characters
        // and escapes cannot forge log lines.
        let value = payload::echo(payload);
        let text = match decode_command(payload, self.max_payload) {
            CommandPayload::Clear => return,
            CommandPayload::Refused { shown, reason } => {
                self.counters.commands_received += 1;
                self.reject_incoming(p, device, field, &shown, reason, CommandSource::Plain);
                return;
            }
            CommandPayload::Text(text) => text,
        };
        let arrival = Arrival {
            device,
            field,
            text: &text,
            value: &value,
            origin: CommandSource::Plain,
            from_store: message.retain,
        };
        self.admit(p, arrival, now);
    }

    /// A command from outside the plain topics, as `…/set` would carry its `text`: the same
    /// validation, book and results, and its end reported with an [`Action::Report`].
    pub(crate) fn on_external(
        &mut self,
        p: &mut Publisher,
        device: &str,
        field: &str,
        text: &str,
        now: Instant,
    ) {
        let value = payload::shortened(text);
        let (shown, reason) = match decode_command(text.as_bytes(), self.max_payload) {
            CommandPayload::Text(text) => {
                let arrival = Arrival {
                    device,
                    field,
                    text: &text,
                    value: &value,
                    origin: CommandSource::External,
                    from_store: false,
                };
                self.admit(p, arrival, now);
                return;
            }
            CommandPayload::Clear => (value, "the command is empty".to_string()),
            CommandPayload::Refused { shown, reason } => (shown, reason),
        };
        if p.devices().contains_key(device) {
            self.counters.commands_received += 1;
            self.reject_incoming(p, device, field, &shown, reason, CommandSource::External);
        } else {
            self.note_unknown_device(device, "an external command");
            report(p, device, field, false);
        }
    }

    fn note_unknown_device(&mut self, device: &str, via: &str) {
        self.counters.unknown_device_commands += 1;
        tracing::warn!(%device, %via, "command for a device that is not configured");
    }

    /// Validates a decoded command and books it.
    fn admit(&mut self, p: &mut Publisher, command: Arrival<'_>, now: Instant) {
        let Arrival {
            device,
            field,
            text,
            value,
            origin,
            from_store,
        } = command;
        let Some(entry) = p.devices().get(device).cloned() else {
            let topic = p.topics().command_topic(device, field);
            self.note_unknown_device(device, &topic);
            if origin == CommandSource::External {
                report(p, device, field, false);
            }
            return;
        };
        self.counters.commands_received += 1;
        // The one plan of the command: the profile refuses unknown and read-only fields and
        // values its rules forbid on the last known state. The line's slot recomputes the
        // writes from its fresh reads.
        let state = p.cache().state(device).unwrap_or_default();
        let plan = match entry.profile.plan_command(field, text, &state) {
            Ok(plan) => plan,
            Err(rejection) => {
                self.reject_incoming(p, device, field, value, rejection.0, origin);
                return;
            }
        };
        let min_write_interval = entry
            .profile
            .field(field)
            .and_then(|info| info.min_write_interval);
        let booked = if from_store {
            // From the broker's retained store: the same command again when it is the one
            // waiting or running (a re-subscription), so it gets no second run or outcome.
            self.book
                .submit(device, field, text, value, min_write_interval, now)
        } else {
            self.book
                .queue(device, field, text, value, min_write_interval, now)
        };
        match booked {
            Admission::AlreadyWaiting => {
                tracing::debug!(%device, %field, "the broker sent the waiting command again");
                if let Some(id) = self.book.waiting_id(device, field) {
                    if origin == CommandSource::External {
                        self.external.insert(id);
                    }
                }
            }
            Admission::Queued { superseded } => {
                log_received(device, field, value, origin);
                if let Some(id) = self.book.waiting_id(device, field) {
                    self.plans.insert(id, plan);
                    if origin == CommandSource::External {
                        self.external.insert(id);
                    }
                }
                if let Some(older) = superseded {
                    let older_was_plain = !self.external.contains(&older.id);
                    self.supersede(p, older);
                    if origin == CommandSource::External && older_was_plain {
                        // Its retained message is still on `…/set`: it must not run again
                        // at the next start.
                        let set = p.topics().command_topic(device, field);
                        p.publish_or_keep(set, String::new(), true);
                    }
                }
            }
        }
        self.dispatch_ready(p, now);
    }

    /// Tells the sender of an external command how it ended (nothing for plain commands).
    fn report_end(&mut self, p: &mut Publisher, command: &TrackedCommand, applied: bool) {
        if self.external.remove(&command.id) {
            report(p, &command.device, &command.field, applied);
        }
    }

    /// A newer command for the same field replaced `older` before it ran. Its retained
    /// message has been replaced by the newer one too: no clear.
    fn supersede(&mut self, p: &mut Publisher, older: TrackedCommand) {
        self.plans.remove(&older.id);
        self.report_end(p, &older, false);
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
        let topic = p.topics().result_topic(&older.device, &older.field);
        p.publish_or_keep(topic, result.to_json(), false);
    }

    /// Rejects a command as it arrives. It is the newest message on its topic, so its
    /// (possibly retained) copy is cleared whatever waits for the field.
    fn reject_incoming(
        &mut self,
        p: &mut Publisher,
        device: &str,
        field: &str,
        shown: &str,
        reason: String,
        origin: CommandSource,
    ) {
        log_received(device, field, shown, origin);
        log_outcome(device, field, shown, Outcome::Rejected, &reason);
        self.counters.commands_rejected += 1;
        let result = CommandResult::new(shown, Outcome::Rejected, reason);
        let topic = p.topics().result_topic(device, field);
        p.publish_or_keep(topic, result.to_json(), false);
        match origin {
            CommandSource::Plain => {
                let set = p.topics().command_topic(device, field);
                p.publish_or_keep(set, String::new(), true);
            }
            CommandSource::External => report(p, device, field, false),
        }
    }

    /// Publishes a result, then clears the (possibly retained) command unless a newer one for
    /// the field is waiting: with MQTT 3.1.1 we cannot tell whether it was retained.
    fn finish_with(&mut self, p: &mut Publisher, device: &str, field: &str, result: CommandResult) {
        let topic = p.topics().result_topic(device, field);
        p.publish_or_keep(topic, result.to_json(), false);
        if !self.book.has_waiting(device, field) {
            let set = p.topics().command_topic(device, field);
            p.publish_or_keep(set, String::new(), true);
        }
    }

    /// Hands every command that may run now to its line.
    pub(crate) fn dispatch_ready(&mut self, p: &mut Publisher, now: Instant) {
        let cache = p.cache();
        let ready = self.book.take_ready(now, |device| cache.is_online(device));
        for command in ready {
            let plan = self.plans.remove(&command.id);
            let line = p.devices().get(&command.device).map(|entry| entry.line);
            let (Some(plan), Some(line)) = (plan, line) else {
                self.fail(p, command, "the command has no line to run on");
                continue;
            };
            tracing::debug!(device = %command.device, field = %command.field, "command handed to the line");
            let bus_command = Command {
                id: command.id,
                device: command.device.clone(),
                plan,
            };
            if !bus_command.plan.is_idempotent() {
                self.clear_then_send(p, line, bus_command, command);
                continue;
            }
            self.on_bus.insert(command.id, command);
            p.push(Action::Send {
                line,
                command: bus_command,
            });
        }
    }

    /// The driver could not hand `command` to its line: the line's queue is `full` (try again
    /// on the next tick), or the line has stopped.
    pub(crate) fn on_send_failed(&mut self, p: &mut Publisher, command: Command, full: bool) {
        if full {
            self.back_to_waiting(p, command);
        } else if let Some(tracked) = self.on_bus.remove(&command.id) {
            self.fail(p, tracked, "the line has stopped");
        }
    }

    /// `command`, taken for the line but not handed to it, waits again; a newer command of
    /// its field that arrived meanwhile supersedes it.
    fn back_to_waiting(&mut self, p: &mut Publisher, command: Command) {
        let Some(tracked) = self.on_bus.remove(&command.id) else {
            return;
        };
        self.plans.insert(command.id, command.plan);
        if let Some(older) = self.book.requeue(tracked) {
            self.supersede(p, older);
        }
    }

    fn fail(&mut self, p: &mut Publisher, command: TrackedCommand, detail: &str) {
        self.book.finish(&command.device, &command.field);
        self.report_end(p, &command, false);
        self.counters.commands_failed += 1;
        log_outcome(
            &command.device,
            &command.field,
            &command.value,
            Outcome::Failed,
            detail,
        );
        let result = CommandResult::new(&command.value, Outcome::Failed, detail);
        self.finish_with(p, &command.device, &command.field, result);
    }

    /// A line's word on how command `id` ended.
    pub(crate) fn on_finished(
        &mut self,
        p: &mut Publisher,
        id: u64,
        outcome: CommandOutcome,
        now: Instant,
    ) {
        let Some(command) = self.on_bus.remove(&id) else {
            tracing::warn!(id, "outcome of a command the bridge did not send");
            return;
        };
        let (word, detail) = outcome_word(outcome);
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
        self.book.finish(&command.device, &command.field);
        self.report_end(p, &command, word == Outcome::Applied);
        let result = CommandResult::new(&command.value, word, detail);
        self.finish_with(p, &command.device, &command.field, result);
        self.dispatch_ready(p, now);
    }

    /// A write from a client of a line's server ran on the line: its outcome goes out on the
    /// field's result topic like a command's (no `…/set` was involved, so none is cleared).
    pub(crate) fn on_client_write(
        &mut self,
        p: &mut Publisher,
        device: &str,
        field: &str,
        value: &str,
        client: &str,
        outcome: CommandOutcome,
    ) {
        let (word, detail) = outcome_word(outcome);
        tracing::info!(%device, %field, ?value, %client, outcome = %word.word(), ?detail, "client write finished");
        let result = CommandResult::new(value, word, detail);
        let topic = p.topics().result_topic(device, field);
        p.publish_or_keep(topic, result.to_json(), false);
    }

    /// A write reached `device` (a command's or a client's, the line says): the write
    /// intervals of `fields` run from `at`, for every source.
    pub(crate) fn on_written(&mut self, device: &str, fields: &[String], at: Instant) {
        for field in fields {
            self.book.note_write(device, field, at);
        }
    }

    /// Commands whose device stayed offline for their time to live end `expired`; then
    /// whatever may run now goes to its line.
    pub(crate) fn on_tick(&mut self, p: &mut Publisher, now: Instant) {
        let cache = p.cache();
        let expired = self
            .book
            .take_expired(now, |device| cache.is_online(device));
        for command in expired {
            self.plans.remove(&command.id);
            self.report_end(p, &command, false);
            self.counters.commands_expired += 1;
            let detail = format!(
                "device {} stayed offline for {} (the command's time to live)",
                command.device,
                humantime::format_duration(self.ttl)
            );
            log_outcome(
                &command.device,
                &command.field,
                &command.value,
                Outcome::Expired,
                &detail,
            );
            let result = CommandResult::new(&command.value, Outcome::Expired, detail);
            self.finish_with(p, &command.device, &command.field, result);
        }
        self.dispatch_ready(p, now);
    }

    /// A command on our topic shape for a device that is not configured: rejected, naming the
    /// configured devices, unless another gateway announces that device under our prefix. Its
    /// retained copy is left alone (it may be meant for a gateway that is not running now).
    fn reject_unknown_device(
        &mut self,
        p: &mut Publisher,
        device: &str,
        field: &str,
        payload: &[u8],
    ) {
        self.counters.unknown_device_commands += 1;
        if self.foreign_devices.contains(device) || payload.is_empty() {
            tracing::debug!(%device, "command for another gateway's device");
            return;
        }
        let shown = payload::echo(payload);
        let reason = format!(
            "unknown device {device:?}: this gateway has {}",
            p.cache().devices().join(", ")
        );
        // Not configured here: a typo in the topic or a device missing from the configuration.
        tracing::warn!(%device, %field, value = ?shown, detail = ?reason, "command for a device that is not configured: rejected");
        self.counters.commands_rejected += 1;
        let result = CommandResult::new(&shown, Outcome::Rejected, reason);
        let topic = p.topics().result_topic(device, field);
        p.publish_or_keep(topic, result.to_json(), false);
    }

    /// Load shedding: the command is refused at once, with its outcome, and the log says so at
    /// most once per [`SHED_LOG_INTERVAL`] with the count.
    fn shed(&mut self, p: &mut Publisher, device: &str, field: &str, payload: &[u8], now: Instant) {
        self.counters.commands_shed += 1;
        let shedding = &mut self.shedding;
        shedding.unlogged += 1;
        if shedding.logged_at.map_or(true, |at| {
            now.saturating_duration_since(at) >= SHED_LOG_INTERVAL
        }) {
            tracing::warn!(
                shed = shedding.unlogged,
                "overloaded: commands refused until the MQTT link catches up"
            );
            shedding.logged_at = Some(now);
            shedding.unlogged = 0;
        }
        let shown = payload::echo(payload);
        self.counters.commands_rejected += 1;
        let result = CommandResult::new(
            &shown,
            Outcome::Rejected,
            "gateway overloaded: the command was not run; send it again later",
        );
        let topic = p.topics().result_topic(device, field);
        p.publish_or_keep(topic, result.to_json(), false);
        let set = p.topics().command_topic(device, field);
        p.publish_or_keep(set, String::new(), true);
    }

    /// An action that must not run twice: its (possibly retained) command is cleared first, and
    /// the command goes to the line only when the broker passes that clearing back to us. A
    /// crash before then loses the action (at most once); a crash after cannot replay it.
    fn clear_then_send(
        &mut self,
        p: &mut Publisher,
        line: usize,
        command: Command,
        tracked: TrackedCommand,
    ) {
        let set = p.topics().command_topic(&tracked.device, &tracked.field);
        tracing::debug!(device = %tracked.device, field = %tracked.field,
            "clearing the command before the action runs");
        self.on_bus.insert(tracked.id, tracked);
        self.clearing.insert(set.clone(), (line, command));
        p.publish_or_keep(set, String::new(), true);
    }

    /// An empty message on `set`: an action waiting for its clearing may run now. The broker
    /// delivers one topic's messages in order, so it was published after the command. A
    /// device that went offline meanwhile gets it like any command, once it is back.
    fn on_cleared(&mut self, p: &mut Publisher, set: &str) {
        let Some((line, command)) = self.clearing.remove(set) else {
            return;
        };
        if p.cache().is_online(&command.device) {
            tracing::debug!(device = %command.device, "command cleared: handed to the line");
            p.push(Action::Send { line, command });
        } else {
            tracing::debug!(device = %command.device, "command cleared: waits for its device");
            self.back_to_waiting(p, command);
        }
    }

    /// After a reconnect, clear again what may not have reached the broker.
    pub(crate) fn clear_again(&mut self, p: &mut Publisher) {
        let topics: Vec<String> = self.clearing.keys().cloned().collect();
        for set in topics {
            p.publish_or_keep(set, String::new(), true);
        }
    }

    /// A device removed by a reload: its waiting commands fail.
    pub(crate) fn forget_device(&mut self, p: &mut Publisher, name: &str) {
        for command in self.book.drain_device(name) {
            self.plans.remove(&command.id);
            self.counters.commands_failed += 1;
            let detail = format!("device {name} is no longer configured (configuration reloaded)");
            let result = CommandResult::new(&command.value, Outcome::Failed, detail);
            self.finish_with(p, name, &command.field, result);
        }
    }

    /// Stopping: actions still waiting for their clearing never ran and fail; waiting
    /// commands stay retained in the broker for the next start.
    pub(crate) fn stop(&mut self, p: &mut Publisher) {
        let uncleared: Vec<(String, (usize, Command))> = self.clearing.drain().collect();
        for (_, (_, command)) in uncleared {
            if let Some(tracked) = self.on_bus.remove(&command.id) {
                self.counters.commands_failed += 1;
                let result = CommandResult::new(
                    &tracked.value,
                    Outcome::Failed,
                    "the gateway stopped before the action was sent",
                );
                let topic = p.topics().result_topic(&tracked.device, &tracked.field);
                p.publish_or_keep(topic, result.to_json(), false);
            }
        }
        let waiting = self.book.drain_waiting();
        self.plans.clear();
        self.external.clear();
        if !waiting.is_empty() {
            tracing::info!(
                count = waiting.len(),
                "waiting commands left for the next start"
            );
        }
    }
}

/// A decoded command on its way into the book: `text` as planned, `value` as sent;
/// `from_store` when the broker sent it from its retained store (the MQTT retain flag).
#[derive(Debug, Clone, Copy)]
struct Arrival<'a> {
    device: &'a str,
    field: &'a str,
    text: &'a str,
    value: &'a str,
    origin: CommandSource,
    from_store: bool,
}

fn report(p: &mut Publisher, device: &str, field: &str, applied: bool) {
    p.push(Action::Report(CommandReport {
        device: device.to_string(),
        field: field.to_string(),
        applied,
    }));
}
