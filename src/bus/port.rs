//! A line's link: what the wire crate's [`Link::open`] opens for it (its serial port or its
//! TCP server, with the line's settings), and when to try again after it was missing, failed under a
//! transaction, or turned out to be no serial port at all. One back-off policy ([`Reopen`])
//! with three schedules ([`Backoff`]). Nothing here runs a transaction or reports to the
//! bridge.
//!
//! A missing or failed port (adapter unplugged, EOF, EIO) is tried again quickly: 100 ms
//! doubling to 3 s. A path that exists but is no serial port (a regular file, `/dev/null`) is a
//! configuration mistake that waiting does not fix (docs/reliability.md B11): it is looked at
//! again only after 5 s doubling to 60 s (the path may be a link that gets pointed at the
//! adapter). A TCP server that refuses or does not accept the connection is tried again after
//! 200 ms doubling to 10 s.

use std::time::{Duration, Instant};

use rtu2mqtt_modbus::link::{Link, LinkSpec};
use rtu2mqtt_modbus::serial::master::MasterOptions;
use rtu2mqtt_modbus::serial::transport::TransportError;
use rtu2mqtt_modbus::tcp::masters::TcpOptions;
use rtu2mqtt_modbus::timing::LineTiming;

use super::line_spec::{LineSpec, Transport};

/// Waits between attempts: the first one, doubling up to the longest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Backoff {
    pub first: Duration,
    pub longest: Duration,
}

/// For a port that is missing or failed.
pub(crate) const MISSING_PORT: Backoff = Backoff {
    first: Duration::from_millis(100),
    longest: Duration::from_secs(3),
};

/// For a port path that is no serial port.
pub(crate) const NOT_A_PORT: Backoff = Backoff {
    first: Duration::from_secs(5),
    longest: Duration::from_secs(60),
};

/// For a TCP server that cannot be reached.
pub(crate) const UNREACHABLE_SERVER: Backoff = Backoff {
    first: Duration::from_millis(200),
    longest: Duration::from_secs(10),
};

impl Backoff {
    /// The schedule for a failed attempt to open the link.
    pub(crate) fn after(error: &OpenError) -> Backoff {
        match error {
            OpenError::Serial(TransportError::NotATerminal { .. }) => NOT_A_PORT,
            OpenError::Serial(_) => MISSING_PORT,
            OpenError::Connect { .. } => UNREACHABLE_SERVER,
        }
    }
}

/// Why a line's link could not be opened (named here for the line, which matches on it).
pub(crate) use rtu2mqtt_modbus::link::OpenError;

/// When the line tries to open its port next.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Reopen {
    at: Instant,
    /// The wait after the next failure, before it is fitted to that failure's schedule.
    next_delay: Duration,
}

impl Reopen {
    /// A line that has not opened its port yet tries at once.
    pub(crate) fn new(now: Instant) -> Self {
        Reopen {
            at: now,
            next_delay: MISSING_PORT.first,
        }
    }

    /// When the next attempt is due.
    pub(crate) fn at(&self) -> Instant {
        self.at
    }

    /// The port is open: its next failure starts the schedule from the beginning.
    pub(crate) fn opened(&mut self) {
        self.next_delay = MISSING_PORT.first;
    }

    /// An attempt failed (or the open port failed): the next one waits under `backoff`, from
    /// where the previous failures left the wait (so a path that was no serial port and is
    /// now missing is tried again within the quick schedule's longest wait). Returns the wait.
    pub(crate) fn failed(&mut self, now: Instant, backoff: Backoff) -> Duration {
        let delay = self.next_delay.clamp(backoff.first, backoff.longest);
        self.at = now + delay;
        self.next_delay = (delay * 2).min(backoff.longest);
        delay
    }
}

/// Opens the line's port, or connects to its server, with the line's settings, and records
/// its frames where the line's are recorded.
pub(crate) async fn open_link(spec: &LineSpec, timing: LineTiming) -> Result<Link, OpenError> {
    let mut link = Link::open(&link_spec(spec), timing).await?;
    if let Some(writer) = spec.recorders.writer(&spec.name) {
        link.record_frames_to(writer);
    }
    Ok(link)
}

/// What the wire crate opens for the line: its port with the master's options from the line's
/// settings, or its server with the line's broadcast turnaround.
fn link_spec(spec: &LineSpec) -> LinkSpec {
    match &spec.transport {
        Transport::Serial => LinkSpec::Serial {
            port: spec.serial.clone(),
            options: MasterOptions {
                echo: spec.echo,
                broadcast_turnaround: spec.broadcast_turnaround,
                inter_char_timeout: spec.byte_timeout,
                ..MasterOptions::default()
            },
        },
        Transport::Tcp {
            endpoint, options, ..
        } => LinkSpec::Tcp {
            endpoint: endpoint.clone(),
            options: TcpOptions {
                broadcast_turnaround: spec.broadcast_turnaround,
                ..*options
            },
        },
    }
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
