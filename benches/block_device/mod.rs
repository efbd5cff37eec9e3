//! The bench device shared by the benches that run a gateway against one simulated line: one
//! block of six holding registers polled back to back, the first register writable (FC06), on
//! a 9600 8N1 pseudo-terminal; and what the simulator's journal says about a command's path
//! (publish → write frame on the wire → result on MQTT), each beside its bound from the frames'
//! lengths at that rate.

// Each bench compiles this module as its own and uses a part of it.
#![allow(dead_code)]

use std::time::{Duration, Instant};

use rtu2mqtt_modbus::timing::{LineTiming, Parity};
use rtu2mqtt_profile::Profile;
use rtu2mqtt_sim::{share, GenericDevice, Pace, RequestRecord, ServeOptions, VirtualLine};
use rtu2mqtt_testkit::PacedPymodbus;
use rumqttc::{AsyncClient, QoS};
use tokio::sync::mpsc::UnboundedReceiver;

use crate::gateway_process::{cpu_time_of, GatewayProcess, Memory};
use crate::wire_bench::{percentile, wire_load, WireLoad, EIGHT_N_ONE};

pub const BAUD: u32 = 9600;

/// Frame lengths of the bench's command slot: the FC06 write and its echo, the read-back of
/// the 6-register block and its answer.
pub const WRITE_LEN: usize = 8;
pub const READ_REQUEST_LEN: usize = 8;
pub const READ_ANSWER_LEN: usize = 17;

/// One device type: one block of six holding registers, the first one writable (FC06); the
/// other five are read-only fields `r1`–`r5` added by [`profile_text`].
pub const PROFILE_HEAD: &str = r#"
[device]
name = "edge-block"
manufacturer = "Bench"
model = "six holding registers"
description = "One 6-register block polled back to back"

[line]
baud = 9600
parity = "none"
address_range = [1, 247]
default_address = 1
min_poll_interval = "1ms"
poll_interval = "1s"
slow_interval = "5min"
startup_delay = "0s"
max_read_registers = 125
max_write_registers = 1
max_read_bits = 1
max_write_bits = 1

[[blocks]]
name = "block"
function = 3
start = 0
count = 6
poll = "fast"

[[fields]]
name = "setpoint"
block = "block"
offset = 0
codec = { type = "u16" }
range = [0, 60000]
write = { function = 6, address = 0 }
"#;

pub fn profile_text() -> String {
    let mut text = PROFILE_HEAD.to_string();
    for register in 1..6 {
        text += &format!(
            "\n[[fields]]\nname = \"r{register}\"\nblock = \"block\"\noffset = {register}\n\
             codec = {{ type = \"u16\" }}\n"
        );
    }
    text
}

/// What the wire and a subscriber saw of one run.
pub struct Wire {
    /// The wire time of every request and answer plus the two t3.5 silences of each
    /// transaction, over the window.
    pub efficiency: f64,
    /// The same with the device's own answer times: each transaction from its request's first
    /// byte to its answer's last byte (however long the device took to answer), plus the t3.5
    /// before the next request, over the window. Equal to `efficiency` on a device that answers
    /// t3.5 after a request; what the gateway alone leaves unused on any other.
    pub efficiency_device_times: f64,
    /// From a request's last byte on the wire to its answer's first: the device's turnaround.
    pub device_turnaround_p50: Duration,
    pub gap_p50: Duration,
    pub gap_p95: Duration,
    pub early: usize,
    /// Requests that reached the device while its answer was still going out.
    pub onto_answer: usize,
    /// Publish → the write frame at the device, and its bound, per command seen.
    pub to_wire: Vec<Duration>,
    pub to_wire_bound: Vec<Duration>,
    /// Per command seen: how much later than its bound its write reached the device.
    pub to_wire_over_bound: Vec<Duration>,
    /// Publish → `…/result` at the subscriber, and its bound, per result seen.
    pub to_result: Vec<Duration>,
    pub to_result_bound: Vec<Duration>,
    /// Per result seen: how much later than its own bound it came.
    pub result_over_bound: Vec<Duration>,
    /// Per result seen: how much later than the bound as the answers were delivered, i.e.
    /// with each answer ending when its last byte reached the gateway's port rather than when
    /// it was on the wire (a USB adapter hands bytes over only at its next chunk): the
    /// gateway's own share of the latency.
    pub result_over_delivered: Vec<Duration>,
    /// Where a result's time goes beyond the wire's: the write's echo end → the read-back
    /// request at the device (t3.5 at best), and the read-back's answer end → the result at
    /// the subscriber (nothing at best).
    pub echo_to_read_back: Vec<Duration>,
    pub read_back_to_result: Vec<Duration>,
}

