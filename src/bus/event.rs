//! What a line reports to the bridge ([`LineEvent`]) and why a report carries its values
//! ([`Origin`]).

use rtu2mqtt_profile::Value;

use super::command::CommandOutcome;

/// What a line reports to the bridge.
#[derive(Debug, Clone, PartialEq)]
pub enum LineEvent {
    /// Freshly decoded values of a device: of a poll, the fields whose registers moved since
    /// the block's last answer (every field of it after the device came online); of a
    /// command's reads, every field of the blocks read.
    Values {
        device: String,
        values: Vec<(String, Value)>,
        /// When the answers were read (wall clock: the history stream's `ts`).
        read_at: std::time::SystemTime,
        /// Why they are reported.
        origin: Origin,
    },
    Availability {
        device: String,
        online: bool,
    },
    /// A command's end, sent after the `Values` of the reads its slot made (so its state is
    /// out before its result).
    CommandFinished {
        /// The [`Command::id`](super::command::Command::id) it answers.
        id: u64,
        device: String,
        outcome: CommandOutcome,
    },
    /// A write reached `device` (or may have: its answer was lost), from any source, and
    /// started the write interval of `fields` (those of the write that have one). Sent before
    /// the `Values` and the end of the slot that wrote.
    Written {
        device: String,
        fields: Vec<String>,
        /// When the slot that wrote ended.
        at: std::time::Instant,
    },
    /// A write from a client of the line's server ran as a command slot (sent after the
    /// `Values` of its reads): its outcome is published like a command's, though no MQTT
    /// command asked for it.
    ClientWriteFinished {
        device: String,
        /// The field (or the profile's shared write frame) written.
        field: String,
        /// The value written, as a command would carry it.
        value: String,
        /// Who wrote (the client's address).
        client: String,
        outcome: CommandOutcome,
    },
}

/// Why a [`LineEvent::Values`] carries its values.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Origin {
    /// A poll read them (with `publish` settings: and they passed their rule).
    #[default]
    Poll,
    /// A command's slot (or its settle re-reads) read them: published whatever the rule.
    Command,
    /// Unchanged, republished because the field's `max_interval` passed: consumers publish
    /// these values even where they equal what they published last.
    Heartbeat,
}
