//! Incoming packets larger than the gateway reads ([`super::connection::MAX_INCOMING_PACKET`]).
//! rumqttc reads such a packet's length, refuses it before reading its body and ends the
//! connection, which is made again after the usual back-off. What would bring the same packet
//! straight back is kept from doing so: a message the broker keeps for a persistent session
//! (the next connection starts a clean session, see the event loops) and a retained message,
//! which comes again with every subscription to a filter matching its topic.
//! [`SubscriptionWatch`] learns which subscription the broker had just acknowledged when the
//! packet came (a broker sends a subscription's retained messages right after its SUBACK), and
//! once the same one has ended [`CUTS_TO_LEAVE_OUT`] connections in a row it is left out of the
//! subscriptions for [`LEFT_OUT_FOR`], so that everything else goes on.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use rumqttc::{ConnectionError, Event, Outgoing, Packet, StateError};

/// How long a subscription that keeps bringing an oversized retained message is left out.
pub const LEFT_OUT_FOR: Duration = Duration::from_secs(3600);
/// Connections in a row ended right after the same subscription before it is left out: once
/// could be a live message that happened to come then.
pub const CUTS_TO_LEAVE_OUT: u32 = 2;

/// The size of the refused packet, when `error` is rumqttc refusing an incoming packet larger
/// than its limit.
pub fn oversized(error: &ConnectionError) -> Option<usize> {
    match error {
        ConnectionError::MqttState(StateError::Deserialization(
            rumqttc::Error::PayloadSizeLimitExceeded(size),
        )) => Some(*size),
        _ => None,
    }
}

/// What is known of where an oversized packet came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Blame {
    /// It did not follow a subscription's acknowledgement: a live message, most likely.
    Unknown,
    /// It came right after the broker acknowledged this subscription: a retained message on a
    /// topic it matches, most likely.
    After(String),
    /// The same, for the [`CUTS_TO_LEAVE_OUT`]th connection in a row: the subscription is left
    /// out from now on, for [`LEFT_OUT_FOR`].
    LeftOut(String),
}

/// The subscriptions of one MQTT connection as they go out and are acknowledged, and those
/// left out. Clones share it: the task that hands subscriptions to the client and the one that
/// polls its event loop.
#[derive(Debug, Clone, Default)]
pub struct SubscriptionWatch {
    inner: Arc<Mutex<Watch>>,
}

#[derive(Debug, Default)]
struct Watch {
    /// Filters handed to the client and not sent yet, in the order the client sends them.
    handed: VecDeque<String>,
    /// Sent on this connection and not acknowledged, by packet id.
    sent: HashMap<u16, String>,
    /// The subscription acknowledged last, while nothing but retained messages followed it.
    just_acked: Option<String>,
    /// The subscription the last oversized packets came right after, and how many connections
    /// in a row they ended.
    suspect: Option<(String, u32)>,
    /// Filters left out of the subscriptions until then.
    left_out: HashMap<String, Instant>,
}

