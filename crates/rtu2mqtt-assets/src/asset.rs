//! What every generated file shares: the executable's name, the command line it is made from,
//! and a file as it is generated.

use std::path::PathBuf;

use clap::CommandFactory;

/// The executable's name, in every generated file.
pub const BIN_NAME: &str = "rtu2mqtt";

/// One generated file: where it goes below the output directory, and its contents.
#[derive(Debug, Clone)]
pub struct Asset {
    pub path: PathBuf,
    pub contents: Vec<u8>,
}

/// The command line as the executable sees it: built, named, without clap's `help` command
/// (every command has `--help`, and a manual page for `help` would say nothing).
pub(crate) fn command() -> clap::Command {
    let mut command = rtu2mqtt::cli::Cli::command()
        .bin_name(BIN_NAME)
        .disable_help_subcommand(true);
    command.build();
    command
}
