//! What the gateway costs an edge box, measured from outside: the built binary runs as its own
//! process (`rtu2mqtt run`) against a real mosquitto and simulated devices on pseudo-terminals
//! (9600 8N1, in this process) that release their answers as real lines do, and is judged by
//! what the devices saw on their end of the wire, by when results reached an MQTT subscriber,
//! and by what /proc says about its CPU time and memory.
//!
//! 1. One line, one device, one 6-register block polled continuously (`poll_interval = "0s"`),
//!    40 commands during a 30 s window, twice: answers released byte by byte at the character
//!    rate (a UART without a deep FIFO), then in USB-adapter chunks (what is on the wire every
//!    4 ms). For each: transactions/s, bus efficiency, the idle gap before each request
//!    against t3.5, early requests (sooner than t3.5; must be 0), CPU of the gateway and of the
//!    simulator (this process) and their ratio, anonymous memory and PSS, and for each command
//!    the time from its publish to the write frame at the device and to its `…/result` at a
//!    subscriber, each beside its physical bound (below).
//! 2. 8 lines × 32 such devices, byte-paced, every device polled continuously: the same
//!    footprint figures.
//!
//! bus efficiency = (wire time of every request and answer + the two mandatory t3.5 silences
//!                   of each transaction) / wall time
//!
//! The bounds, from frame lengths and the baud rate alone: a command published while a poll is
//! on the wire can reach the wire no sooner than that transaction's end plus t3.5; its result
//! no sooner than that plus the write (8 bytes), t3.5, its answer (8), t3.5, the read-back (8),
//! t3.5 and its answer (17).
//!
//! Memory is what the process costs the box: anonymous memory (RssAnon from
//! /proc/<pid>/status, Private_Dirty from /proc/<pid>/smaps_rollup) and PSS (the shared pages
//! divided among their users), not VmRSS, whose clean file pages the kernel drops by itself.
//!
//! Prints figures beside their targets; asserts nothing. Run: `cargo bench --bench
//! edge_footprint` (about two minutes after the build); another build of the gateway is
//! measured with `EDGE_FOOTPRINT_GATEWAY=/path/to/rtu2mqtt`.

#[path = "../tests/it/support/mod.rs"]
mod support;
mod wire_bench;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rtu2mqtt::profile::Profile;
use rtu2mqtt::sim::{share, GenericDevice, Pace, RequestRecord, ServeOptions, VirtualLine};
use rtu2mqtt_modbus::timing::{LineTiming, Parity};
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use support::Mosquitto;
use tokio::sync::mpsc;
use wire_bench::{command_client, percentile, wire_load, Gateway, WireLoad, EIGHT_N_ONE};

const BAUD: u32 = 9600;
const WARM_UP: Duration = Duration::from_secs(5);
const WINDOW: Duration = Duration::from_secs(30);
const COMMANDS: u32 = 40;
const MANY_LINES: usize = 8;
const DEVICES_PER_LINE: u8 = 32;
const MANY_WINDOW: Duration = Duration::from_secs(15);
/// The one-line runs: how the simulator releases answers, and what that stands for.
const PACES: [(Pace, &str); 2] = [
    (Pace::Bytes, "byte by byte at the character rate"),
    (
        Pace::Usb {
            every: Duration::from_millis(4),
        },
        "in USB-adapter chunks, one every 4 ms",
    ),
];
/// Frame lengths of the bench's command slot: the FC06 write and its echo, the read-back of
/// the 6-register block and its answer.
const WRITE_LEN: usize = 8;
const READ_REQUEST_LEN: usize = 8;
const READ_ANSWER_LEN: usize = 17;

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

