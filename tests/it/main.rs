//! The integration tests, one binary, grouped by area (`cargo test --test it lines::` runs an
//! area, `cargo test --test it lines::pty_line::` one module):
//!
//! - `wire`: the wire against peers written by others (pymodbus).
//! - `lines`: reading devices on a bus, scheduling, sharing a line.
//! - `profiles`: profiles end to end through the gateway.
//! - `bridge`: the plant on MQTT: values, commands, discovery, views, TLS.
//! - `reliability`: faults and pressure, each with its bound.
//! - `sparkplug`: Sparkplug B.
//! - `daemon`: the process as an operator runs it: start, health, logs, reload, the console.
//! - `cli`: commissioning, `profiles`, `check`, the manual pages.
//! - `packaging`: container, Debian package, systemd unit.
//! - `repository`: the layers, the module maps and the documents.
//!
//! `support` is what they share (a real mosquitto, an MQTT test client, the gateway over the
//! simulated plant, child processes, frames as hex text). Each crate's own tests live in its
//! `tests/` (`cargo test -p rtu2mqtt-modbus` runs the golden frames).

use rtu2mqtt_testkit as support;

mod bridge;
mod cli;
mod daemon;
mod lines;
mod packaging;
mod profiles;
mod reliability;
mod repository;
mod sparkplug;
mod wire;
