//! The demo's command line (clap): `rtu2mqtt-demo [--broker URL] [--port N] [--log]` runs the
//! seed plant with no hardware; `rtu2mqtt-demo simulate …` serves one simulated device (or a
//! seed plant line) for a gateway elsewhere.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use rtu2mqtt::cli::parse_address;
use rtu2mqtt_sim::Pace;

#[derive(Debug, Parser)]
#[command(
    name = "rtu2mqtt-demo",
    version,
    about = "The seed plant with no hardware: simulated devices on virtual serial lines, an \
             embedded MQTT broker and the gateway",
    args_conflicts_with_subcommands = true
)]
pub struct Cli {
    #[command(flatten)]
    pub demo: DemoArgs,
    #[command(subcommand)]
    pub command: Option<Command>,
}

/// How the demo runs.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Use this broker instead of the embedded one (mqtt://host:port).
    #[arg(long)]
    pub broker: Option<String>,
    /// Port of the embedded broker on 127.0.0.1.
    #[arg(long, default_value_t = 1883)]
    pub port: u16,
    /// Print log lines instead of the live table: changes, commands and outcomes at once,
    /// values that change on every poll gathered into a summary at most every 10 s.
    #[arg(long)]
    pub log: bool,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// One simulated device (or a seed plant line) on a serial port, or behind a TCP port as a
    /// serial device server (tcp://) or a Modbus TCP gateway (modbus-tcp://).
    Simulate(SimulateArgs),
}

#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Built-in profile name or profile file path.
    #[arg(
        long,
        required_unless_present = "seed_line",
        conflicts_with = "seed_line"
    )]
    pub profile: Option<String>,
    /// A whole line of the seed plant instead of one device: `a` (dust collector at 1, air
    /// shower at 0x81) or `b` (valve at 1).
    #[arg(long)]
    pub seed_line: Option<String>,
    /// Serial port path.
    #[arg(long, required_unless_present = "listen", conflicts_with = "listen")]
    pub port: Option<PathBuf>,
    /// Serve on TCP instead: tcp://HOST:PORT (raw RTU frames) or modbus-tcp://HOST:PORT.
    #[arg(long)]
    pub listen: Option<String>,
    /// Device address (default: the profile's usual address).
    #[arg(long, value_parser = parse_address)]
    pub address: Option<u8>,
    #[arg(long, default_value_t = 9600)]
    pub baud: u32,
    /// none | even | odd
    #[arg(long, default_value = "none")]
    pub parity: String,
    /// When answers reach the port: `instant` (no wire time), `frame` (whole, after their wire
    /// time; `--pace` alone), `bytes` (byte by byte at the character rate, like a UART) or
    /// `usb:Nms` (what is on the wire every N ms, N from 1 to 16, like a USB adapter).
    #[arg(
        long,
        value_name = "PACE",
        num_args = 0..=1,
        default_value = "instant",
        default_missing_value = "frame",
        value_parser = str::parse::<Pace>
    )]
    pub pace: Pace,
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_demo_runs_without_a_command_and_simulate_is_its_one_command() {
        let commands: Vec<String> = Cli::command()
            .get_subcommands()
            .map(|command| command.get_name().to_string())
            .collect();
        assert_eq!(commands, ["simulate"]);
        let plain = Cli::try_parse_from(["rtu2mqtt-demo", "--log", "--port", "1884"]);
        let plain = plain.expect("the demo's own flags parse");
        assert!(plain.command.is_none() && plain.demo.log && plain.demo.port == 1884);
        let simulate = Cli::try_parse_from([
            "rtu2mqtt-demo",
            "simulate",
            "--profile",
            "wuzhou-valve",
            "--port",
            "/dev/null",
        ]);
        assert!(matches!(
            simulate.map(|cli| cli.command),
            Ok(Some(Command::Simulate(_)))
        ));
    }
}
