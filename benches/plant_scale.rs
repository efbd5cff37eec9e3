//! A plant on one box, from nothing: a real mosquitto on a free loopback port, simulated
//! devices in this process, and the built gateway binary as its own process (measured by its
//! pid) with a generated configuration, Home Assistant discovery, the JSON view and the history
//! journal on. Two kinds of plant, one row each in the table:
//!
//! - **Modbus TCP**, for each N: a loopback simulator of N meters (`scale_sim`: 100 `f32`
//!   points each, 1 % of them changing a second), N `modbus-tcp://` lines of one device each,
//!   100 points in two blocks of 100 registers polled every second.
//! - **RS485** (`rtu_plant`): L lines × D Eastron SDM120 energy meters (8 × 32 unless told), each
//!   line a pseudo-terminal at 9600 8N1 whose answers are released byte by byte at the
//!   character rate, the meters' readings moving as a loaded meter's do; the gateway polls them
//!   with the built-in `eastron-sdm120` profile, its baud rate set to the lines' (two blocks of
//!   38 and 10 input registers every cycle, one of 4 every minute), at the profile's interval
//!   of 10 s, which is printed beside the wire time of one round of a line's meters.
//!
//! For each row it prints the start-up (gateway started → every device's first value on MQTT),
//! the gateway's CPU (% of one core) and memory (`Anonymous` and `Pss` from smaps_rollup, with
//! RssAnon and Private_Dirty beside them) in steady state, the MQTT messages per second the
//! broker received from it, and the poll lateness measured where the requests arrive, at the
//! simulators (time between a block's successive requests beyond its interval; p50, p99,
//! skipped polls); for the RS485 row also each line's bus load (wire time of the requests,
//! answers and t3.5 silences over the window; mean and highest of the lines), the transactions
//! per second with the gateway's CPU time per transaction, and the requests that came sooner
//! than t3.5 after the line's last byte or onto an answer. The CPU of this process (the
//! simulators and the counting subscriber) is printed beside. At the largest N it then stops
//! mosquitto for an outage, starts it again on the same port and counts the values the gateway
//! measured (served changes at the simulator) against those that reached a subscriber on the
//! history stream, live and replayed, and the lateness during the outage and the replay. The
//! RS485 row runs after the Modbus TCP rows.
//!
//! Run: `cargo bench --bench plant_scale` (about ten minutes after the build). Environment:
//! `PLANT_SCALE_DEVICES=10,100,1000` (the Modbus TCP device counts; `0` runs none),
//! `PLANT_SCALE_RTU=8x32` (RS485 lines × meters per line, at most 247; `0` skips the row),
//! `PLANT_SCALE_WARMUP=20` and `PLANT_SCALE_WINDOW=60` (seconds after start-up before and of
//! the steady-state window), `PLANT_SCALE_OUTAGE=60` (seconds; `0` skips the outage),
//! `PLANT_SCALE_GATEWAY=path` (another gateway binary). Asserts nothing.

mod gateway_process;
mod rtu_plant;
mod scale_sim;
mod wire_bench;

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use gateway_process::{cpu_time_of, GatewayProcess, Memory};
use rtu2mqtt_testkit::{Mosquitto, Recorder};
use rtu_plant::RtuPlant;
use rumqttc::{MqttOptions, QoS};
use scale_sim::{Lateness, ScalePlant, POINTS};

const POLL_INTERVAL: Duration = Duration::from_secs(1);
const CLIENT_ID: &str = "plant-scale";

