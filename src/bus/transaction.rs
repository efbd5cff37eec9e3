//! One request/answer exchange with retries, as the line task runs it: a tracing span per
//! transaction (line, device, function), per-device counters and latencies, and a result that
//! says what the caller must do (use the answer, handle an exception, give up, or close a port
//! that is gone). The timing on the wire is the master's; nothing here sleeps.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use tracing::Instrument;

use rtu2mqtt_modbus::link::Link;
use rtu2mqtt_modbus::{Error as MasterError, PortFault, Reply};
use rtu2mqtt_modbus::{Request, SlaveId, Transact};

use super::device_spec::DeviceSpec;
use super::stats::DeviceStats;

/// Why an exchange gave no answer from the device. A device's exception answer is not a
/// failure: it comes back as the `Err` of a [`Reply`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Failure {
    /// No usable answer after every attempt: the last attempt's problem (timeout, CRC, …).
    NoAnswer(MasterError),
    /// The port failed (EOF, EIO): it must be closed and reopened.
    PortGone(PortFault),
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failure::NoAnswer(last) => write!(f, "no answer ({last})"),
            Failure::PortGone(error) => write!(f, "port failed: {error}"),
        }
    }
}

/// What every exchange with one device of a line shares: its line, name and address, the
/// answer timeout and the line's turnaround.
#[derive(Debug, Clone)]
pub(crate) struct ExchangeContext<'a> {
    pub line: &'a str,
    pub device: &'a str,
    pub slave: SlaveId,
    pub timeout: Duration,
    pub turnaround: &'a Turnaround,
}

/// The gateway's own time between the end of one transaction and the start of the next when
/// that one was already due: what the line adds beyond the wire's mandatory silence (which the
/// master waits out inside the next transaction, so this time is hidden in it when shorter).
/// Atomics only so that a line task holding a reference across awaits stays `Send`.
#[derive(Debug)]
pub(crate) struct Turnaround {
    epoch: Instant,
    /// Nanoseconds since `epoch` when the last transaction ended; 0 after a wait.
    ended: AtomicU64,
    count: AtomicU64,
    total_nanos: AtomicU64,
    worst_nanos: AtomicU64,
}

impl Default for Turnaround {
    fn default() -> Self {
        Turnaround {
            epoch: Instant::now(),
            ended: AtomicU64::new(0),
            count: AtomicU64::new(0),
            total_nanos: AtomicU64::new(0),
            worst_nanos: AtomicU64::new(0),
        }
    }
}

impl Turnaround {
    fn nanos(&self, at: Instant) -> u64 {
        u64::try_from(at.saturating_duration_since(self.epoch).as_nanos())
            .unwrap_or(u64::MAX)
            .max(1)
    }

    /// A transaction starts now.
    pub(crate) fn starting(&self) {
        let ended = self.ended.swap(0, Ordering::Relaxed);
        if ended == 0 {
            return;
        }
        let gap = self.nanos(Instant::now()).saturating_sub(ended);
        self.count.fetch_add(1, Ordering::Relaxed);
        self.total_nanos.fetch_add(gap, Ordering::Relaxed);
        self.worst_nanos.fetch_max(gap, Ordering::Relaxed);
    }

    /// A transaction ended now.
    pub(crate) fn ended(&self) {
        self.ended
            .store(self.nanos(Instant::now()), Ordering::Relaxed);
    }

    /// The silence after the last transaction is over: the line's own time runs from here
    /// (the silence is the wire's, not overhead).
    pub(crate) fn silence_over(&self) {
        let ended = self.ended.load(Ordering::Relaxed);
        if ended != 0 {
            self.ended
                .store(self.nanos(Instant::now()).max(ended), Ordering::Relaxed);
        }
    }

    /// The line waits for something to become due: the gap that follows is not overhead.
    pub(crate) fn idle(&self) {
        self.ended.store(0, Ordering::Relaxed);
    }

    /// Mean and worst turnaround so far.
    pub(crate) fn figures(&self) -> Option<(Duration, Duration)> {
        let count = self.count.load(Ordering::Relaxed);
        if count == 0 {
            return None;
        }
        let mean = self.total_nanos.load(Ordering::Relaxed) / count;
        let worst = self.worst_nanos.load(Ordering::Relaxed);
        Some((Duration::from_nanos(mean), Duration::from_nanos(worst)))
    }
}

impl<'a> ExchangeContext<'a> {
    /// The exchanges with the configured `device` on the line named `line`.
    pub(crate) fn for_device(
        line: &'a str,
        device: &'a DeviceSpec,
        timeout: Duration,
        turnaround: &'a Turnaround,
    ) -> Self {
        ExchangeContext {
            line,
            device: &device.name,
            slave: device.address,
            timeout,
            turnaround,
        }
    }

    /// Sends `request` up to `attempts` times (at least once) until the device answers,
    /// normally or with an exception (not retried: it is the device's word).
    pub(crate) async fn run(
        &self,
        master: &mut Link,
        stats: &mut DeviceStats,
        request: &Request,
        attempts: u32,
    ) -> Result<Reply, Failure> {
        let mut attempt = 0;
        loop {
            let span = tracing::debug_span!(
                "transaction",
                line = self.line,
                device = self.device,
                function = request.function().value(),
                attempt
            );
            self.turnaround.starting();
            let started = Instant::now();
            let result = master
                .transact(self.slave, request, self.timeout)
                .instrument(span)
                .await;
            self.turnaround.ended();
            stats.transactions += 1;
            let error = match result {
                Ok(reply) => {
                    if reply.is_err() {
                        stats.exceptions += 1;
                    }
                    record_latency(stats, started.elapsed());
                    return Ok(reply);
                }
                Err(MasterError::PortGone(fault)) => return Err(Failure::PortGone(fault)),
                Err(error) => error,
            };
            match error {
                MasterError::Timeout(_) => stats.timeouts += 1,
                MasterError::Crc => stats.crc_errors += 1,
                _ => stats.bad_answers += 1,
            }
            tracing::debug!(
                line = self.line,
                device = self.device,
                attempt,
                "transaction failed: {error}"
            );
            attempt += 1;
            if attempt >= attempts.max(1) {
                return Err(Failure::NoAnswer(error));
            }
        }
    }
}

fn record_latency(stats: &mut DeviceStats, latency: Duration) {
    stats.last_latency = Some(latency);
    stats.worst_latency = Some(stats.worst_latency.map_or(latency, |w| w.max(latency)));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_silence_after_a_transaction_is_not_the_lines_own_time() {
        let turnaround = Turnaround::default();
        turnaround.ended();
        // The wire's silence: far longer than the line's own decision.
        std::thread::sleep(Duration::from_millis(30));
        turnaround.silence_over();
        turnaround.starting();
        let (mean, worst) = turnaround.figures().expect("one sample");
        assert!(worst < Duration::from_millis(15), "{mean:?} / {worst:?}");

        // Idle time is no sample at all.
        turnaround.ended();
        turnaround.idle();
        turnaround.silence_over();
        turnaround.starting();
        assert_eq!(turnaround.figures().map(|(_, worst)| worst), Some(worst));
    }
}
