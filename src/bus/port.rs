//! A line's serial port: opening it as a [`Master`] with the line's settings, and when to try
//! again after it was missing, failed under a transaction, or turned out to be no serial port
//! at all. One back-off policy ([`Reopen`]) with two schedules ([`Backoff`]). Nothing here runs
//! a transaction or reports to the bridge.
//!
//! A missing or failed port (adapter unplugged, EOF, EIO) is tried again quickly: 100 ms
//! doubling to 3 s. A path that exists but is no serial port (a regular file, `/dev/null`) is a
//! configuration mistake that waiting does not fix (docs/reliability.md B11): it is looked at
//! again only after 5 s doubling to 60 s (the path may be a link that gets pointed at the
//! adapter).

use std::time::{Duration, Instant};

use crate::rtu::master::{Master, MasterOptions};
use crate::rtu::timing::LineTiming;
use crate::rtu::transport::{Port, TransportError};

use super::LineSpec;

/// Waits between attempts: the first one, doubling up to the longest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Backoff {
    pub first: Duration,
    pub longest: Duration,
}

/// For a port that is missing or failed.
pub const MISSING_PORT: Backoff = Backoff {
    first: Duration::from_millis(100),
    longest: Duration::from_secs(3),
};

/// For a port path that is no serial port.
pub const NOT_A_PORT: Backoff = Backoff {
    first: Duration::from_secs(5),
    longest: Duration::from_secs(60),
};

impl Backoff {
    /// The schedule for a failed attempt to open the port.
    pub fn after(error: &TransportError) -> Backoff {
        match error {
            TransportError::NotATerminal { .. } => NOT_A_PORT,
            _ => MISSING_PORT,
        }
    }
}

/// When the line tries to open its port next.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reopen {
    at: Instant,
    /// The wait after the next failure, before it is fitted to that failure's schedule.
    next_delay: Duration,
}

impl Reopen {
    /// A line that has not opened its port yet tries at once.
    pub fn new(now: Instant) -> Self {
        Reopen {
            at: now,
            next_delay: MISSING_PORT.first,
        }
    }

    /// When the next attempt is due.
    pub fn at(&self) -> Instant {
        self.at
    }

    /// The port is open: its next failure starts the schedule from the beginning.
    pub fn opened(&mut self) {
        self.next_delay = MISSING_PORT.first;
    }

    /// An attempt failed (or the open port failed): the next one waits under `backoff`, from
    /// where the previous failures left the wait (so a path that was no serial port and is
    /// now missing is tried again within the quick schedule's longest wait). Returns the wait.
    pub fn failed(&mut self, now: Instant, backoff: Backoff) -> Duration {
        let delay = self.next_delay.clamp(backoff.first, backoff.longest);
        self.at = now + delay;
        self.next_delay = (delay * 2).min(backoff.longest);
        delay
    }
}

/// Opens the line's port and puts a master on it with the line's settings.
pub fn open_master(spec: &LineSpec, timing: LineTiming) -> Result<Master, TransportError> {
    let port = Port::open(&spec.serial)?;
    let options = MasterOptions {
        echo: spec.echo,
        broadcast_turnaround: spec.broadcast_turnaround,
        inter_char_timeout: spec.byte_timeout,
        ..MasterOptions::default()
    };
    let mut master = Master::new(port, timing, options);
    if let Some(log) = &spec.frame_log {
        master.record_frames_to(Box::new(log.writer(&spec.name)));
    }
    Ok(master)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn waits(reopen: &mut Reopen, backoff: Backoff, count: usize) -> Vec<u64> {
        let now = Instant::now();
        (0..count)
            .map(|_| reopen.failed(now, backoff).as_millis() as u64)
            .collect()
    }

    #[test]
    fn a_missing_port_is_tried_again_quickly_up_to_three_seconds() {
        let mut reopen = Reopen::new(Instant::now());
        assert_eq!(
            waits(&mut reopen, MISSING_PORT, 7),
            [100, 200, 400, 800, 1600, 3000, 3000]
        );
        // Open again: the next failure starts over.
        reopen.opened();
        assert_eq!(waits(&mut reopen, MISSING_PORT, 2), [100, 200]);
    }

    #[test]
    fn a_path_that_is_no_serial_port_is_looked_at_slowly_up_to_a_minute() {
        let mut reopen = Reopen::new(Instant::now());
        assert_eq!(
            waits(&mut reopen, NOT_A_PORT, 6),
            [5000, 10_000, 20_000, 40_000, 60_000, 60_000]
        );
        // The path is now simply missing: back on the quick schedule's longest wait.
        assert_eq!(waits(&mut reopen, MISSING_PORT, 2), [3000, 3000]);
    }

    #[test]
    fn the_next_attempt_is_due_after_the_wait() {
        let now = Instant::now();
        let mut reopen = Reopen::new(now);
        assert_eq!(reopen.at(), now);
        let wait = reopen.failed(now, MISSING_PORT);
        assert_eq!(reopen.at(), now + wait);
    }
}
