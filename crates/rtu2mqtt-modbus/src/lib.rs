//! The Modbus RTU wire protocol: everything between a [`frame::Request`] and the bytes on an
//! RS485 line, a serial device server's TCP stream or a Modbus TCP gateway.
//!
//! `crc`, `frame`, `codec` and `timing` are pure (no I/O, no tokio). `clock` holds the precise
//! sleep the line's silences need. `transport` is the only code in the crate that touches a
//! serial port; `master` runs one transaction at a time on it with the serial-line
//! specification's timing. `tcp_link` runs them over TCP (a serial device server's raw stream,
//! or Modbus TCP with `mbap`); `link` is what a line holds, whichever of them it is.
//! `answer_framing` is the one framer of their answers, `outcome` how a transaction ends, and
//! `link_core` what the three share (the transaction wrapper, counters, frame recorder,
//! late-answer guard). `frame_log` writes the frames of every line to one file from a thread
//! of its own.

// Kept true on every build, as in the daemon: `pub` is the crate's surface, every public type
// prints with `{:?}`, the 2018 idioms.
#![warn(unreachable_pub, missing_debug_implementations, rust_2018_idioms)]

pub mod answer_framing;
pub mod clock;
pub mod codec;
pub mod crc;
pub mod frame;
pub mod frame_log;
pub mod link;
pub mod link_core;
pub mod master;
pub mod mbap;
pub mod outcome;
pub mod tcp_link;
pub mod timing;
pub mod transport;

// The README's example compiles as a doctest.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;

pub use frame::{ExceptionCode, FunctionCode, Request, Response, SlaveId};
pub use link_core::Transact;
pub use outcome::{Error, PortFault, Reply, WireCounters};
