//! What the gateway costs an edge box, measured from outside: the built binary runs as its own
//! process (`rtu2mqtt run`) against a real mosquitto and paced simulated devices on
//! pseudo-terminals (9600 8N1, in this process), and is judged by what the devices saw on
//! their end of the wire and by what /proc says about its CPU time and memory.
//!
//! 1. One line, one device, one 6-register block polled continuously (`poll_interval = "0s"`),
//!    40 commands during a 60 s window: transactions/s, bus efficiency, the idle gap before
//!    each request against t3.5 (p50/p95/p99/longest), early requests (sooner than t3.5; must
//!    be 0),
//!    command latency from the publish to the write frame's first byte at the device
//!    (p50/p95), CPU % of one core, RSS and peak RSS.
//! 2. 8 lines × 32 such devices, every device polled continuously: the same footprint figures.
//!
//! bus efficiency = (wire time of every request and answer + the two mandatory t3.5 silences
//!                   of each transaction) / wall time
//!
//! The windows start after a warm-up, so they measure the running loops; the peak RSS is the
//! start-up's.
//!
//! Prints figures beside their targets; asserts nothing. Run: `cargo bench --bench
//! edge_footprint` (about a minute and a half after the build); another build of the gateway
//! is measured with `EDGE_FOOTPRINT_GATEWAY=/path/to/rtu2mqtt`.

#[path = "../tests/it/support/mod.rs"]
mod support;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use rtu2mqtt::profile::Profile;
use rtu2mqtt::sim::{share, GenericDevice, RequestRecord, ServeOptions, VirtualLine};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use support::{Mosquitto, TestClient};

const BAUD: u32 = 9600;
const WARM_UP: Duration = Duration::from_secs(5);
const WINDOW: Duration = Duration::from_secs(60);
const COMMANDS: u32 = 40;
const MANY_LINES: usize = 8;
const DEVICES_PER_LINE: u8 = 32;
const MANY_WINDOW: Duration = Duration::from_secs(20);

/// One device type: one block of six holding registers, the first one writable (FC06); the
/// other five are read-only fields `r1`–`r5` added by [`profile_text`].
const PROFILE_HEAD: &str = r#"
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

fn profile_text() -> String {
    let mut text = PROFILE_HEAD.to_string();
    for register in 1..6 {
        text += &format!(
            "\n[[fields]]\nname = \"r{register}\"\nblock = \"block\"\noffset = {register}\n\
             codec = {{ type = \"u16\" }}\n"
        );
    }
    text
}

const EIGHT_N_ONE: CharFormat = CharFormat {
    data_bits: 8,
    parity: Parity::None,
    stop_bits: 1,
};

fn main() -> anyhow::Result<()> {
    // The simulated devices and the MQTT client; the gateway is another process.
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir()?;
    let profile_path = dir.path().join("edge-block.toml");
    let profile_text = profile_text();
    std::fs::write(&profile_path, &profile_text)?;
    let profile = Profile::from_toml(&profile_text, "edge-block")
        .map_err(|e| anyhow::anyhow!("bench profile: {e:?}"))?;
    let one = runtime.block_on(one_line(&broker, dir.path(), &profile_path, &profile))?;
    let many = runtime.block_on(many_lines(&broker, dir.path(), &profile_path, &profile))?;
    report(&one, &many);
    Ok(())
}

/// Footprint of the gateway process over a window.
struct Footprint {
    transactions_per_second: f64,
    cpu_percent: f64,
    rss_kib: u64,
    peak_rss_kib: u64,
    /// Of the RSS: heap and stacks (the rest is the binary's and libraries' pages).
    anon_kib: u64,
    threads: u64,
}

struct Wire {
    efficiency: f64,
    gap_p50: Duration,
    gap_p95: Duration,
    gap_p99: Duration,
    gap_max: Duration,
    early: usize,
    command_p50: Option<Duration>,
    command_p95: Option<Duration>,
    commands_seen: usize,
}

