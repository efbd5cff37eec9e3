//! Bus efficiency of one line polling a paced simulated device back to back (the air shower's
//! 22-coil read with its minimum interval and start-up delay lifted), with commands injected
//! while it polls. Prints figures; asserts nothing.
//!
//! efficiency = (wire time of every request and answer + the two mandatory t3.5 silences of
//!              each transaction) / wall time
//!
//! measured from the simulator's journal (what really arrived on its end of the pty and what it
//! sent back, paced at the character rate). Also printed: reads/s, command latency (mean, p99),
//! the line's own bus-load figure, process RSS and CPU time, and where the time beyond the wire
//! goes per transaction: the simulator's pacing, the gateway with both pty wake-ups, and (from
//! a separate pass with the master's frame recorder on) the master's own share of it.
//!
//! Run: `cargo bench --bench bus_efficiency` (about 35 s).

use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::mpsc;

use rtu2mqtt::bus::{spawn_line, Command, CommandOutcome, DeviceSpec, LineEvent, LineSpec};
use rtu2mqtt_modbus::frame_log::FrameLog;
use rtu2mqtt_modbus::serial::transport::SerialSettings;
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_profile::{DeviceState, Profile};
use rtu2mqtt_sim::{share, AirShower, ServeOptions, VirtualLine};
use tokio_util::sync::CancellationToken;

const AIR_SHOWER_TOML: &str = include_str!("../config/profiles/lixian-air-shower.toml");
const WARM_UP: Duration = Duration::from_secs(2);
const MEASURE: Duration = Duration::from_secs(8);
const COMMAND_EVERY: Duration = Duration::from_millis(250);

struct Figures {
    baud: u32,
    efficiency: f64,
    line_bus_load: f64,
    reads_per_second: f64,
    transactions: usize,
    commands: usize,
    mean_latency: Duration,
    p99_latency: Duration,
    min_silence: Option<Duration>,
    cpu: Duration,
    wall: Duration,
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    // The simulator stands for a device at the other end of the wire: it runs on a runtime of
    // its own, so that its pacing (which spins briefly before each answer) does not take a
    // worker from the gateway's runtime, which in production has the host to itself.
    let simulator = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_name("simulator")
        .enable_all()
        .build()?;
    let profile = Arc::new(fast_air_shower()?);
    let mut all = Vec::new();
    for baud in [9600, 38400] {
        all.push(runtime.block_on(measure(baud, profile.clone(), simulator.handle(), None))?);
    }
    println!();
    println!(
        "{:>6} {:>10} {:>9} {:>8} {:>6} {:>5} {:>9} {:>9} {:>10} {:>7}",
        "baud",
        "efficiency",
        "bus_load",
        "reads/s",
        "txns",
        "cmds",
        "cmd_mean",
        "cmd_p99",
        "min_t3.5",
        "cpu%"
    );
    for f in &all {
        println!(
            "{:>6} {:>10.3} {:>9.3} {:>8.1} {:>6} {:>5} {:>9.1?} {:>9.1?} {:>10} {:>7.1}",
            f.baud,
            f.efficiency,
            f.line_bus_load,
            f.reads_per_second,
            f.transactions,
            f.commands,
            f.mean_latency,
            f.p99_latency,
            f.min_silence
                .map_or("-".to_string(), |s| format!("{:.2?}", s)),
            100.0 * f.cpu.as_secs_f64() / f.wall.as_secs_f64(),
        );
    }
    println!("process RSS: {} kB", rss_kb().unwrap_or(0));
    println!("(efficiency target ≥ 0.95; cpu% is the whole process, simulator included)");
    // A separate pass with the master's frame recorder on (it costs a file write per frame,
    // so the figures above are taken without it): the master's own share of the overhead.
    println!();
    println!("38400 baud again, with the master's frame recorder on (not in the table):");
    let recording = tempfile::NamedTempFile::new()?;
    runtime.block_on(measure(
        38400,
        profile.clone(),
        simulator.handle(),
        Some(recording.path()),
    ))?;
    print_master_share(recording.path(), LineTiming::new(38400, EIGHT_N_ONE))?;
    Ok(())
}

fn fast_air_shower() -> anyhow::Result<Profile> {
    let text = AIR_SHOWER_TOML
        .replace(
            "min_poll_interval = \"500ms\"",
            "min_poll_interval = \"1ms\"",
        )
        .replace("startup_delay = \"1s\"", "startup_delay = \"0s\"");
    Profile::from_toml(&text, "air shower, back to back")
        .map_err(|e| anyhow::anyhow!("profile: {e:?}"))
}

const EIGHT_N_ONE: CharFormat = CharFormat {
    data_bits: 8,
    parity: Parity::None,
    stop_bits: 1,
};

