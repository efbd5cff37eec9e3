//! The simulator crate's own tests, one binary (`cargo test -p rtu2mqtt-sim`; `-- sim_tcp::`
//! runs one module):
//!
//! - `sim_pty`: the simulated devices over real pseudo-terminals, driven with raw frames.
//! - `sim_tcp`: the simulators behind a TCP port, raw RTU and Modbus TCP, with network faults.
//! - `hex`: frames written as spaced hex text.

mod hex;
mod sim_pty;
mod sim_tcp;
