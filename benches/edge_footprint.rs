//! What the gateway costs an edge box, measured from outside: the built binary runs as its own
//! process (`rtu2mqtt run`) against a real mosquitto and simulated devices on pseudo-terminals
//! (9600 8N1, in this process) that release their answers as real lines do, and is judged by
//! what the devices saw on their end of the wire, by when results reached an MQTT subscriber,
//! and by what /proc says about its CPU time and memory.
//!
//! 1. One line, one device, one 6-register block polled continuously (`poll_interval = "0s"`),
//!    40 commands during a 30 s window, five times: answers released byte by byte at the
//!    character rate (a UART without a deep FIFO), the same with a 5 ms and with a 16 ms pause
//!    inside every answer, then in USB-adapter chunks (what is on the wire every 4 ms, then
//!    every 16 ms). For each: transactions/s, bus efficiency, the idle gap before each request
//!    against t3.5, early requests (sooner than t3.5; must be 0), requests onto an answer
//!    (must be 0), CPU of the gateway and of the simulator (this process) and their ratio,
//!    anonymous memory and PSS, and for each command the time from its publish to the write
//!    frame at the device and to its `…/result` at a subscriber, each beside its physical bound (below), and where a result's time beyond
//!    its bound goes (the silence before the read-back; the read-back's answer to the result).
//! 2. 8 lines × 32 such devices, byte-paced, every device polled continuously: the same
//!    footprint figures.
//!
//! bus efficiency = (wire time of every request and answer, pauses inside answers included,
//!                   + the two mandatory t3.5 silences of each transaction) / wall time
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
//! Every run is repeated (three rounds, or `EDGE_FOOTPRINT_ROUNDS`) and each figure printed as
//! its median over the rounds with the range beside it, so that one disturbed run shows as
//! such. Prints figures beside their targets; asserts nothing. Run: `cargo bench --bench
//! edge_footprint` (about eleven minutes after the build for three rounds); another build of the
//! gateway is measured with `EDGE_FOOTPRINT_GATEWAY=/path/to/rtu2mqtt`.

mod block_device;
mod gateway_process;
use rtu2mqtt_testkit as support;
mod wire_bench;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use block_device::{
    command_window, millis, ms_f, over_rounds, profile_text, spawn_line, transaction_wire_time,
    wire_figures, ResultAfter, Wire, Writes, BAUD,
};
use gateway_process::{GatewayProcess, Memory};
use rtu2mqtt_modbus::timing::LineTiming;
use rtu2mqtt_profile::Profile;
use rtu2mqtt_sim::{Pace, VirtualLine};
use rumqttc::QoS;
use support::Mosquitto;
use wire_bench::{command_client, percentile, timed_subscriber, EIGHT_N_ONE};

const WARM_UP: Duration = Duration::from_secs(5);
const WINDOW: Duration = Duration::from_secs(30);
const COMMANDS: u32 = 40;
const MANY_LINES: usize = 8;
const DEVICES_PER_LINE: u8 = 32;
const MANY_WINDOW: Duration = Duration::from_secs(15);
/// The one-line runs: how the simulator releases answers, a pause inside every answer (a
/// device that stalls mid-frame), and what that stands for.
const RUNS: [(Pace, Option<Duration>, &str); 5] = [
    (Pace::Bytes, None, "byte by byte at the character rate"),
    (
        Pace::Bytes,
        Some(Duration::from_millis(5)),
        "byte by byte, with a 5 ms pause inside every answer",
    ),
    (
        Pace::Bytes,
        Some(Duration::from_millis(16)),
        "byte by byte, with a 16 ms pause inside every answer",
    ),
    (
        Pace::Usb {
            every: Duration::from_millis(4),
        },
        None,
        "in USB-adapter chunks, one every 4 ms",
    ),
    (
        Pace::Usb {
            every: Duration::from_millis(16),
        },
        None,
        "in USB-adapter chunks, one every 16 ms",
    ),
];
/// Rounds of every run; figures are printed as the median and the range over the rounds.
/// `EDGE_FOOTPRINT_ROUNDS` sets another number.
const DEFAULT_ROUNDS: usize = 3;
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
    let rounds = std::env::var("EDGE_FOOTPRINT_ROUNDS")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .filter(|n| *n > 0)
        .unwrap_or(DEFAULT_ROUNDS);
    let mut runs: Vec<Vec<OneLine>> = RUNS.iter().map(|_| Vec::new()).collect();
    let mut many = Vec::new();
    for round in 0..rounds {
        eprintln!("round {} of {rounds}", round + 1);
        for (index, (pace, pause, _)) in RUNS.into_iter().enumerate() {
            let run = runtime.block_on(one_line(
                &broker,
                dir.path(),
                &profile_path,
                &profile,
                pace,
                pause,
                round * RUNS.len() + index,
            ))?;
            runs[index].push(run);
        }
        many.push(runtime.block_on(many_lines(
            &broker,
            dir.path(),
            &profile_path,
            &profile,
            round,
        ))?);
    }
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

