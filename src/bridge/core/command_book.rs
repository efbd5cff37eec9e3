//! The command book: which commands wait and which are on the bus. Newest per field wins (an
//! older waiting command is superseded), a command waits while its device is offline, while a
//! command for the same field is still on the bus, or while the field's minimum write interval
//! runs. That interval runs from the last write that reached the device from any source (a
//! command or a client of a served line), as the line reports it ([`CommandBook::note_write`]). Only waiting for an offline device is bounded by the time to live: a command waiting
//! behind one on the bus (a valve still settling) or behind the write interval waits for a
//! device that answers, and runs when its turn comes. QoS 1 redeliveries (DUP) are recognised so a write
//! never runs twice because of one. Pure: the clock is passed in.

use std::collections::{HashMap, VecDeque};
use std::time::{Duration, Instant};

/// How long a received QoS 1 message is remembered for spotting its redelivery.
const REDELIVERY_WINDOW: Duration = Duration::from_secs(60);
/// Bound on remembered messages.
const REDELIVERY_MEMORY: usize = 256;

/// One command on its way: waiting or on the bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TrackedCommand {
    pub id: u64,
    pub device: String,
    pub field: String,
    /// The command text the profile plans from (trimmed).
    pub text: String,
    /// The payload as sent, echoed in `value` on `…/result` ([`super::payload::echo`]).
    pub value: String,
    pub received: Instant,
    /// When the command expires if its device stays offline until then; `None` while the
    /// device is online (the clock starts again when it is next seen offline).
    pub offline_deadline: Option<Instant>,
    /// The field's minimum time between two writes.
    pub min_write_interval: Option<Duration>,
}

/// What became of a submitted command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Admission {
    /// Waiting; `superseded` is the older command of the same field it replaced.
    Queued { superseded: Option<TrackedCommand> },
    /// The same payload as the command already waiting for this field (a retained command
    /// received again): nothing new to do.
    AlreadyWaiting,
}

type Key = (String, String);

#[derive(Debug)]
pub struct CommandBook {
    ttl: Duration,
    next_id: u64,
    waiting: HashMap<Key, TrackedCommand>,
    on_bus: HashMap<Key, TrackedCommand>,
    last_write: HashMap<Key, Instant>,
    /// (seen at, topic, packet id, payload hash): hashes keep this small whatever the payloads.
    recent: VecDeque<(Instant, String, u16, u64)>,
}

impl CommandBook {
    pub fn new(ttl: Duration) -> Self {
        CommandBook {
            ttl,
            next_id: 1,
            waiting: HashMap::new(),
            on_bus: HashMap::new(),
            last_write: HashMap::new(),
            recent: VecDeque::new(),
        }
    }

    /// True when this QoS 1 message is a redelivery (DUP) of one seen within the window.
    /// Every message is remembered.
    pub fn is_redelivery(
        &mut self,
        topic: &str,
        pkid: u16,
        payload: &[u8],
        dup: bool,
        now: Instant,
    ) -> bool {
        while let Some((seen, ..)) = self.recent.front() {
            if now.duration_since(*seen) > REDELIVERY_WINDOW
                || self.recent.len() > REDELIVERY_MEMORY
            {
                self.recent.pop_front();
            } else {
                break;
            }
        }
        let hash = payload_hash(payload);
        let seen = self
            .recent
            .iter()
            .any(|(_, t, id, h)| *id == pkid && *h == hash && t == topic);
        if dup && seen {
            return true;
        }
        self.recent.push_back((now, topic.to_string(), pkid, hash));
        false
    }

    /// Queues a validated command (`text` as planned, `value` as sent). An older waiting
    /// command for the same field is superseded.
    pub fn submit(
        &mut self,
        device: &str,
        field: &str,
        text: &str,
        value: &str,
        min_write_interval: Option<Duration>,
        now: Instant,
    ) -> Admission {
        if self.is_current(device, field, value) {
            return Admission::AlreadyWaiting;
        }
        self.queue(device, field, text, value, min_write_interval, now)
    }

    /// The command waiting for this field, or on the bus for it, carries `value`: a retained
    /// command the broker delivers again (a re-subscription) is that same command.
    pub fn is_current(&self, device: &str, field: &str, value: &str) -> bool {
        let key = (device.to_string(), field.to_string());
        self.waiting.get(&key).is_some_and(|w| w.value == value)
            || self.on_bus.get(&key).is_some_and(|c| c.value == value)
    }