fn main() -> anyhow::Result<()> {
    // The simulated devices and the MQTT client; the gateway is another process.
    let runtime = wire_bench::runtime()?;
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir()?;
    let profile_path = dir.path().join("edge-block.toml");
    let profile_text = profile_text();
    std::fs::write(&profile_path, &profile_text)?;
    let profile = Profile::from_toml(&profile_text, "edge-block")
        .map_err(|e| anyhow::anyhow!("bench profile: {e:?}"))?;
    let mut runs = Vec::new();
    for (index, (pace, label)) in PACES.into_iter().enumerate() {
        let run = runtime.block_on(one_line(
            &broker,
            dir.path(),
            &profile_path,
            &profile,
            pace,
            index,
        ))?;
        runs.push((label, run));
    }
    let many = runtime.block_on(many_lines(&broker, dir.path(), &profile_path, &profile))?;
    report(&runs, &many);
    Ok(())
}

/// Footprint of the gateway process over a window.
struct Footprint {
    transactions_per_second: f64,
    cpu_percent: f64,
    memory: Memory,
}

/// One one-line run: the gateway's footprint, the simulator's CPU, what the wire and the
/// subscriber saw.
struct OneLine {
    footprint: Footprint,
    simulator_cpu_percent: f64,
    wire: Wire,
}

struct Wire {
    efficiency: f64,
    gap_p50: Duration,
    gap_p95: Duration,
    early: usize,
    /// Publish → the write frame at the device, and its bound, per command seen.
    to_wire: Vec<Duration>,
    to_wire_bound: Vec<Duration>,
    /// Publish → `…/result` at the subscriber, and its bound, per result seen.
    to_result: Vec<Duration>,
    to_result_bound: Vec<Duration>,
}

/// A subscriber that notes when each message on its topic arrived.
async fn timed_subscriber(
    port: u16,
    topic: &str,
    client_id: &str,
) -> anyhow::Result<mpsc::UnboundedReceiver<Instant>> {
    let mut options = MqttOptions::new(client_id, "127.0.0.1", port);
    options.set_keep_alive(Duration::from_secs(30));
    let (client, mut eventloop) = AsyncClient::new(options, 16);
    let mut network = eventloop.network_options();
    network.set_tcp_nodelay(true);
    eventloop.set_network_options(network);
    client.subscribe(topic, QoS::AtMostOnce).await?;
    let (tx, rx) = mpsc::unbounded_channel();
    let (subscribed_tx, subscribed_rx) = tokio::sync::oneshot::channel();
    tokio::spawn(async move {
        let _client = client;
        let mut subscribed_tx = Some(subscribed_tx);
        loop {
            match eventloop.poll().await {
                Ok(Event::Incoming(Packet::Publish(_))) => {
                    if tx.send(Instant::now()).is_err() {
                        return;
                    }
                }
                Ok(Event::Incoming(Packet::SubAck(_))) => {
                    if let Some(subscribed) = subscribed_tx.take() {
                        let _ = subscribed.send(());
                    }
                }
                Ok(_) => {}
                Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
            }
        }
    });
    tokio::time::timeout(Duration::from_secs(10), subscribed_rx).await??;
    Ok(rx)
}

