//! A line's poll plan computed from its devices' read blocks and the wire timing: blocks and
//! frames per cycle, wire time per cycle (request + answer + 2 × t3.5 per block) and the bus
//! load at the configured intervals, each block on its own cadence (fast, slow, a period of
//! its own; a `once` block is read at start, after a write and on refresh, and takes no share
//! in steady state). Pure arithmetic, used by validation (a plan over 100 % is an error) and
//! printed by `rtu2mqtt check`.
//!
//! A device polled continuously (`poll_interval = "0s"`) takes whatever time the line has left,
//! as often as its profile's minimum allows: it never makes a plan over 100 %, and a line with
//! one is counted as full when its periodic polls leave it nothing idle.

use std::time::Duration;

use crate::bus::{DeviceSpec, LineSpec};
use rtu2mqtt_modbus::timing::LineTiming;
use rtu2mqtt_profile::PollClass;

/// One block's share of its line.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockLoad {
    pub name: String,
    /// The read request, as `check` shows it (`FC03 0x0000 ×11`).
    pub request: rtu2mqtt_modbus::Request,
    pub class: PollClass,
    /// How often it is read in steady state; None for a `once` block.
    pub period: Option<Duration>,
    /// Wire time of one read.
    pub wire_time: Duration,
    /// Share of the line's time it takes (zero for a `once` block).
    pub load: f64,
}

/// One device's share of its line.
#[derive(Debug, Clone, PartialEq)]
pub struct DevicePlan {
    pub name: String,
    pub profile: String,
    pub address: u8,
    pub poll_interval: Duration,
    /// Polled back to back (`poll_interval` zero), never sooner than the profile allows.
    pub continuous: bool,
    pub slow_interval: Duration,
    pub fast_blocks: usize,
    pub slow_blocks: usize,
    /// Wire time of one fast cycle (every poll interval).
    pub fast_wire_time: Duration,
    /// Wire time of the slow blocks (every slow interval).
    pub slow_wire_time: Duration,
    /// Share of the line taken by the blocks with a period of their own.
    pub timed_load: f64,
    /// Every block with its cadence, in the profile's order.
    pub blocks: Vec<BlockLoad>,
    /// Share of the line's time this device takes (0.0–1.0 and beyond); for a continuous
    /// device, what it takes on a line of its own.
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
    /// Share of the line's time the plan takes: 1.0 with a continuous device.
    pub bus_load: f64,
    /// Share taken by the polls on a fixed interval (every device's slow blocks included):
    /// above 1.0 the line cannot keep them.
    pub periodic_load: f64,
    /// A device is polled continuously.
    pub continuous: bool,
}

impl LinePlan {
    pub fn of(line: &LineSpec) -> LinePlan {
        let timing = LineTiming::new(line.serial.baud, line.serial.format);
        let devices: Vec<DevicePlan> = line
            .devices
            .iter()
            .map(|device| device_plan(device, &timing))
            .collect();
        let periodic_load: f64 = devices
            .iter()
            .map(|d| {
                if d.continuous {
                    share(d.slow_wire_time, d.slow_interval) + d.timed_load
                } else {
                    d.bus_load
                }
            })
            .sum();
        let continuous = devices.iter().any(|d| d.continuous);
        LinePlan {
            name: line.name.clone(),
            timing,
            frames_per_cycle: devices.iter().map(|d| 2 * d.fast_blocks).sum(),
            wire_time_per_cycle: devices.iter().map(|d| d.fast_wire_time).sum(),
            bus_load: if continuous { 1.0 } else { periodic_load },
            periodic_load,
            continuous,
            devices,
        }
    }
}

