//! rtu2mqtt-modbus: the Modbus RTU wire protocol, everything between a [`frame::Request`] and
//! the bytes on an RS485 line, a serial device server's TCP stream or a Modbus TCP gateway.
//! Grouped as tokio-modbus groups its `rtu` and `tcp`:
//!
//! - Pure, no I/O and no tokio: [`frame`] (the types with the specification's names and their
//!   arithmetic), [`crc`], [`codec`] (byte work, and [`decode_error`]: why bytes are not the
//!   answer), [`device_id`] (FC43/14 Read Device Identification: its types and byte work),
//!   [`timing`] (character time, t1.5, t3.5, the response timeout), `outcome` (how a transaction ends: [`Reply`], [`Error`],
//!   [`WireCounters`], re-exported here).
//! - What every link shares: [`answer_framing`] (the one framer of their answers) and
//!   `transaction` (the [`Transact`] wrapper, re-exported here, with the counters, frame
//!   recorder and late-answer guard inside the crate), so that the three links frame, count,
//!   record and guard alike.
//! - [`serial`]: the RS485 line: [`serial::transport`] (the serial port, the only code here
//!   that touches one), [`serial::master`] (one RTU transaction at a time with the
//!   serial-line specification's timing) and [`serial::reception`] (how the master frames an
//!   answer from its port's reads and silences, without I/O or clock).
//! - [`tcp`]: the TCP masters in [`tcp::masters`] (a serial device server's raw RTU stream, or
//!   Modbus TCP through [`tcp::mbap`]).
//! - [`link`]: what a line holds, whichever of the three it is ([`link::Link`]), opened by
//!   [`link::Link::open`]; the one list of the transports, their url schemes and names.
//! - [`clock`]: the precise wait the line's silences need; [`frame_log`]: the frames of every
//!   line written to one file from a thread of its own; [`live_frames`]: the same records handed
//!   to whoever watches them live.

// Kept true on every build, as in the daemon: `pub` is the crate's surface and each public item
// says what it is, every public type prints with `{:?}`, the 2018 idioms.
#![warn(
    unreachable_pub,
    missing_docs,
    missing_debug_implementations,
    rust_2018_idioms
)]

pub mod answer_framing;
pub mod clock;
pub mod codec;
pub mod crc;
pub mod decode_error;
pub mod device_id;
pub mod frame;
pub mod frame_log;
pub mod link;
pub mod live_frames;
mod outcome;
pub mod serial;
pub mod tcp;
pub mod timing;
mod transaction;

// The README's example compiles as a doctest.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;

pub use device_id::{DeviceIdObject, DeviceIdentification, ReadDeviceIdCode};
pub use frame::{ExceptionCode, FunctionCode, Request, Response, SlaveId};
pub use outcome::{Error, PortFault, Reply, WireCounters};
pub use transaction::{FrameSink, Transact};
