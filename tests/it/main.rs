//! The integration tests, one binary: each module is one area's tests (`cargo test --test it
//! pty_line::` runs one of them), `support` is what they share (a real mosquitto, an MQTT test
//! client, the gateway over the simulated plant, child processes, frames as hex text).

use rtu2mqtt_testkit as support;

mod acceptance;
mod actions;
mod answer_gaps;
mod bridge_reliability;
mod cadence;
mod calm_start;
mod cli_docs;
mod codec_props;
mod commissioning;
mod config_valid;
mod console;
mod crash_exactly_once;
mod daemon_health;
mod device_identification;
mod discovery;
mod docker_files;
mod fuzz_smoke;
mod gateway_e2e;
mod golden_frames;
mod history;
mod layers;
mod library;
mod line_server;
mod logs;
mod module_maps;
mod number_grammar;
mod oversized_messages;
mod package_files;
mod plant_connection;
mod profile_codecs;
mod profiles_cli;
mod profiles_golden;
mod profiles_valid;
mod pty_line;
mod pty_master;
mod publish;
mod pymodbus_rtu;
mod readme;
mod reliability;
mod reload;
mod scheduler_cadence;
mod scheduler_time;
mod sim_pty;
mod sim_tcp;
mod soak;
mod sparkplug_decode;
mod sparkplug_e2e;
mod sparkplug_node;
mod sparkplug_readme;
mod systemd_unit;
mod tcp_lines;
mod trust_store;
mod unavailable_values;
