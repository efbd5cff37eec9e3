//! Faults and pressure, each with its bound (docs/reliability.md):
//!
//! - `reliability`: one fault per test, the figure a plant cares about bounded.
//! - `bridge_reliability`: exactly one outcome per command under floods.
//! - `crash_exactly_once`: a crash at every step of a command's life.
//! - `oversized_messages`: messages larger than the gateway reads.
//! - `history`: values measured while the broker is away come out after it is back.
//! - `soak`: two minutes of the soak run.

mod bridge_reliability;
mod crash_exactly_once;
mod history;
mod oversized_messages;
#[allow(clippy::module_inception)]
mod reliability;
mod soak;
