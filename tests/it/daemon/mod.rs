//! The gateway process as an operator runs and watches it:
//!
//! - `calm_start`: a normal start reads calm in the journal.
//! - `daemon_health`: readiness, the watchdog and the status file under a service manager.
//! - `logs`: what `run` writes to stderr when it is no terminal.
//! - `reload`: the configuration reloaded on SIGHUP.
//! - `console`: the browser console in a real browser.

mod calm_start;
mod console;
mod daemon_health;
mod logs;
mod reload;