async fn one_line(
    broker: &Mosquitto,
    dir: &Path,
    profile_path: &Path,
    profile: &Profile,
    pace: Pace,
    run: usize,
) -> anyhow::Result<OneLine> {
    let line = spawn_line(profile, 1, pace)?;
    let config = config_file(
        dir,
        &format!("one-{run}"),
        broker,
        profile_path,
        &[&line],
        1,
    )?;
    let mut gateway = Gateway::start(&config)?;
    // Client ids of their own per run: the previous run's clients may still be connected.
    let mut results = timed_subscriber(
        broker.port,
        "plant/block-1-1/setpoint/result",
        &format!("bench-results-{run}"),
    )
    .await?;
    let client = command_client(broker.port, &format!("bench-commands-{run}")).await;
    tokio::time::sleep(WARM_UP).await;
    while results.try_recv().is_ok() {}

    let start = Instant::now();
    let cpu_start = gateway.cpu_time()?;
    let simulator_start = cpu_time_of("self")?;
    let mut published = Vec::new();
    let every = WINDOW / COMMANDS;
    for i in 0..COMMANDS {
        let value = 1000 + 100 * run as u16 + i as u16;
        tokio::time::sleep_until((start + every * i + every / 2).into()).await;
        published.push((value, Instant::now()));
        client
            .publish(
                "plant/block-1-1/setpoint/set",
                QoS::AtLeastOnce,
                false,
                value.to_string().into_bytes(),
            )
            .await?;
    }
    tokio::time::sleep_until((start + WINDOW).into()).await;
    let wall = start.elapsed();
    let cpu = gateway.cpu_time()? - cpu_start;
    let simulator_cpu = cpu_time_of("self")? - simulator_start;
    let memory = gateway.memory()?;
    gateway.stop();
    let mut arrivals = Vec::new();
    while let Ok(at) = results.try_recv() {
        arrivals.push(at);
    }

    let records: Vec<RequestRecord> = line
        .journal()
        .requests()
        .into_iter()
        .filter(|r| r.arrived >= start && r.arrived < start + wall)
        .collect();
    Ok(OneLine {
        footprint: Footprint {
            transactions_per_second: records.len() as f64 / wall.as_secs_f64(),
            cpu_percent: 100.0 * cpu.as_secs_f64() / wall.as_secs_f64(),
            memory,
        },
        simulator_cpu_percent: 100.0 * simulator_cpu.as_secs_f64() / wall.as_secs_f64(),
        wire: wire_figures(&records, wall, &published, &arrivals),
    })
}

async fn many_lines(
    broker: &Mosquitto,
    dir: &Path,
    profile_path: &Path,
    profile: &Profile,
) -> anyhow::Result<Footprint> {
    let lines = (0..MANY_LINES)
        .map(|_| spawn_line(profile, DEVICES_PER_LINE, Pace::Bytes))
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
        memory,
    })
}

/// A 9600 8N1 line paced by `pace` with `devices` bench devices at addresses 1, 2, …
fn spawn_line(profile: &Profile, devices: u8, pace: Pace) -> anyhow::Result<VirtualLine> {
    let shared = (1..=devices)
        .map(|address| share(GenericDevice::from_profile(profile, address)).1)
        .collect();
    Ok(VirtualLine::spawn(
        ServeOptions::new(BAUD, Parity::None).pacing(pace),
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

/// What the gateway's memory costs: anonymous memory two ways, and PSS.
struct Memory {
    /// RssAnon from /proc/<pid>/status: heap and stacks resident.
    rss_anon_kib: u64,
    /// Private_Dirty from /proc/<pid>/smaps_rollup: pages only this process has written.
    private_dirty_kib: u64,
    /// Pss from /proc/<pid>/smaps_rollup: resident pages, shared ones divided among users.
    pss_kib: u64,
    threads: u64,
}

/// `name:` in a /proc file of `key: value kB` lines, in KiB (0 when absent).
fn proc_field(text: &str, name: &str) -> u64 {
    text.lines()
        .find(|l| l.starts_with(name))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<u64>().ok())
        .unwrap_or(0)
}

/// User and system CPU time so far of `/proc/<pid>` (`self` for this process).
fn cpu_time_of(pid: &str) -> anyhow::Result<Duration> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))?;
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

/// The gateway binary measured: `EDGE_FOOTPRINT_GATEWAY`, else this build's `rtu2mqtt`.
fn gateway_binary() -> PathBuf {
    std::env::var_os("EDGE_FOOTPRINT_GATEWAY").map_or_else(
        || PathBuf::from(env!("CARGO_BIN_EXE_rtu2mqtt")),
        PathBuf::from,
    )
}

/// The gateway measured, as its own process. Another build of the gateway can be measured in
/// its place (a static build, one with symbols for a profiler): EDGE_FOOTPRINT_GATEWAY.
impl Gateway {
    fn start(config: &Path) -> anyhow::Result<Gateway> {
        Gateway::start_binary(&gateway_binary(), config)
    }

