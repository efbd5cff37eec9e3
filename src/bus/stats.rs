//! Live statistics of a line and its devices.

use std::time::Instant;

/// A snapshot of a line's statistics, published on a watch channel after every transaction
/// and at least once a second (the watchdog reads `heartbeat`).
#[derive(Debug, Clone)]
pub struct LineStats {
    pub heartbeat: Instant,
}