fn main() -> anyhow::Result<()> {
    let devices: Vec<usize> = std::env::var("PLANT_SCALE_DEVICES")
        .unwrap_or_else(|_| "10,100,1000".into())
        .split(',')
        .filter_map(|n| n.trim().parse().ok())
        .filter(|n| *n > 0)
        .collect();
    let rtu = rtu_shape(&std::env::var("PLANT_SCALE_RTU").unwrap_or_else(|_| "8x32".into()))?;
    let settings = Settings {
        warm_up: seconds("PLANT_SCALE_WARMUP", 20),
        window: seconds("PLANT_SCALE_WINDOW", 60),
        outage: seconds("PLANT_SCALE_OUTAGE", 60),
        gateway: std::env::var("PLANT_SCALE_GATEWAY")
            .map(PathBuf::from)
            .unwrap_or_else(|_| PathBuf::from(env!("CARGO_BIN_EXE_rtu2mqtt"))),
    };
    println!(
        "plant scale: gateway {}; Modbus TCP: {} points per device at {:?}; warm-up {} s, \
         window {} s",
        settings.gateway.display(),
        POINTS,
        POLL_INTERVAL,
        settings.warm_up.as_secs(),
        settings.window.as_secs()
    );
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()?;
    let largest = devices.iter().copied().max().unwrap_or(0);
    let mut rows = Vec::new();
    for &n in &devices {
        let outage = (n == largest && !settings.outage.is_zero()).then_some(settings.outage);
        let row = runtime.block_on(run(n, &settings, outage))?;
        println!("{}", row.line());
        rows.push(row);
    }
    if let Some((lines, per_line)) = rtu {
        let row = runtime.block_on(run_rtu(lines, per_line, &settings))?;
        println!("{}", row.line());
        rows.push(row);
    }
    println!("\n{}", Row::header());
    for row in &rows {
        println!("{}", row.line());
    }
    Ok(())
}

/// `LxD` (lines × meters per line) from `PLANT_SCALE_RTU`; `0` (or `0x…`) for none.
fn rtu_shape(text: &str) -> anyhow::Result<Option<(usize, u8)>> {
    let text = text.trim();
    if text == "0" {
        return Ok(None);
    }
    let shape = text
        .split_once(['x', 'X', '×'])
        .and_then(|(lines, per_line)| {
            Some((
                lines.trim().parse::<usize>().ok()?,
                per_line.trim().parse::<u8>().ok()?,
            ))
        });
    match shape {
        Some((0, _)) | Some((_, 0)) => Ok(None),
        Some((lines, per_line)) if per_line <= 247 => Ok(Some((lines, per_line))),
        _ => anyhow::bail!(
            "PLANT_SCALE_RTU=`{text}`: expected LINESxMETERS (meters per line 1–247), or 0"
        ),
    }
}

struct Settings {
    warm_up: Duration,
    window: Duration,
    outage: Duration,
    gateway: PathBuf,
}

fn seconds(name: &str, default: u64) -> Duration {
    Duration::from_secs(
        std::env::var(name)
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(default),
    )
}

/// One plant's figures.
struct Row {
    /// The device count, and for an RS485 plant its lines × meters per line.
    devices: usize,
    shape: Option<(usize, u8)>,
    start_up: Option<Duration>,
    cpu_percent: f64,
    /// This process's CPU over the window: the simulators and the counting subscriber.
    bench_cpu_percent: f64,
    memory: Memory,
    messages_per_second: f64,
    by_kind: Vec<(String, f64)>,
    lateness: Lateness,
    /// The lines' wires over the window (RS485 only).
    wire: Option<rtu_plant::Wire>,
}

impl Row {
    /// The row of `devices` from their start-up, the steady-state window and the lateness in it.
    fn measured(
        devices: usize,
        start_up: Option<Duration>,
        steady: Steady,
        lateness: Lateness,
    ) -> Row {
        Row {
            devices,
            shape: None,
            start_up,
            cpu_percent: steady.cpu_percent,
            bench_cpu_percent: steady.bench_cpu_percent,
            memory: steady.memory,
            messages_per_second: steady.by_kind.iter().map(|(_, rate)| rate).sum(),
            by_kind: steady.by_kind,
            lateness,
            wire: None,
        }
    }

