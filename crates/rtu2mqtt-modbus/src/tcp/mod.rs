//! Modbus over TCP: [`masters`] runs transactions through a serial device server (raw RTU
//! frames on a TCP stream) or a Modbus TCP gateway, whose framing [`mbap`] reads and writes.

pub mod masters;
pub mod mbap;
