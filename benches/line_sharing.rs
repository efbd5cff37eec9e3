//! What a served line (`[lines.serve]`) gives its Modbus TCP clients and what sharing costs
//! the line, measured from outside: the built binary runs as its own process (`rtu2mqtt run`)
//! against a real mosquitto and the seed plant's line-a (the dust collector at 1, the air
//! shower at 0x81) simulated on a pseudo-terminal at 9600 8N1 whose answers are released byte
//! by byte at the character rate. Clients are plain Modbus TCP sockets reading the dust
//! collector's polled block (`01 03 10 00 00 06`).
//!
//! 1. `cache = "0s"`, every read goes to the line:
//!    - idle line: one client, one read at a time with a pause between reads, the gateway's
//!      own polls beside it: client latency p50 / p95 (request written → answer read);
//!    - busy line: three clients reading back to back and an MQTT gear command every second:
//!      their latency p50 / p95, the line's efficiency, the idle gap before each request, and
//!      early requests (sooner than t3.5 after the line's last byte; must be 0).
//! 2. `cache = "1s"`: three clients reading the polled block in a loop: the share of their
//!    reads answered from the cache (`cache_hits` / `client_requests` of the line's stats).
//!
//! efficiency = (wire time of every request and answer + the two mandatory t3.5 silences of
//!               each transaction) / wall time, from the simulator's journal, as in
//!               `benches/edge_footprint.rs`.
//!
//! Prints figures; asserts nothing. Run: `cargo bench --bench line_sharing` (about two minutes
//! after the build).

mod gateway_process;
use rtu2mqtt_testkit as support;
mod wire_bench;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use gateway_process::GatewayProcess;
use rtu2mqtt_modbus::timing::{LineTiming, Parity};
use rtu2mqtt_sim::VirtualLine;
use rtu2mqtt_sim::{share, AirShower, DustCollector, Pace, RequestRecord, ServeOptions};
use rumqttc::{MqttOptions, QoS};
use support::{free_port, Mosquitto, Recorder};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::watch;
use wire_bench::{command_client, percentile, wire_load, WireLoad, EIGHT_N_ONE};

const BAUD: u32 = 9600;
const WARM_UP: Duration = Duration::from_secs(5);
const IDLE_READS: usize = 100;
const IDLE_PAUSE: Duration = Duration::from_millis(100);
const BUSY_WINDOW: Duration = Duration::from_secs(30);
const CACHE_WINDOW: Duration = Duration::from_secs(20);
/// A client of the cache run waits this long between its reads, as a polling client does.
const CACHE_PAUSE: Duration = Duration::from_millis(50);
const CLIENTS: usize = 3;
/// The dust collector's block: the request's PDU, and its answer's length in Modbus TCP.
const BLOCK_READ: &str = "00 00 00 06 01 03 10 00 00 06";
const BLOCK_ANSWER_LEN: usize = 7 + 2 + 12;

fn main() -> anyhow::Result<()> {
    let runtime = wire_bench::runtime()?;
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir()?;
    let load_before = load_average();
    let line_run = runtime.block_on(uncached(&broker, dir.path()))?;
    let cache_run = runtime.block_on(cached(&broker, dir.path()))?;
    report(&line_run, &cache_run, &load_before, &load_average());
    Ok(())
}

/// The figures of the run without cache.
struct LineRun {
    idle: Vec<Duration>,
    busy: Vec<Duration>,
    busy_wall: Duration,
    commands: usize,
    wire: Wire,
}

struct Wire {
    transactions: usize,
    efficiency: f64,
    gap_p50: Duration,
    gap_p95: Duration,
    early: usize,
}

/// The figures of the run with `cache = "1s"`.
struct CacheRun {
    reads: usize,
    requests: u64,
    hits: u64,
    on_the_wire: usize,
    wall: Duration,
}

/// Seed line-a byte-paced: the dust collector (running) and the air shower.
fn spawn_line() -> anyhow::Result<VirtualLine> {
    let (dust, dust_shared) = share(DustCollector::new(1));
    rtu2mqtt_sim::lock(&dust).set_power(true);
    let (_shower, shower_shared) = share(AirShower::new());
    Ok(VirtualLine::spawn(
        ServeOptions::new(BAUD, Parity::None).pacing(Pace::Bytes),
        vec![dust_shared, shower_shared],
    )?)
}