async fn one_line(
    broker: &Mosquitto,
    dir: &Path,
    profile_path: &Path,
    profile: &Profile,
    pace: Pace,
    pause: Option<Duration>,
    run: usize,
) -> anyhow::Result<OneLine> {
    let line = spawn_line(profile, 1, pace)?;
    line.faults().update(|f| f.pause_mid_answer = pause);
    let config = config_file(
        dir,
        &format!("one-{run}"),
        broker,
        profile_path,
        &[&line],
        1,
    )?;
    let mut gateway = start_gateway(&config)?;
    // Client ids of their own per run: the previous run's clients may still be connected.
    let (_subscriber, mut results) = timed_subscriber(
        broker.port,
        "plant/block-1-1/setpoint/result",
        &format!("bench-results-{run}"),
        QoS::AtMostOnce,
    )
    .await?;
    let client = command_client(broker.port, &format!("bench-commands-{run}")).await;
    tokio::time::sleep(WARM_UP).await;
    let window = command_window(
        &gateway,
        &line,
        &client,
        Writes {
            topic: "plant/block-1-1/setpoint/set",
            first_value: 1000 + 100 * (run % 500) as u16,
            count: COMMANDS,
        },
        &mut results,
        WINDOW,
    )
    .await?;
    gateway.stop();
    Ok(OneLine {
        footprint: Footprint {
            transactions_per_second: window.transactions_per_second(),
            cpu_percent: window.gateway_cpu_percent(),
            memory: window.memory,
        },
        simulator_cpu_percent: window.simulator_cpu_percent(),
        wire: wire_figures(
            &window.records,
            window.wall,
            pause,
            &window.published,
            &window.results,
            ResultAfter::ReadBack,
        ),
    })
}

async fn many_lines(
    broker: &Mosquitto,
    dir: &Path,
    profile_path: &Path,
    profile: &Profile,
    round: usize,
) -> anyhow::Result<Footprint> {
    let lines = (0..MANY_LINES)
        .map(|_| spawn_line(profile, DEVICES_PER_LINE, Pace::Bytes))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let refs: Vec<&VirtualLine> = lines.iter().collect();
    let config = config_file(
        dir,
        &format!("many-{round}"),
        broker,
        profile_path,
        &refs,
        DEVICES_PER_LINE,
    )?;
    let mut gateway = start_gateway(&config)?;
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

/// The gateway binary measured: `EDGE_FOOTPRINT_GATEWAY`, else this build's `rtu2mqtt`.
fn gateway_binary() -> PathBuf {
    std::env::var_os("EDGE_FOOTPRINT_GATEWAY").map_or_else(
        || PathBuf::from(env!("CARGO_BIN_EXE_rtu2mqtt")),
        PathBuf::from,
    )
}

/// The gateway measured, as its own process. Another build can be measured in its place (a
/// static build, one with symbols for a profiler): EDGE_FOOTPRINT_GATEWAY=/path/to/rtu2mqtt.
fn start_gateway(config: &Path) -> anyhow::Result<GatewayProcess> {
    GatewayProcess::start(&gateway_binary(), config, "warn")
}

fn ms(duration: Duration) -> String {
    format!("{:.2} ms", duration.as_secs_f64() * 1000.0)
}

fn mib(kib: u64) -> String {
    format!("{:.2} MiB", kib as f64 / 1024.0)
}

fn row(figure: &str, value: String, target: &str) {
    println!("{figure:<48} {value:>30}   {target}");
}

/// The p-th percentile of one latency list of each run, in ms, over the rounds.
fn latency(runs: &[OneLine], list: impl Fn(&Wire) -> &Vec<Duration>, p: usize) -> String {
    over_rounds(
        runs.iter()
            .filter(|run| !list(&run.wire).is_empty())
            .map(|run| millis(percentile(list(&run.wire), p))),
        ms_f,
    )
}

/// `p50 / p95` of one latency list, each over the rounds.
fn latency_pair(runs: &[OneLine], list: impl Fn(&Wire) -> &Vec<Duration> + Copy) -> String {
    format!("{} / {}", latency(runs, list, 50), latency(runs, list, 95))
}

/// The gateway process's CPU and memory against their targets, over the rounds.
fn footprint_rows<'a>(
    footprints: impl Iterator<Item = &'a Footprint> + Clone,
    cpu_target: &str,
    anon_target: &str,
) {
    row(
        "gateway CPU (one core)",
        over_rounds(footprints.clone().map(|f| f.cpu_percent), |v| {
            format!("{v:.2} %")
        }),
        cpu_target,
    );
    let in_mib = |kib: u64| kib as f64 / 1024.0;
    let show_mib = |v: f64| format!("{v:.2} MiB");
    row(
        "anonymous memory: RssAnon",
        over_rounds(
            footprints.clone().map(|f| in_mib(f.memory.rss_anon_kib)),
            show_mib,
        ),
        anon_target,
    );
    row(
        "anonymous memory: Private_Dirty",
        over_rounds(
            footprints
                .clone()
                .map(|f| in_mib(f.memory.private_dirty_kib)),
            show_mib,
        ),
        "",
    );
    row(
        "PSS",
        over_rounds(
            footprints.clone().map(|f| in_mib(f.memory.pss_kib)),
            show_mib,
        ),
        "",
    );
    row(
        "threads",
        over_rounds(footprints.map(|f| f.memory.threads as f64), |v| {
            format!("{v:.0}")
        }),
        "",
    );
}