    /// User and system CPU time so far (/proc/<pid>/stat, utime + stime).
    fn cpu_time(&self) -> anyhow::Result<Duration> {
        cpu_time_of(&self.child.id().to_string())
    }

    fn memory(&self) -> anyhow::Result<Memory> {
        let pid = self.child.id();
        let status = std::fs::read_to_string(format!("/proc/{pid}/status"))?;
        let rollup = std::fs::read_to_string(format!("/proc/{pid}/smaps_rollup"))?;
        Ok(Memory {
            rss_anon_kib: proc_field(&status, "RssAnon:"),
            private_dirty_kib: proc_field(&rollup, "Private_Dirty:"),
            pss_kib: proc_field(&rollup, "Pss:"),
            threads: proc_field(&status, "Threads:"),
        })
    }
}

fn wire_figures(
    records: &[RequestRecord],
    wall: Duration,
    published: &[(u16, Instant)],
    results: &[Instant],
) -> Wire {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    let WireLoad { busy, gaps, early } = wire_load(records, &timing);
    let slot = timing.frame_time(WRITE_LEN)
        + timing.t3_5
        + timing.frame_time(WRITE_LEN)
        + timing.t3_5
        + timing.frame_time(READ_REQUEST_LEN)
        + timing.t3_5
        + timing.frame_time(READ_ANSWER_LEN);
    let (mut to_wire, mut to_wire_bound) = (Vec::new(), Vec::new());
    let (mut to_result, mut to_result_bound) = (Vec::new(), Vec::new());
    for (index, (value, at)) in published.iter().enumerate() {
        // The transaction on the wire when the command was published: the line is free for
        // the write t3.5 after its last byte.
        let free_at = records
            .iter()
            .rev()
            .find(|r| r.arrived <= *at)
            .map(|r| {
                let end = r.answer_timing.as_ref().map_or_else(
                    || r.arrived + timing.frame_time(r.frame.len()),
                    |answer| answer.due,
                );
                end + timing.t3_5
            })
            .map_or(*at, |free| free.max(*at));
        let bound = free_at - *at;
        if let Some(write) = records.iter().find(|r| {
            r.frame.get(1) == Some(&0x06) && r.frame.get(4..6) == Some(&value.to_be_bytes()[..])
        }) {
            to_wire.push(write.arrived.saturating_duration_since(*at));
            to_wire_bound.push(bound);
        }
        // Commands are far apart: the first result after a publish, before the next, is its.
        let next = published.get(index + 1).map(|(_, next)| *next);
        if let Some(result) = results
            .iter()
            .find(|&&r| r >= *at && next.map_or(true, |next| r < next))
        {
            to_result.push(result.saturating_duration_since(*at));
            to_result_bound.push(bound + slot);
        }
    }
    for list in [
        &mut to_wire,
        &mut to_wire_bound,
        &mut to_result,
        &mut to_result_bound,
    ] {
        list.sort();
    }
    Wire {
        efficiency: busy.as_secs_f64() / wall.as_secs_f64(),
        gap_p50: percentile(&gaps, 50),
        gap_p95: percentile(&gaps, 95),
        early,
        to_wire,
        to_wire_bound,
        to_result,
        to_result_bound,
    }
}

/// One read of the block on the wire: request (8 bytes), answer (17) and both t3.5 silences.
fn transaction_wire_time() -> Duration {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    timing.frame_time(READ_REQUEST_LEN) + timing.frame_time(READ_ANSWER_LEN) + 2 * timing.t3_5
}

fn ms(duration: Duration) -> String {
    format!("{:.2} ms", duration.as_secs_f64() * 1000.0)
}

fn mib(kib: u64) -> String {
    format!("{:.2} MiB", kib as f64 / 1024.0)
}