    fn header() -> String {
        format!(
            "{:>12} {:>9} {:>7} {:>10} {:>10} {:>9} {:>9} {:>13} {:>8} {:>15}",
            "N",
            "start-up",
            "CPU %",
            "anon MiB",
            "PSS MiB",
            "msgs/s",
            "late p50",
            "late p99",
            "skipped",
            "bus load (max)"
        )
    }

    fn line(&self) -> String {
        let mut kinds = String::new();
        for (kind, rate) in &self.by_kind {
            let _ = write!(kinds, " {kind} {rate:.0}/s;");
        }
        let devices = match self.shape {
            Some((lines, per_line)) => format!("{} ({lines}×{per_line})", self.devices),
            None => self.devices.to_string(),
        };
        let (bus_load, timing) = match &self.wire {
            Some(wire) if !wire.loads.is_empty() => {
                let mean = wire.loads.iter().sum::<f64>() / wire.loads.len() as f64;
                let highest = wire.loads.iter().copied().fold(0.0, f64::max);
                (
                    format!("{:.1} % ({:.1} %)", mean * 100.0, highest * 100.0),
                    format!(
                        " {:.1} transactions/s, {:.0} µs of gateway CPU each; {} requests \
                         sooner than t3.5, {} onto an answer;",
                        wire.transactions_per_second,
                        self.cpu_percent * 1e4 / wire.transactions_per_second.max(0.001),
                        wire.early,
                        wire.onto_answer
                    ),
                )
            }
            _ => ("-".to_string(), String::new()),
        };
        format!(
            "{:>12} {:>9} {:>7.2} {:>10.2} {:>10.2} {:>9.0} {:>9} {:>13} {:>8} {:>15}   ({} requests; RssAnon {:.2} MiB, Private_Dirty {:.2} MiB; {} threads; simulators and subscriber {:.2} % CPU;{timing}{kinds})",
            devices,
            self.start_up
                .map_or("never".into(), |d| format!("{:.2} s", d.as_secs_f64())),
            self.cpu_percent,
            self.memory.anonymous_kib as f64 / 1024.0,
            self.memory.pss_kib as f64 / 1024.0,
            self.messages_per_second,
            format!("{:.1} ms", ms(self.lateness.percentile(50.0))),
            format!("{:.1} ms", ms(self.lateness.percentile(99.0))),
            self.lateness.skipped,
            bus_load,
            self.lateness.gaps,
            self.memory.rss_anon_kib as f64 / 1024.0,
            self.memory.private_dirty_kib as f64 / 1024.0,
            self.memory.threads,
            self.bench_cpu_percent,
        )
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

/// What the gateway cost over the steady-state window, and the window itself.
struct Steady {
    from: Instant,
    to: Instant,
    cpu_percent: f64,
    bench_cpu_percent: f64,
    memory: Memory,
    by_kind: Vec<(String, f64)>,
}

/// Waits for every device's first value (the start-up, from `started`), lets the warm-up
/// pass, then measures the gateway over the window.
async fn steady_state(
    gateway: &GatewayProcess,
    counter: &Counter,
    started: Instant,
    settings: &Settings,
) -> anyhow::Result<(Option<Duration>, Steady)> {
    let start_up = counter
        .every_device_seen(Duration::from_secs(120))
        .await
        .map(|seen| seen - started);
    match start_up {
        Some(d) => println!(
            "start-up: every device's first value after {:.2} s",
            d.as_secs_f64()
        ),
        None => println!("start-up: not every device had a value after 120 s"),
    }
    tokio::time::sleep(settings.warm_up).await;

    let cpu_before = gateway.cpu_time()?;
    let bench_cpu_before = cpu_time_of("self")?;
    let counts_before = counter.counts();
    let from = Instant::now();
    let mut memory = Memory::default();
    while from.elapsed() < settings.window {
        tokio::time::sleep(Duration::from_secs(1)).await;
        memory = memory.max(gateway.memory()?);
    }
    let to = Instant::now();
    let seconds = (to - from).as_secs_f64();
    let cpu = (gateway.cpu_time()? - cpu_before).as_secs_f64() / seconds;
    let bench_cpu = (cpu_time_of("self")? - bench_cpu_before).as_secs_f64() / seconds;
    let counts_after = counter.counts();
    let mut by_kind: Vec<(String, f64)> = counts_after
        .iter()
        .map(|(kind, after)| {
            let before = counts_before.get(kind).copied().unwrap_or(0);
            (kind.clone(), (after - before) as f64 / seconds)
        })
        .collect();
    by_kind.sort_by(|a, b| a.0.cmp(&b.0));
    Ok((
        start_up,
        Steady {
            from,
            to,
            cpu_percent: cpu * 100.0,
            bench_cpu_percent: bench_cpu * 100.0,
            memory,
            by_kind,
        },
    ))
}

async fn run(devices: usize, settings: &Settings, outage: Option<Duration>) -> anyhow::Result<Row> {
    println!("\n— {devices} devices —");
    let files = tempfile::tempdir()?;
    let mut broker = Mosquitto::start_durable();
    let counter = Counter::connect(broker.port, devices).await?;
    let plant = ScalePlant::spawn(devices).await?;
    let config = write_config(files.path(), broker.port, &plant)?;
    let started = Instant::now();
    let mut gateway = GatewayProcess::start(&settings.gateway, &config, "warn")?;

    let (start_up, steady) = steady_state(&gateway, &counter, started, settings).await?;
    let lateness = {
        let requests = plant.log.requests.lock().map_err(poisoned)?;
        Lateness::of(&requests, steady.from, steady.to, POLL_INTERVAL)
    };
    let row = Row::measured(devices, start_up, steady, lateness);
    if let Some(outage) = outage {
        println!("{}", row.line());
        broker_outage(&mut broker, &mut gateway, &plant, &counter, outage).await?;
    }
    gateway.stop();
    plant.stop();
    Ok(row)
}

/// The RS485 row: `lines` byte-paced lines of `per_line` moving SDM120 meters each.
async fn run_rtu(lines: usize, per_line: u8, settings: &Settings) -> anyhow::Result<Row> {
    let devices = lines * usize::from(per_line);
    let profile = rtu_plant::profile()?;
    let interval = profile.limits().default_poll_interval;
    let round = rtu_plant::round_wire_time(&profile, per_line);
    println!(
        "\n— {devices} devices: {lines} RS485 lines × {per_line} Eastron SDM120 meters, {} baud \
         8N1, answers byte by byte —",
        rtu_plant::BAUD
    );
    println!(
        "one round of a line's {per_line} meters takes {:.2} s on the wire; poll interval {} s \
         (expected bus load {:.1} %, the slow block's {:.1} % included)",
        round.as_secs_f64(),
        interval.as_secs(),
        100.0
            * (round.as_secs_f64() / interval.as_secs_f64().max(0.001)
                + rtu_plant::slow_share(&profile, per_line)),
        100.0 * rtu_plant::slow_share(&profile, per_line)
    );
    let files = tempfile::tempdir()?;
    let broker = Mosquitto::start_durable();
    let counter = Counter::connect(broker.port, devices).await?;
    let plant = RtuPlant::spawn(lines, per_line)?;
    let config = write_rtu_config(files.path(), broker.port, &plant, interval)?;
    let started = Instant::now();
    let mut gateway = GatewayProcess::start(&settings.gateway, &config, "warn")?;

    let (start_up, steady) = steady_state(&gateway, &counter, started, settings).await?;
    let requests = plant.requests(&rtu_plant::fast_blocks(&profile), steady.to);
    let lateness = Lateness::of(&requests, steady.from, steady.to, interval);
    let row = Row {
        shape: Some((lines, per_line)),
        wire: Some(plant.wire(steady.from, steady.to)),
        ..Row::measured(devices, start_up, steady, lateness)
    };
    gateway.stop();
    drop(plant);
    drop(broker);
    Ok(row)
}

/// Stops the broker for `outage`, starts it again on the same port, and counts what the
/// gateway measured against what reached the history stream.
async fn broker_outage(
    broker: &mut Mosquitto,
    gateway: &mut GatewayProcess,
    plant: &ScalePlant,
    counter: &Counter,
    outage: Duration,
) -> anyhow::Result<()> {
    println!("outage: mosquitto stopped for {} s", outage.as_secs());
    let cpu_before = gateway.cpu_time()?;
    let down = Instant::now();
    let down_wall = SystemTime::now();
    broker.stop();
    let mut memory = Memory::default();
    while down.elapsed() < outage {
        tokio::time::sleep(Duration::from_secs(1)).await;
        memory = memory.max(gateway.memory()?);
    }
    let up = Instant::now();
    let up_wall = SystemTime::now();
    let outage_cpu = (gateway.cpu_time()? - cpu_before).as_secs_f64() / (up - down).as_secs_f64();
    broker.restart();
    let measured_in_outage = plant
        .log
        .changes_served
        .lock()
        .map_err(poisoned)?
        .iter()
        .filter(|at| **at >= down && **at < up)
        .count();
    println!(
        "outage: {measured_in_outage} values measured while the broker was away; gateway CPU \
         {:.2} %, anonymous memory at most {:.2} MiB, Pss {:.2} MiB",
        outage_cpu * 100.0,
        memory.anonymous_kib as f64 / 1024.0,
        memory.pss_kib as f64 / 1024.0
    );
    // The replay: from the first history value read in the outage until they stop coming
    // (the gateway reconnects after its back-off, up to two minutes).
    let cpu_before = gateway.cpu_time()?;
    let mut replayed = 0;
    let mut quiet_since = Instant::now();
    let mut replay_memory = Memory::default();
    let deadline = Instant::now() + Duration::from_secs(900);
    let patience = |replayed| Duration::from_secs(if replayed == 0 { 120 } else { 15 });
    while Instant::now() < deadline && quiet_since.elapsed() < patience(replayed) {
        tokio::time::sleep(Duration::from_millis(500)).await;
        replay_memory = replay_memory.max(gateway.memory()?);
        let now = counter.history_values_between(down_wall, up_wall);
        if now != replayed {
            replayed = now;
            quiet_since = Instant::now();
        }
    }
    let replay_end = quiet_since;
    let replay_seconds = (replay_end - up).as_secs_f64();
    let replay_cpu = (gateway.cpu_time()? - cpu_before).as_secs_f64() / up.elapsed().as_secs_f64();
    println!(
        "replay: {replayed} history values read in the outage reached the subscriber, the last \
         {replay_seconds:.1} s after the broker came back ({:.0} values/s); gateway CPU {:.2} % \
         meanwhile, anonymous memory at most {:.2} MiB, Pss {:.2} MiB",
        replayed as f64 / replay_seconds.max(0.001),
        replay_cpu * 100.0,
        replay_memory.anonymous_kib as f64 / 1024.0,
        replay_memory.pss_kib as f64 / 1024.0
    );
    let lateness = {
        let requests = plant.log.requests.lock().map_err(poisoned)?;
        Lateness::of(&requests, down, replay_end, POLL_INTERVAL)
    };
    println!(
        "lateness from the broker's stop to the replay's end: p50 {:.1} ms, p99 {:.1} ms, \
         worst {:.1} ms, {} skipped of {} polls",
        ms(lateness.percentile(50.0)),
        ms(lateness.percentile(99.0)),
        ms(lateness.percentile(100.0)),
        lateness.skipped,
        lateness.gaps
    );
    // Every value of the run: values stop changing, what is in flight settles.
    plant.freeze();
    tokio::time::sleep(Duration::from_secs(10)).await;
    let measured = plant.log.changes_served.lock().map_err(poisoned)?.len();
    let (received, distinct) = counter.history_values();
    println!(
        "whole run: {measured} values measured (first reads included), {received} on the \
         history stream ({distinct} distinct device/field/instant): {} lost, {} twice",
        measured.saturating_sub(distinct),
        received.saturating_sub(distinct)
    );
    Ok(())
}

fn poisoned<T>(_: std::sync::PoisonError<T>) -> anyhow::Error {
    anyhow::anyhow!("a simulator task panicked")
}

/// The profile of the simulated meter and the gateway's configuration; returns its path.
fn write_config(dir: &Path, broker_port: u16, plant: &ScalePlant) -> anyhow::Result<PathBuf> {
    let profile = scale_sim::profile_text(true);
    std::fs::write(dir.join("scale-meter.toml"), profile)?;
    let mut config = gateway_sections(dir, broker_port);
    for (index, addr) in plant.addrs.iter().enumerate() {
        let _ = write!(
            config,
            "[[lines]]\nname = \"line{index:04}\"\nurl = \"modbus-tcp://{addr}\"\n\n\
             [[lines.devices]]\nname = \"{}\"\nprofile = \"scale-meter.toml\"\naddress = 1\n\
             poll_interval = \"1s\"\n\n",
            device_name(index)
        );
    }
    let path = dir.join("rtu2mqtt.toml");
    std::fs::write(&path, config)?;
    Ok(path)
}

/// The gateway's configuration for the RS485 plant (the same MQTT, view, discovery and history
/// settings as the Modbus TCP rows); returns its path.
fn write_rtu_config(
    dir: &Path,
    broker_port: u16,
    plant: &RtuPlant,
    interval: Duration,
) -> anyhow::Result<PathBuf> {
    std::fs::write(dir.join("sdm120.toml"), rtu_plant::profile_text())?;
    let mut config = gateway_sections(dir, broker_port);
    for (line, served) in plant.lines.iter().enumerate() {
        let _ = write!(
            config,
            "[[lines]]\nname = \"rs485-{line}\"\nport = \"{}\"\nbaud = {}\nparity = \"none\"\n\n",
            served.path().display(),
            rtu_plant::BAUD
        );
        for address in 1..=plant.per_line {
            let _ = write!(
                config,
                "[[lines.devices]]\nname = \"{}\"\nprofile = \"sdm120.toml\"\n\
                 address = {address}\npoll_interval = \"{}ms\"\n\n",
                device_name(plant.device_index(line, address)),
                interval.as_millis()
            );
        }
    }
    let path = dir.join("rtu2mqtt.toml");
    std::fs::write(&path, config)?;
    Ok(path)
}

/// The configuration's sections before its lines, the same for every plant: MQTT with Home
/// Assistant discovery, the JSON view, the history journal in `dir`, no status file.
fn gateway_sections(dir: &Path, broker_port: u16) -> String {
    format!(
        "[mqtt]\nurl = \"mqtt://127.0.0.1:{broker_port}\"\nclient_id = \"{CLIENT_ID}\"\n\
         prefix = \"plant\"\ndiscovery = true\n\n[gateway]\njson_view = true\n\n\
         [health]\nstatus_file = \"\"\n\n[history]\npath = \"{}\"\n\n",
        dir.join("history").display()
    )
}

fn device_name(index: usize) -> String {
    format!("d{index:04}")
}

/// What a subscriber on `plant/#` and `homeassistant/#` (persistent session, QoS 1) received.
#[derive(Default)]
struct Received {
    by_kind: HashMap<String, u64>,
    first_value: Vec<Option<Instant>>,
    devices_seen: usize,
    /// Each history document: when it was read (its `ts`), its device, its field names.
    history: Vec<(SystemTime, u32, Vec<String>)>,
}

struct Counter {
    received: Arc<Mutex<Received>>,
    _recorder: Recorder,
}

impl Counter {
    async fn connect(port: u16, devices: usize) -> anyhow::Result<Counter> {
        let mut options = MqttOptions::new("plant-scale-counter", "127.0.0.1", port);
        options.set_keep_alive(Duration::from_secs(30));
        options.set_clean_session(false);
        options.set_max_packet_size(16 << 20, 1 << 20);
        options.set_inflight(1000);
        let received = Arc::new(Mutex::new(Received {
            first_value: vec![None; devices],
            ..Received::default()
        }));
        let into = Arc::clone(&received);
        let subscriptions = [
            ("plant/#", QoS::AtLeastOnce),
            ("homeassistant/#", QoS::AtLeastOnce),
        ];
        let recorder = Recorder::start(options, false, &subscriptions, move |topic, payload| {
            if let Ok(mut received) = into.lock() {
                received.note(topic, payload);
            }
        })
        .await?;
        Ok(Counter {
            received,
            _recorder: recorder,
        })
    }

    /// When every device had its first value (None: not within `limit`).
    async fn every_device_seen(&self, limit: Duration) -> Option<Instant> {
        let deadline = Instant::now() + limit;
        while Instant::now() < deadline {
            if let Ok(received) = self.received.lock() {
                if received.devices_seen == received.first_value.len() {
                    return received.first_value.iter().flatten().max().copied();
                }
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        None
    }

    fn counts(&self) -> HashMap<String, u64> {
        self.received
            .lock()
            .map(|received| received.by_kind.clone())
            .unwrap_or_default()
    }

    /// History values read between `from` and `to` (by their `ts`).
    fn history_values_between(&self, from: SystemTime, to: SystemTime) -> usize {
        self.received.lock().map_or(0, |received| {
            received
                .history
                .iter()
                .filter(|(ts, _, _)| *ts >= from && *ts < to)
                .map(|(_, _, fields)| fields.len())
                .sum()
        })
    }

    /// History values received, and how many distinct (device, field, ts) they are.
    fn history_values(&self) -> (usize, usize) {
        self.received.lock().map_or((0, 0), |received| {
            let mut distinct = std::collections::HashSet::new();
            let mut all = 0;
            for (ts, device, fields) in &received.history {
                for field in fields {
                    all += 1;
                    distinct.insert((*device, field.as_str(), *ts));
                }
            }
            (all, distinct.len())
        })
    }
}

impl Received {
    fn note(&mut self, topic: &str, payload: &[u8]) {
        let levels: Vec<&str> = topic.split('/').collect();
        let kind = match levels.as_slice() {
            ["homeassistant", ..] => "discovery",
            ["plant", "gateway", ..] => "gateway",
            ["plant", _, "availability"] => "availability",
            ["plant", device, "history"] => {
                self.note_history(device, payload);
                "history"
            }
            ["plant", device, _] => {
                self.note_value(device);
                "value"
            }
            ["plant", _] => "json_view",
            _ => "other",
        };
        *self.by_kind.entry(kind.to_string()).or_insert(0) += 1;
    }

    fn note_value(&mut self, device: &str) {
        let index = device
            .strip_prefix('d')
            .and_then(|n| n.parse::<usize>().ok());
        if let Some(first) = index.and_then(|i| self.first_value.get_mut(i)) {
            if first.is_none() {
                *first = Some(Instant::now());
                self.devices_seen += 1;
            }
        }
    }

    fn note_history(&mut self, device: &str, payload: &[u8]) {
        let Some(index) = device.strip_prefix('d').and_then(|n| n.parse().ok()) else {
            return;
        };
        let Ok(document) = serde_json::from_slice::<serde_json::Value>(payload) else {
            return;
        };
        let ts = document
            .get("ts")
            .and_then(|ts| ts.as_str())
            .and_then(|ts| humantime::parse_rfc3339(ts).ok());
        let fields = document
            .get("values")
            .and_then(|values| values.as_object())
            .map(|values| values.keys().cloned().collect())
            .unwrap_or_default();
        if let Some(ts) = ts {
            self.history.push((ts, index, fields));
        }
    }
}
