//! The gateway's claim on its own topics: its status, its devices' availability and state.
//! It remembers what it published on each (in flight until the broker echoes it back) so that
//! an echo of its own message is never mistaken for someone else's, nor is a message the broker
//! took before it (the broker delivers one topic's messages in the order it took them, so that
//! one arrives ahead of the echo, and ours replaces it: the gateway's own `offline` from before a
//! restart, handed over with the persistent session or the retained message, is one). Any
//! other message that contradicts the truth (a retained `offline` by another client, a stale
//! Will, a fake state value) is answered by publishing the truth again, at most once per topic
//! per [`REASSERT_INTERVAL`] so that two publishers can never loop at full speed; the log blames
//! another client only when the message is not the gateway's own Will. Pure: it decides, the
//! core publishes; the clock is passed in.
//!
//! The status and availability topics change rarely and are watched all the time. State
//! topics carry most of the gateway's traffic, so they are not: watching them all would bring
//! every value the gateway publishes back to it. Instead one device at a time is audited for
//! [`AUDIT_WINDOW`] (longer for a device with many topics, so the audit costs at most
//! [`AUDIT_TOPICS_PER_SECOND`] messages a second), in turn: the core subscribes to that device's topics behind what it has
//! already queued (so what the broker then holds is all the gateway's earlier word), judges
//! what the broker hands over and what arrives meanwhile, and unsubscribes. A contradiction
//! left by another client is found within one round of the devices and set right then.

use std::collections::{HashMap, HashSet, VecDeque};
use std::time::{Duration, Instant};

/// Own messages remembered per topic while their echo is awaited.
const IN_FLIGHT: usize = 8;
/// The shortest time between two re-assertions of one topic.
pub(crate) const REASSERT_INTERVAL: Duration = Duration::from_secs(2);
/// How long one device's state topics are watched in its turn, at least.
pub(crate) const AUDIT_WINDOW: Duration = Duration::from_secs(1);
/// Topics audited per second at most: a device with more topics is watched for longer, so
/// the messages the broker hands over for the audit stay this few whatever the plant's size.
pub(crate) const AUDIT_TOPICS_PER_SECOND: u32 = 50;

/// What a turn of the state audit asks for.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(crate) struct AuditTurn {
    /// The device whose audit is over: unsubscribe from its topics.
    pub ended: Option<String>,
    /// The device audited from now: subscribe to its topics.
    pub started: Option<String>,
}

/// What to do about a message seen on a guarded topic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum GuardVerdict {
    /// Our own message, or one that agrees with the truth.
    Fine,
    /// Someone else contradicted the truth: publish it again.
    Reassert,
    /// Contradicted, but re-asserted too recently: [`TopicGuard::due`] names it later.
    Hold,
}

#[derive(Debug, Default)]
pub(crate) struct TopicGuard {
    /// Our payloads per topic, oldest first, until the broker echoes them.
    in_flight: HashMap<String, VecDeque<String>>,
    last_reassert: HashMap<String, Instant>,
    /// Topics already reported in the log (once each).
    reported: HashSet<String>,
    /// Contradicted topics waiting for their interval to pass.
    held: HashSet<String>,
    /// The topic and payload of the gateway's own Last Will.
    own_will: Option<(String, String)>,
    /// The device whose state topics are watched now, and until when.
    audited: Option<(String, Instant)>,
    /// Where the round of audits goes on.
    next_audit: usize,
}

impl TopicGuard {
    /// A guard that knows the gateway's Last Will: when the broker publishes it (one of the
    /// gateway's own connections ended: the broker stopping, a late Will of an earlier
    /// connection), the truth goes back all the same, but the log does not blame another
    /// client.
    pub(crate) fn with_own_will(topic: &str, payload: &str) -> Self {
        TopicGuard {
            own_will: Some((topic.to_string(), payload.to_string())),
            ..TopicGuard::default()
        }
    }

    /// We publish `payload` on `topic`.
    pub(crate) fn sent(&mut self, topic: &str, payload: &str) {
        let queue = self.in_flight.entry(topic.to_string()).or_default();
        if queue.len() >= IN_FLIGHT {
            queue.pop_front();
        }
        queue.push_back(payload.to_string());
    }

    /// A new connection: echoes of the old one will not come, and the audit starts again.
    /// Returns the device whose audit the lost connection interrupted (a persistent session
    /// may still hold its subscription).
    pub(crate) fn reset(&mut self) -> Option<String> {
        self.in_flight.clear();
        self.audited.take().map(|(device, _)| device)
    }

    /// The device whose state topics are watched now.
    pub(crate) fn audited(&self) -> Option<&str> {
        self.audited.as_ref().map(|(device, _)| device.as_str())
    }

