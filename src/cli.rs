//! The command line (clap): `run | check | demo | simulate | profiles | health`.

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "rtu2mqtt",
    version,
    about = "Modbus RTU (RS485) to MQTT gateway"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the gateway daemon.
    Run {
        /// Configuration file.
        #[arg(
            long,
            env = "RTU2MQTT_CONFIG",
            default_value = "/etc/rtu2mqtt/config.toml"
        )]
        config: PathBuf,
    },
    /// Validate the configuration and profiles and print each line's poll plan; touches no port
    /// and no broker.
    Check {
        #[arg(
            long,
            env = "RTU2MQTT_CONFIG",
            default_value = "/etc/rtu2mqtt/config.toml"
        )]
        config: PathBuf,
    },
    /// The whole seed plant with no hardware: simulated devices on virtual serial lines, an
    /// embedded MQTT broker and the gateway.
    Demo {
        /// Use this broker instead of the embedded one (mqtt://host:port).
        #[arg(long)]
        broker: Option<String>,
        /// Port of the embedded broker on 127.0.0.1.
        #[arg(long, default_value_t = 1883)]
        port: u16,
        /// Print one log line per published change instead of the live table.
        #[arg(long)]
        log: bool,
    },
    /// One simulated device on a serial port (a pty, or a real adapter for bench tests).
    Simulate {
        /// Built-in profile name or profile file path.
        #[arg(long)]
        profile: String,
        /// Serial port path.
        #[arg(long)]
        port: PathBuf,
        /// Device address (default: the profile's usual address).
        #[arg(long, value_parser = parse_address)]
        address: Option<u8>,
        #[arg(long, default_value_t = 9600)]
        baud: u32,
        /// none | even | odd
        #[arg(long, default_value = "none")]
        parity: String,
        /// Pace answers at the wire's character rate.
        #[arg(long)]
        pace: bool,
    },
    /// List the built-in profiles (and profile files given) with their fields.
    Profiles {
        /// Extra profile files to list.
        paths: Vec<PathBuf>,
    },
    /// Exit 0 when the daemon's status file is fresh (Docker HEALTHCHECK).
    Health {
        #[arg(long, default_value = "/run/rtu2mqtt/health")]
        status_file: PathBuf,
        /// Maximum age of the status file.
        #[arg(long, default_value = "30s", value_parser = humantime::parse_duration)]
        max_age: std::time::Duration,
    },
}

/// Accepts `129` or `0x81`.
pub fn parse_address(text: &str) -> Result<u8, String> {
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u8::from_str_radix(hex, 16),
        None => text.parse::<u8>(),
    };
    parsed.map_err(|_| format!("`{text}` is not an address 0–255 (decimal or 0x hex)"))
}