    /// Queues a command that arrived live: a new command even when its payload equals the one
    /// waiting (the older one is superseded, so each gets its own outcome).
    pub fn queue(
        &mut self,
        device: &str,
        field: &str,
        text: &str,
        value: &str,
        min_write_interval: Option<Duration>,
        now: Instant,
    ) -> Admission {
        let key = (device.to_string(), field.to_string());
        let command = TrackedCommand {
            id: self.next_id,
            device: device.to_string(),
            field: field.to_string(),
            text: text.to_string(),
            value: value.to_string(),
            received: now,
            offline_deadline: Some(now + self.ttl),
            min_write_interval,
        };
        self.next_id += 1;
        let superseded = self.waiting.insert(key, command);
        Admission::Queued { superseded }
    }

    /// Waiting commands that may go to the bus now (device online, field not on the bus, write
    /// interval over), moved to "on the bus".
    pub fn take_ready(
        &mut self,
        now: Instant,
        is_online: impl Fn(&str) -> bool,
    ) -> Vec<TrackedCommand> {
        let ready: Vec<Key> = self
            .waiting
            .iter()
            .filter(|(key, command)| {
                is_online(&key.0)
                    && !self.on_bus.contains_key(*key)
                    && self.write_allowed_at(key, command) <= now
            })
            .map(|(key, _)| key.clone())
            .collect();
        let mut taken: Vec<TrackedCommand> = ready
            .into_iter()
            .filter_map(|key| {
                let command = self.waiting.remove(&key)?;
                self.on_bus.insert(key, command.clone());
                Some(command)
            })
            .collect();
        taken.sort_by_key(|command| command.id);
        taken
    }

    /// Waiting commands whose device has stayed offline for their whole time to live, removed.
    /// A command of an online device never expires here: it waits for a command on the bus or
    /// for the write interval, both of which end.
    pub fn take_expired(
        &mut self,
        now: Instant,
        is_online: impl Fn(&str) -> bool,
    ) -> Vec<TrackedCommand> {
        let ttl = self.ttl;
        let mut expired: Vec<Key> = Vec::new();
        for (key, command) in self.waiting.iter_mut() {
            if is_online(&key.0) {
                command.offline_deadline = None;
                continue;
            }
            let deadline = *command.offline_deadline.get_or_insert(now + ttl);
            if deadline <= now {
                expired.push(key.clone());
            }
        }
        let mut taken: Vec<TrackedCommand> = expired
            .into_iter()
            .filter_map(|key| self.waiting.remove(&key))
            .collect();
        taken.sort_by_key(|command| command.id);
        taken
    }

    /// A command left the bus (any outcome).
    pub fn finish(&mut self, device: &str, field: &str) {
        self.on_bus.remove(&(device.to_string(), field.to_string()));
    }

    /// A write of `field` reached `device` at `at` (the line says so, whoever wrote): the
    /// field's write interval runs from there.
    pub fn note_write(&mut self, device: &str, field: &str, at: Instant) {
        let last = self
            .last_write
            .entry((device.to_string(), field.to_string()))
            .or_insert(at);
        *last = (*last).max(at);
    }

    /// Puts a command that could not be handed to the bus back to waiting. When a newer one
    /// arrived meanwhile, that one stays and the returned older one is superseded.
    pub fn requeue(&mut self, command: TrackedCommand) -> Option<TrackedCommand> {
        let key = (command.device.clone(), command.field.clone());
        self.on_bus.remove(&key);
        if self.waiting.contains_key(&key) {
            return Some(command);
        }
        self.waiting.insert(key, command);
        None
    }

    /// The id of the command waiting for this field.
    pub fn waiting_id(&self, device: &str, field: &str) -> Option<u64> {
        self.waiting
            .get(&(device.to_string(), field.to_string()))
            .map(|command| command.id)
    }

    /// A newer command for this field is waiting.
    pub fn has_waiting(&self, device: &str, field: &str) -> bool {
        self.waiting
            .contains_key(&(device.to_string(), field.to_string()))
    }

    pub fn on_bus_count(&self) -> usize {
        self.on_bus.len()
    }

    pub fn waiting_count(&self) -> usize {
        self.waiting.len()
    }

    /// Every waiting command, removed (shutdown: they stay retained in the broker).
    pub fn drain_waiting(&mut self) -> Vec<TrackedCommand> {
        self.waiting.drain().map(|(_, command)| command).collect()
    }