/// A 9600 8N1 line paced by `pace` with `devices` bench devices at addresses 1, 2, …
pub fn spawn_line(profile: &Profile, devices: u8, pace: Pace) -> anyhow::Result<VirtualLine> {
    let shared = (1..=devices)
        .map(|address| share(GenericDevice::from_profile(profile, address)).1)
        .collect();
    Ok(VirtualLine::spawn(
        ServeOptions::new(BAUD, Parity::None).pacing(pace),
        shared,
    )?)
}

/// A simulated line a gateway is measured on: its pseudo-terminal and the requests its
/// device saw, in the project's journal records.
pub trait BenchLine {
    fn path(&self) -> std::path::PathBuf;
    fn requests(&self) -> anyhow::Result<Vec<RequestRecord>>;
    /// The simulator's own process, when it is not this one.
    fn process(&self) -> Option<u32> {
        None
    }
}

impl BenchLine for VirtualLine {
    fn path(&self) -> std::path::PathBuf {
        VirtualLine::path(self)
    }

    fn requests(&self) -> anyhow::Result<Vec<RequestRecord>> {
        Ok(self.journal().requests())
    }
}

impl BenchLine for PacedPymodbus {
    fn path(&self) -> std::path::PathBuf {
        PacedPymodbus::path(self).to_path_buf()
    }

    fn requests(&self) -> anyhow::Result<Vec<RequestRecord>> {
        PacedPymodbus::requests(self)
    }

    fn process(&self) -> Option<u32> {
        Some(PacedPymodbus::process(self))
    }
}

/// What a gateway publishes a command's outcome after, which sets its bound.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResultAfter {
    /// The write's echo, then a read-back of the block (rtu2mqtt's `…/result`).
    ReadBack,
    /// The write's echo alone: the value written is published as the new state.
    Echo,
}

