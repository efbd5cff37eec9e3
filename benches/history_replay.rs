//! What the history journal costs and how fast it empties, measured from outside: the built
//! binary runs as its own process (`rtu2mqtt run`) against a real mosquitto and the seed plant
//! (dust collector and air shower on line-a, valve on line-b, simulated on pseudo-terminals
//! paced at 9600 baud in this process), polled at its profiles' own intervals.
//!
//! 1. A real outage: the broker is killed for [`OUTAGE`] while the gateway keeps polling. Then
//!    the journal's files are read back: records, values (fields in the documents), bytes on
//!    disk per record and per value; and what the gateway process wrote to the disk meanwhile
//!    (/proc/<pid>/io `write_bytes`: what reached the block layer, the once-a-second syncs of
//!    partly written pages included) per value journaled, beside the journal's own growth.
//! 2. An hour's outage, without waiting an hour: the gateway is stopped, and the crate's own
//!    journal writer appends an hour's worth of the seed plant's records at the rate measured
//!    in 1 (the real records over and over, read instants spread across the hour). The broker
//!    is restarted and the gateway started on that journal; a subscriber on the history topics
//!    counts what arrives. Replay rate (records/s from the first replayed record to the last),
//!    CPU of the gateway over the replay (/proc/<pid>/stat, utime + stime, % of one core) and
//!    its memory (RssAnon from /proc/<pid>/status, Pss from /proc/<pid>/smaps_rollup, the
//!    highest of samples every 100 ms).
//!
//! Prints figures; asserts nothing. Run: `cargo bench --bench history_replay` (about two and
//! a half minutes after the build).

mod gateway_process;
use rtu2mqtt_testkit as support;
mod wire_bench;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use gateway_process::{GatewayProcess, Memory};
use rtu2mqtt::config::HistoryConfig;
use rtu2mqtt::history::document::{epoch_ms, values_of};
use rtu2mqtt::history::record::decode;
use rtu2mqtt::history::{Journal, Record};
use rtu2mqtt_sim::SeedPlant;
use rumqttc::QoS;
use support::{Mosquitto, PlantConfig};
use wire_bench::timed_subscriber;

/// The seed plant settles (first reads, births) before the outage.
const WARM_UP: Duration = Duration::from_secs(10);
const OUTAGE: Duration = Duration::from_secs(60);
const HOUR: Duration = Duration::from_secs(3600);
/// Longest the replay of the hour may take before the bench gives up on it.
const REPLAY_BOUND: Duration = Duration::from_secs(180);
const SAMPLE: Duration = Duration::from_millis(100);

fn main() -> anyhow::Result<()> {
    wire_bench::runtime()?.block_on(run())
}

