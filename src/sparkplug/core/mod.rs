//! The edge node's rules, driven by [`super::driver`]:
//!
//! - [`protobuf`]: the Sparkplug B protobuf payload.
//! - [`metrics`]: profile fields as typed metrics, and command metrics back into command text.
//! - [`node_metrics`]: line statistics as node metrics, and the sampler that feeds them.
//! - [`session`]: the pure edge node state machine; [`session_interface`]: the plain data it
//!   takes and gives.
//! - [`bd_seq`]: the next bdSeq, kept in the state directory across restarts.

pub mod bd_seq;
pub mod metrics;
pub(crate) mod node_metrics;
pub mod protobuf;
pub mod session;
pub mod session_interface;
