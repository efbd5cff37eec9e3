//! The RS485 plant of the scale bench: lines of simulated Eastron SDM120 energy meters, each
//! line a pseudo-terminal at 9600 8N1 whose answers are released byte by byte at the character
//! rate, served on a runtime of its own in the bench's process (the gateway is measured by its
//! pid, so the simulators' CPU is never counted as its). Each meter answers from the device
//! library's register map with its readings moving as a loaded meter's do.
//!
//! It is also the RTU row's stopwatch: the lines' journals say when each block of each meter
//! was asked for (the poll lateness) and how busy each wire was.

use std::time::{Duration, Instant};

use rtu2mqtt_modbus::frame::{Request as ModbusRequest, SlaveId};
use rtu2mqtt_modbus::timing::{LineTiming, Parity};
use rtu2mqtt_profile::{PollClass, Profile};
use rtu2mqtt_sim::{share, GenericDevice, Pace, Raw, Reply, ServeOptions, SimDevice, VirtualLine};

use crate::scale_sim::Request;
use crate::wire_bench::{wire_load, EIGHT_N_ONE};

/// The lines' baud rate (8N1).
pub const BAUD: u32 = 9600;
/// The meters' profile: the built-in SDM120 profile, whose meters come set to 2400 baud.
const SDM120_PROFILE: &str = include_str!("../../config/profiles/eastron-sdm120.toml");

/// The built-in SDM120 profile as it stands for meters set to the lines' baud rate on their
/// display (the SDM120 runs at up to 9600), so that the gateway polls them without warning
/// that the line differs from the profile's rate.
pub fn profile_text() -> String {
    SDM120_PROFILE.replace("baud = 2400", &format!("baud = {BAUD}"))
}

pub fn profile() -> anyhow::Result<Profile> {
    Profile::from_toml(&profile_text(), "eastron-sdm120 at 9600 baud")
        .map_err(|e| anyhow::anyhow!("the SDM120 profile: {e:?}"))
}

/// `lines` pseudo-terminals with `per_line` meters each (addresses 1, 2, …), served until
/// dropped.
pub struct RtuPlant {
    pub lines: Vec<VirtualLine>,
    pub per_line: u8,
    /// Dropped after the lines, which stop serving when dropped.
    runtime: Option<tokio::runtime::Runtime>,
}

impl RtuPlant {
    pub fn spawn(lines: usize, per_line: u8) -> anyhow::Result<RtuPlant> {
        // The simulators pace every byte with a precise wait: a runtime of their own keeps
        // that off the bench's MQTT subscriber and its off theirs.
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("rtu-simulators")
            .enable_all()
            .build()?;
        let started = Instant::now();
        let options = ServeOptions::new(BAUD, Parity::None).pacing(Pace::Bytes);
        let served = {
            let _inside = runtime.enter();
            (0..lines)
                .map(|line| {
                    let meters = (1..=per_line)
                        .map(|address| {
                            let index = plant_index(line, per_line, address) as u32;
                            share(MovingMeter::new(address, index, started)).1
                        })
                        .collect();
                    VirtualLine::spawn(options, meters)
                })
                .collect::<std::io::Result<Vec<_>>>()?
        };
        Ok(RtuPlant {
            lines: served,
            per_line,
            runtime: Some(runtime),
        })
    }

    /// The meters' index across the plant (the `d<index>` of their names).
    pub fn device_index(&self, line: usize, address: SlaveId) -> usize {
        plant_index(line, self.per_line, address)
    }

    /// The reads of the blocks in `blocks` (their first registers) that reached a meter up to
    /// `to`, as the lines' journals have them (each keeps its last 10,000 frames, about 25
    /// minutes of 32 meters polled every 10 s).
    pub fn requests(&self, blocks: &[u16], to: Instant) -> Vec<Request> {
        let mut requests = Vec::new();
        for (line, served) in self.lines.iter().enumerate() {
            for record in served.journal().requests() {
                if !record.crc_ok || record.arrived > to || record.frame.len() < 4 {
                    continue;
                }
                let start = u16::from_be_bytes([record.frame[2], record.frame[3]]);
                if !blocks.contains(&start) {
                    continue;
                }
                requests.push(Request {
                    device: self.device_index(line, record.frame[0]) as u32,
                    start,
                    at: record.arrived,
                });
            }
        }
        requests.sort_by_key(|request| request.at);
        requests
    }

    /// What the lines' wires carried between `from` and `to`.
    pub fn wire(&self, from: Instant, to: Instant) -> Wire {
        let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
        let window = to.saturating_duration_since(from).as_secs_f64().max(0.001);
        let mut wire = Wire::default();
        for line in &self.lines {
            let records: Vec<_> = line
                .journal()
                .requests()
                .into_iter()
                .filter(|r| r.arrived >= from && r.arrived < to)
                .collect();
            let load = wire_load(&records, &timing, None);
            wire.loads.push(load.busy.as_secs_f64() / window);
            wire.transactions_per_second += records.len() as f64 / window;
            wire.early += load.early;
            // Only a line's first request ever has no silence before it; the window starts
            // long after it.
            wire.onto_answer += records
                .iter()
                .filter(|r| r.silence_before.is_none())
                .count();
        }
        wire
    }
}

