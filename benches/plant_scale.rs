//! A plant of Modbus TCP devices on one box, from nothing: a real mosquitto on a free loopback
//! port, a loopback simulator of N meters in this process (`scale_sim`: 100 `f32` points each,
//! 1 % of them changing a second), and the built gateway binary as its own process with a
//! generated configuration: N `modbus-tcp://` lines of one device each, 100 points in two blocks
//! of 100 registers polled every second, Home Assistant discovery, the JSON view and the history
//! journal on.
//!
//! For each N it prints the start-up (gateway started → every device's first value on MQTT),
//! the gateway's CPU (% of one core) and memory (`Anonymous` and `Pss` from smaps_rollup, with
//! RssAnon and Private_Dirty beside them) in steady state,
//! the MQTT messages per second the broker received from it, and the poll lateness measured at
//! the simulator (time between a block's successive requests beyond 1 s; p50, p99, skipped
//! polls). At the largest N it then stops mosquitto for an outage, starts it again on the same
//! port and counts the values the gateway measured (served changes at the simulator) against
//! those that reached a subscriber on the history stream, live and replayed, and the lateness
//! during the outage and the replay.
//!
//! Run: `cargo bench --bench plant_scale` (about eight minutes after the build). Environment:
//! `PLANT_SCALE_DEVICES=10,100,1000` (the device counts), `PLANT_SCALE_WARMUP=20` and
//! `PLANT_SCALE_WINDOW=60` (seconds after start-up before and of the steady-state window),
//! `PLANT_SCALE_OUTAGE=60` (seconds; `0` skips the outage), `PLANT_SCALE_GATEWAY=path` (another
//! gateway binary). Asserts nothing.

mod gateway_process;
mod scale_sim;

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use gateway_process::{GatewayProcess, Memory};
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use scale_sim::{Lateness, ScalePlant, POINTS};

const POLL_INTERVAL: Duration = Duration::from_secs(1);
const CLIENT_ID: &str = "plant-scale";