async fn one_line(
    broker: &Mosquitto,
    dir: &Path,
    profile_path: &Path,
    profile: &Profile,
) -> anyhow::Result<(Footprint, Wire)> {
    let line = spawn_line(profile, 1)?;
    let config = config_file(dir, "one", broker, profile_path, &[&line], 1)?;
    let mut gateway = Gateway::start(&config)?;
    let mut client = TestClient::connect(broker.port, "bench-commands").await;
    client.subscribe("plant/block-1-1/setpoint/result").await;
    tokio::time::sleep(WARM_UP).await;

    let start = Instant::now();
    let cpu_start = gateway.cpu_time()?;
    let mut published = Vec::new();
    let every = WINDOW / COMMANDS;
    for i in 0..COMMANDS {
        let value = 1000 + i as u16;
        tokio::time::sleep_until((start + every * i + every / 2).into()).await;
        published.push((value, Instant::now()));
        client
            .publish(
                "plant/block-1-1/setpoint/set",
                value.to_string().into_bytes(),
                false,
            )
            .await;
    }
    tokio::time::sleep_until((start + WINDOW).into()).await;
    let wall = start.elapsed();
    let cpu = gateway.cpu_time()? - cpu_start;
    let memory = gateway.memory()?;
    gateway.stop();

    let records: Vec<RequestRecord> = line
        .journal()
        .requests()
        .into_iter()
        .filter(|r| r.arrived >= start && r.arrived < start + wall)
        .collect();
    let footprint = Footprint {
        transactions_per_second: records.len() as f64 / wall.as_secs_f64(),
        cpu_percent: 100.0 * cpu.as_secs_f64() / wall.as_secs_f64(),
        rss_kib: memory.rss_kib,
        peak_rss_kib: memory.peak_rss_kib,
        anon_kib: memory.anon_kib,
        threads: memory.threads,
    };
    Ok((footprint, wire_figures(&records, wall, &published)))
}

async fn many_lines(
    broker: &Mosquitto,
    dir: &Path,
    profile_path: &Path,
    profile: &Profile,
) -> anyhow::Result<Footprint> {
    let lines = (0..MANY_LINES)
        .map(|_| spawn_line(profile, DEVICES_PER_LINE))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let refs: Vec<&VirtualLine> = lines.iter().collect();
    let config = config_file(dir, "many", broker, profile_path, &refs, DEVICES_PER_LINE)?;
    let mut gateway = Gateway::start(&config)?;
    tokio::time::sleep(WARM_UP).await;
    let counted = |lines: &[VirtualLine]| -> usize {
        lines.iter().map(|l| l.journal().request_count()).sum()
    };
    let start = Instant::now();
    let requests_start = counted(&lines);
    let cpu_start = gateway.cpu_time()?;
    tokio::time::sleep(MANY_WINDOW).await;
    let wall = start.elapsed();
    let cpu = gateway.cpu_time()? - cpu_start;
    let requests = counted(&lines) - requests_start;
    let memory = gateway.memory()?;
    gateway.stop();
    Ok(Footprint {
        transactions_per_second: requests as f64 / wall.as_secs_f64(),
        cpu_percent: 100.0 * cpu.as_secs_f64() / wall.as_secs_f64(),
        rss_kib: memory.rss_kib,
        peak_rss_kib: memory.peak_rss_kib,
        anon_kib: memory.anon_kib,
        threads: memory.threads,
    })
}

/// A paced 9600 8N1 line with `devices` bench devices at addresses 1, 2, …
fn spawn_line(profile: &Profile, devices: u8) -> anyhow::Result<VirtualLine> {
    let shared = (1..=devices)
        .map(|address| share(GenericDevice::from_profile(profile, address)).1)
        .collect();
    Ok(VirtualLine::spawn(
        ServeOptions::new(BAUD, Parity::None).paced(true),
        shared,
    )?)
}

/// A configuration with one `[[lines]]` per virtual line, `devices` continuously polled
/// bench devices on each (named `block-<line>-<address>`).
fn config_file(
    dir: &Path,
    name: &str,
    broker: &Mosquitto,
    profile_path: &Path,
    lines: &[&VirtualLine],
    devices: u8,
) -> anyhow::Result<PathBuf> {
    let mut text = format!(
        "[mqtt]\nurl = \"{}\"\nclient_id = \"bench-{name}\"\n\n[health]\nstatus_file = \"\"\n",
        broker.url()
    );
    for (index, line) in lines.iter().enumerate() {
        let number = index + 1;
        text += &format!(
            "\n[[lines]]\nname = \"line-{number}\"\nport = \"{}\"\nbaud = {BAUD}\nparity = \"none\"\n",
            line.path().display()
        );
        for address in 1..=devices {
            text += &format!(
                "\n[[lines.devices]]\nname = \"block-{number}-{address}\"\nprofile = \"{}\"\n\
                 address = {address}\npoll_interval = \"0s\"\n",
                profile_path.display()
            );
        }
    }
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text)?;
    Ok(path)
}

