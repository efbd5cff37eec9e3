//! The completion scripts for bash, zsh and fish, named as each shell looks for them.

use std::path::PathBuf;

use clap_complete::Shell;

use crate::asset::{command, Asset, BIN_NAME};

/// Where each completion script goes below the output directory, named as its shell looks for
/// it once installed (bash: `rtu2mqtt`, zsh: `_rtu2mqtt`, fish: `rtu2mqtt.fish`).
pub const COMPLETIONS: [(Shell, &str); 3] = [
    (Shell::Bash, "completions/rtu2mqtt.bash"),
    (Shell::Zsh, "completions/_rtu2mqtt"),
    (Shell::Fish, "completions/rtu2mqtt.fish"),
];

/// The completion scripts for bash, zsh and fish.
pub fn completions() -> Vec<Asset> {
    COMPLETIONS
        .iter()
        .map(|(shell, path)| {
            let mut contents = Vec::new();
            clap_complete::generate(*shell, &mut command(), BIN_NAME, &mut contents);
            Asset {
                path: PathBuf::from(path),
                contents,
            }
        })
        .collect()
}
