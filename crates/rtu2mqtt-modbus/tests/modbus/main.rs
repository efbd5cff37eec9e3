//! The wire crate's own tests, one binary (`cargo test -p rtu2mqtt-modbus`; `-- golden_frames::`
//! runs one module):
//!
//! - `golden_frames`: every frame of docs/devices.md, byte for byte, both ways.
//! - `codec_props`: every request and answer survives encode → decode; no bytes make a decoder
//!   panic.
//! - `pty_master`: the master against a scripted device on a real pseudo-terminal pair.
//! - `answer_gaps`: answers that pause inside, and a master started while an answer is on the
//!   wire, against a paced simulated device.
//!
//! Its tests against pymodbus, which need the workspace's test harness, are in `tests/it/wire`.

mod answer_gaps;
mod codec_props;
mod golden_frames;
mod pty_master;
