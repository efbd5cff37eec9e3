//! The `rtu2mqtt` binary: parses the command line, sets up logging and hands over to the
//! library. Errors reach the user here, with their context, as a non-zero exit.

use std::process::ExitCode;

use clap::Parser;
use rtu2mqtt::cli::{Cli, Command};

fn main() -> ExitCode {
    let cli = Cli::parse();
    rtu2mqtt::app::logging::init(rtu2mqtt::app::logging::DEFAULT_FILTER);
    let result = match cli.command {
        Command::Run { config } => rtu2mqtt::app::run(&config),
        Command::Check { config } => rtu2mqtt::app::check::check(&config),
        Command::Scan(args) => rtu2mqtt::commissioning::scan::scan(&args),
        Command::Read(args) => rtu2mqtt::commissioning::read::read(&args),
        Command::Sunspec(args) => rtu2mqtt::commissioning::sunspec::sunspec(&args),
        Command::Profiles { paths } => rtu2mqtt::app::profiles::print_profiles(&paths),
        Command::Health {
            status_file,
            max_age,
        } => rtu2mqtt::health::check_status_file(&status_file, max_age),
    };
    match result {
        Ok(code) => code,
        Err(error) => {
            eprintln!("rtu2mqtt: {error:#}");
            ExitCode::FAILURE
        }
    }
}
