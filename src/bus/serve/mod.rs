//! The line shared with other Modbus masters: a server in front of a line (`[lines.serve]`)
//! that takes Modbus TCP (or RTU over TCP) requests from clients and hands each one to the
//! line task as a slot of its scheduler, so the line keeps its one master and its timing.
//!
//! [`spec`] is what a served line is (its URL, framing, [`Access`] and places) and what a client
//! asks of it ([`ClientRequest`]); [`policy`] decides, without I/O, what a request may do under
//! the line's access;
//! [`server`] accepts clients and frames their requests, [`places`] decides who holds the
//! `max_clients` places; [`queue`] is the line task's side of the requests' channel and the
//! cache of polled blocks it answers reads from, and `served_side` is everything a line task
//! keeps of its clients (their turn, the cache, counters, settling writes, the answers' rules).
//! The line task runs their requests as slots (`bus::line`'s `client_requests`). `fuzzing`
//! drives one connection with bytes alone, for the fuzz targets.

#[doc(hidden)]
pub mod fuzzing;
pub mod places;
pub(crate) mod policy;
pub(crate) mod queue;
pub(crate) mod served_side;
pub(crate) mod server;
pub mod spec;

pub use spec::{Access, ClientRequest, ServeFraming, ServeSpec, DEFAULT_MAX_CLIENTS};
