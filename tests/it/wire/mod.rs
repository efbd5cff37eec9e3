//! The wire against peers written by others, where the daemon's test harness is needed:
//!
//! - `device_identification`: Read Device Identification against the frames pymodbus builds.
//! - `pymodbus_rtu`: the master against pymodbus's own RTU server behind a byte pacer.
//! - `sim_tcp`: pymodbus reads the TCP simulator; the demo's `simulate` serves a line over TCP.
//!
//! The wire crate's own tests (golden frames, codec properties, the pty master) are in
//! crates/rtu2mqtt-modbus/tests, the simulator's in crates/rtu2mqtt-sim/tests.

mod device_identification;
mod pymodbus_rtu;
mod sim_tcp;
