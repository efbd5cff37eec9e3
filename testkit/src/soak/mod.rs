//! A soak run: the gateway binary as a process of its own over the seed plant on ptys and
//! [`rig::TCP_LINES`] Modbus TCP lines (100 devices), three Modbus TCP clients of its line
//! server, MQTT commands, and at random: broker outages (mosquitto killed and started again),
//! device drop-outs, SIGHUP reloads and journal outages (its tmpfs full during a broker
//! outage). At the end it checks that the gateway never panicked nor exited, that every alarm
//! state the seed dust collector took while the broker was away came on its history topic in
//! order, that no simulated device refused a write, and that anonymous memory, PSS and open
//! descriptors stayed flat over the second half of the run ([`sampler::Trend`]).
//!
//! One concern per file: `run` (the run from start to end), [`rig`] (the plant and the
//! gateway's configuration), `chaos` (the random events), [`observer`] (the MQTT client: commands sent, history and outcomes read),
//! [`sampler`] (what `/proc` says of the gateway, and the trend) and `report` (the checks and
//! figures printed at the end).
//!
//! `scripts/soak DURATION` runs it from the `soak` binary; `tests/it/reliability/soak.rs` runs
//! two minutes.

pub mod observer;
pub mod rig;
pub mod sampler;

mod chaos;
mod report;
mod run;

pub use self::report::Report;
pub use self::run::{run, Options};