impl Drop for RtuPlant {
    /// Stops serving and ends the simulators' runtime (without waiting: it may be dropped
    /// inside the bench's own runtime).
    fn drop(&mut self) {
        self.lines.clear();
        if let Some(runtime) = self.runtime.take() {
            runtime.shutdown_background();
        }
    }
}

/// The index across the plant of the meter at `address` on `line`.
fn plant_index(line: usize, per_line: u8, address: SlaveId) -> usize {
    line * usize::from(per_line) + usize::from(address).saturating_sub(1)
}

/// The lines' wires over a window.
#[derive(Debug, Default)]
pub struct Wire {
    /// Each line's load: the wire time of its requests and answers and the two t3.5
    /// silences of each transaction, over the window's length.
    pub loads: Vec<f64>,
    /// Requests on all lines, per second of the window.
    pub transactions_per_second: f64,
    /// Requests sooner than t3.5 after the line's last byte, on all lines.
    pub early: usize,
    /// Requests that reached a meter while an answer was still going out, on all lines.
    pub onto_answer: usize,
}

/// The first registers of the blocks a profile polls every cycle.
pub fn fast_blocks(profile: &Profile) -> Vec<u16> {
    profile
        .read_blocks()
        .iter()
        .filter(|block| block.class == PollClass::Fast)
        .filter_map(|block| block.request.read_span().map(|(start, _)| start))
        .collect()
}

/// One polling round of `devices` meters on the wire: each fast block's request and answer,
/// each followed by t3.5.
pub fn round_wire_time(profile: &Profile, devices: u8) -> Duration {
    wire_time_of_class(profile, PollClass::Fast) * u32::from(devices)
}

/// The slow blocks' share of the wire: their transactions over the profile's slow interval.
pub fn slow_share(profile: &Profile, devices: u8) -> f64 {
    let slow = profile.limits().slow_interval.as_secs_f64().max(0.001);
    (wire_time_of_class(profile, PollClass::Slow) * u32::from(devices)).as_secs_f64() / slow
}

/// The wire time of one meter's reads of the blocks of `class`.
fn wire_time_of_class(profile: &Profile, class: PollClass) -> Duration {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    profile
        .read_blocks()
        .iter()
        .filter(|block| block.class == class)
        .map(|block| transaction_time(&timing, &block.request))
        .sum()
}

fn transaction_time(timing: &LineTiming, request: &ModbusRequest) -> Duration {
    timing.frame_time(request.frame_len())
        + timing.frame_time(request.answer_len())
        + timing.t3_5 * 2
}

/// An SDM120 from the device library's register map whose readings move with the clock: its
/// voltage every second, its load (current and powers) every five seconds, its frequency every
/// seven, its energy counters by what the load draws. Each meter has its own phase, so that a
/// line's meters do not all move together.
struct MovingMeter {
    registers: GenericDevice,
    index: u32,
    started: Instant,
}

impl MovingMeter {
    fn new(address: SlaveId, index: u32, started: Instant) -> MovingMeter {
        MovingMeter {
            registers: rtu2mqtt_sim::library::sdm120().map.device(address),
            index,
            started,
        }
    }

    /// The readings at `now`, written where the SDM120's map has them.
    fn move_readings(&mut self, now: Instant) {
        let elapsed = now.saturating_duration_since(self.started).as_secs_f64();
        let second = elapsed as u64;
        let phase = u64::from(self.index);
        let voltage = 228.0 + ((second * 13 + phase * 7) % 40) as f32 * 0.1;
        let power = 400.0 + 25.0 * ((second / 5 + phase * 3) % 40) as f32;
        let frequency = 49.90 + ((second / 7 + phase) % 20) as f32 * 0.01;
        // About 0.8 kW drawn on average: the import counter steps 0.001 kWh every 4.5 s.
        let hours = elapsed / 3600.0;
        let import = 1000.0 + f64::from(self.index) * 10.0 + 0.8 * hours;
        let import_reactive = 300.0 + f64::from(self.index) + 0.2 * hours;
        let export = 12.5;
        let export_reactive = 4.5;
        let readings = [
            (0x0000, voltage),
            (0x0006, power / voltage),
            (0x000C, power),
            (0x0012, power / 0.97),
            (0x0018, power * 0.25),
            (0x0046, frequency),
            (0x0048, import as f32),
            (0x004C, import_reactive as f32),
            (0x0156, (import + export) as f32),
            (0x0158, (import_reactive + export_reactive) as f32),
        ];
        for (address, value) in readings {
            for (offset, word) in (0u16..).zip(Raw::F32(value).words()) {
                self.registers.set_input_register(address + offset, word);
            }
        }
    }
}

impl SimDevice for MovingMeter {
    fn address(&self) -> SlaveId {
        self.registers.address()
    }

    fn handle(&mut self, request: &ModbusRequest, now: Instant) -> Reply {
        self.move_readings(now);
        self.registers.handle(request, now)
    }

    fn kind(&self) -> &'static str {
        "moving SDM120"
    }
}
