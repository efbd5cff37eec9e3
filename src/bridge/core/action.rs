//! What the bridge core asks its driver to do: the [`Action`]s (publish, subscribe, hand a
//! command or a refresh request to a line, report an external command's end, carry a change set to the history
//! stream) and the messages they carry.

use rumqttc::QoS;

use crate::bus::Command;

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
    /// Subscribe ahead of everything queued.
    Subscribe {
        filter: String,
        qos: QoS,
    },
    /// Subscribe behind what is already queued: what the broker then hands over holds every
    /// publish decided before.
    SubscribeInTurn {
        filter: String,
        qos: QoS,
    },
    /// Unsubscribe behind what is already queued (never ahead of its subscription).
    UnsubscribeInTurn {
        filter: String,
    },
    /// Hand `command` to line number `line`; report a refusal with
    /// [`super::Core::on_send_failed`].
    Send {
        line: usize,
        command: Command,
    },
    /// Ask line number `line` to read every block of `device` in its next slots
    /// (`<prefix>/<device>/refresh`); nothing comes back.
    Refresh {
        line: usize,
        device: String,
    },
    /// Tell the sender of an external command how it ended.
    Report(CommandReport),
    /// A change set for the history stream: published (QoS 1, not retained) when the broker
    /// is there and nothing older waits in the journal, journaled otherwise.
    History(HistoryEntry),
}

/// One device's change set on its history topic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HistoryEntry {
    pub device: String,
    /// `<prefix>/<device>/history`.
    pub topic: String,
    /// When the answers were read, in milliseconds since the Unix epoch.
    pub at_ms: u64,
    /// `{"ts":…,"values":{…}}`.
    pub document: String,
}

/// How an external command (a Sparkplug DCMD) ended: `applied` only when the device took the
/// value; any other end (refused, superseded, expired, failed, not applied) lets the sender
/// show the device's true value again.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandReport {
    pub device: String,
    pub field: String,
    pub applied: bool,
}
