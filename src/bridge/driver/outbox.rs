//! The driver's own queue of what goes to the MQTT client: the client's request queue is kept
//! short, and everything waiting is held here, where it can be ordered and bounded. Control
//! requests (subscriptions, the Disconnect) go first, then outcomes and state, then re-sends
//! (discovery documents, statistics). A retained topic is queued once: a newer payload replaces
//! the waiting one in place (newest wins). On a lost connection everything the core publishes
//! again on the next one (state, availability, discovery) is dropped, so nothing stale goes out
//! after a reconnect; outcomes and clears are kept. Pure data: no client, no clock.

use std::collections::{HashMap, VecDeque};

use rumqttc::QoS;

use crate::bridge::core::Publish;

/// Entries held at most; beyond, the oldest re-send, then the oldest entry, is dropped (and
/// reported by [`Outbox::push`]).
pub(crate) const MAX_OUTBOX: usize = 100_000;

/// One order for the MQTT client, as the writer task carries it out.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum ClientOrder {
    Publish(Publish),
    Subscribe { filter: String, qos: QoS },
    Unsubscribe { filter: String },
    Disconnect,
}

/// How urgent a publish is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Urgency {
    /// Outcomes, clears, state, availability.
    Urgent,
    /// Documents the core sends again anyway (discovery, statistics).
    Resend,
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum Entry {
    Once(Publish),
    /// The newest payload for this retained topic is in `retained`.
    Retained(String),
    /// A (un)subscription that keeps its place among the publishes.
    InTurn(ClientOrder),
}

#[derive(Debug, Default)]
pub(crate) struct Outbox {
    control: VecDeque<ClientOrder>,
    urgent: VecDeque<Entry>,
    resend: VecDeque<Entry>,
    retained: HashMap<String, Publish>,
}

impl Outbox {
    /// Entries waiting (a coalesced retained topic counts once).
    pub(crate) fn len(&self) -> usize {
        self.control.len() + self.urgent.len() + self.resend.len()
    }

