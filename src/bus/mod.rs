//! One task per line (a serial port or a TCP link). [`spawn_line`] starts it: it owns the port (through
//! [`rtu2mqtt_modbus::serial::master::Master`]), asks the pure [`scheduler`] what is due, runs polls and
//! command slots (read → write → read-back, nothing interleaved), tracks device health
//! (offline after N failures, capped back-off probing) and line statistics, and reports
//! [`LineEvent`]s. Commands arrive on [`LineHandle::command_tx`] (a [`command_queue`]) and run before the next poll;
//! refresh requests (a device's every block read at once) on [`LineHandle::refresh_tx`], served
//! after the commands and ahead of the polls.
//! A line with a [`serve::ServeSpec`] also serves other Modbus masters through [`serve`]: their
//! requests are slots of the same scheduler, after commands and before polls.
//! Fields with `publish` settings are reported by exception ([`report`], applied by the line's
//! [`reporter`] task), so every consumer of the events sees the same series.

pub mod availability;
pub mod cadence;
pub mod command_queue;
mod commands;
pub(crate) mod device;
pub(crate) mod line;
pub(crate) mod outcome;
pub(crate) mod poll;
pub(crate) mod port;
pub(crate) mod report;
pub(crate) mod reporter;
pub mod scheduler;
pub mod serve;
pub(crate) mod slot;
pub mod stats;
pub(crate) mod transaction;
pub(crate) mod write_clock;

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{mpsc, watch};

use rtu2mqtt_modbus::serial::transport::SerialSettings;
use rtu2mqtt_modbus::tcp::masters::{TcpEndpoint, TcpKind, TcpOptions};
use rtu2mqtt_modbus::SlaveId;
use rtu2mqtt_profile::{CommandPlan, Profile, PublishRule, Value};

pub use outcome::CommandFailure;
pub use stats::LineStats;
pub use write_clock::WriteClock;

/// One configured device on a line.
#[derive(Debug, Clone)]
pub struct DeviceSpec {
    pub name: String,
    pub address: SlaveId,
    pub profile: Arc<Profile>,
    /// Zero: continuously, as often as the profile's minimum allows.
    pub poll_interval: Duration,
    /// When values are published, for every field whose profile leaves a key unset.
    pub publish: PublishRule,
}

/// What a line talks through.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Transport {
    /// The serial port at [`LineSpec::serial`]'s path.
    Serial,
    /// A serial device server (`tcp://`: raw RTU, timed by [`LineSpec::serial`]'s baud and
    /// format) or a Modbus TCP gateway (`modbus-tcp://`).
    Tcp {
        endpoint: TcpEndpoint,
        options: TcpOptions,
        /// Added to the default response timeout for the network's round trip.
        network_allowance: Duration,
    },
}

impl Transport {
    /// How `check` and the logs name it.
    pub fn describe(&self, serial: &SerialSettings) -> String {
        match self {
            Transport::Serial => format!("serial port {}", serial.path),
            Transport::Tcp { endpoint, .. } => match endpoint.kind {
                TcpKind::RawRtu => format!("serial device server {} (raw RTU)", endpoint.url()),
                TcpKind::ModbusTcp => format!("Modbus TCP gateway {}", endpoint.url()),
            },
        }
    }
}

/// One configured line with its devices.
#[derive(Debug, Clone)]
pub struct LineSpec {
    pub name: String,
    /// The serial port and its character format. On a TCP line `path` holds the url (for logs)
    /// and baud and format time the server's serial side.
    pub serial: SerialSettings,
    pub transport: Transport,
    /// None: derived from baud and the longest expected answer plus a device margin.
    pub response_timeout: Option<Duration>,
    /// Retries after a failed transaction (timeout, CRC, truncated answer).
    pub retries: u32,
    /// Consecutive failed polls after which a device is reported offline.
    pub offline_after: u32,
    /// The adapter echoes what it sends.
    pub echo: bool,
    /// Silence after a broadcast write.
    pub broadcast_turnaround: Duration,
    /// Longest pause inside an answer (None: the master's default).
    pub byte_timeout: Option<Duration>,
    /// Record every frame of the line here (`gateway.frame_log`).
    pub frame_log: Option<rtu2mqtt_modbus::frame_log::FrameLog>,
    pub devices: Vec<DeviceSpec>,
    /// The line served to other Modbus masters (`[lines.serve]`; none: not served).
    pub serve: Option<serve::ServeSpec>,
}

/// What a line reports to the bridge.
#[derive(Debug, Clone, PartialEq)]
pub enum LineEvent {
    /// Freshly decoded values of a device (every field of the blocks just read).
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
        /// The [`Command::id`] it answers.
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

/// How a command ended on the bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CommandOutcome {
    /// Written, and the read-back shows the value.
    Applied { detail: String },
    /// Acknowledged, but the read-back differs.
    NotApplied { detail: String },
    /// Refused by the profile's rules on the fresh state: nothing written.
    Rejected { detail: String },
    /// An exception answer, no answer after the retries, or the port is gone.
    Failed { cause: CommandFailure },
}

/// A command for the line's queue. Its end comes back as [`LineEvent::CommandFinished`] with
/// the same `id`, on the line's events channel.
#[derive(Debug)]
pub struct Command {
    /// Chosen by the sender; the line only echoes it.
    pub id: u64,
    pub device: String,
    pub plan: CommandPlan,
}

/// The bridge's handle on a running line.
#[derive(Debug, Clone)]
pub struct LineHandle {
    pub name: String,
    pub command_tx: command_queue::CommandSender,
    /// Refresh requests, by device name: each of the device's blocks is read in the line's next
    /// slots and what changed is reported.
    pub refresh_tx: mpsc::Sender<String>,
    pub stats_rx: watch::Receiver<LineStats>,
}

pub use line::{spawn_line, spawn_line_in_phase, spawn_line_with_clock};
