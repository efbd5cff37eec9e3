//! A plant of Modbus TCP meters that costs little, for the scale benches: one tokio task per
//! listening port and per connection, each device 200 holding registers read as 100 `f32`
//! points (high word first), each device changing one point a second (1 % of its points),
//! at a moment of its own.
//!
//! It is also the bench's stopwatch: it notes when each block of each device was asked for
//! (the poll lateness is measured here, where the requests arrive) and counts the point changes
//! its answers carry for the first time (what the gateway measured).

// Each bench compiles this module as its own and uses a part of it.
#![allow(dead_code)]

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// Points per device, each an `f32` over two holding registers.
pub const POINTS: usize = 100;
/// Each point changes once in this period; the device's points take turns, one a second.
const POINT_PERIOD: Duration = Duration::from_secs(POINTS as u64);

/// One request for a block: which device, which block (its first register), when.
#[derive(Debug, Clone, Copy)]
pub struct Request {
    pub device: u32,
    pub start: u16,
    pub at: Instant,
}

/// What every connection reports to.
#[derive(Debug)]
pub struct PlantLog {
    pub requests: Mutex<Vec<Request>>,
    /// Point changes carried by an answer for the first time, each with the instant it was
    /// served (the first answer of a device carries every point).
    pub changes_served: Mutex<Vec<Instant>>,
    /// Values stop changing (the end of a run: what was measured can be counted out).
    pub frozen_at: Mutex<Option<Instant>>,
    pub answers: AtomicU64,
    pub connections: AtomicU64,
    pub stopped: AtomicBool,
}

/// The simulated plant: one listening port per device.
#[derive(Debug)]
pub struct ScalePlant {
    pub addrs: Vec<SocketAddr>,
    pub log: Arc<PlantLog>,
}

impl ScalePlant {
    /// Binds `devices` loopback ports and serves them on the current runtime.
    pub async fn spawn(devices: usize) -> std::io::Result<ScalePlant> {
        let log = Arc::new(PlantLog {
            requests: Mutex::new(Vec::new()),
            changes_served: Mutex::new(Vec::new()),
            frozen_at: Mutex::new(None),
            answers: AtomicU64::new(0),
            connections: AtomicU64::new(0),
            stopped: AtomicBool::new(false),
        });
        let started = Instant::now();
        let mut addrs = Vec::with_capacity(devices);
        for device in 0..devices {
            let listener = TcpListener::bind("127.0.0.1:0").await?;
            addrs.push(listener.local_addr()?);
            let log = Arc::clone(&log);
            tokio::spawn(async move {
                while let Ok((stream, _)) = listener.accept().await {
                    if log.stopped.load(Ordering::Relaxed) {
                        return;
                    }
                    log.connections.fetch_add(1, Ordering::Relaxed);
                    let _ = stream.set_nodelay(true);
                    tokio::spawn(serve(stream, device as u32, Arc::clone(&log), started));
                }
            });
        }
        Ok(ScalePlant { addrs, log })
    }

    /// Values stop changing from now on.
    pub fn freeze(&self) {
        if let Ok(mut frozen) = self.log.frozen_at.lock() {
            *frozen = Some(Instant::now());
        }
    }

    pub fn stop(&self) {
        self.log.stopped.store(true, Ordering::Relaxed);
    }
}

/// The profile of the simulated meter: `POINTS` `f32` points in two blocks of registers, with
/// Home Assistant's `measurement` state class when `measured`.
pub fn profile_text(measured: bool) -> String {
    use std::fmt::Write as _;
    let mut profile = String::from(
        "[device]\nname = \"scale-meter\"\nmanufacturer = \"Bench\"\nmodel = \"100 f32 points\"\n\
         description = \"Simulated meter of the scale bench\"\n\n[line]\naddress_range = [1, 247]\n\
         min_poll_interval = \"1s\"\npoll_interval = \"1s\"\n\n",
    );
    let half = POINTS / 2;
    for (block, start) in [("points_a", 0), ("points_b", 2 * half)] {
        let _ = write!(
            profile,
            "[[blocks]]\nname = \"{block}\"\nfunction = 3\nstart = {start}\ncount = {}\n\n",
            2 * half
        );
    }
    let ha = if measured {
        "ha = { state_class = \"measurement\" }\n"
    } else {
        ""
    };
    for point in 0..POINTS {
        let block = if point < half { "points_a" } else { "points_b" };
        let _ = write!(
            profile,
            "[[fields]]\nname = \"p{point:03}\"\nblock = \"{block}\"\noffset = {}\n\
             codec = {{ type = \"f32\", word_order = \"high_first\", decimals = 2 }}\n{ha}\n",
            2 * (point % half)
        );
    }
    profile
}

/// How many times point `point` of `device` has changed by `at`.
fn generation(device: u32, point: usize, at: Duration) -> u64 {
    // Point p changes when the clock passes p seconds (mod the period), shifted by a few
    // milliseconds per device so the plant's changes spread over each second.
    let shift = Duration::from_secs(POINTS as u64 - point as u64)
        + Duration::from_millis(u64::from(device % 1000));
    ((at + shift).as_millis() / POINT_PERIOD.as_millis()) as u64
}

