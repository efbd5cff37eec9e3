//! The figures the bridge lets others read outside its loop: the running lines' statistics and
//! its own counters, both refreshed every tick (the metrics endpoint and the console).

use tokio::sync::watch;

use crate::bridge::observers::statistics::{prometheus_text, BridgeStats};
use crate::bus::LineStats;

/// What the bridge lets observers outside its loop read: the running lines' statistics and
/// its own counters (both refreshed every tick), for whoever asks.
#[derive(Debug, Clone)]
pub struct BridgeFigures {
    pub lines: watch::Receiver<Vec<watch::Receiver<LineStats>>>,
    pub counters: watch::Receiver<BridgeStats>,
}

impl BridgeFigures {
    /// The running lines' statistics now.
    pub fn line_stats(&self) -> Vec<LineStats> {
        self.lines
            .borrow()
            .iter()
            .map(|rx| rx.borrow().clone())
            .collect()
    }

    /// The bridge's counters as of its last tick.
    pub fn counters(&self) -> BridgeStats {
        self.counters.borrow().clone()
    }

    /// The Prometheus exposition text of both.
    pub fn prometheus_text(&self) -> String {
        prometheus_text(&self.line_stats(), &self.counters())
    }
}
