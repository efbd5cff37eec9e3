//! What the core is given from outside its rules: an incoming MQTT message ([`Incoming`],
//! as much of it as the rules look at) and a command from outside the plain topics
//! ([`ExternalCommand`]).

use rumqttc::QoS;

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
