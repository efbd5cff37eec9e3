//! One task per line (a serial port or a TCP link). [`spawn_line`] starts it: it owns the port (through
//! [`rtu2mqtt_modbus::serial::master::Master`]), asks the pure [`scheduler`] what is due, runs polls and
//! command slots (read → write → read-back, nothing interleaved), tracks device health
//! (offline after N failures, capped back-off probing) and line statistics, and reports
//! [`LineEvent`]s. Commands arrive on [`LineHandle::command_tx`] (a [`command::queue`]) and run
//! before the next poll;
//! refresh requests (a device's every block read at once) on [`LineHandle::refresh_tx`], served
//! after the commands and ahead of the polls.
//! A line with a [`serve::ServeSpec`] also serves other Modbus masters through [`serve`]: their
//! requests are slots of the same scheduler, after commands and before polls.
//! Fields with `publish` settings are reported by exception ([`report`], applied by the line's
//! [`reporter`] task), so every consumer of the events sees the same series.
//!
//! One concern per file: `line` (the line's task: its loop, its commands' side and its served
//! side), `line_spec` and `device_spec` (what a line and a device are started with), `port`
//! (the link opened through the wire crate, with one reopen back-off), `device` (a device's
//! state on the line), `poll` (one block's read, with the exception-02 fallback), [`command`]
//! (a command from its queue to its outcome), `transaction` (one request with its retries),
//! [`cadence`] (each block's cadence), [`scheduler`] (what is due), [`availability`] (offline
//! and back-off), [`stats`] (the line's statistics), `event` (what a line reports),
//! `write_clock` (when each field was last written, by any source), [`report`] and [`reporter`]
//! (report by exception), [`serve`] (the line served to other masters).

pub mod availability;
pub mod cadence;
pub mod command;
pub(crate) mod device;
pub(crate) mod device_spec;
pub(crate) mod event;
pub(crate) mod line;
pub(crate) mod line_spec;
pub(crate) mod poll;
pub(crate) mod port;
pub(crate) mod report;
pub(crate) mod reporter;
pub mod scheduler;
pub mod serve;
pub mod stats;
pub(crate) mod transaction;
pub(crate) mod write_clock;

pub use command::{Command, CommandFailure, CommandOutcome};
pub use device_spec::DeviceSpec;
pub use event::{LineEvent, Origin};
pub use line_spec::{FrameRecorders, LineSpec, Transport};
pub use stats::LineStats;
pub use write_clock::WriteClock;

pub use line::{spawn_line, spawn_line_in_phase, spawn_line_with_clock, LineHandle};