fn config_file(
    dir: &Path,
    name: &str,
    broker: &Mosquitto,
    line: &VirtualLine,
    port: u16,
    cache: &str,
) -> anyhow::Result<PathBuf> {
    let text = format!(
        r#"[mqtt]
url = "{url}"
client_id = "bench-{name}"
prefix = "plant"

[gateway]
stats_interval = "1s"

[health]
status_file = ""

[[lines]]
name = "line-a"
port = "{path}"
baud = {BAUD}
parity = "none"

[lines.serve]
listen = "modbus-tcp://127.0.0.1:{port}"
cache = "{cache}"

[[lines.devices]]
name = "dust_collector"
profile = "ruiwan-dust-collector"
address = 1

[[lines.devices]]
name = "air_shower"
profile = "lixian-air-shower"
address = 0x81
"#,
        url = broker.url(),
        path = line.path().display(),
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text)?;
    Ok(path)
}

async fn uncached(broker: &Mosquitto, dir: &Path) -> anyhow::Result<LineRun> {
    let line = spawn_line()?;
    let port = free_port();
    let config = config_file(dir, "share-line", broker, &line, port, "0s")?;
    let _gateway = start_gateway(&config)?;
    tokio::time::sleep(WARM_UP).await;

    let mut client = connect(port).await?;
    let mut idle = Vec::with_capacity(IDLE_READS);
    for transaction in 0..IDLE_READS {
        idle.push(timed_read(&mut client, transaction as u16).await?);
        tokio::time::sleep(IDLE_PAUSE).await;
    }
    drop(client);

    let commands = command_client(broker.port, "bench-share-commands").await;
    let start = Instant::now();
    let end = start + BUSY_WINDOW;
    let mut readers = Vec::new();
    for _ in 0..CLIENTS {
        readers.push(tokio::spawn(read_until(port, end, Duration::ZERO)));
    }
    let mut sent = 0;
    while Instant::now() + Duration::from_secs(1) < end {
        let gear = 1 + sent % 10;
        commands
            .publish(
                "plant/dust_collector/gear/set",
                QoS::AtLeastOnce,
                false,
                gear.to_string().into_bytes(),
            )
            .await?;
        sent += 1;
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
    let mut busy = Vec::new();
    for reader in readers {
        busy.extend(reader.await??);
    }
    let wall = start.elapsed();
    let records: Vec<RequestRecord> = line
        .journal()
        .requests()
        .into_iter()
        .filter(|r| r.arrived >= start && r.arrived < start + wall)
        .collect();
    idle.sort();
    busy.sort();
    Ok(LineRun {
        idle,
        busy,
        busy_wall: wall,
        commands: sent,
        wire: wire_figures(&records, wall),
    })
}

async fn cached(broker: &Mosquitto, dir: &Path) -> anyhow::Result<CacheRun> {
    let line = spawn_line()?;
    let port = free_port();
    let config = config_file(dir, "share-cache", broker, &line, port, "1s")?;
    let _gateway = start_gateway(&config)?;
    let (_stats_client, stats) =
        stats_subscriber(broker.port, "plant/gateway/bench-share-cache/stats/line-a").await?;
    tokio::time::sleep(WARM_UP).await;
    let before = line_counters(&stats);
    let start = Instant::now();
    let end = start + CACHE_WINDOW;
    let mut readers = Vec::new();
    for _ in 0..CLIENTS {
        readers.push(tokio::spawn(read_until(port, end, CACHE_PAUSE)));
    }
    let mut reads = 0;
    for reader in readers {
        reads += reader.await??.len();
    }
    let wall = start.elapsed();
    // The statistics after the last read: the next document the gateway publishes.
    let mut next = stats.clone();
    next.borrow_and_update();
    tokio::time::timeout(Duration::from_secs(5), next.changed()).await??;
    let after = line_counters(&stats);
    let block = [1u8, 0x03, 0x10, 0x00, 0x00, 0x06];
    let on_the_wire = line
        .journal()
        .requests()
        .iter()
        .filter(|r| r.arrived >= start && r.arrived < start + wall && r.frame.starts_with(&block))
        .count();
    Ok(CacheRun {
        reads,
        requests: after.0.saturating_sub(before.0),
        hits: after.1.saturating_sub(before.1),
        on_the_wire,
        wall,
    })
}

/// (client_requests, cache_hits) in line-a's last statistics document.
fn line_counters(stats: &watch::Receiver<serde_json::Value>) -> (u64, u64) {
    let line = stats.borrow();
    let count = |key: &str| line[key].as_u64().unwrap_or(0);
    (count("client_requests"), count("cache_hits"))
}

async fn connect(port: u16) -> anyhow::Result<TcpStream> {
    let stream = TcpStream::connect(("127.0.0.1", port)).await?;
    stream.set_nodelay(true)?;
    Ok(stream)
}

/// One read of the dust collector's block: the time from writing the request to reading the
/// whole answer.
async fn timed_read(stream: &mut TcpStream, transaction: u16) -> anyhow::Result<Duration> {
    let mut request = transaction.to_be_bytes().to_vec();
    request.extend(support::hex::decode(BLOCK_READ));
    let sent = Instant::now();
    stream.write_all(&request).await?;
    let mut answer = [0u8; BLOCK_ANSWER_LEN];
    tokio::time::timeout(Duration::from_secs(10), stream.read_exact(&mut answer)).await??;
    let latency = sent.elapsed();
    anyhow::ensure!(
        answer[..2] == transaction.to_be_bytes() && answer[7] == 0x03,
        "unexpected answer {}",
        support::hex::encode(&answer)
    );
    Ok(latency)
}

/// A client reading the block until `end`, `pause` between reads: its latencies.
async fn read_until(port: u16, end: Instant, pause: Duration) -> anyhow::Result<Vec<Duration>> {
    let mut stream = connect(port).await?;
    let mut latencies = Vec::new();
    let mut transaction = 0u16;
    while Instant::now() < end {
        latencies.push(timed_read(&mut stream, transaction).await?);
        transaction = transaction.wrapping_add(1);
        tokio::time::sleep(pause).await;
    }
    Ok(latencies)
}

/// The last document published on `topic` (while the returned [`Recorder`] is held).
async fn stats_subscriber(
    port: u16,
    topic: &str,
) -> anyhow::Result<(Recorder, watch::Receiver<serde_json::Value>)> {
    let options = MqttOptions::new("bench-share-stats", "127.0.0.1", port);
    let (tx, rx) = watch::channel(serde_json::Value::Null);
    let recorder = Recorder::start(
        options,
        false,
        &[(topic, QoS::AtMostOnce)],
        move |_, payload| {
            if let Ok(doc) = serde_json::from_slice(payload) {
                tx.send_replace(doc);
            }
        },
    )
    .await?;
    Ok((recorder, rx))
}

fn wire_figures(records: &[RequestRecord], wall: Duration) -> Wire {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    let WireLoad { busy, gaps, early } = wire_load(records, &timing, None);
    Wire {
        transactions: records.len(),
        efficiency: busy.as_secs_f64() / wall.as_secs_f64(),
        gap_p50: percentile(&gaps, 50),
        gap_p95: percentile(&gaps, 95),
        early,
    }
}

fn ms(duration: Duration) -> String {
    format!("{:.1} ms", duration.as_secs_f64() * 1000.0)
}

/// /proc/loadavg's first three fields.
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .unwrap_or_default()
        .split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}