    /// The audit's turn at `now` among `devices` (in configuration order): the audit under
    /// way ends once its window has passed (what was awaited on its topics is forgotten with
    /// `is_audited_topic`, since those echoes will not come), and the next device's begins,
    /// watched for [`AUDIT_WINDOW`] or, when it has more topics (`topics_of`), for as long as
    /// [`AUDIT_TOPICS_PER_SECOND`] takes to cover them.
    pub(crate) fn audit_turn(
        &mut self,
        devices: &[String],
        now: Instant,
        topics_of: impl Fn(&str) -> usize,
        is_audited_topic: impl Fn(&str, &str) -> bool,
    ) -> AuditTurn {
        let mut turn = AuditTurn::default();
        if let Some((device, until)) = &self.audited {
            if now < *until {
                return turn;
            }
            let device = device.clone();
            self.in_flight
                .retain(|topic, _| !is_audited_topic(&device, topic));
            self.audited = None;
            turn.ended = Some(device);
        }
        if devices.is_empty() {
            return turn;
        }
        let device = devices[self.next_audit % devices.len()].clone();
        self.next_audit = (self.next_audit + 1) % devices.len();
        let topics = u32::try_from(topics_of(&device)).unwrap_or(u32::MAX);
        let window = AUDIT_WINDOW.max(Duration::from_secs(1) * topics / AUDIT_TOPICS_PER_SECOND);
        self.audited = Some((device.clone(), now + window));
        turn.started = Some(device);
        turn
    }

    /// `payload` arrived on `topic`, whose truth is `truth`. The broker delivers one topic's
    /// messages in order, so our echo is the oldest of our in-flight payloads that matches, and
    /// anything else that arrives while one of ours is in flight was taken before ours, which
    /// replaces it.
    pub(crate) fn judge(
        &mut self,
        topic: &str,
        payload: &str,
        truth: &str,
        now: Instant,
    ) -> GuardVerdict {
        if let Some(queue) = self.in_flight.get_mut(topic) {
            if let Some(position) = queue.iter().position(|sent| sent == payload) {
                queue.drain(..=position);
                // Nothing left to await on this topic: keeping its entry would hold a topic
                // string and a queue for every topic the gateway ever published on.
                if queue.is_empty() {
                    self.in_flight.remove(topic);
                }
                return GuardVerdict::Fine;
            }
            tracing::debug!(%topic, seen = ?payload, "a message from before ours, which replaces it");
            return GuardVerdict::Fine;
        }
        if payload == truth {
            return GuardVerdict::Fine;
        }
        if self
            .last_reassert
            .get(topic)
            .is_some_and(|at| now.saturating_duration_since(*at) < REASSERT_INTERVAL)
        {
            self.held.insert(topic.to_string());
            return GuardVerdict::Hold;
        }
        self.held.remove(topic);
        self.last_reassert.insert(topic.to_string(), now);
        let own_will = self
            .own_will
            .as_ref()
            .is_some_and(|(will_topic, will)| will_topic == topic && will == payload);
        if own_will {
            tracing::info!(%topic, seen = ?payload, truth = %truth,
                "the broker published this gateway's own Will (one of its connections ended): \
                 publishing the truth again");
        } else if self.reported.insert(topic.to_string()) {
            tracing::warn!(%topic, seen = ?payload, truth = %truth,
                "another client overwrote one of this gateway's topics: publishing the truth again");
        } else {
            tracing::debug!(%topic, seen = ?payload, "overwritten again: publishing the truth again");
        }
        GuardVerdict::Reassert
    }