/// From the frame recording: the time from the master seeing an answer (its `rx` record) to
/// its next request (the `tx` record, written just before the write), less t3.5: the master's
/// wait overshoot and the line task's own turn-around. The rest of the "gateway and wake-ups"
/// figure is the two pty read wake-ups (the master's for the answer, the simulator's for the
/// request) and the master's write call.
fn print_master_share(recording: &std::path::Path, timing: LineTiming) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(recording)?;
    let mut previous_rx: Option<f64> = None;
    let mut beyond = Vec::new();
    for line in text.lines() {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let (Some(at), Some(direction)) = (fields.get(1), fields.get(2)) else {
            continue;
        };
        let Ok(at) = at.parse::<f64>() else {
            continue;
        };
        match *direction {
            "rx" => previous_rx = Some(at),
            "tx" => {
                if let Some(rx) = previous_rx.take() {
                    beyond.push((at - rx) * 1e6 - timing.t3_5.as_secs_f64() * 1e6);
                }
            }
            _ => {}
        }
    }
    if beyond.is_empty() {
        return Ok(());
    }
    beyond.sort_by(f64::total_cmp);
    let mean = beyond.iter().sum::<f64>() / beyond.len() as f64;
    println!(
        "38400 baud, frame recorder on: answer seen → next request, beyond t3.5: mean {mean:.1}µs, median {:.1}µs, p99 {:.1}µs over {} transactions (µs timestamps; the master's own share of the gateway figure)",
        beyond[beyond.len() / 2],
        beyond[(beyond.len() * 99).div_ceil(100).saturating_sub(1)],
        beyond.len()
    );
    Ok(())
}

