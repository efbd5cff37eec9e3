//! The command line beside `run`:
//!
//! - `commissioning`: `scan`, `read` and `sunspec` against simulated devices on real ptys.
//! - `profiles_cli`: `rtu2mqtt profiles`.
//! - `config_valid`: the configuration as users meet it, and `rtu2mqtt check`.
//! - `cli_docs`: the manual pages and completions say what `--help` says.

mod cli_docs;
pub(crate) mod commissioning;
mod config_valid;
mod profiles_cli;