async fn run() -> anyhow::Result<()> {
    let mut broker = Mosquitto::start();
    let plant = SeedPlant::spawn(true)?;
    let files = tempfile::tempdir()?;
    let journal_dir = files.path().join("history");
    let config_path = files.path().join("rtu2mqtt.toml");
    let text = PlantConfig::default().text(&broker, &plant, "history-bench");
    std::fs::write(
        &config_path,
        format!("{text}\n[history]\npath = \"{}\"\n", journal_dir.display()),
    )?;

    // 1. A real outage.
    let mut gateway = start_gateway(&config_path)?;
    tokio::time::sleep(WARM_UP).await;
    broker.kill();
    let written_before = gateway.write_bytes()?;
    tokio::time::sleep(OUTAGE).await;
    let written = gateway.write_bytes()?.saturating_sub(written_before);
    let outage = read_journal(&journal_dir)?;
    gateway.stop();
    let records = outage.records.len() as f64;
    let values = outage.values as f64;
    let per_second = records / OUTAGE.as_secs_f64();

    // 2. An hour's outage, written by the journal's own writer at the measured rate.
    std::fs::remove_dir_all(&journal_dir)?;
    let hour_records = (per_second * HOUR.as_secs_f64()).round() as u64;
    let hour_bytes = write_hour(&journal_dir, &outage.records, hour_records)?;
    broker.restart();
    let (_subscriber, mut arrivals) = timed_subscriber(
        broker.port,
        "plant/+/history",
        "history-bench-historian",
        QoS::AtLeastOnce,
    )
    .await?;
    let mut seen = 0u64;
    let mut gateway = start_gateway(&config_path)?;
    let started = Instant::now();
    let mut first: Option<(Instant, Duration)> = None;
    let mut last: Option<(Instant, Duration)> = None;
    let mut peak = Memory::default();
    while started.elapsed() < REPLAY_BOUND {
        tokio::time::sleep(SAMPLE).await;
        while arrivals.try_recv().is_ok() {
            seen += 1;
        }
        if seen > 0 && first.is_none() {
            first = Some((Instant::now(), gateway.cpu_time()?));
        }
        peak = peak.max(gateway.memory()?);
        if seen >= hour_records {
            last = Some((Instant::now(), gateway.cpu_time()?));
            break;
        }
    }
    let after = gateway.memory()?;
    gateway.stop();

    println!("history journal and replay, seed plant (3 devices on 2 lines at 9600 baud, the profiles' poll intervals)");
    println!(
        "\n1. a real outage of {} s (broker killed)",
        OUTAGE.as_secs()
    );
    row(
        "records journaled",
        format!("{records} ({per_second:.2}/s)"),
    );
    row(
        "values journaled",
        format!("{values} ({:.2} per record)", values / records.max(1.0)),
    );
    row(
        "journal bytes on disk",
        format!(
            "{} ({:.1} per record, {:.1} per value)",
            outage.bytes,
            outage.bytes as f64 / records.max(1.0),
            outage.bytes as f64 / values.max(1.0)
        ),
    );
    row(
        "written to disk by the gateway (write_bytes)",
        format!(
            "{written} ({:.1} per value journaled; {:.1}× the journal's growth)",
            written as f64 / values.max(1.0),
            written as f64 / (outage.bytes as f64).max(1.0)
        ),
    );
    println!(
        "\n2. replay of an hour's outage: {hour_records} records, {hour_bytes} bytes, written by \
         the journal's writer at the rate of 1"
    );
    match (first, last) {
        (Some((first_at, first_cpu)), Some((last_at, last_cpu))) => {
            let wall = last_at.saturating_duration_since(first_at);
            let cpu = last_cpu.saturating_sub(first_cpu);
            row(
                "gateway start to first replayed record",
                format!("{:.2} s", first_at.duration_since(started).as_secs_f64()),
            );
            row(
                "replay",
                format!(
                    "{:.2} s, {:.0} records/s",
                    wall.as_secs_f64(),
                    hour_records as f64 / wall.as_secs_f64().max(1e-3)
                ),
            );
            row(
                "gateway CPU during the replay",
                format!(
                    "{:.1} % of one core",
                    100.0 * cpu.as_secs_f64() / wall.as_secs_f64().max(1e-3)
                ),
            );
        }
        _ => row(
            "replay",
            format!(
                "not complete within {} s: {} of {hour_records} records seen",
                REPLAY_BOUND.as_secs(),
                seen
            ),
        ),
    }
    row(
        "gateway memory, highest during the replay",
        format!(
            "RssAnon {} KiB, Pss {} KiB",
            peak.rss_anon_kib, peak.pss_kib
        ),
    );
    row(
        "gateway memory after it",
        format!(
            "RssAnon {} KiB, Pss {} KiB",
            after.rss_anon_kib, after.pss_kib
        ),
    );
    Ok(())
}

fn row(figure: &str, value: String) {
    println!("  {figure:<46} {value}");
}

/// What a journal directory holds.
struct Outage {
    records: Vec<Record>,
    values: u64,
    bytes: u64,
}

fn read_journal(dir: &Path) -> anyhow::Result<Outage> {
    let mut outage = Outage {
        records: Vec::new(),
        values: 0,
        bytes: 0,
    };
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)?
        .flatten()
        .map(|entry| entry.path())
        .collect();
    paths.sort();
    for path in paths {
        let bytes = std::fs::read(&path)?;
        outage.bytes += bytes.len() as u64;
        for record in decode(&bytes).records {
            outage.values += values_of(&record.document).map_or(0, |v| v.len() as u64);
            outage.records.push(record);
        }
    }
    Ok(outage)
}

/// `count` records, the `sample` over and over, their read instants spread evenly over the
/// hour that ends now; the bytes on disk.
fn write_hour(dir: &Path, sample: &[Record], count: u64) -> anyhow::Result<u64> {
    let config = HistoryConfig {
        path: dir.to_path_buf(),
        max_size: 1 << 30,
        max_age: Duration::from_secs(7 * 24 * 3600),
    };
    let mut journal = Journal::open(&config);
    if let Some(problem) = journal.problem() {
        anyhow::bail!("the journal cannot be written: {problem}");
    }
    let now = epoch_ms(SystemTime::now());
    let start = now.saturating_sub(HOUR.as_millis() as u64);
    let step = HOUR.as_millis() as u64 / count.max(1);
    for (n, record) in sample.iter().cycle().take(count as usize).enumerate() {
        let at_ms = start + n as u64 * step;
        journal.append(
            &Record {
                at_ms,
                device: record.device.clone(),
                document: record.document.clone(),
            },
            now,
        );
    }
    journal.sync();
    Ok(journal.stats().bytes)
}

/// This build's gateway as its own process.
fn start_gateway(config: &Path) -> anyhow::Result<GatewayProcess> {
    GatewayProcess::start(Path::new(env!("CARGO_BIN_EXE_rtu2mqtt")), config, "error")
}