    /// Held topics whose interval has passed, to re-assert now.
    pub(crate) fn due(&mut self, now: Instant) -> Vec<String> {
        let last = &self.last_reassert;
        let due: Vec<String> = self
            .held
            .iter()
            .filter(|topic| {
                last.get(*topic).map_or(true, |at| {
                    now.saturating_duration_since(*at) >= REASSERT_INTERVAL
                })
            })
            .cloned()
            .collect();
        for topic in &due {
            self.held.remove(topic);
            self.last_reassert.insert(topic.clone(), now);
        }
        due
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn what_arrives_ahead_of_our_echo_is_older_than_ours_and_no_contradiction() {
        let now = Instant::now();
        let mut guard = TopicGuard::default();
        let status = "plant/gateway/gw1/status";
        // Connected again: `online` sent; the broker first hands over what it took before
        // (the last run's `offline`, queued for the session and kept as the retained
        // message), then echoes ours.
        guard.sent(status, "online");
        for earlier in ["offline", "offline"] {
            assert_eq!(
                guard.judge(status, earlier, "online", now),
                GuardVerdict::Fine
            );
        }
        assert_eq!(
            guard.judge(status, "online", "online", now),
            GuardVerdict::Fine
        );
        // Once ours is there, a contradiction is someone else's.
        assert_eq!(
            guard.judge(status, "offline", "online", now),
            GuardVerdict::Reassert
        );
    }

    #[test]
    fn the_gateways_own_will_is_set_right_like_any_contradiction() {
        let now = Instant::now();
        let status = "plant/gateway/gw1/status";
        let mut guard = TopicGuard::with_own_will(status, "offline");
        assert_eq!(
            guard.judge(status, "offline", "online", now),
            GuardVerdict::Reassert
        );
        assert!(guard.reported.is_empty(), "not reported as another client");
        assert_eq!(
            guard.judge(status, "gone", "online", now + REASSERT_INTERVAL),
            GuardVerdict::Reassert
        );
        assert!(guard.reported.contains(status));
    }

    #[test]
    fn devices_are_audited_in_turn_for_as_long_as_their_topics_take() {
        let now = Instant::now();
        let devices = vec!["a".to_string(), "b".to_string()];
        let state_of = |device: &str, topic: &str| topic.starts_with(&format!("p/{device}/"));
        // `a` has few topics, `b` five seconds' worth.
        let topics_of = |device: &str| {
            if device == "a" {
                3
            } else {
                5 * AUDIT_TOPICS_PER_SECOND as usize
            }
        };
        let mut guard = TopicGuard::default();
        let first = guard.audit_turn(&devices, now, topics_of, state_of);
        assert_eq!(first.started.as_deref(), Some("a"));
        assert_eq!(first.ended, None);
        guard.sent("p/a/gear", "3");
        guard.sent("p/status", "online");
        // Within the window nothing changes.
        let within = now + AUDIT_WINDOW / 2;
        assert_eq!(
            guard.audit_turn(&devices, within, topics_of, state_of),
            AuditTurn::default()
        );
        assert_eq!(guard.audited(), Some("a"));
        let b_from = now + AUDIT_WINDOW;
        let second = guard.audit_turn(&devices, b_from, topics_of, state_of);
        assert_eq!(second.ended.as_deref(), Some("a"));
        assert_eq!(second.started.as_deref(), Some("b"));
        // The audited device's awaited echoes are forgotten, the rest are not.
        assert!(!guard.in_flight.contains_key("p/a/gear"));
        assert!(guard.in_flight.contains_key("p/status"));
        // The larger device is watched for longer.
        let b_within = b_from + Duration::from_secs(4);
        assert_eq!(
            guard.audit_turn(&devices, b_within, topics_of, state_of),
            AuditTurn::default()
        );
        let b_over = b_from + Duration::from_secs(5);
        let third = guard.audit_turn(&devices, b_over, topics_of, state_of);
        assert_eq!(third.ended.as_deref(), Some("b"));
        assert_eq!(third.started.as_deref(), Some("a"));
        // A lost connection interrupts the audit under way.
        assert_eq!(guard.reset().as_deref(), Some("a"));
        assert_eq!(guard.audited(), None);
    }

    #[test]
    fn own_echoes_pass_and_a_foreign_contradiction_is_answered_once_per_interval() {
        let now = Instant::now();
        let mut guard = TopicGuard::default();
        guard.sent("plant/a/gear", "3");
        guard.sent("plant/a/gear", "4");
        // The echo of the older value while the newer is in flight is ours.
        assert_eq!(
            guard.judge("plant/a/gear", "3", "4", now),
            GuardVerdict::Fine
        );
        assert_eq!(
            guard.judge("plant/a/gear", "4", "4", now),
            GuardVerdict::Fine
        );
        assert_eq!(
            guard.judge("plant/a/gear", "99", "4", now),
            GuardVerdict::Reassert
        );
        guard.sent("plant/a/gear", "4");
        assert_eq!(
            guard.judge("plant/a/gear", "4", "4", now),
            GuardVerdict::Fine
        );
        assert_eq!(
            guard.judge("plant/a/gear", "98", "4", now + Duration::from_millis(10)),
            GuardVerdict::Hold
        );
        assert!(guard.due(now + Duration::from_millis(20)).is_empty());
        assert_eq!(guard.due(now + REASSERT_INTERVAL), vec!["plant/a/gear"]);
        assert_eq!(
            guard.judge("plant/a/gear", "4", "4", now + REASSERT_INTERVAL),
            GuardVerdict::Fine
        );
        assert_eq!(
            guard.judge("plant/a/gear", "97", "4", now + REASSERT_INTERVAL * 2),
            GuardVerdict::Reassert
        );
    }
}
