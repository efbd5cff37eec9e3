//! The `rtu2mqtt-demo` binary: the demo, or with `simulate` one simulated device.

use std::process::ExitCode;

use clap::Parser;
use rtu2mqtt_demo::cli::{Cli, Command};

/// rumqttd (the embedded broker) logs every client connection at INFO and ordinary disconnects
/// at ERROR: noise for a demo user. `RUST_LOG=rumqttd=info` brings it back.
const DEMO_LOG_FILTER: &str = "info,rumqttd=off";

fn main() -> ExitCode {
    let cli = Cli::parse();
    rtu2mqtt::app::logging::init(DEMO_LOG_FILTER);
    let result = match cli.command {
        None => rtu2mqtt_demo::demo::demo(cli.demo.broker, cli.demo.port, cli.demo.log),
        Some(Command::Simulate(args)) => rtu2mqtt_demo::simulate::simulate(&args),
    };
    match result {
        Ok(code) => code,
        Err(error) => {
            eprintln!("rtu2mqtt-demo: {error:#}");
            ExitCode::FAILURE
        }
    }
}
