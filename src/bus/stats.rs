//! Live statistics of a line and its devices, published by the line task on a watch channel
//! after every transaction and at least once a second.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use rtu2mqtt_modbus::WireCounters;

/// Counters and latencies of one device.
#[derive(Debug, PartialEq)]
pub struct DeviceStats {
    pub name: String,
    pub online: bool,
    pub transactions: u64,
    pub timeouts: u64,
    pub crc_errors: u64,
    pub exceptions: u64,
    /// Answers that were truncated, from another address or function, or malformed.
    pub bad_answers: u64,
    /// Polls that delivered values.
    pub polls_ok: u64,
    /// Polls that gave no usable answer after their retries (probes included).
    pub polls_failed: u64,
    /// Fields whose raw data was invalid (bad BCD): not published, counted here.
    pub field_errors: u64,
    /// Times a field turned unavailable (a NaN, an `invalid` mark, an unnamed enum code):
    /// one per episode, however many polls it lasts.
    pub unavailable_episodes: u64,
    /// Consecutive failed polls (resets on success).
    pub consecutive_failures: u32,
    pub last_latency: Option<Duration>,
    pub worst_latency: Option<Duration>,
    /// Exception 02 answers to a merged block read that made the line read the block in
    /// parts: expected from some devices, so not among `exceptions` or any failure.
    pub split_read_fallbacks: u64,
}

/// `clone_from` keeps the name's allocation: the line copies every device's figures into the
/// published snapshot after each transaction, without allocating.
impl Clone for DeviceStats {
    fn clone(&self) -> Self {
        DeviceStats {
            name: self.name.clone(),
            ..*self
        }
    }

    fn clone_from(&mut self, source: &Self) {
        let mut name = std::mem::take(&mut self.name);
        name.clone_from(&source.name);
        // Every other field is Copy (a new field that is not fails to compile here).
        *self = DeviceStats { name, ..*source };
    }
}

impl DeviceStats {
    /// Empty statistics of a device that has not been heard yet.
    pub fn new(name: &str) -> Self {
        DeviceStats {
            name: name.to_string(),
            online: false,
            transactions: 0,
            timeouts: 0,
            crc_errors: 0,
            exceptions: 0,
            bad_answers: 0,
            polls_ok: 0,
            polls_failed: 0,
            field_errors: 0,
            unavailable_episodes: 0,
            consecutive_failures: 0,
            last_latency: None,
            worst_latency: None,
            split_read_fallbacks: 0,
        }
    }
}

/// Bus load over a sliding window: wire time carried per wall time, from samples of the line's
/// growing wire time (on every kind of line the serial wire time of its frames and silences,
/// the model of the poll plan's estimate). Until the line has run for a whole window, the time
/// before its first sample counts as idle: the figure grows to the line's load over the first
/// window, rather than showing the first transactions' share of the first moments.
#[derive(Debug, Clone)]
pub struct LoadWindow {
    window: Duration,
    samples: VecDeque<(Instant, Duration)>,
}

impl LoadWindow {
    pub fn new(window: Duration) -> Self {
        LoadWindow {
            window,
            samples: VecDeque::new(),
        }
    }

    /// Adds the wire time carried so far at `now`; the load (0.0–1.0) since the oldest sample
    /// still in the window, over the whole window while less time has passed.
    pub fn sample(&mut self, now: Instant, wire_time: Duration) -> f64 {
        self.samples.push_back((now, wire_time));
        while self
            .samples
            .get(1)
            .is_some_and(|(at, _)| now.duration_since(*at) >= self.window)
        {
            self.samples.pop_front();
        }
        let Some((since, wire_then)) = self.samples.front() else {
            return 0.0;
        };
        let wall = now.duration_since(*since).max(self.window).as_secs_f64();
        if wall <= 0.0 {
            return 0.0;
        }
        let wire = wire_time.saturating_sub(*wire_then).as_secs_f64();
        (wire / wall).min(1.0)
    }
}

/// A snapshot of a line's statistics.
#[derive(Debug, PartialEq)]
pub struct LineStats {
    pub line: String,
    /// Refreshed on every turn of the line's loop: the watchdog's proof that the task is alive.
    pub heartbeat: Instant,
    pub port_open: bool,
    /// Times the port failed (EOF, EIO) or could not be opened.
    pub port_failures: u64,
    pub transactions: u64,
    pub timeouts: u64,
    pub crc_errors: u64,
    pub truncated: u64,
    pub unexpected_answers: u64,
    pub exceptions: u64,
    pub late_answers: u64,
    pub stray_bytes: u64,
    /// Frames from another address heard while waiting for an answer.
    pub wrong_address: u64,
    /// Silences longer than t1.5 inside answers, tolerated up to the byte timeout.
    pub long_gaps: u64,
    /// Share of wall time the line carried frames and mandatory silences, over the last
    /// measuring window (0.0–1.0).
    pub bus_load: f64,
    /// Wire time of all frames and mandatory silences since the line started.
    pub wire_time: Duration,
    /// The line's own time from the end of a transaction to the start of the next one that
    /// was already due (mean, worst): what the gateway adds between back-to-back frames.
    pub turnaround_mean: Option<Duration>,
    pub turnaround_worst: Option<Duration>,
    pub commands: u64,
    /// Time from a command's arrival on the line to its outcome.
    pub last_command_latency: Option<Duration>,
    pub worst_command_latency: Option<Duration>,
    /// Requests from the line's server's clients (`[lines.serve]`), refused ones included.
    pub client_requests: u64,
    /// Client reads answered from a poll younger than the server's `cache`.
    pub cache_hits: u64,
    /// Client requests refused before the line (access, unknown unit, malformed).
    pub client_refusals: u64,
    /// Client requests answered 06 (server device busy): their client pipelined too many, or
    /// a field it writes was inside its write interval.
    pub client_busy: u64,
    /// Client connections closed to give their place to a newcomer (no completed request).
    pub client_evicted: u64,
    pub devices: Vec<DeviceStats>,
}

