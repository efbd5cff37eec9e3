//! A line's poll plan computed from its devices' read blocks and the wire timing: blocks and
//! frames per cycle, wire time per cycle (request + answer + 2 × t3.5 per block) and the bus
//! load at the configured intervals. Pure arithmetic, used by validation (a plan over 100 % is
//! an error) and printed by `rtu2mqtt check`.

use std::time::Duration;

use crate::bus::{DeviceSpec, LineSpec};
use crate::profile::PollClass;
use crate::rtu::timing::LineTiming;

/// One device's share of its line.
#[derive(Debug, Clone, PartialEq)]
pub struct DevicePlan {
    pub name: String,
    pub profile: String,
    pub address: u8,
    pub poll_interval: Duration,
    pub slow_interval: Duration,
    pub fast_blocks: usize,
    pub slow_blocks: usize,
    /// Wire time of one fast cycle (every poll interval).
    pub fast_wire_time: Duration,
    /// Wire time of the slow blocks (every slow interval).
    pub slow_wire_time: Duration,
    /// Share of the line's time this device takes (0.0–1.0 and beyond).
    pub bus_load: f64,
}

/// The plan of one line.
#[derive(Debug, Clone, PartialEq)]
pub struct LinePlan {
    pub name: String,
    pub timing: LineTiming,
    pub devices: Vec<DevicePlan>,
    /// Requests and answers of one fast cycle of every device.
    pub frames_per_cycle: usize,
    /// Wire time of one fast cycle of every device.
    pub wire_time_per_cycle: Duration,
    pub bus_load: f64,
}

impl LinePlan {
    pub fn of(line: &LineSpec) -> LinePlan {
        let timing = LineTiming::new(line.serial.baud, line.serial.format);
        let devices: Vec<DevicePlan> = line
            .devices
            .iter()
            .map(|device| device_plan(device, &timing))
            .collect();
        LinePlan {
            name: line.name.clone(),
            timing,
            frames_per_cycle: devices.iter().map(|d| 2 * d.fast_blocks).sum(),
            wire_time_per_cycle: devices.iter().map(|d| d.fast_wire_time).sum(),
            bus_load: devices.iter().map(|d| d.bus_load).sum(),
            devices,
        }
    }
}

/// Wire time of one transaction: request, answer and the t3.5 silence after each.
pub fn transaction_wire_time(timing: &LineTiming, request: &crate::rtu::Request) -> Duration {
    let request_len = request.frame_len();
    let answer_len = request.answer_len();
    timing.frame_time(request_len) + timing.frame_time(answer_len) + 2 * timing.t3_5
}

fn device_plan(device: &DeviceSpec, timing: &LineTiming) -> DevicePlan {
    let limits = device.profile.limits();
    let mut plan = DevicePlan {
        name: device.name.clone(),
        profile: device.profile.name().to_string(),
        address: device.address,
        poll_interval: device.poll_interval,
        slow_interval: limits.slow_interval,
        fast_blocks: 0,
        slow_blocks: 0,
        fast_wire_time: Duration::ZERO,
        slow_wire_time: Duration::ZERO,
        bus_load: 0.0,
    };
    for block in device.profile.read_blocks() {
        let wire = transaction_wire_time(timing, &block.request);
        match block.class {
            PollClass::Fast => {
                plan.fast_blocks += 1;
                plan.fast_wire_time += wire;
            }
            PollClass::Slow => {
                plan.slow_blocks += 1;
                plan.slow_wire_time += wire;
            }
        }
    }
    plan.bus_load = share(plan.fast_wire_time, plan.poll_interval)
        + share(plan.slow_wire_time, plan.slow_interval);
    plan
}

fn share(busy: Duration, every: Duration) -> f64 {
    if every.is_zero() {
        return if busy.is_zero() { 0.0 } else { f64::INFINITY };
    }
    busy.as_secs_f64() / every.as_secs_f64()
}
