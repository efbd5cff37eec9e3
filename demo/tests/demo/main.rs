//! The demo's tests: the `rtu2mqtt-demo` binary with its embedded broker (or a mosquitto of the
//! harness), watched on MQTT like a user would (`plant_demo`), and its live table on a real
//! terminal, tmux (`screen`).

use rtu2mqtt_testkit as support;

/// The demo binary under test.
const DEMO: &str = env!("CARGO_BIN_EXE_rtu2mqtt-demo");

mod plant_demo;
mod screen;