fn report(line: &LineRun, cache: &CacheRun, load_before: &str, load_after: &str) {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    let cpus = std::thread::available_parallelism().map_or(0, usize::from);
    println!("line sharing: seed line-a (dust collector + air shower), 9600 8N1, byte-paced");
    println!("machine: {cpus} CPUs, load average {load_before} before, {load_after} after");
    println!(
        "client latency, idle line (one client, polls only, {} reads): p50 {}, p95 {}",
        line.idle.len(),
        ms(percentile(&line.idle, 50)),
        ms(percentile(&line.idle, 95))
    );
    println!(
        "client latency, busy line ({CLIENTS} clients back to back + {} MQTT commands in {:.0} s, \
         {} reads): p50 {}, p95 {}",
        line.commands,
        line.busy_wall.as_secs_f64(),
        line.busy.len(),
        ms(percentile(&line.busy, 50)),
        ms(percentile(&line.busy, 95))
    );
    println!(
        "line with {CLIENTS} clients: {} transactions, efficiency {:.1} %, gap before a request \
         p50 {} p95 {} (t3.5 = {}), early requests (inside t3.5) {}",
        line.wire.transactions,
        line.wire.efficiency * 100.0,
        ms(line.wire.gap_p50),
        ms(line.wire.gap_p95),
        ms(timing.t3_5),
        line.wire.early
    );
    let ratio = if cache.requests == 0 {
        0.0
    } else {
        cache.hits as f64 / cache.requests as f64 * 100.0
    };
    println!(
        "cache = \"1s\", {CLIENTS} clients reading the polled block every {} for {:.0} s: {} \
         reads, {} of {} client requests from the cache ({ratio:.1} %), {} block reads on the \
         wire",
        ms(CACHE_PAUSE),
        cache.wall.as_secs_f64(),
        cache.reads,
        cache.hits,
        cache.requests,
        cache.on_the_wire
    );
}

/// This build's gateway binary on `config`.
fn start_gateway(config: &Path) -> anyhow::Result<GatewayProcess> {
    GatewayProcess::start(Path::new(env!("CARGO_BIN_EXE_rtu2mqtt")), config, "warn")
}