fn value(device: u32, point: usize, generation: u64) -> f32 {
    (device % 100) as f32 * 10.0 + point as f32 + generation as f32 * 0.25
}

/// One client connection: Modbus TCP, function 3 only.
async fn serve(mut stream: TcpStream, device: u32, log: Arc<PlantLog>, started: Instant) {
    let mut served_generation: Vec<Option<u64>> = vec![None; POINTS];
    let mut header = [0u8; 7];
    let mut pdu = [0u8; 256];
    let mut answer: Vec<u8> = Vec::with_capacity(9 + 250);
    loop {
        if stream.read_exact(&mut header).await.is_err() || log.stopped.load(Ordering::Relaxed) {
            return;
        }
        let length = usize::from(u16::from_be_bytes([header[4], header[5]]));
        if !(2..=254).contains(&length) {
            return;
        }
        let body = &mut pdu[..length - 1];
        if stream.read_exact(body).await.is_err() {
            return;
        }
        let now = Instant::now();
        answer.clear();
        answer.extend_from_slice(&header[..4]);
        let function = body[0];
        if function != 3 || body.len() != 5 {
            // Illegal function.
            answer.extend_from_slice(&3u16.to_be_bytes());
            answer.extend_from_slice(&[header[6], function | 0x80, 1]);
        } else {
            let start = u16::from_be_bytes([body[1], body[2]]);
            let count = u16::from_be_bytes([body[3], body[4]]);
            if count == 0 || count > 125 || usize::from(start) + usize::from(count) > 2 * POINTS {
                answer.extend_from_slice(&3u16.to_be_bytes());
                answer.extend_from_slice(&[header[6], 0x83, 2]);
            } else {
                if let Ok(mut requests) = log.requests.lock() {
                    requests.push(Request {
                        device,
                        start,
                        at: now,
                    });
                }
                let frozen = log.frozen_at.lock().ok().and_then(|frozen| *frozen);
                let clock = frozen.unwrap_or(now).saturating_duration_since(started);
                answer.extend_from_slice(&(3 + 2 * count).to_be_bytes());
                answer.extend_from_slice(&[header[6], 3, (2 * count) as u8]);
                let mut new_changes = 0;
                for register in start..start + count {
                    let point = usize::from(register / 2);
                    let generation = generation(device, point, clock);
                    let bits = value(device, point, generation).to_bits();
                    let word = if register % 2 == 0 {
                        (bits >> 16) as u16
                    } else {
                        bits as u16
                    };
                    answer.extend_from_slice(&word.to_be_bytes());
                    // A point is counted once, at its first register in the answer.
                    if register % 2 == 1 || register + 1 >= start + count {
                        continue;
                    }
                    if served_generation[point] != Some(generation) {
                        served_generation[point] = Some(generation);
                        new_changes += 1;
                    }
                }
                if new_changes > 0 {
                    if let Ok(mut changes) = log.changes_served.lock() {
                        changes.extend(std::iter::repeat(now).take(new_changes));
                    }
                }
            }
        }
        if stream.write_all(&answer).await.is_err() {
            return;
        }
        log.answers.fetch_add(1, Ordering::Relaxed);
    }
}

/// Poll lateness of the requests noted between `from` and `to`: for each block of each device,
/// the time between two successive requests beyond `interval`.
#[derive(Debug, Default)]
pub struct Lateness {
    /// Each gap's lateness, shortest first.
    pub late: Vec<Duration>,
    /// Polls that never came: a gap of k intervals (rounded) skipped k − 1.
    pub skipped: u64,
    /// Blocks that were never asked for in the window although their device was.
    pub gaps: usize,
}

impl Lateness {
    pub fn of(requests: &[Request], from: Instant, to: Instant, interval: Duration) -> Lateness {
        let mut last: std::collections::HashMap<(u32, u16), Instant> = Default::default();
        let mut lateness = Lateness::default();
        for request in requests.iter().filter(|r| r.at <= to) {
            let key = (request.device, request.start);
            if let Some(previous) = last.insert(key, request.at) {
                if request.at < from {
                    continue;
                }
                let gap = request.at - previous;
                lateness.late.push(gap.saturating_sub(interval));
                let intervals = (gap.as_secs_f64() / interval.as_secs_f64()).round() as u64;
                lateness.skipped += intervals.saturating_sub(1);
            }
        }
        // A block whose last request is older than the window's end by more than two
        // intervals has stopped being polled: count those intervals as skipped.
        for at in last.values() {
            let silent = to.saturating_duration_since(*at);
            let intervals = (silent.as_secs_f64() / interval.as_secs_f64()).floor() as u64;
            lateness.skipped += intervals.saturating_sub(1);
        }
        lateness.gaps = lateness.late.len();
        lateness.late.sort();
        lateness
    }

    pub fn percentile(&self, p: f64) -> Duration {
        if self.late.is_empty() {
            return Duration::ZERO;
        }
        let index = ((self.late.len() - 1) as f64 * p / 100.0).round() as usize;
        self.late[index.min(self.late.len() - 1)]
    }
}