fn report(runs: &[Vec<OneLine>], many: &[Footprint]) {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    let t3_5 = timing.t3_5;
    let binary = gateway_binary();
    println!();
    println!("gateway: {}", binary.display());
    if let Ok(metadata) = std::fs::metadata(&binary) {
        println!("binary size: {}", mib(metadata.len() / 1024));
    }
    println!(
        "rounds: {}; each figure is the median over the rounds, (lowest–highest) beside it",
        many.len()
    );
    for ((_, _, label), runs) in RUNS.iter().zip(runs) {
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
            over_rounds(
                runs.iter().map(|r| r.footprint.transactions_per_second),
                |v| format!("{v:.1}"),
            ),
            &format!("wire limit {wire_limit:.1}"),
        );
        row(
            "bus efficiency",
            over_rounds(runs.iter().map(|r| r.wire.efficiency), |v| {
                format!("{v:.3}")
            }),
            "≥ 0.985",
        );
        row(
            "idle gap before a request p50",
            over_rounds(runs.iter().map(|r| millis(r.wire.gap_p50)), ms_f),
            &format!(
                "≤ t3.5 + 0.25 ms = {}",
                ms(t3_5 + Duration::from_micros(250))
            ),
        );
        row(
            "idle gap before a request p95",
            over_rounds(runs.iter().map(|r| millis(r.wire.gap_p95)), ms_f),
            "",
        );
        row(
            "early requests (sooner than t3.5), all rounds",
            runs.iter().map(|r| r.wire.early).sum::<usize>().to_string(),
            "0",
        );
        row(
            "requests onto an answer, all rounds",
            runs.iter()
                .map(|r| r.wire.onto_answer)
                .sum::<usize>()
                .to_string(),
            "0",
        );
        let seen = |list: fn(&Wire) -> &Vec<Duration>| {
            runs.iter().map(|r| list(&r.wire).len()).sum::<usize>()
        };
        let asked = COMMANDS as usize * runs.len();
        row(
            "command → write frame on the wire p50 / p95",
            latency_pair(runs, |w| &w.to_wire),
            &format!("({} of {asked} seen)", seen(|w| &w.to_wire)),
        );
        row(
            "  its physical bound p50 / p95",
            latency_pair(runs, |w| &w.to_wire_bound),
            "",
        );
        row(
            "command → …/result on MQTT p50 / p95",
            latency_pair(runs, |w| &w.to_result),
            &format!("({} of {asked} seen)", seen(|w| &w.to_result)),
        );
        row(
            "  its physical bound p50 / p95",
            latency_pair(runs, |w| &w.to_result_bound),
            "",
        );
        row(
            "  result later than its bound p50 / p95",
            latency_pair(runs, |w| &w.result_over_bound),
            "≤ 4 ms / ≤ 5 ms",
        );
        row(
            "  later than the bound as answers were delivered",
            latency_pair(runs, |w| &w.result_over_delivered),
            "(the gateway's own share)",
        );
        row(
            "  write echo end → read-back at device p50",
            latency(runs, |w| &w.echo_to_read_back, 50),
            &format!("t3.5 = {}", ms(t3_5)),
        );
        row(
            "  read-back answer end → result p50",
            latency(runs, |w| &w.read_back_to_result, 50),
            "0",
        );
        footprint_rows(runs.iter().map(|r| &r.footprint), "", "≤ 1 MiB");
        row(
            "simulator CPU (this process)",
            over_rounds(runs.iter().map(|r| r.simulator_cpu_percent), |v| {
                format!("{v:.2} %")
            }),
            "",
        );
        row(
            "gateway CPU / simulator CPU",
            over_rounds(
                runs.iter()
                    .filter(|r| r.simulator_cpu_percent > 0.0)
                    .map(|r| r.footprint.cpu_percent / r.simulator_cpu_percent),
                |v| format!("{v:.2}"),
            ),
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
        over_rounds(many.iter().map(|f| f.transactions_per_second), |v| {
            format!("{v:.1}")
        }),
        "",
    );
    footprint_rows(many.iter(), "", "≤ 4 MiB");
    println!(
        "\nt3.5 at {BAUD} baud: {}; CPU from /proc/<pid>/stat (utime + stime); memory from \
         /proc/<pid>/status (RssAnon) and /proc/<pid>/smaps_rollup (Private_Dirty, Pss)",
        ms(t3_5)
    );
}