    /// The waiting commands of `device`, removed (the device is no longer configured).
    pub fn drain_device(&mut self, device: &str) -> Vec<TrackedCommand> {
        let keys: Vec<Key> = self
            .waiting
            .keys()
            .filter(|(name, _)| name == device)
            .cloned()
            .collect();
        keys.iter()
            .filter_map(|key| self.waiting.remove(key))
            .collect()
    }

    fn write_allowed_at(&self, key: &Key, command: &TrackedCommand) -> Instant {
        match (self.last_write.get(key), command.min_write_interval) {
            (Some(last), Some(interval)) => *last + interval,
            _ => command.received,
        }
    }
}

fn payload_hash(payload: &[u8]) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    payload.hash(&mut hasher);
    hasher.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    const TTL: Duration = Duration::from_secs(300);

    #[test]
    fn waits_for_the_device_then_runs_once() {
        let start = Instant::now();
        let mut book = CommandBook::new(TTL);
        assert!(matches!(
            book.submit("dust", "gear", "8", "8", None, start),
            Admission::Queued { superseded: None }
        ));
        assert!(book.take_ready(start, |_| false).is_empty());
        let ready = book.take_ready(start, |_| true);
        assert_eq!(ready.len(), 1);
        assert_eq!(ready[0].text, "8");
        assert!(book.take_ready(start, |_| true).is_empty());
    }

    #[test]
    fn newest_per_field_wins() {
        let start = Instant::now();
        let mut book = CommandBook::new(TTL);
        book.submit("dust", "gear", "3", "3", None, start);
        let Admission::Queued {
            superseded: Some(older),
        } = book.submit("dust", "gear", "8", "8", None, start)
        else {
            panic!("not superseded")
        };
        assert_eq!(older.text, "3");
        assert_eq!(
            book.submit("dust", "gear", "8", "8", None, start),
            Admission::AlreadyWaiting
        );
        // Another field is independent.
        book.submit("dust", "power", "ON", "ON", None, start);
        let ready = book.take_ready(start, |_| true);
        let texts: Vec<&str> = ready.iter().map(|c| c.text.as_str()).collect();
        assert_eq!(texts, ["8", "ON"]);
    }

    #[test]
    fn the_same_text_sent_differently_is_a_new_command() {
        let start = Instant::now();
        let mut book = CommandBook::new(TTL);
        book.submit("dust", "gear", "8", "8", None, start);
        let Admission::Queued {
            superseded: Some(older),
        } = book.submit("dust", "gear", "8", " 8\n", None, start)
        else {
            panic!("not superseded")
        };
        assert_eq!(older.value, "8");
        let ready = book.take_ready(start, |_| true);
        assert_eq!(ready[0].value, " 8\n");
        assert_eq!(ready[0].text, "8");
    }

    #[test]
    fn one_command_per_field_on_the_bus() {
        let start = Instant::now();
        let mut book = CommandBook::new(TTL);
        book.submit("dust", "gear", "3", "3", None, start);
        assert_eq!(book.take_ready(start, |_| true).len(), 1);
        book.submit("dust", "gear", "4", "4", None, start);
        assert!(book.take_ready(start, |_| true).is_empty());
        assert!(book.has_waiting("dust", "gear"));
        book.finish("dust", "gear");
        assert_eq!(book.take_ready(start, |_| true)[0].text, "4");
    }

    #[test]
    fn a_requeued_command_yields_to_a_newer_one() {
        let start = Instant::now();
        let mut book = CommandBook::new(TTL);
        book.submit("dust", "gear", "3", "3", None, start);
        let taken = book.take_ready(start, |_| true).remove(0);
        book.submit("dust", "gear", "4", "4", None, start);
        assert_eq!(book.requeue(taken).map(|c| c.text), Some("3".to_string()));
        assert_eq!(book.take_ready(start, |_| true)[0].text, "4");
        book.finish("dust", "gear");
        // Without a newer one it waits again.
        book.submit("dust", "gear", "5", "5", None, start);
        let five = book.take_ready(start, |_| true).remove(0);
        assert_eq!(book.requeue(five), None);
        assert_eq!(book.take_ready(start, |_| true)[0].text, "5");
    }

    #[test]
    fn expires_after_its_time_to_live() {
        let start = Instant::now();
        let mut book = CommandBook::new(TTL);
        book.submit("dust", "gear", "3", "3", None, start);
        assert!(book
            .take_expired(start + TTL - Duration::from_secs(1), |_| false)
            .is_empty());
        let expired = book.take_expired(start + TTL, |_| false);
        assert_eq!(expired.len(), 1);
        assert!(book.take_ready(start + TTL, |_| true).is_empty());
    }

    #[test]
    fn waiting_behind_a_command_on_the_bus_never_expires() {
        let start = Instant::now();
        let mut book = CommandBook::new(TTL);
        book.submit("valve", "opening", "100", "100", None, start);
        assert_eq!(book.take_ready(start, |_| true).len(), 1);
        book.submit("valve", "opening", "50", "50", None, start);
        // The first one settles for longer than the time to live; the device answers.
        let much_later = start + TTL * 3;
        assert!(book.take_expired(much_later, |_| true).is_empty());
        book.finish("valve", "opening");
        assert_eq!(book.take_ready(much_later, |_| true)[0].text, "50");
    }

    #[test]
    fn the_time_to_live_counts_from_when_the_device_is_seen_offline() {
        let start = Instant::now();
        let mut book = CommandBook::new(TTL);
        book.submit("valve", "opening", "100", "100", None, start);
        assert_eq!(book.take_ready(start, |_| true).len(), 1);
        book.submit("valve", "opening", "50", "50", None, start);
        let offline_at = start + TTL * 2;
        assert!(book.take_expired(start + TTL, |_| true).is_empty());
        assert!(book.take_expired(offline_at, |_| false).is_empty());
        assert!(book
            .take_expired(offline_at + TTL - Duration::from_secs(1), |_| false)
            .is_empty());
        let expired = book.take_expired(offline_at + TTL, |_| false);
        assert_eq!(expired.len(), 1);
        assert_eq!(expired[0].text, "50");
    }

    #[test]
    fn minimum_write_interval_delays() {
        let start = Instant::now();
        let interval = Some(Duration::from_secs(10));
        let mut book = CommandBook::new(TTL);
        book.submit("valve", "setpoint", "1", "1", interval, start);
        assert_eq!(book.take_ready(start, |_| true).len(), 1);
        book.finish("valve", "setpoint");
        book.note_write("valve", "setpoint", start);
        book.submit("valve", "setpoint", "2", "2", interval, start);
        assert!(book
            .take_ready(start + Duration::from_secs(9), |_| true)
            .is_empty());
        assert_eq!(
            book.take_ready(start + Duration::from_secs(10), |_| true)[0].text,
            "2"
        );
    }

    #[test]
    fn a_write_from_another_source_starts_the_interval_too() {
        let start = Instant::now();
        let interval = Some(Duration::from_secs(10));
        let mut book = CommandBook::new(TTL);
        // A client of the served line wrote the setpoint; then a command comes.
        book.note_write("valve", "setpoint", start);
        book.submit("valve", "setpoint", "1", "1", interval, start);
        assert!(book
            .take_ready(start + Duration::from_secs(1), |_| true)
            .is_empty());
        // The newest wins while it waits.
        book.submit("valve", "setpoint", "2", "2", interval, start);
        let at_the_end = start + Duration::from_secs(10);
        let ready = book.take_ready(at_the_end, |_| true);
        assert_eq!(ready.len(), 1);
        assert_eq!(ready[0].text, "2");
        // An older report never moves the interval's start back.
        book.finish("valve", "setpoint");
        book.note_write("valve", "setpoint", at_the_end);
        book.note_write("valve", "setpoint", start);
        book.submit("valve", "setpoint", "3", "3", interval, at_the_end);
        assert!(book
            .take_ready(at_the_end + Duration::from_secs(9), |_| true)
            .is_empty());
    }

    #[test]
    fn recognises_qos1_redelivery() {
        let now = Instant::now();
        let mut book = CommandBook::new(TTL);
        assert!(!book.is_redelivery("p/d/f/set", 7, b"ON", false, now));
        assert!(book.is_redelivery("p/d/f/set", 7, b"ON", true, now));
        // The same text again, not flagged DUP, is a new command.
        assert!(!book.is_redelivery("p/d/f/set", 7, b"ON", false, now));
        // Outside the window it is new again.
        let later = now + REDELIVERY_WINDOW + Duration::from_secs(1);
        assert!(!book.is_redelivery("p/d/f/set", 8, b"ON", true, later));
    }
}