    /// Entries of [`Urgency::Resend`] waiting (discovery documents, statistics).
    pub(crate) fn resend_len(&self) -> usize {
        self.resend.len()
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub(crate) fn push_control(&mut self, request: ClientOrder) {
        self.control.push_back(request);
    }

    /// Queues a (un)subscription behind the urgent publishes already waiting.
    pub(crate) fn push_in_turn(&mut self, request: ClientOrder) {
        self.urgent.push_back(Entry::InTurn(request));
    }

    /// Queues `publish`; returns what had to be dropped to stay within [`MAX_OUTBOX`].
    pub(crate) fn push(&mut self, publish: Publish, urgency: Urgency) -> Option<Publish> {
        if publish.retain {
            if let Some(queued) = self.retained.get_mut(&publish.topic) {
                let keep = queued.keep || publish.keep;
                *queued = Publish { keep, ..publish };
                return None;
            }
        }
        let dropped = if self.len() >= MAX_OUTBOX {
            self.drop_oldest()
        } else {
            None
        };
        let entry = if publish.retain {
            let topic = publish.topic.clone();
            self.retained.insert(topic.clone(), publish);
            Entry::Retained(topic)
        } else {
            Entry::Once(publish)
        };
        match urgency {
            Urgency::Urgent => self.urgent.push_back(entry),
            Urgency::Resend => self.resend.push_back(entry),
        }
        dropped
    }

    fn drop_oldest(&mut self) -> Option<Publish> {
        let entry = self
            .resend
            .pop_front()
            .or_else(|| self.urgent.pop_front())?;
        self.resolve(entry)
    }

    fn resolve(&mut self, entry: Entry) -> Option<Publish> {
        match entry {
            Entry::Once(publish) => Some(publish),
            Entry::Retained(topic) => self.retained.remove(&topic),
            Entry::InTurn(_) => None,
        }
    }

    /// Takes out the waiting publishes `wanted` picks (never retained ones), in their order.
    pub(crate) fn take_where(&mut self, wanted: impl Fn(&Publish) -> bool) -> Vec<Publish> {
        let mut taken = Vec::new();
        self.urgent.retain(|entry| match entry {
            Entry::Once(publish) if wanted(publish) => {
                taken.push(publish.clone());
                false
            }
            _ => true,
        });
        taken
    }

    /// The next request in priority order.
    pub(crate) fn pop(&mut self) -> Option<ClientOrder> {
        if let Some(control) = self.control.pop_front() {
            return Some(control);
        }
        while let Some(entry) = self.urgent.pop_front().or_else(|| self.resend.pop_front()) {
            if let Entry::InTurn(request) = entry {
                return Some(request);
            }
            if let Some(publish) = self.resolve(entry) {
                return Some(ClientOrder::Publish(publish));
            }
        }
        None
    }

    /// The connection is gone: what the next connection publishes afresh is dropped, outcomes
    /// and clears (`keep`) stay. Returns how many were dropped.
    pub(crate) fn on_disconnect(&mut self) -> usize {
        let before = self.len();
        self.control.clear();
        self.resend.clear();
        let retained = &self.retained;
        // A new connection makes its own subscriptions.
        self.urgent.retain(|entry| match entry {
            Entry::Once(publish) => publish.keep,
            Entry::Retained(topic) => retained.get(topic).is_some_and(|p| p.keep),
            Entry::InTurn(_) => false,
        });
        let kept: std::collections::HashSet<&String> = self
            .urgent
            .iter()
            .filter_map(|entry| match entry {
                Entry::Retained(topic) => Some(topic),
                Entry::Once(_) | Entry::InTurn(_) => None,
            })
            .collect();
        let stale: Vec<String> = self
            .retained
            .keys()
            .filter(|topic| !kept.contains(topic))
            .cloned()
            .collect();
        for topic in stale {
            self.retained.remove(&topic);
        }
        before - self.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn publish(topic: &str, payload: &str, retain: bool, keep: bool) -> Publish {
        Publish {
            topic: topic.to_string(),
            payload: payload.to_string(),
            qos: QoS::AtLeastOnce,
            retain,
            keep,
        }
    }

    fn topics_in_order(outbox: &mut Outbox) -> Vec<String> {
        std::iter::from_fn(|| outbox.pop())
            .map(|request| match request {
                ClientOrder::Publish(p) => format!("{}={}", p.topic, p.payload),
                ClientOrder::Subscribe { filter, .. } => format!("sub {filter}"),
                ClientOrder::Unsubscribe { filter } => format!("unsub {filter}"),
                ClientOrder::Disconnect => "disconnect".to_string(),
            })
            .collect()
    }

    #[test]
    fn control_first_then_urgent_then_resends_and_newest_retained_wins_in_place() {
        let mut outbox = Outbox::default();
        outbox.push(publish("ha/config", "{}", true, false), Urgency::Resend);
        outbox.push(publish("p/a/gear", "3", true, false), Urgency::Urgent);
        outbox.push(
            publish("p/a/gear/result", "r1", false, true),
            Urgency::Urgent,
        );
        outbox.push(publish("p/a/gear", "4", true, false), Urgency::Urgent);
        outbox.push_control(ClientOrder::Subscribe {
            filter: "p/+/+/set".to_string(),
            qos: QoS::AtLeastOnce,
        });
        assert_eq!(outbox.len(), 4);
        assert_eq!(
            topics_in_order(&mut outbox),
            [
                "sub p/+/+/set",
                "p/a/gear=4",
                "p/a/gear/result=r1",
                "ha/config={}"
            ]
        );
        assert!(outbox.is_empty());
    }

    #[test]
    fn a_subscription_in_turn_keeps_its_place_behind_earlier_publishes() {
        let mut outbox = Outbox::default();
        outbox.push(publish("p/a/gear", "3", true, false), Urgency::Urgent);
        outbox.push_in_turn(ClientOrder::Subscribe {
            filter: "p/a/+".to_string(),
            qos: QoS::AtLeastOnce,
        });
        // A newer payload for a topic queued before takes the older one's place.
        outbox.push(publish("p/a/gear", "4", true, false), Urgency::Urgent);
        outbox.push(publish("p/a/power", "ON", true, false), Urgency::Urgent);
        outbox.push_in_turn(ClientOrder::Unsubscribe {
            filter: "p/a/+".to_string(),
        });
        assert_eq!(
            topics_in_order(&mut outbox),
            ["p/a/gear=4", "sub p/a/+", "p/a/power=ON", "unsub p/a/+"]
        );
        // A lost connection drops them: the next one makes its own.
        outbox.push_in_turn(ClientOrder::Unsubscribe {
            filter: "p/a/+".to_string(),
        });
        assert_eq!(outbox.on_disconnect(), 1);
        assert!(outbox.is_empty());
    }

    #[test]
    fn a_lost_connection_keeps_outcomes_and_clears_only() {
        let mut outbox = Outbox::default();
        outbox.push(publish("p/a/gear", "3", true, false), Urgency::Urgent);
        outbox.push(
            publish("p/a/gear/result", "r1", false, true),
            Urgency::Urgent,
        );
        outbox.push(publish("p/a/gear/set", "", true, true), Urgency::Urgent);
        outbox.push(publish("ha/config", "{}", true, false), Urgency::Resend);
        assert_eq!(outbox.on_disconnect(), 2);
        assert_eq!(
            topics_in_order(&mut outbox),
            ["p/a/gear/result=r1", "p/a/gear/set="]
        );
    }

    #[test]
    fn taken_publishes_leave_in_order_and_the_rest_stays() {
        let mut outbox = Outbox::default();
        let once = |topic: &str| Publish {
            topic: topic.to_string(),
            payload: String::new(),
            qos: QoS::AtLeastOnce,
            retain: false,
            keep: true,
        };
        for topic in ["a/history", "a/result", "b/history"] {
            outbox.push(once(topic), Urgency::Urgent);
        }
        let taken = outbox.take_where(|publish| publish.topic.ends_with("history"));
        let topics: Vec<&str> = taken.iter().map(|p| p.topic.as_str()).collect();
        assert_eq!(topics, ["a/history", "b/history"]);
        assert_eq!(outbox.pop(), Some(ClientOrder::Publish(once("a/result"))));
        assert_eq!(outbox.pop(), None);
    }
}
