//! The files a package installs beside `rtu2mqtt` that are made from its command line's own
//! definition ([`rtu2mqtt::cli::Cli`]): a manual page for `rtu2mqtt` and one for each of its
//! commands (`rtu2mqtt-run(1)`, …), and completions for bash, zsh and fish. Generated from the
//! same definition `--help` prints, they cannot describe another command line.
//!
//! This is a crate of its own so that the generators stay out of the daemon's executable.
//!
//! - [`asset`]: the executable's name, the command line every file is made from, a file.
//! - [`manual`]: the manual pages.
//! - [`completions`](mod@completions): the completion scripts.
//! - [`write`](mod@write): every file written below a directory.

pub mod asset;
pub mod completions;
pub mod manual;
pub mod write;

pub use asset::{Asset, BIN_NAME};
pub use completions::{completions, COMPLETIONS};
pub use manual::manual_pages;
pub use write::write_all;