/// The run's figures from its journal `records` over `wall`: the line's load, and for each
/// command (`published`: its value and when) its write on the wire and its first result among
/// `results` (when each arrived), each beside its bound.
pub fn wire_figures(
    records: &[RequestRecord],
    wall: Duration,
    pause: Option<Duration>,
    published: &[(u16, Instant)],
    results: &[Instant],
    result_after: ResultAfter,
) -> Wire {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    let WireLoad { busy, gaps, early } = wire_load(records, &timing, pause);
    let write_and_echo = timing.frame_time(WRITE_LEN) + timing.t3_5 + timing.frame_time(WRITE_LEN);
    let slot = match result_after {
        ResultAfter::ReadBack => {
            write_and_echo
                + timing.t3_5
                + timing.frame_time(READ_REQUEST_LEN)
                + timing.t3_5
                + timing.frame_time(READ_ANSWER_LEN)
        }
        ResultAfter::Echo => write_and_echo,
    };
    let device_busy: Duration = records
        .iter()
        .map(|r| {
            r.answer_timing.as_ref().map_or_else(
                || timing.frame_time(r.frame.len()),
                |answer| answer.handed_over.saturating_duration_since(r.arrived),
            ) + timing.t3_5
        })
        .sum();
    let mut turnarounds: Vec<Duration> = records
        .iter()
        .filter_map(|r| {
            let answer_start = r.answer_timing.as_ref()?.due
                - timing.frame_time(r.answer.as_ref().map_or(0, Vec::len));
            Some(
                answer_start
                    .saturating_duration_since(r.arrived + timing.frame_time(r.frame.len())),
            )
        })
        .collect();
    turnarounds.sort();
    let mut wire = Wire {
        efficiency: busy.as_secs_f64() / wall.as_secs_f64(),
        efficiency_device_times: device_busy.as_secs_f64() / wall.as_secs_f64(),
        device_turnaround_p50: percentile(&turnarounds, 50),
        gap_p50: percentile(&gaps, 50),
        gap_p95: percentile(&gaps, 95),
        early,
        // Only the simulator's first request ever has no silence before it; the window starts
        // well after it.
        onto_answer: records
            .iter()
            .filter(|r| r.silence_before.is_none())
            .count(),
        to_wire: Vec::new(),
        to_wire_bound: Vec::new(),
        to_wire_over_bound: Vec::new(),
        to_result: Vec::new(),
        to_result_bound: Vec::new(),
        result_over_bound: Vec::new(),
        result_over_delivered: Vec::new(),
        echo_to_read_back: Vec::new(),
        read_back_to_result: Vec::new(),
    };
    for (index, (value, at)) in published.iter().enumerate() {
        // The transaction on the wire when the command was published: the line is free for
        // the write t3.5 after its last byte (on the wire, or as delivered to the gateway).
        let in_flight = records.iter().rev().find(|r| r.arrived <= *at);
        let free_after = |delivered: bool| {
            in_flight
                .map(|r| {
                    let end = r.answer_timing.as_ref().map_or_else(
                        || r.arrived + timing.frame_time(r.frame.len()),
                        |answer| {
                            if delivered {
                                answer.handed_over
                            } else {
                                answer.due
                            }
                        },
                    );
                    end + timing.t3_5
                })
                .map_or(*at, |free| free.max(*at))
        };
        let bound = free_after(false) - *at;
        let write = records.iter().position(|r| {
            r.frame.get(1) == Some(&0x06) && r.frame.get(4..6) == Some(&value.to_be_bytes()[..])
        });
        if let Some(write) = write.and_then(|w| records.get(w)) {
            wire.to_wire
                .push(write.arrived.saturating_duration_since(*at));
            wire.to_wire_bound.push(bound);
            wire.to_wire_over_bound.push(
                write
                    .arrived
                    .saturating_duration_since(*at)
                    .saturating_sub(bound),
            );
        }
        // Commands are far apart: the first result after a publish, before the next, is its.
        let next = published.get(index + 1).map(|(_, next)| *next);
        let Some(result) = results
            .iter()
            .find(|&&r| r >= *at && next.map_or(true, |next| r < next))
        else {
            continue;
        };
        let taken = result.saturating_duration_since(*at);
        wire.to_result.push(taken);
        wire.to_result_bound.push(bound + slot);
        wire.result_over_bound
            .push(taken.saturating_sub(bound + slot));
        // The read-back is the request right after the write.
        let pair = write.and_then(|w| Some((records.get(w)?, records.get(w + 1)?)));
        if let Some((write, read_back)) = pair {
            if let (Some(echo), Some(answer)) = (&write.answer_timing, &read_back.answer_timing) {
                wire.echo_to_read_back
                    .push(read_back.arrived.saturating_duration_since(echo.due));
                wire.read_back_to_result
                    .push(result.saturating_duration_since(answer.due));
                let echo_delivered = free_after(true).saturating_duration_since(*at)
                    + echo.handed_over.saturating_duration_since(write.arrived);
                let delivered = match result_after {
                    ResultAfter::ReadBack => {
                        echo_delivered
                            + timing.t3_5
                            + answer
                                .handed_over
                                .saturating_duration_since(read_back.arrived)
                    }
                    ResultAfter::Echo => echo_delivered,
                };
                wire.result_over_delivered
                    .push(taken.saturating_sub(delivered));
            }
        }
    }
    for list in [
        &mut wire.to_wire,
        &mut wire.to_wire_bound,
        &mut wire.to_wire_over_bound,
        &mut wire.to_result,
        &mut wire.to_result_bound,
        &mut wire.result_over_bound,
        &mut wire.result_over_delivered,
        &mut wire.echo_to_read_back,
        &mut wire.read_back_to_result,
    ] {
        list.sort();
    }
    wire
}

/// One read of the block on the wire: request (8 bytes), answer (17) and both t3.5 silences.
pub fn transaction_wire_time() -> Duration {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    timing.frame_time(READ_REQUEST_LEN) + timing.frame_time(READ_ANSWER_LEN) + 2 * timing.t3_5
}