/// `clone_from` reuses the name and the device list: the line publishes a snapshot after every
/// transaction, without allocating.
impl Clone for LineStats {
    fn clone(&self) -> Self {
        LineStats {
            line: self.line.clone(),
            devices: self.devices.clone(),
            ..*self
        }
    }

    fn clone_from(&mut self, source: &Self) {
        let mut line = std::mem::take(&mut self.line);
        let mut devices = std::mem::take(&mut self.devices);
        line.clone_from(&source.line);
        devices.clone_from(&source.devices);
        // Every other field is Copy (a new field that is not fails to compile here).
        *self = LineStats {
            line,
            devices,
            ..*source
        };
    }
}

impl LineStats {
    /// Empty statistics of a line that has not run yet.
    pub fn new(line: &str, devices: &[String], now: Instant) -> Self {
        LineStats {
            line: line.to_string(),
            heartbeat: now,
            port_open: false,
            port_failures: 0,
            transactions: 0,
            timeouts: 0,
            crc_errors: 0,
            truncated: 0,
            unexpected_answers: 0,
            exceptions: 0,
            late_answers: 0,
            stray_bytes: 0,
            wrong_address: 0,
            long_gaps: 0,
            bus_load: 0.0,
            wire_time: Duration::ZERO,
            turnaround_mean: None,
            turnaround_worst: None,
            commands: 0,
            last_command_latency: None,
            worst_command_latency: None,
            client_requests: 0,
            cache_hits: 0,
            client_refusals: 0,
            client_busy: 0,
            client_evicted: 0,
            devices: devices.iter().map(|name| DeviceStats::new(name)).collect(),
        }
    }

    /// Puts the devices' current figures into the snapshot, reusing its allocations.
    pub fn set_devices<'a>(&mut self, devices: impl ExactSizeIterator<Item = &'a DeviceStats>) {
        if self.devices.len() != devices.len() {
            self.devices = devices.cloned().collect();
            return;
        }
        for (kept, current) in self.devices.iter_mut().zip(devices) {
            kept.clone_from(current);
        }
    }

    /// Takes the line's wire counters (the sum over every master the line has had). The
    /// snapshot keeps them as flat fields: that is the shape the metrics and status file show.
    pub fn record_wire(&mut self, counters: &WireCounters) {
        self.transactions = counters.requests;
        self.timeouts = counters.timeouts;
        self.crc_errors = counters.crc_errors;
        self.truncated = counters.truncated;
        self.unexpected_answers = counters.unexpected;
        self.exceptions = counters.exceptions;
        self.late_answers = counters.late_answers;
        self.stray_bytes = counters.stray_bytes;
        self.wrong_address = counters.wrong_address;
        self.long_gaps = counters.long_gaps;
        self.wire_time = counters.wire_time;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_snapshot_copied_in_place_equals_its_source_and_keeps_its_buffers() {
        let now = Instant::now();
        let names = ["valve".to_string(), "dust_collector".to_string()];
        let mut device = DeviceStats::new("dust_collector");
        device.timeouts = 3;
        device.worst_latency = Some(Duration::from_millis(12));
        let mut source = LineStats::new("line-a", &names, now);
        source.transactions = 7;
        source.bus_load = 0.5;
        source.set_devices([DeviceStats::new("valve"), device].iter());
        assert_eq!(source.devices[1].timeouts, 3);

        let mut published = LineStats::new("line-a", &names, now);
        let buffers = |stats: &LineStats| {
            (
                stats.line.as_ptr(),
                stats.devices.as_ptr(),
                stats.devices[1].name.as_ptr(),
            )
        };
        let before = buffers(&published);
        published.clone_from(&source);
        assert_eq!(published, source);
        assert_eq!(buffers(&published), before, "no new allocation");
        assert_eq!(published.clone(), source);
    }

    #[test]
    fn load_is_wire_time_per_wall_time_over_the_window() {
        let start = Instant::now();
        let mut load = LoadWindow::new(Duration::from_secs(10));
        assert_eq!(load.sample(start, Duration::ZERO), 0.0);
        // Within the first window the time before the start counts as idle: 1 s of wire time
        // in the first 2 s is 10 % of the window, not half of the 2 s.
        let early = load.sample(start + Duration::from_secs(2), Duration::from_secs(1));
        assert_eq!(early, 0.1);
        // A line that starts with a burst of transactions shows no burst: 50 ms of wire time
        // in the first 53 ms is half a percent of the window.
        let mut burst = LoadWindow::new(Duration::from_secs(10));
        burst.sample(start, Duration::ZERO);
        let first = burst.sample(start + Duration::from_millis(53), Duration::from_millis(50));
        assert!((first - 0.005).abs() < 1e-12, "{first}");
        // Once the window has passed, it is the window's own load.
        let filled = load.sample(start + Duration::from_secs(10), Duration::from_secs(5));
        assert_eq!(filled, 0.5);
        // The first sample leaves the window: the load is measured from the second.
        let later = load.sample(start + Duration::from_secs(12), Duration::from_secs(6));
        assert_eq!(later, 0.5);
        let capped = load.sample(start + Duration::from_secs(13), Duration::from_secs(30));
        assert_eq!(capped, 1.0);
    }
}