fn main() -> anyhow::Result<()> {
    let devices: Vec<usize> = std::env::var("PLANT_SCALE_DEVICES")
        .unwrap_or_else(|_| "10,100,1000".into())
        .split(',')
        .filter_map(|n| n.trim().parse().ok())
        .collect();
    let settings = Settings {
        warm_up: seconds("PLANT_SCALE_WARMUP", 20),
        window: seconds("PLANT_SCALE_WINDOW", 60),
        outage: seconds("PLANT_SCALE_OUTAGE", 60),
        gateway: std::env::var("PLANT_SCALE_GATEWAY")
            .map(PathBuf::from)
            .unwrap_or_else(|_| PathBuf::from(env!("CARGO_BIN_EXE_rtu2mqtt"))),
    };
    println!(
        "plant scale: gateway {}; {} points per device at {:?}; warm-up {} s, window {} s",
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
    println!("\n{}", Row::header());
    for row in &rows {
        println!("{}", row.line());
    }
    Ok(())
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

/// One device count's figures.
struct Row {
    devices: usize,
    start_up: Option<Duration>,
    cpu_percent: f64,
    memory: Memory,
    messages_per_second: f64,
    by_kind: Vec<(String, f64)>,
    lateness: Lateness,
}

impl Row {
    fn header() -> String {
        format!(
            "{:>6} {:>9} {:>7} {:>10} {:>10} {:>9} {:>9} {:>13} {:>8}",
            "N",
            "start-up",
            "CPU %",
            "anon MiB",
            "PSS MiB",
            "msgs/s",
            "late p50",
            "late p99",
            "skipped"
        )
    }

    fn line(&self) -> String {
        let mut kinds = String::new();
        for (kind, rate) in &self.by_kind {
            let _ = write!(kinds, " {kind} {rate:.0}/s;");
        }
        format!(
            "{:>6} {:>9} {:>7.2} {:>10.2} {:>10.2} {:>9.0} {:>9} {:>13} {:>8}   ({} requests; RssAnon {:.2} MiB, Private_Dirty {:.2} MiB; {} threads;{kinds})",
            self.devices,
            self.start_up
                .map_or("never".into(), |d| format!("{:.2} s", d.as_secs_f64())),
            self.cpu_percent,
            self.memory.anonymous_kib as f64 / 1024.0,
            self.memory.pss_kib as f64 / 1024.0,
            self.messages_per_second,
            format!("{:.1} ms", ms(self.lateness.percentile(50.0))),
            format!("{:.1} ms", ms(self.lateness.percentile(99.0))),
            self.lateness.skipped,
            self.lateness.gaps,
            self.memory.rss_anon_kib as f64 / 1024.0,
            self.memory.private_dirty_kib as f64 / 1024.0,
            self.memory.threads,
        )
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

async fn run(devices: usize, settings: &Settings, outage: Option<Duration>) -> anyhow::Result<Row> {
    println!("\n— {devices} devices —");
    let files = tempfile::tempdir()?;
    let mut broker = Broker::start(files.path().join("broker"))?;
    let counter = Counter::connect(broker.port, devices).await?;
    let plant = ScalePlant::spawn(devices).await?;
    let config = write_config(files.path(), broker.port, &plant)?;
    let started = Instant::now();
    let mut gateway = GatewayProcess::start(&settings.gateway, &config, "warn")?;

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
    let counts_before = counter.counts();
    let from = Instant::now();
    let mut memory = Memory::default();
    while from.elapsed() < settings.window {
        tokio::time::sleep(Duration::from_secs(1)).await;
        memory = memory.max(gateway.memory()?);
    }
    let to = Instant::now();
    let cpu = (gateway.cpu_time()? - cpu_before).as_secs_f64() / (to - from).as_secs_f64();
    let counts_after = counter.counts();
    let seconds = (to - from).as_secs_f64();
    let mut by_kind: Vec<(String, f64)> = counts_after
        .iter()
        .map(|(kind, after)| {
            let before = counts_before.get(kind).copied().unwrap_or(0);
            (kind.clone(), (after - before) as f64 / seconds)
        })
        .collect();
    by_kind.sort_by(|a, b| a.0.cmp(&b.0));
    let lateness = {
        let requests = plant.log.requests.lock().map_err(poisoned)?;
        Lateness::of(&requests, from, to, POLL_INTERVAL)
    };
    let row = Row {
        devices,
        start_up,
        cpu_percent: cpu * 100.0,
        memory,
        messages_per_second: by_kind.iter().map(|(_, rate)| rate).sum(),
        by_kind,
        lateness,
    };
    if let Some(outage) = outage {
        println!("{}", row.line());
        broker_outage(&mut broker, &mut gateway, &plant, &counter, outage).await?;
    }
    gateway.stop();
    plant.stop();
    Ok(row)
}

/// Stops the broker for `outage`, starts it again on the same port, and counts what the
/// gateway measured against what reached the history stream.
async fn broker_outage(
    broker: &mut Broker,
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
    broker.launch()?;
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
    let mut profile = String::from(
        "[device]\nname = \"scale-meter\"\nmanufacturer = \"Bench\"\nmodel = \"100 f32 points\"\n\
         description = \"Simulated meter of the scale bench\"\n\n[line]\naddress_range = [1, 247]\n\
         min_poll_interval = \"1s\"\npoll_interval = \"1s\"\n\n",
    );
    let half = POINTS / 2;
    for (block, start) in [("points_a", 0), ("points_b", 2 * half)] {
        let _ = write!(
            profile,
            "[[blocks]]\nname = \"{block}\"\nfunction = 3\nstart = {start}\ncount = {}\n\n",
            2 * half
        );
    }
    for point in 0..POINTS {
        let block = if point < half { "points_a" } else { "points_b" };
        let _ = write!(
            profile,
            "[[fields]]\nname = \"p{point:03}\"\nblock = \"{block}\"\noffset = {}\n\
             codec = {{ type = \"f32\", word_order = \"high_first\", decimals = 2 }}\n\
             ha = {{ state_class = \"measurement\" }}\n\n",
            2 * (point % half)
        );
    }
    std::fs::write(dir.join("scale-meter.toml"), profile)?;
    let mut config = format!(
        "[mqtt]\nurl = \"mqtt://127.0.0.1:{broker_port}\"\nclient_id = \"{CLIENT_ID}\"\n\
         prefix = \"plant\"\ndiscovery = true\n\n[gateway]\njson_view = true\n\n\
         [health]\nstatus_file = \"\"\n\n[history]\npath = \"{}\"\n\n",
        dir.join("history").display()
    );
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

fn device_name(index: usize) -> String {
    format!("d{index:04}")
}

/// mosquitto on a free loopback port, with persistence so that a subscriber's session and
/// its queued messages outlive a restart; its own log of errors only.
struct Broker {
    port: u16,
    dir: PathBuf,
    child: Option<Child>,
}

impl Broker {
    fn start(dir: PathBuf) -> anyhow::Result<Broker> {
        std::fs::create_dir_all(&dir)?;
        // mosquitto drops root privileges: let it write its database and log there.
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o777))?;
        let port = std::net::TcpListener::bind("127.0.0.1:0")?
            .local_addr()?
            .port();
        let mut broker = Broker {
            port,
            dir,
            child: None,
        };
        broker.launch()?;
        Ok(broker)
    }

    fn launch(&mut self) -> anyhow::Result<()> {
        let config = self.dir.join("mosquitto.conf");
        std::fs::write(
            &config,
            format!(
                "persistence true\npersistence_location {}/\nautosave_interval 0\n\
                 log_dest file {}\nlog_type error\nlog_type warning\n\
                 max_queued_messages 10000000\nlistener {} 127.0.0.1\nallow_anonymous true\n",
                self.dir.display(),
                self.dir.join("mosquitto.log").display(),
                self.port
            ),
        )?;
        let child = Command::new("/usr/sbin/mosquitto")
            .arg("-c")
            .arg(&config)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()?;
        self.child = Some(child);
        let deadline = Instant::now() + Duration::from_secs(10);
        while std::net::TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            anyhow::ensure!(Instant::now() < deadline, "mosquitto did not start");
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(())
    }

    /// SIGTERM (mosquitto saves its sessions), then waits for the process to end.
    fn stop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let pid = nix::unistd::Pid::from_raw(child.id() as i32);
            let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
            let deadline = Instant::now() + Duration::from_secs(20);
            while Instant::now() < deadline {
                if let Ok(Some(_)) = child.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        self.stop();
    }
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
    _client: AsyncClient,
}

impl Counter {
    async fn connect(port: u16, devices: usize) -> anyhow::Result<Counter> {
        let mut options = MqttOptions::new("plant-scale-counter", "127.0.0.1", port);
        options.set_keep_alive(Duration::from_secs(30));
        options.set_clean_session(false);
        options.set_max_packet_size(16 << 20, 1 << 20);
        options.set_inflight(1000);
        let (client, mut eventloop) = AsyncClient::new(options, 64);
        client.subscribe("plant/#", QoS::AtLeastOnce).await?;
        client
            .subscribe("homeassistant/#", QoS::AtLeastOnce)
            .await?;
        let received = Arc::new(Mutex::new(Received {
            first_value: vec![None; devices],
            ..Received::default()
        }));
        let (subscribed_tx, subscribed_rx) = tokio::sync::oneshot::channel();
        let into = Arc::clone(&received);
        tokio::spawn(async move {
            let mut subscribed_tx = Some(subscribed_tx);
            let mut subacks = 0;
            loop {
                match eventloop.poll().await {
                    Ok(Event::Incoming(Packet::Publish(publish))) => {
                        if let Ok(mut received) = into.lock() {
                            received.note(&publish.topic, &publish.payload);
                        }
                    }
                    Ok(Event::Incoming(Packet::SubAck(_))) => {
                        subacks += 1;
                        if subacks == 2 {
                            if let Some(subscribed) = subscribed_tx.take() {
                                let _ = subscribed.send(());
                            }
                        }
                    }
                    Ok(_) => {}
                    Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
                }
            }
        });
        tokio::time::timeout(Duration::from_secs(10), subscribed_rx).await??;
        Ok(Counter {
            received,
            _client: client,
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
