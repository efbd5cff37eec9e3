//! The lines: reading devices on a bus and sharing it.
//!
//! - `pty_line`: the line task over real pseudo-terminals with the simulated seed devices.
//! - `tcp_lines`: lines over the network (a serial device server, a Modbus TCP gateway).
//! - `line_server`: a served line (`[lines.serve]`) to pymodbus clients beside the gateway.
//! - `cadence`: per-block cadence end to end.
//! - `scheduler_cadence`, `scheduler_time`: the bus scheduler as a pure function of time.

pub(crate) mod cadence;
mod line_server;
mod pty_line;
mod scheduler_cadence;
mod scheduler_time;
mod tcp_lines;