/// Wire time of one transaction: request, answer and the t3.5 silence after each.
pub fn transaction_wire_time(timing: &LineTiming, request: &rtu2mqtt_modbus::Request) -> Duration {
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
        continuous: device.poll_interval.is_zero(),
        slow_interval: limits.slow_interval,
        fast_blocks: 0,
        slow_blocks: 0,
        fast_wire_time: Duration::ZERO,
        slow_wire_time: Duration::ZERO,
        timed_load: 0.0,
        blocks: Vec::new(),
        bus_load: 0.0,
    };
    let wires: Vec<Duration> = device
        .profile
        .read_blocks()
        .iter()
        .map(|block| transaction_wire_time(timing, &block.request))
        .collect();
    for (block, &wire) in device.profile.read_blocks().iter().zip(&wires) {
        match block.class {
            PollClass::Fast => {
                plan.fast_blocks += 1;
                plan.fast_wire_time += wire;
            }
            PollClass::Slow => {
                plan.slow_blocks += 1;
                plan.slow_wire_time += wire;
            }
            PollClass::Every(period) => plan.timed_load += share(wire, period),
            PollClass::Once => {}
        }
    }
    // Continuously: one fast cycle after the other, or the profile's minimum between polls.
    let fast_period = if plan.continuous {
        limits.min_poll_interval.max(plan.fast_wire_time)
    } else {
        plan.poll_interval
    };
    plan.bus_load = share(plan.fast_wire_time, fast_period)
        + share(plan.slow_wire_time, plan.slow_interval)
        + plan.timed_load;
    plan.blocks = device
        .profile
        .read_blocks()
        .iter()
        .zip(wires)
        .map(|(block, wire_time)| {
            let period = match block.class {
                PollClass::Fast => Some(fast_period),
                PollClass::Slow => Some(plan.slow_interval),
                PollClass::Every(period) => Some(period),
                PollClass::Once => None,
            };
            BlockLoad {
                name: block.name.clone(),
                request: block.request.clone(),
                class: block.class,
                period,
                wire_time,
                load: period.map_or(0.0, |period| share(wire_time, period)),
            }
        })
        .collect();
    plan
}

fn share(busy: Duration, every: Duration) -> f64 {
    if every.is_zero() {
        return if busy.is_zero() { 0.0 } else { f64::INFINITY };
    }
    busy.as_secs_f64() / every.as_secs_f64()
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    /// The valve (min poll interval 500 ms) and the air shower on one 9600 baud line.
    fn config(valve_poll: &str, shower_poll: &str) -> String {
        format!(
            r#"
[mqtt]
url = "mqtt://127.0.0.1:1883"
client_id = "edge1"

[[lines]]
name = "line-a"
port = "/dev/ttyUSB0"
baud = 9600
parity = "even"

[[lines.devices]]
name = "valve"
profile = "wuzhou-valve"
address = 1
poll_interval = "{valve_poll}"

[[lines.devices]]
name = "shower"
profile = "lixian-air-shower"
address = 0x81
poll_interval = "{shower_poll}"
"#
        )
    }

    fn reasons(text: &str) -> Vec<String> {
        match crate::config::from_str(text, Path::new(".")) {
            Ok(_) => Vec::new(),
            Err(problems) => problems.0.iter().map(|p| p.to_string()).collect(),
        }
    }

    #[test]
    fn zero_is_continuous_and_fills_the_line_without_overloading_it() {
        let text = config("0s", "1s");
        assert_eq!(reasons(&text), Vec::<String>::new());
        let config = crate::config::from_str(&text, Path::new(".")).unwrap();
        let plan = LinePlan::of(&config.lines[0]);
        assert!(plan.continuous);
        assert!(plan.devices[0].continuous && !plan.devices[1].continuous);
        assert_eq!(plan.bus_load, 1.0);
        assert!(plan.periodic_load < 1.0, "{}", plan.periodic_load);
        // On a line of its own the valve is polled no more often than its profile's minimum.
        let valve = &plan.devices[0];
        assert_eq!(
            valve.bus_load,
            share(valve.fast_wire_time, Duration::from_millis(500))
                + share(valve.slow_wire_time, valve.slow_interval)
        );
    }

    #[test]
    fn below_the_profile_minimum_is_refused_zero_is_continuous() {
        // Below the profile's minimum is refused; zero is not "below", it is continuous.
        let too_fast = reasons(&config("100ms", "1s"));
        assert!(
            too_fast.iter().any(|r| r.contains("under the minimum")),
            "{too_fast:?}"
        );
        assert!(reasons(&config("0s", "500ms")).is_empty());
    }
}