async fn measure(
    baud: u32,
    profile: Arc<Profile>,
    simulator: &tokio::runtime::Handle,
    frame_log: Option<&std::path::Path>,
) -> anyhow::Result<Figures> {
    let format = EIGHT_N_ONE;
    let timing = LineTiming::new(baud, format);
    let (_shower, shared) = share(AirShower::new());
    let line = {
        let _on_simulator = simulator.enter();
        VirtualLine::spawn(
            ServeOptions::new(baud, Parity::None).paced(true),
            vec![shared],
        )?
    };
    let spec = LineSpec {
        name: format!("bench-{baud}"),
        serial: SerialSettings {
            path: line.path().to_string_lossy().into_owned(),
            baud,
            format,
            rs485: None,
        },
        transport: rtu2mqtt::bus::Transport::Serial,
        response_timeout: None,
        retries: 1,
        offline_after: 3,
        echo: false,
        broadcast_turnaround: Duration::from_millis(100),
        byte_timeout: None,
        recorders: rtu2mqtt::bus::FrameRecorders {
            log: frame_log.map(FrameLog::create).transpose()?,
            live: None,
        },
        console: false,
        serve: None,
        devices: vec![DeviceSpec {
            name: "air_shower".into(),
            address: 0x81,
            profile: profile.clone(),
            poll_interval: Duration::ZERO,
            publish: Default::default(),
        }],
    };
    let (events_tx, mut events_rx) = mpsc::channel(4096);
    let token = CancellationToken::new();
    let trigger = token.clone();
    let (handle, task) = spawn_line(spec, events_tx, token);
    let mut state = DeviceState::new();
    let drain = |state: &mut DeviceState, events_rx: &mut mpsc::Receiver<LineEvent>| {
        while let Ok(event) = events_rx.try_recv() {
            if let LineEvent::Values { values, .. } = event {
                state.extend(values);
            }
        }
    };

    tokio::time::sleep(WARM_UP).await;
    drain(&mut state, &mut events_rx);
    let journal = line.journal();
    let skip = journal.request_count();
    let stats_before = handle.stats_rx.borrow().clone();
    let cpu_before = cpu_time();
    let started = Instant::now();
    let mut latencies = Vec::new();
    let mut light = false;
    while started.elapsed() < MEASURE {
        tokio::time::sleep(COMMAND_EVERY).await;
        drain(&mut state, &mut events_rx);
        light = !light;
        let text = if light { "ON" } else { "OFF" };
        let plan = profile
            .plan_command("light", text, &state)
            .map_err(|e| anyhow::anyhow!("command: {e}"))?;
        let sent = Instant::now();
        let id = latencies.len() as u64;
        handle
            .command_tx
            .send(Command {
                id,
                device: "air_shower".into(),
                plan,
            })
            .await?;
        // The outcome comes on the events channel, after the values of the command's reads.
        let outcome = loop {
            match events_rx.recv().await {
                Some(LineEvent::CommandFinished {
                    id: done, outcome, ..
                }) if done == id => break outcome,
                Some(LineEvent::Values { values, .. }) => state.extend(values),
                Some(_) => {}
                None => anyhow::bail!("the line stopped"),
            }
        };
        latencies.push(sent.elapsed());
        if !matches!(outcome, CommandOutcome::Applied { .. }) {
            eprintln!("command outcome: {outcome:?}");
        }
    }
    let wall = started.elapsed();
    let cpu = cpu_time().saturating_sub(cpu_before);
    let stats_after = handle.stats_rx.borrow().clone();
    trigger.cancel();
    task.await?;

    // Journal records between the measuring window's ends.
    let end = started + wall;
    let records: Vec<_> = journal
        .requests()
        .into_iter()
        .skip(skip)
        .filter(|r| r.arrived >= started && r.arrived < end)
        .collect();
    let mut wire = Duration::ZERO;
    let mut reads = 0usize;
    for record in &records {
        wire += timing.frame_time(record.frame.len()) + timing.t3_5;
        if let Some(answer) = &record.answer {
            wire += timing.frame_time(answer.len()) + timing.t3_5;
        }
        if record.frame.get(1) == Some(&0x01) {
            reads += 1;
        }
    }
    let min_silence = records.iter().filter_map(|r| r.silence_before).min();
    // Where the time beyond the wire goes, per transaction, from the simulator's instants
    // (every transaction's cycle is: request arrives, the simulator's answer is due, it is
    // handed to the pty, the next request arrives):
    //  - simulator, framing: due − (arrival + request wire time + t3.5 + answer wire time)
    //  - simulator, pacing: handed to the pty − due
    //  - gateway and both wake-ups: silence before the next request (from the hand-over) − t3.5
    //    (the master's read wake-up, its wait's overshoot, its write, the simulator's read
    //    wake-up).
    let silences: Vec<Duration> = records.iter().filter_map(|r| r.silence_before).collect();
    let answered: Vec<_> = records
        .iter()
        .filter_map(|r| Some((r, r.answer.as_ref()?, r.answer_timing?)))
        .collect();
    if !silences.is_empty() && !answered.is_empty() {
        let mean =
            |values: &[Duration]| values.iter().sum::<Duration>() / values.len().max(1) as u32;
        let silence_mean = mean(&silences);
        let short = silences.iter().filter(|s| **s < timing.t3_5).count();
        let framing: Vec<Duration> = answered
            .iter()
            .map(|(r, answer, t)| {
                t.due.saturating_duration_since(
                    r.arrived
                        + timing.frame_time(r.frame.len())
                        + timing.t3_5
                        + timing.frame_time(answer.len()),
                )
            })
            .collect();
        let pacing: Vec<Duration> = answered
            .iter()
            .map(|(_, _, t)| t.handed_over.saturating_duration_since(t.due))
            .collect();
        let write_call: Vec<Duration> = answered
            .iter()
            .map(|(_, _, t)| t.write_returned.saturating_duration_since(t.handed_over))
            .collect();
        // The silence as the simulator used to measure it, from when its write returned.
        let short_from_write_return = records
            .windows(2)
            .filter(|pair| {
                pair[0].answer_timing.is_some_and(|t| {
                    pair[1].arrived.saturating_duration_since(t.write_returned) < timing.t3_5
                })
            })
            .count();
        let overhead = wall.saturating_sub(wire) / records.len().max(1) as u32;
        println!(
            "{baud} baud: t3.5 {:.2?}, char {:.2?}; silence before requests mean {:.2?}, min {:.2?}, {short} of {} shorter than t3.5 ({short_from_write_return} measured from the return of the simulator's write)",
            timing.t3_5,
            timing.char_time,
            silence_mean,
            min_silence.unwrap_or_default(),
            silences.len(),
        );
        println!(
            "{baud} baud: overhead per transaction {:.1?} = gateway and wake-ups {:.1?} + simulator framing {:.1?} + simulator pacing {:.1?} (its write call, not counted: {:.1?})",
            overhead,
            silence_mean.saturating_sub(timing.t3_5),
            mean(&framing),
            mean(&pacing),
            mean(&write_call),
        );
    }
    latencies.sort_unstable();
    let mean_latency = if latencies.is_empty() {
        Duration::ZERO
    } else {
        latencies.iter().sum::<Duration>() / latencies.len() as u32
    };
    let p99_latency = latencies
        .get((latencies.len() * 99).div_ceil(100).saturating_sub(1))
        .copied()
        .unwrap_or_default();
    let line_wire = stats_after.wire_time.saturating_sub(stats_before.wire_time);
    println!(
        "{baud} baud: the line's own turnaround between back-to-back transactions: mean {:.1?}, worst {:.1?}",
        stats_after.turnaround_mean.unwrap_or_default(),
        stats_after.turnaround_worst.unwrap_or_default()
    );
    println!(
        "{baud} baud: {} transactions, wire+silences {:.3?} of {:.3?} wall; the line's own wire-time counter: {:.3?}",
        records.len(),
        wire,
        wall,
        line_wire
    );
    Ok(Figures {
        baud,
        efficiency: wire.as_secs_f64() / wall.as_secs_f64(),
        line_bus_load: line_wire.as_secs_f64() / wall.as_secs_f64(),
        reads_per_second: reads as f64 / wall.as_secs_f64(),
        transactions: records.len(),
        commands: latencies.len(),
        mean_latency,
        p99_latency,
        min_silence,
        cpu,
        wall,
    })
}

fn rss_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

fn cpu_time() -> Duration {
    // SAFETY: getrusage only writes the struct it is given, which is fully owned here.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let ok = unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } == 0;
    if !ok {
        return Duration::ZERO;
    }
    let micros = |t: libc::timeval| {
        Duration::from_secs(t.tv_sec.max(0) as u64) + Duration::from_micros(t.tv_usec.max(0) as u64)
    };
    micros(usage.ru_utime) + micros(usage.ru_stime)
}
