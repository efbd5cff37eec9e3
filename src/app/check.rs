//! `rtu2mqtt check`: validates the configuration and its profiles without touching a port or a
//! broker, and prints each line's poll plan (devices, blocks, frames and wire time per cycle,
//! bus load) in a form that can be pasted into a bug report. Exit 0 valid, 1 invalid.

use std::fmt::Write as _;
use std::path::Path;
use std::process::ExitCode;
use std::time::Duration;

use crate::config::plan::LinePlan;
use crate::config::{self, Config};
use crate::rtu::timing::Parity;

pub fn check(path: &Path) -> anyhow::Result<ExitCode> {
    match config::load(path) {
        Ok(config) => {
            print!("{}", report(path, &config));
            Ok(ExitCode::SUCCESS)
        }
        Err(problems) => {
            eprintln!("{}: {problems}", path.display());
            Ok(ExitCode::FAILURE)
        }
    }
}

/// The text `check` prints for a valid configuration.
pub fn report(path: &Path, config: &Config) -> String {
    let mut out = String::new();
    let mqtt = &config.mqtt;
    let _ = writeln!(
        out,
        "{}: valid (rtu2mqtt {})",
        path.display(),
        env!("CARGO_PKG_VERSION")
    );
    let _ = writeln!(
        out,
        "mqtt: {}://{}:{} as {:?}, prefix {:?}, discovery {}",
        if mqtt.tls.is_some() { "mqtts" } else { "mqtt" },
        mqtt.host,
        mqtt.port,
        mqtt.client_id,
        mqtt.prefix,
        if mqtt.discovery {
            format!("on ({})", mqtt.discovery_prefix)
        } else {
            "off".to_string()
        }
    );
    for warning in &config.warnings {
        let _ = writeln!(out, "warning: {warning}");
    }
    for line in &config.lines {
        let plan = LinePlan::of(line);
        let serial = &line.serial;
        let _ = writeln!(
            out,
            "\nline {} on {}: {} baud {}{}{}, t3.5 {}",
            line.name,
            serial.path,
            serial.baud,
            serial.format.data_bits,
            parity_letter(serial.format.parity),
            serial.format.stop_bits,
            millis(plan.timing.t3_5)
        );
        let _ = writeln!(
            out,
            "  {:<20} {:<24} {:>4} {:>7} {:>11} {:>11} {:>17} {:>7}",
            "device", "profile", "addr", "poll", "blocks f/s", "wire fast", "wire slow", "load"
        );
        for device in &plan.devices {
            let _ = writeln!(
                out,
                "  {:<20} {:<24} {:>4} {:>7} {:>11} {:>11} {:>17} {:>6.1}%",
                device.name,
                device.profile,
                device.address,
                if device.continuous {
                    "continuous".to_string()
                } else {
                    humantime::format_duration(device.poll_interval).to_string()
                },
                format!("{}/{}", device.fast_blocks, device.slow_blocks),
                millis(device.fast_wire_time),
                format!(
                    "{} /{}",
                    millis(device.slow_wire_time),
                    humantime::format_duration(device.slow_interval)
                ),
                device.bus_load * 100.0
            );
        }
        let _ = writeln!(
            out,
            "  per fast cycle: {} frames, {} on the wire; bus load {:.1} %{}",
            plan.frames_per_cycle,
            millis(plan.wire_time_per_cycle),
            plan.bus_load * 100.0,
            if plan.continuous {
                format!(
                    " (polled continuously; periodic polls {:.1} %)",
                    plan.periodic_load * 100.0
                )
            } else {
                String::new()
            }
        );
    }
    out
}

fn parity_letter(parity: Parity) -> char {
    match parity {
        Parity::None => 'N',
        Parity::Even => 'E',
        Parity::Odd => 'O',
    }
}

fn millis(duration: Duration) -> String {
    format!("{:.2} ms", duration.as_secs_f64() * 1000.0)
}