impl SubscriptionWatch {
    fn lock(&self) -> MutexGuard<'_, Watch> {
        // Nothing in here is left half done by a panic elsewhere: the data is still good.
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Before `filter` is handed to the client: false when it is left out now (said in the
    /// log), true when it may go (and it is then expected to go out in this order).
    pub fn handing(&self, filter: &str, now: Instant) -> bool {
        let mut watch = self.lock();
        watch.left_out.retain(|_, until| *until > now);
        if let Some(until) = watch.left_out.get(filter) {
            tracing::warn!(subscription = %filter, left_out_for = %humantime::format_duration(
                Duration::from_secs(until.saturating_duration_since(now).as_secs())),
                "MQTT subscription left out: a retained message larger than the gateway reads \
                 lies on a topic it matches");
            return false;
        }
        watch.handed.push_back(filter.to_string());
        true
    }

    /// `filter`, just accepted by [`SubscriptionWatch::handing`], did not reach the client
    /// after all (its queue was full).
    pub fn not_handed(&self, filter: &str) {
        let mut watch = self.lock();
        if watch.handed.back().is_some_and(|last| last == filter) {
            watch.handed.pop_back();
        }
    }

    /// A new client: nothing handed to the one before will go out.
    pub fn new_client(&self) {
        let mut watch = self.lock();
        watch.handed.clear();
        watch.sent.clear();
        watch.just_acked = None;
    }

    /// What the client's event loop reported (or still held when the connection failed), in
    /// order.
    pub fn seen(&self, event: &Event) {
        let mut watch = self.lock();
        match event {
            Event::Outgoing(Outgoing::Subscribe(pkid)) => {
                if let Some(filter) = watch.handed.pop_front() {
                    watch.sent.insert(*pkid, filter);
                }
            }
            Event::Incoming(Packet::SubAck(ack)) => {
                if let Some(filter) = watch.sent.remove(&ack.pkid) {
                    watch.just_acked = Some(filter);
                }
            }
            // A live message: what comes after it is no subscription's retained message.
            Event::Incoming(Packet::Publish(publish)) if !publish.retain => {
                watch.just_acked = None;
            }
            Event::Incoming(Packet::ConnAck(_)) => {
                watch.sent.clear();
                watch.just_acked = None;
            }
            _ => {}
        }
    }

    /// The connection ended (after every event the client still held was [`seen`]).
    /// `unsent` are the subscriptions the client had taken and not sent, now dropped (the
    /// next connection subscribes anew), in order; `oversized` when an oversized packet ended
    /// it. Returns where that packet came from.
    ///
    /// [`seen`]: SubscriptionWatch::seen
    pub fn connection_ended(&self, unsent: &[String], oversized: bool, now: Instant) -> Blame {
        let mut watch = self.lock();
        for filter in unsent {
            if watch.handed.front() == Some(filter) {
                watch.handed.pop_front();
            } else {
                // Out of step with the client: forget what was handed rather than pair the
                // next subscriptions with the wrong filters.
                watch.handed.clear();
                break;
            }
        }
        watch.sent.clear();
        let just_acked = watch.just_acked.take();
        if !oversized {
            watch.suspect = None;
            return Blame::Unknown;
        }
        let Some(filter) = just_acked else {
            watch.suspect = None;
            return Blame::Unknown;
        };
        let cuts = match &watch.suspect {
            Some((suspect, cuts)) if *suspect == filter => cuts + 1,
            _ => 1,
        };
        if cuts >= CUTS_TO_LEAVE_OUT {
            watch.suspect = None;
            watch.left_out.insert(filter.clone(), now + LEFT_OUT_FOR);
            return Blame::LeftOut(filter);
        }
        watch.suspect = Some((filter.clone(), cuts));
        Blame::After(filter)
    }
}

/// Says why the connection ended: the packet's size and the limit, where it came from as far
/// as is known, and (`clean_next`) that the next connection starts a clean session.
pub fn log_oversized(connection: &str, size: usize, limit: usize, blame: &Blame, clean_next: bool) {
    let session = if clean_next {
        "; the next connection starts a clean session, so that the broker does not deliver it \
         again (what it kept for this session is dropped)"
    } else {
        ""
    };
    match blame {
        Blame::Unknown => tracing::error!(
            connection,
            size,
            limit,
            "an incoming MQTT message larger than the gateway reads was refused unread, which \
             closes the connection; it is made again{session}. A broker message_size_limit at \
             most the gateway's limit refuses such messages before they are sent"
        ),
        Blame::After(filter) => tracing::error!(
            connection, size, limit, subscription = %filter,
            "an incoming MQTT message larger than the gateway reads was refused unread, which \
             closes the connection; it is made again{session}. It came right after the broker \
             acknowledged the subscription: a retained message on a topic it matches comes \
             again with every subscription (clear it with an empty retained message, or set the \
             broker's message_size_limit to at most the gateway's limit)"
        ),
        Blame::LeftOut(filter) => tracing::error!(
            connection, size, limit, subscription = %filter,
            left_out_for = %humantime::format_duration(LEFT_OUT_FOR),
            "an incoming MQTT message larger than the gateway reads was refused unread, which \
             closes the connection; it is made again{session}. The subscription is left out of \
             the subscriptions: a retained message larger than the gateway reads on a topic it \
             matches ended {CUTS_TO_LEAVE_OUT} connections in a row right after it was \
             subscribed (clear it with an empty retained message, or set the broker's \
             message_size_limit to at most the gateway's limit)"
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rumqttc::{ConnAck, ConnectReturnCode, Publish, QoS, SubAck, SubscribeReasonCode};

    fn suback(pkid: u16) -> Event {
        Event::Incoming(Packet::SubAck(SubAck::new(
            pkid,
            vec![SubscribeReasonCode::Success(QoS::AtLeastOnce)],
        )))
    }

    fn publish(topic: &str, retain: bool) -> Event {
        let mut publish = Publish::new(topic, QoS::AtLeastOnce, "x");
        publish.retain = retain;
        Event::Incoming(Packet::Publish(publish))
    }

    /// A connection that subscribes `filters` in order and sees each acknowledged.
    fn subscribed(watch: &SubscriptionWatch, filters: &[&str], now: Instant) {
        watch.seen(&Event::Incoming(Packet::ConnAck(ConnAck::new(
            ConnectReturnCode::Success,
            false,
        ))));
        for (pkid, filter) in (1..).zip(filters) {
            if watch.handing(filter, now) {
                watch.seen(&Event::Outgoing(Outgoing::Subscribe(pkid)));
                watch.seen(&suback(pkid));
            }
        }
    }

    #[test]
    fn the_subscription_acknowledged_right_before_is_blamed_and_left_out_the_second_time() {
        let watch = SubscriptionWatch::default();
        let now = Instant::now();
        let filters = [
            "plant/+/+/set",
            "homeassistant/device/+/config",
            "plant/+/refresh",
        ];
        // The oversized packet follows the second subscription's acknowledgement and one of
        // its retained messages.
        subscribed(&watch, &filters[..2], now);
        watch.seen(&publish("homeassistant/device/a/config", true));
        let config = filters[1].to_string();
        assert_eq!(
            watch.connection_ended(&[], true, now),
            Blame::After(config.clone())
        );
        subscribed(&watch, &filters[..2], now);
        assert_eq!(
            watch.connection_ended(&[], true, now),
            Blame::LeftOut(config.clone())
        );
        // Left out of the next connections; the others still go, and are paired rightly.
        assert!(!watch.handing(&config, now));
        subscribed(&watch, &[filters[0], filters[2]], now);
        assert_eq!(
            watch.connection_ended(&[], true, now),
            Blame::After(filters[2].to_string())
        );
        // Until the time is up.
        assert!(watch.handing(&config, now + LEFT_OUT_FOR));
    }

    #[test]
    fn a_live_message_or_another_end_clears_the_blame() {
        let watch = SubscriptionWatch::default();
        let now = Instant::now();
        subscribed(&watch, &["a/#"], now);
        watch.seen(&publish("a/b", false));
        assert_eq!(watch.connection_ended(&[], true, now), Blame::Unknown);
        // Once after it, then a connection lost for another reason: no second in a row.
        subscribed(&watch, &["a/#"], now);
        assert_eq!(
            watch.connection_ended(&[], true, now),
            Blame::After("a/#".into())
        );
        subscribed(&watch, &["a/#"], now);
        assert_eq!(watch.connection_ended(&[], false, now), Blame::Unknown);
        subscribed(&watch, &["a/#"], now);
        assert_eq!(
            watch.connection_ended(&[], true, now),
            Blame::After("a/#".into())
        );
    }

    #[test]
    fn subscriptions_never_sent_are_not_paired_with_the_next_ones() {
        let watch = SubscriptionWatch::default();
        let now = Instant::now();
        // Two handed, the connection fails before either goes out: the client gives both
        // back; the next connection's subscription is paired with its own packet id.
        assert!(watch.handing("a/#", now));
        assert!(watch.handing("b/#", now));
        assert_eq!(
            watch.connection_ended(&["a/#".into(), "b/#".into()], false, now),
            Blame::Unknown
        );
        subscribed(&watch, &["c/#"], now);
        assert_eq!(
            watch.connection_ended(&[], true, now),
            Blame::After("c/#".into())
        );
        // One that never reached the client is not waited for either.
        assert!(watch.handing("d/#", now));
        watch.not_handed("d/#");
        subscribed(&watch, &["e/#"], now);
        assert_eq!(
            watch.connection_ended(&[], true, now),
            Blame::After("e/#".into())
        );
    }

    #[test]
    fn only_an_incoming_size_refusal_is_oversized() {
        let refused = ConnectionError::MqttState(StateError::Deserialization(
            rumqttc::Error::PayloadSizeLimitExceeded(67_108_873),
        ));
        assert_eq!(oversized(&refused), Some(67_108_873));
        let lost = ConnectionError::Io(std::io::Error::from(std::io::ErrorKind::UnexpectedEof));
        assert_eq!(oversized(&lost), None);
    }
}