fn row(figure: &str, value: String, target: &str) {
    println!("{figure:<44} {value:>26}   {target}");
}

/// `p50 / p95` of a sorted list, `-` when empty.
fn p50_p95(sorted: &[Duration]) -> String {
    if sorted.is_empty() {
        return "-".into();
    }
    format!(
        "{} / {}",
        ms(percentile(sorted, 50)),
        ms(percentile(sorted, 95))
    )
}

/// The gateway process's CPU and memory against their targets.
fn footprint_rows(footprint: &Footprint, cpu_target: &str, anon_target: &str) {
    row(
        "gateway CPU (one core)",
        format!("{:.2} %", footprint.cpu_percent),
        cpu_target,
    );
    let memory = &footprint.memory;
    row(
        "anonymous memory: RssAnon / Private_Dirty",
        format!(
            "{} / {}",
            mib(memory.rss_anon_kib),
            mib(memory.private_dirty_kib)
        ),
        anon_target,
    );
    row(
        "PSS; threads",
        format!("{}; {}", mib(memory.pss_kib), memory.threads),
        "",
    );
}

fn report(runs: &[(&str, OneLine)], many: &Footprint) {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    let t3_5 = timing.t3_5;
    let binary = gateway_binary();
    println!();
    println!("gateway: {}", binary.display());
    if let Ok(metadata) = std::fs::metadata(&binary) {
        println!("binary size: {}", mib(metadata.len() / 1024));
    }
    for (label, run) in runs {
        let wire = &run.wire;
        println!();
        println!(
            "one line, 9600 8N1, answers released {label}; one 6-register block polled \
             continuously, {COMMANDS} commands in {} s",
            WINDOW.as_secs()
        );
        row("figure", "measured".into(), "target / bound");
        let wire_limit = 1.0 / transaction_wire_time().as_secs_f64();
        row(
            "transactions/s",
            format!("{:.1}", run.footprint.transactions_per_second),
            &format!("wire limit {wire_limit:.1}"),
        );
        row(
            "bus efficiency",
            format!("{:.3}", wire.efficiency),
            "≥ 0.985",
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
            "early requests (sooner than t3.5)",
            wire.early.to_string(),
            "0",
        );
        row(
            "command → write frame on the wire p50 / p95",
            p50_p95(&wire.to_wire),
            &format!(
                "bound {} ({} of {COMMANDS} seen)",
                p50_p95(&wire.to_wire_bound),
                wire.to_wire.len()
            ),
        );
        row(
            "command → …/result on MQTT p50 / p95",
            p50_p95(&wire.to_result),
            &format!(
                "bound {} ({} of {COMMANDS} seen)",
                p50_p95(&wire.to_result_bound),
                wire.to_result.len()
            ),
        );
        footprint_rows(&run.footprint, "", "≤ 1 MiB");
        let ratio = if run.simulator_cpu_percent > 0.0 {
            format!(
                "{:.2}",
                run.footprint.cpu_percent / run.simulator_cpu_percent
            )
        } else {
            "-".into()
        };
        row(
            "simulator CPU (this process); gateway/simulator",
            format!("{:.2} %; {ratio}", run.simulator_cpu_percent),
            "",
        );
    }
    println!();
    println!(
        "{MANY_LINES} lines × {DEVICES_PER_LINE} devices, byte-paced, every device polled \
         continuously, {} s",
        MANY_WINDOW.as_secs()
    );
    row(
        "transactions/s (all lines)",
        format!("{:.1}", many.transactions_per_second),
        "",
    );
    footprint_rows(many, "", "≤ 4 MiB");
    println!(
        "\nt3.5 at {BAUD} baud: {}; CPU from /proc/<pid>/stat (utime + stime); memory from \
         /proc/<pid>/status (RssAnon) and /proc/<pid>/smaps_rollup (Private_Dirty, Pss)",
        ms(t3_5)
    );
}
