//! The task that owns one line: its loop. It keeps the link open ([`super::port`]: a serial
//! port or a TCP connection, the same loop for both),
//! asks the [`Scheduler`] what is due, runs command slots and settle re-reads
//! ([`super::command`]) before polls ([`super::poll`]), carries out what they report, turns
//! answers into values through each
//! device's runtime ([`super::device`]) and reports [`LineEvent`]s. It publishes [`LineStats`]
//! after every transaction and at least once a second.
//!
//! Its command side (commands, refreshes, settle re-reads, the write clock) is in
//! [`command_side`], its served side (clients' requests as line slots) in [`client_requests`];
//! both are further `impl Line` blocks on the one state this file owns.
//!
//! A served line ([`super::serve`]) takes its clients' requests when no command waits, one
//! client slot at a time and a due poll between two of them; reads a young poll answered
//! exactly (or, of a block the device reads linearly, in part) come from its cache.
//!
//! A port path that is no serial port fails the line without ending the daemon: its devices
//! are offline, every attempt logs an ERROR naming the path, and the gateway's other lines
//! keep serving their devices.
//!
//! A transaction is never cancelled half-way: shutdown, commands and timers are only looked at
//! between transactions, so the line is always left with a complete frame exchange on it.
//!
//! Files: [`task`] (the state and the loop), `command_side` and `client_requests`.

mod client_requests;
mod command_side;
mod task;

pub(crate) use task::default_response_timeout;
use task::Line;
pub use task::{spawn_line, spawn_line_in_phase, spawn_line_with_clock, LineHandle};
