//! A serial line whose device is pymodbus's own Modbus RTU server (written by others), behind
//! a pacer that releases every byte at the wire's rate: `tests/interop/paced_rtu_server.py`.
//! Its journal, read back as the project's simulator journals are ([`RequestRecord`]), lets a
//! bench measure the wire the same way on a simulator this project did not write.

use std::io::{BufRead as _, BufReader};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use nix::time::{clock_gettime, ClockId};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_sim::wire::crc_ok;
use rtu2mqtt_sim::{AnswerTiming, RequestRecord};
use serde_json::Value;

use crate::child::KillOnDrop;
use crate::hex;
use crate::pymodbus;

/// pymodbus serving unit 1 on a paced 8N1 line; the process ends on drop.
pub struct PacedPymodbus {
    process: KillOnDrop,
    /// The gateway's end of the line.
    path: PathBuf,
    journal: PathBuf,
    _dir: tempfile::TempDir,
    timing: LineTiming,
}

impl PacedPymodbus {
    /// Starts the server with `registers` holding registers (all 0) at `baud`, 8N1, and
    /// waits until it has said where its line is.
    pub fn spawn(baud: u32, registers: u16) -> anyhow::Result<PacedPymodbus> {
        let dir = tempfile::tempdir()?;
        let journal = dir.path().join("journal.jsonl");
        let mut command = pymodbus::command("paced_rtu_server.py");
        command
            .arg(baud.to_string())
            .arg(&journal)
            .arg(registers.to_string())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            // pymodbus warns of its next major version's data store on every start.
            .stderr(Stdio::null());
        let mut process = KillOnDrop::spawn(command).context("python3 with pymodbus")?;
        let stdout = process.0.stdout.take().context("the server's stdout")?;
        let mut first = String::new();
        BufReader::new(stdout).read_line(&mut first)?;
        let path = PathBuf::from(first.trim());
        anyhow::ensure!(
            path.starts_with("/dev/"),
            "the paced pymodbus server did not start (is pymodbus with pyserial installed?)"
        );
        let format = CharFormat {
            data_bits: 8,
            parity: Parity::None,
            stop_bits: 1,
        };
        Ok(PacedPymodbus {
            process,
            path,
            journal,
            _dir: dir,
            timing: LineTiming::new(baud, format),
        })
    }

    /// The server's process id (its CPU time is the simulator's).
    pub fn process(&self) -> u32 {
        self.process.id()
    }

    /// The pseudo-terminal the gateway opens.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Every request the server saw so far, in order, with its answer: the records of the
    /// project's own simulator, the silence before each from the end of the frame before it
    /// (either direction, an answer's from when its last byte was handed over).
    pub fn requests(&self) -> anyhow::Result<Vec<RequestRecord>> {
        let clock = MonotonicClock::now()?;
        let text = std::fs::read_to_string(&self.journal)?;
        let mut records: Vec<RequestRecord> = Vec::new();
        let mut line_free_at: Option<Instant> = None;
        for line in text.lines() {
            // The last line may be half written.
            let Ok(entry) = serde_json::from_str::<Value>(line) else {
                continue;
            };
            let frame = hex::decode(entry["frame"].as_str().context("a frame in hex")?);
            if entry.get("request").is_some() {
                let arrived = clock.instant(&entry["at"])?;
                let silence_before =
                    line_free_at.map(|free| arrived.saturating_duration_since(free));
                line_free_at = Some(arrived + self.timing.frame_time(frame.len()));
                records.push(RequestRecord {
                    crc_ok: crc_ok(&frame),
                    frame,
                    arrived,
                    silence_before,
                    answer: None,
                    answer_timing: None,
                });
            } else if let Some(record) = records.last_mut() {
                let timing = AnswerTiming {
                    due: clock.instant(&entry["due"])?,
                    handed_over: clock.instant(&entry["handed_over"])?,
                    write_returned: clock.instant(&entry["written"])?,
                };
                line_free_at = Some(timing.handed_over);
                record.answer = Some(frame);
                record.answer_timing = Some(timing);
            }
        }
        Ok(records)
    }
}

/// CLOCK_MONOTONIC (the journal's times) read beside `Instant::now()`, to turn one into the
/// other.
struct MonotonicClock {
    instant: Instant,
    nanos: i128,
}

impl MonotonicClock {
    fn now() -> anyhow::Result<MonotonicClock> {
        let instant = Instant::now();
        let now = clock_gettime(ClockId::CLOCK_MONOTONIC)?;
        Ok(MonotonicClock {
            instant,
            nanos: i128::from(now.tv_sec()) * 1_000_000_000 + i128::from(now.tv_nsec()),
        })
    }

    fn instant(&self, nanos: &Value) -> anyhow::Result<Instant> {
        let nanos = i128::from(nanos.as_i64().context("a time in nanoseconds")?);
        let offset = Duration::from_nanos(u64::try_from((nanos - self.nanos).abs())?);
        if nanos >= self.nanos {
            Ok(self.instant + offset)
        } else {
            self.instant
                .checked_sub(offset)
                .context("a journal time before the clock's start")
        }
    }
}