/// The median of one figure over the rounds, with its range when there are several.
pub fn over_rounds(values: impl IntoIterator<Item = f64>, show: impl Fn(f64) -> String) -> String {
    let mut values: Vec<f64> = values.into_iter().filter(|v| v.is_finite()).collect();
    if values.is_empty() {
        return "-".into();
    }
    values.sort_by(f64::total_cmp);
    let median = values[(values.len() - 1) / 2];
    match (values.first(), values.last()) {
        (Some(low), Some(high)) if values.len() > 1 => {
            format!("{} ({}–{})", show(median), show(*low), show(*high))
        }
        _ => show(median),
    }
}

pub fn ms_f(value: f64) -> String {
    format!("{value:.2} ms")
}

pub fn millis(duration: Duration) -> f64 {
    duration.as_secs_f64() * 1000.0
}

/// What one measuring window saw: its length, the CPU time the gateway and this process (the
/// simulator and the bench's MQTT clients) spent in it, the gateway's memory at its end, the
/// requests the simulator received in it, the commands published and the results that came.
pub struct Window {
    pub wall: Duration,
    pub gateway_cpu: Duration,
    pub simulator_cpu: Duration,
    pub memory: Memory,
    pub records: Vec<RequestRecord>,
    pub published: Vec<(u16, Instant)>,
    pub results: Vec<Instant>,
}

impl Window {
    pub fn transactions_per_second(&self) -> f64 {
        self.records.len() as f64 / self.wall.as_secs_f64()
    }

    pub fn gateway_cpu_percent(&self) -> f64 {
        100.0 * self.gateway_cpu.as_secs_f64() / self.wall.as_secs_f64()
    }

    pub fn simulator_cpu_percent(&self) -> f64 {
        100.0 * self.simulator_cpu.as_secs_f64() / self.wall.as_secs_f64()
    }
}

/// The writes a window publishes: `count` of them on `topic` (QoS 1), values `first_value`,
/// `first_value + 1`, …
pub struct Writes<'a> {
    pub topic: &'a str,
    pub first_value: u16,
    pub count: u32,
}

/// A window of `length` with `writes` published evenly, each in the middle of its share of
/// the window; `results` notes the arrivals of whatever answers them.
pub async fn command_window(
    gateway: &GatewayProcess,
    line: &(impl BenchLine + ?Sized),
    client: &AsyncClient,
    writes: Writes<'_>,
    results: &mut UnboundedReceiver<Instant>,
    length: Duration,
) -> anyhow::Result<Window> {
    while results.try_recv().is_ok() {}
    let start = Instant::now();
    let cpu_start = gateway.cpu_time()?;
    let simulator_cpu_time = || -> anyhow::Result<Duration> {
        let own = line
            .process()
            .map_or(Ok(Duration::ZERO), |pid| cpu_time_of(&pid.to_string()))?;
        Ok(cpu_time_of("self")? + own)
    };
    let simulator_start = simulator_cpu_time()?;
    let mut published = Vec::new();
    let every = length / writes.count.max(1);
    for i in 0..writes.count {
        let value = writes.first_value.wrapping_add(i as u16);
        tokio::time::sleep_until((start + every * i + every / 2).into()).await;
        published.push((value, Instant::now()));
        client
            .publish(
                writes.topic,
                QoS::AtLeastOnce,
                false,
                value.to_string().into_bytes(),
            )
            .await?;
    }
    tokio::time::sleep_until((start + length).into()).await;
    let wall = start.elapsed();
    let gateway_cpu = gateway.cpu_time()?.saturating_sub(cpu_start);
    let simulator_cpu = simulator_cpu_time()?.saturating_sub(simulator_start);
    let memory = gateway.memory()?;
    let mut arrivals = Vec::new();
    while let Ok(at) = results.try_recv() {
        arrivals.push(at);
    }
    let records = line
        .requests()?
        .into_iter()
        .filter(|r| r.arrived >= start && r.arrived < start + wall)
        .collect();
    Ok(Window {
        wall,
        gateway_cpu,
        simulator_cpu,
        memory,
        records,
        published,
        results: arrivals,
    })
}
