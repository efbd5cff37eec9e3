//! The profile crate's own tests, one binary (`cargo test -p rtu2mqtt-profile`; `--
//! profiles_golden::` runs one module):
//!
//! - `profiles_valid`: every profile file loads and validates; broken ones are refused with
//!   errors that name the file and the key.
//! - `profiles_golden`: the built-in profiles against docs/devices.md, request and value, byte
//!   for byte, and against the simulated devices.
//! - `number_grammar`: the one number grammar of every numeric command.
//! - `fuzz_smoke`: hostile frames, profile text and commands never panic.
//! - `support`: what they share (the configuration and profile directories, a command's refusal, frames as hex text).

mod fuzz_smoke;
mod number_grammar;
mod profiles_golden;
mod profiles_valid;
mod support;
