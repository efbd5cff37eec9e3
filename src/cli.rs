//! The command line (clap): `run | check | scan | read | sunspec | profiles | health`.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

use rtu2mqtt_modbus::timing::Parity;

/// The version `--version` shows: the package's, with the commit it was built from when built
/// from a git checkout (`0.1.0 (abc1234)`; see build.rs).
pub const VERSION: &str = env!("RTU2MQTT_VERSION");

#[derive(Debug, Parser)]
#[command(
    name = "rtu2mqtt",
    version = VERSION,
    about = "Modbus RTU (RS485) to MQTT gateway",
    long_about = "Modbus RTU (RS485) to MQTT gateway.\n\n\
        rtu2mqtt polls the devices on serial lines (local ports, serial device servers, Modbus \
        TCP gateways) as their profiles describe, publishes every field on MQTT and applies \
        commands validated against the profile. `rtu2mqtt run` is the daemon (the systemd \
        service rtu2mqtt); the other commands check a configuration, commission devices and \
        report the daemon's health."
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
        /// Configuration file.
        #[arg(
            long,
            env = "RTU2MQTT_CONFIG",
            default_value = "/etc/rtu2mqtt/config.toml"
        )]
        config: PathBuf,
    },
    /// Probe a serial port for devices: each baud rate, parity and address with a harmless read
    /// (never a write). Prints a table of what answered where.
    Scan(ScanArgs),
    /// One raw read, shown as hex and decoded every way a profile could (never a write).
    Read(ReadArgs),
    /// Find a SunSpec device's map ("SunS" at 40000, 0 or 50000), walk its model chain, print
    /// what it found on stderr and write a profile for the models known (never a write).
    Sunspec(SunspecArgs),
    /// List profiles with their fields: every built-in one, or only those named.
    Profiles {
        /// Built-in profile names and/or profile file paths (none: every built-in profile).
        #[arg(value_name = "NAME|FILE")]
        paths: Vec<PathBuf>,
    },
    /// Exit 0 when the daemon's status file is fresh (Docker HEALTHCHECK).
    Health {
        /// The status file the daemon rewrites.
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

/// Parses `1-247`, `1,2,0x81` or a mix of both, in the order given, without repeats next to
/// each other.
pub fn parse_addresses(text: &str) -> Result<Vec<u8>, String> {
    let mut addresses = Vec::new();
    for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (first, last) = match part.split_once('-') {
            Some((first, last)) => (parse_address(first.trim())?, parse_address(last.trim())?),
            None => (parse_address(part)?, parse_address(part)?),
        };
        if first == 0 || first > last {
            return Err(format!(
                "address range `{part}`: expected FIRST-LAST within 1–255"
            ));
        }
        addresses.extend(first..=last);
    }
    if addresses.is_empty() {
        return Err(format!("no address to scan in `{text}`"));
    }
    addresses.dedup();
    Ok(addresses)
}

/// Parses `none | even | odd`.
pub fn parse_parity(text: &str) -> anyhow::Result<Parity> {
    match text.to_ascii_lowercase().as_str() {
        "none" | "n" => Ok(Parity::None),
        "even" | "e" => Ok(Parity::Even),
        "odd" | "o" => Ok(Parity::Odd),
        other => anyhow::bail!("parity `{other}`: expected none, even or odd"),
    }
}

/// Where a commissioning command reaches a line: a serial port, or a serial device server or
/// Modbus TCP gateway by URL.
#[derive(Debug, Args)]
pub struct LinkArgs {
    /// Serial port path (a running gateway's port is refused).
    #[arg(long, required_unless_present = "url", conflicts_with = "url")]
    pub port: Option<PathBuf>,
    /// Instead of a port: `tcp://host:port` (a serial device server) or
    /// `modbus-tcp://host:port` (a Modbus TCP gateway; baud and parity are the gateway's).
    #[arg(long)]
    pub url: Option<String>,
}

#[derive(Debug, Args)]
pub struct ScanArgs {
    #[command(flatten)]
    pub link: LinkArgs,
    /// Baud rates to try, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "9600,19200,4800,38400,2400,57600,115200"
    )]
    pub baud: Vec<u32>,
    /// Parities to try, comma-separated (none, even, odd).
    #[arg(long, value_delimiter = ',', default_value = "none,even")]
    pub parity: Vec<String>,
    /// Addresses to probe: `1-247`, `1,2,0x81` or a mix.
    #[arg(long, default_value = "1-247")]
    pub addresses: String,
    /// Response timeout of a full probe. On a serial port a silent address is left after the
    /// probe's wire time plus 20 ms or so, and probed fully only if it answers late.
    #[arg(long, default_value = "100ms", value_parser = humantime::parse_duration)]
    pub timeout: std::time::Duration,
    /// Read this profile's blocks at every address found and show the decoded fields.
    #[arg(long)]
    pub profile: Option<String>,
    /// A directory of profile files (`*.toml`) a device found may be named by too, besides
    /// the built-in ones, when its identification matches theirs.
    #[arg(long, value_name = "DIR")]
    pub profiles: Option<std::path::PathBuf>,
}

#[derive(Debug, Args)]
pub struct ReadArgs {
    #[command(flatten)]
    pub link: LinkArgs,
    #[arg(long, value_parser = parse_address)]
    pub address: u8,
    /// 1 (coils), 2 (discrete inputs), 3 (holding registers) or 4 (input registers).
    #[arg(long, default_value_t = 3)]
    pub function: u8,
    /// First register or bit: decimal or 0x hex.
    #[arg(long, value_parser = parse_u16)]
    pub start: u16,
    #[arg(long, default_value_t = 1)]
    pub count: u16,
    #[arg(long, default_value_t = 9600)]
    pub baud: u32,
    /// none | even | odd
    #[arg(long, default_value = "none")]
    pub parity: String,
    #[arg(long, default_value = "500ms", value_parser = humantime::parse_duration)]
    pub timeout: std::time::Duration,
}

#[derive(Debug, Args)]
pub struct SunspecArgs {
    #[command(flatten)]
    pub link: LinkArgs,
    #[arg(long, value_parser = parse_address)]
    pub address: u8,
    #[arg(long, default_value_t = 9600)]
    pub baud: u32,
    /// none | even | odd
    #[arg(long, default_value = "none")]
    pub parity: String,
    #[arg(long, default_value = "1s", value_parser = humantime::parse_duration)]
    pub timeout: std::time::Duration,
    /// Write the profile to this file instead of standard output.
    #[arg(long)]
    pub output: Option<PathBuf>,
}

/// Accepts `4096` or `0x1000`.
pub fn parse_u16(text: &str) -> Result<u16, String> {
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u16::from_str_radix(hex, 16),
        None => text.parse::<u16>(),
    };
    parsed.map_err(|_| format!("`{text}` is not a number 0–65535 (decimal or 0x hex)"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_daemon_has_no_demo_and_no_simulator() {
        let commands: Vec<String> = Cli::command()
            .get_subcommands()
            .map(|command| command.get_name().to_string())
            .collect();
        assert_eq!(
            commands,
            ["run", "check", "scan", "read", "sunspec", "profiles", "health"]
        );
    }

    #[test]
    fn parities_are_read_by_name_or_letter() {
        assert_eq!(parse_parity("Even").ok(), Some(Parity::Even));
        assert_eq!(parse_parity("o").ok(), Some(Parity::Odd));
        assert_eq!(parse_parity("none").ok(), Some(Parity::None));
        assert!(parse_parity("mark").is_err());
    }
}