/// What /proc/<pid>/status says about the gateway's memory.
struct Memory {
    rss_kib: u64,
    peak_rss_kib: u64,
    anon_kib: u64,
    threads: u64,
}

/// The gateway binary measured: `EDGE_FOOTPRINT_GATEWAY`, else this build's `rtu2mqtt`.
fn gateway_binary() -> PathBuf {
    std::env::var_os("EDGE_FOOTPRINT_GATEWAY").map_or_else(
        || PathBuf::from(env!("CARGO_BIN_EXE_rtu2mqtt")),
        PathBuf::from,
    )
}

/// The gateway as its own process.
struct Gateway {
    child: Child,
}

impl Gateway {
    fn start(config: &Path) -> anyhow::Result<Gateway> {
        // Another build of the gateway can be measured in its place (a static build, one with
        // symbols for a profiler): EDGE_FOOTPRINT_GATEWAY=/path/to/rtu2mqtt.
        let child = Command::new(gateway_binary())
            .arg("run")
            .arg("--config")
            .arg(config)
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()?;
        Ok(Gateway { child })
    }

    /// User and system CPU time so far (/proc/<pid>/stat, utime + stime).
    fn cpu_time(&self) -> anyhow::Result<Duration> {
        let stat = std::fs::read_to_string(format!("/proc/{}/stat", self.child.id()))?;
        // The command name may hold spaces: the fields after it start behind the last ')'.
        let after_name = stat
            .rsplit_once(')')
            .map(|(_, rest)| rest)
            .ok_or_else(|| anyhow::anyhow!("unreadable /proc stat"))?;
        let fields: Vec<&str> = after_name.split_whitespace().collect();
        // utime and stime are fields 14 and 15 of the line, 12 and 13 after the name.
        let ticks: u64 = fields
            .get(11..13)
            .ok_or_else(|| anyhow::anyhow!("short /proc stat"))?
            .iter()
            .map(|f| f.parse::<u64>().unwrap_or(0))
            .sum();
        // SAFETY: sysconf takes no pointers.
        let per_second = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as u64;
        Ok(Duration::from_secs_f64(ticks as f64 / per_second as f64))
    }

    /// VmRSS, VmHWM and RssAnon in KiB, and the thread count.
    fn memory(&self) -> anyhow::Result<Memory> {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id()))?;
        let field = |name: &str| {
            status
                .lines()
                .find(|l| l.starts_with(name))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse::<u64>().ok())
                .unwrap_or(0)
        };
        Ok(Memory {
            rss_kib: field("VmRSS:"),
            peak_rss_kib: field("VmHWM:"),
            anon_kib: field("RssAnon:"),
            threads: field("Threads:"),
        })
    }

    fn stop(&mut self) {
        let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
        let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.stop();
        }
    }
}

fn wire_figures(records: &[RequestRecord], wall: Duration, published: &[(u16, Instant)]) -> Wire {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    let busy: Duration = records
        .iter()
        .map(|r| {
            timing.frame_time(r.frame.len())
                + timing.frame_time(r.answer.as_ref().map_or(0, Vec::len))
                + 2 * timing.t3_5
        })
        .sum();
    let mut gaps: Vec<Duration> = records.iter().filter_map(|r| r.silence_before).collect();
    gaps.sort();
    let early = gaps.iter().filter(|gap| **gap < timing.t3_5).count();
    let mut latencies: Vec<Duration> = published
        .iter()
        .filter_map(|(value, at)| {
            records
                .iter()
                .find(|r| {
                    r.frame.get(1) == Some(&0x06)
                        && r.frame.get(4..6) == Some(&value.to_be_bytes()[..])
                })
                .map(|r| r.arrived.saturating_duration_since(*at))
        })
        .collect();
    latencies.sort();
    Wire {
        efficiency: busy.as_secs_f64() / wall.as_secs_f64(),
        gap_p50: percentile(&gaps, 50),
        gap_p95: percentile(&gaps, 95),
        gap_p99: percentile(&gaps, 99),
        gap_max: gaps.last().copied().unwrap_or_default(),
        early,
        command_p50: (!latencies.is_empty()).then(|| percentile(&latencies, 50)),
        command_p95: (!latencies.is_empty()).then(|| percentile(&latencies, 95)),
        commands_seen: latencies.len(),
    }
}

