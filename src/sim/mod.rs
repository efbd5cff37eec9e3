//! Simulated devices built from profiles, with per-device behaviour, wire pacing and fault
//! injection, served on a (pseudo-)serial port.

pub mod cli;
