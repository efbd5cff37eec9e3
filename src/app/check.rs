//! `rtu2mqtt check`: validates the configuration and its profiles without touching a port or a
//! broker, and prints each line's poll plan (devices, each block with its cadence, wire time
//! and share of the line, frames and wire time per cycle, bus load), what each line talks
//! through and where it is served, in a form that can be pasted into a bug report. Exit 0
//! valid, 1 invalid or when the history journal's directory cannot be written by the user
//! running it (`run` would serve live values and report itself unhealthy).

use std::fmt::Write as _;
use std::path::Path;
use std::process::ExitCode;
use std::time::Duration;

use crate::bus::line::default_response_timeout;
use crate::bus::Transport;
use crate::config::poll_plan::{BlockLoad, LinePlan};
use crate::config::{self, Config};
use crate::history::Journal;
use rtu2mqtt_profile::registry::describe_read;
use rtu2mqtt_profile::PollClass;

pub fn check(path: &Path) -> anyhow::Result<ExitCode> {
    match config::load(path) {
        Ok(config) => {
            print!("{}", report(path, &config));
            let journal_unusable = config
                .history
                .as_ref()
                .is_some_and(|history| Journal::unusable(&history.path).is_some());
            Ok(if journal_unusable {
                ExitCode::FAILURE
            } else {
                ExitCode::SUCCESS
            })
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
    if let Some(sparkplug) = &config.sparkplug {
        let node = &sparkplug.identity;
        let _ = writeln!(
            out,
            "sparkplug: spBv1.0/{}/…/{} on {}://{}:{} as {:?}{}",
            node.group_id,
            node.edge_node_id,
            if sparkplug.mqtt.tls.is_some() {
                "mqtts"
            } else {
                "mqtt"
            },
            sparkplug.mqtt.host,
            sparkplug.mqtt.port,
            sparkplug.mqtt.client_id,
            node.primary_host_id
                .as_ref()
                .map(|host| format!(", births wait for primary host {host:?}"))
                .unwrap_or_default()
        );
    }
    if let Some(web) = &config.web {
        let scheme = if web.tls.is_some() { "https" } else { "http" };
        let access = if web.token.is_some() {
            "a login with the token; commands allowed"
        } else {
            "no login, loopback only, reads only"
        };
        let _ = writeln!(out, "console: {scheme}://{}/ ({access})", web.listen);
    }
    if let Some(history) = &config.history {
        let _ = writeln!(
            out,
            "history: journal in {}, at most {} bytes, records kept {}; stream on {}",
            history.path.display(),
            history.max_size,
            humantime::format_duration(history.max_age),
            config.mqtt.topics().history_filter(),
        );
        if let Some(problem) = Journal::unusable(&history.path) {
            let _ = writeln!(
                out,
                "history.path: cannot be written (as uid {}): {problem}; `run` would serve live \
                 values and report itself unhealthy until it can",
                running_uid()
            );
        }
        let holds = match Journal::inspect(&history.path) {
            Ok(Some(stats)) => format!(
                "{} records waiting in {} bytes, {} damaged parts",
                stats.waiting, stats.bytes, stats.damaged
            ),
            Ok(None) => "nothing yet (the directory is made at start)".to_string(),
            Err(error) => format!("cannot be read: {error}"),
        };
        let _ = writeln!(out, "history journal: {holds}");
    }
    for warning in &config.warnings {
        let _ = writeln!(out, "warning: {warning}");
    }
    for line in &config.lines {
        let plan = LinePlan::of(line);
        let serial = &line.serial;
        let format = format!("{} baud {}", serial.baud, serial.format);
        let t3_5 = millis(plan.timing.t3_5);
        let timeout = millis(
            line.response_timeout
                .unwrap_or_else(|| default_response_timeout(line, &plan.timing)),
        );
        let _ = match &line.transport {
            Transport::Serial => writeln!(
                out,
                "\nline {} on {}: {format}, t3.5 {t3_5}",
                line.name, serial.path
            ),
            Transport::Tcp {
                endpoint,
                network_allowance,
                ..
            } => {
                let kind = endpoint.kind;
                let what = format!("{}, {}", kind.server_name(), kind.framing());
                if kind.times_its_serial_side() {
                    writeln!(
                        out,
                        "\nline {} on {} ({what}): response timeout {timeout}; the gateway times \
                         its serial side, load estimated at {format}",
                        line.name,
                        endpoint.url()
                    )
                } else {
                    writeln!(
                        out,
                        "\nline {} on {} ({what}): {format} on its serial side, t3.5 {t3_5}, \
                         response timeout {timeout} (network allowance {})",
                        line.name,
                        endpoint.url(),
                        millis(*network_allowance)
                    )
                }
            }
        };
        if let Some(serve) = &line.serve {
            let _ = writeln!(
                out,
                "  served on {} to at most {} clients, access {}, cache {}",
                serve.url(),
                serve.max_clients,
                serve.access.word(),
                if serve.cache.is_zero() {
                    "off (every read goes to the line)".to_string()
                } else {
                    humantime::format_duration(serve.cache).to_string()
                }
            );
        }
        let _ = writeln!(
            out,
            "  {:<20} {:<24} {:>4} {:>10} {:>6} {:>7}",
            "device", "profile", "addr", "poll", "blocks", "load"
        );
        for device in &plan.devices {
            let _ = writeln!(
                out,
                "  {:<20} {:<24} {:>4} {:>10} {:>6} {:>6.1}%",
                device.name,
                device.profile,
                device.address,
                if device.continuous {
                    "continuous".to_string()
                } else {
                    humantime::format_duration(device.poll_interval).to_string()
                },
                device.blocks.len(),
                device.bus_load * 100.0
            );
            for block in &device.blocks {
                let _ = writeln!(
                    out,
                    "    {:<18} {:<20} {:<21} {:>10} {:>6}",
                    block.name,
                    describe_read(&block.request),
                    cadence(block, device.continuous),
                    millis(block.wire_time),
                    if block.period.is_some() {
                        format!("{:.1}%", block.load * 100.0)
                    } else {
                        "-".to_string()
                    }
                );
            }
        }
        let once: Vec<&BlockLoad> = plan
            .devices
            .iter()
            .flat_map(|device| &device.blocks)
            .filter(|block| block.period.is_none())
            .collect();
        if !once.is_empty() {
            let _ = writeln!(
                out,
                "  once: {} block{}, {} on the wire at start, after a write into them and on \
                 refresh; no load in steady state",
                once.len(),
                if once.len() == 1 { "" } else { "s" },
                millis(once.iter().map(|block| block.wire_time).sum()),
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

/// How often a block is read: `fast every 1s`, `slow every 1m`, `every 15s`, `once`.
fn cadence(block: &BlockLoad, continuous: bool) -> String {
    let period = block
        .period
        .map(|period| humantime::format_duration(period).to_string())
        .unwrap_or_default();
    match block.class {
        PollClass::Fast if continuous => "fast, continuously".to_string(),
        PollClass::Fast => format!("fast every {period}"),
        PollClass::Slow => format!("slow every {period}"),
        PollClass::Every(_) => format!("every {period}"),
        PollClass::Once => "once".to_string(),
    }
}

/// The user `check` runs as, by number ("?" where /proc is not there).
fn running_uid() -> String {
    use std::os::unix::fs::MetadataExt as _;
    std::fs::metadata("/proc/self").map_or_else(|_| "?".to_string(), |meta| meta.uid().to_string())
}

fn millis(duration: Duration) -> String {
    format!("{:.2} ms", duration.as_secs_f64() * 1000.0)
}