/// One read of the block on the wire: request (8 bytes), answer (17) and both t3.5 silences.
fn transaction_wire_time() -> Duration {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    timing.frame_time(8) + timing.frame_time(17) + 2 * timing.t3_5
}

fn percentile(sorted: &[Duration], p: usize) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    let index = (sorted.len() * p).div_ceil(100).saturating_sub(1);
    sorted[index.min(sorted.len() - 1)]
}

fn ms(duration: Duration) -> String {
    format!("{:.2} ms", duration.as_secs_f64() * 1000.0)
}

fn mib(kib: u64) -> String {
    format!("{:.1} MiB", kib as f64 / 1024.0)
}

fn row(figure: &str, value: String, target: &str) {
    println!("{figure:<44} {value:>22}   {target}");
}

/// The gateway process's CPU and memory against their targets.
fn footprint_rows(footprint: &Footprint, cpu_target: &str, rss_target: &str) {
    row(
        "gateway CPU (one core)",
        format!("{:.2} %", footprint.cpu_percent),
        cpu_target,
    );
    row(
        "gateway RSS / peak",
        format!(
            "{} / {}",
            mib(footprint.rss_kib),
            mib(footprint.peak_rss_kib)
        ),
        rss_target,
    );
    row(
        "  of which heap and stacks; threads",
        format!("{}; {}", mib(footprint.anon_kib), footprint.threads),
        "",
    );
}

fn report((one, wire): &(Footprint, Wire), many: &Footprint) {
    let t3_5 = LineTiming::new(BAUD, EIGHT_N_ONE).t3_5;
    println!();
    println!("gateway: {}", gateway_binary().display());
    println!(
        "one line, 9600 8N1, one 6-register block polled continuously, {COMMANDS} commands in {} s",
        WINDOW.as_secs()
    );
    row("figure", "measured".into(), "target");
    let wire_limit = 1.0 / transaction_wire_time().as_secs_f64();
    row(
        "transactions/s",
        format!("{:.1}", one.transactions_per_second),
        &format!("wire limit {wire_limit:.1}"),
    );
    row(
        "bus efficiency",
        format!("{:.3}", wire.efficiency),
        "≥ 0.99",
    );
    row(
        "idle gap before a request p50 / p95",
        format!("{} / {}", ms(wire.gap_p50), ms(wire.gap_p95)),
        &format!(
            "p50 ≤ t3.5 + 0.25 ms = {}",
            ms(t3_5 + Duration::from_micros(250))
        ),
    );
    row(
        "  p99 / longest",
        format!("{} / {}", ms(wire.gap_p99), ms(wire.gap_max)),
        "",
    );
    row(
        "early requests (sooner than t3.5)",
        wire.early.to_string(),
        "0",
    );
    row(
        "command latency p50 / p95",
        match (wire.command_p50, wire.command_p95) {
            (Some(p50), Some(p95)) => format!("{} / {}", ms(p50), ms(p95)),
            _ => "-".into(),
        },
        &format!(
            "p95 ≤ 35 ms ({} of {COMMANDS} writes seen)",
            wire.commands_seen
        ),
    );
    footprint_rows(one, "≤ 0.7 %", "≤ 5.5 MiB");
    println!();
    println!(
        "{MANY_LINES} lines × {DEVICES_PER_LINE} devices, every device polled continuously, {} s",
        MANY_WINDOW.as_secs()
    );
    row(
        "transactions/s (all lines)",
        format!("{:.1}", many.transactions_per_second),
        "",
    );
    footprint_rows(many, "", "≤ 10 MiB");
    println!(
        "\nt3.5 at {BAUD} baud: {}; CPU from /proc/<pid>/stat (utime + stime), memory from \
         /proc/<pid>/status (VmRSS, VmHWM)",
        ms(t3_5)
    );
}
