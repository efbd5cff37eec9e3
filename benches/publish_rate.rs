//! What publishing by exception saves the broker, measured from outside: the built binary runs
//! as its own process (`rtu2mqtt run`) against a real mosquitto and the seed plant as the demo
//! runs it (dust collector switched on, so its fan speed and temperature move; air shower and
//! valve; simulated on pseudo-terminals paced at 9600 baud in this process), polled at the
//! example configuration's intervals. A subscriber on `#` counts every message the broker
//! delivers, after a warm-up (first values, births), over a window of a few minutes:
//!
//! 1. without `publish` settings (every change is published);
//! 2. with `publish = { deadband_percent = 1.0, max_interval = "60s" }` as every device's
//!    default.
//!
//! Prints messages per minute, in all and by kind of topic; asserts nothing. Run: `cargo bench
//! --bench publish_rate` (about seven minutes after the build; `PUBLISH_RATE_WINDOW=300` sets
//! the window in seconds).

mod gateway_process;
use rtu2mqtt_testkit as support;
mod wire_bench;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

use gateway_process::GatewayProcess;
use rtu2mqtt_sim::{self as sim, SeedPlant};
use support::{Mosquitto, PlantConfig, TestClient};

/// The plant settles (first values of every block, slow ones included) before counting.
const WARM_UP: Duration = Duration::from_secs(15);
/// Counted by default: three heartbeat intervals.
const WINDOW: Duration = Duration::from_secs(180);
/// The device-wide default of the second run.
const PUBLISH: &str = "publish = { deadband_percent = 1.0, max_interval = \"60s\" }";

fn main() -> anyhow::Result<()> {
    let window = std::env::var("PUBLISH_RATE_WINDOW")
        .ok()
        .and_then(|seconds| seconds.parse().ok())
        .map_or(WINDOW, Duration::from_secs);
    wire_bench::runtime()?.block_on(run(window))
}

async fn run(window: Duration) -> anyhow::Result<()> {
    println!(
        "broker messages per minute, seed plant (3 devices on 2 lines at 9600 baud, dust \
         collector on, the example's poll intervals), {} s counted after {} s of warm-up",
        window.as_secs(),
        WARM_UP.as_secs()
    );
    let every_change = count(None, window).await?;
    let by_exception = count(Some(PUBLISH), window).await?;
    let minutes = window.as_secs_f64() / 60.0;
    let kinds: Vec<&String> = every_change
        .keys()
        .chain(by_exception.keys())
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect();
    println!(
        "\n{:<34} {:>14} {:>14}",
        "topics", "every change", "1 % + 60 s"
    );
    for kind in kinds {
        let per_minute = |counts: &BTreeMap<String, u64>| {
            counts.get(kind).copied().unwrap_or(0) as f64 / minutes
        };
        println!(
            "{kind:<34} {:>14.1} {:>14.1}",
            per_minute(&every_change),
            per_minute(&by_exception)
        );
    }
    let total = |counts: &BTreeMap<String, u64>| counts.values().sum::<u64>() as f64 / minutes;
    let (before, after) = (total(&every_change), total(&by_exception));
    println!("{:<34} {before:>14.1} {after:>14.1}", "all messages");
    println!(
        "\nwith a 1 % deadband and a 60 s heartbeat as every device's default: {after:.1} \
         messages per minute instead of {before:.1} ({:.0} % fewer)",
        100.0 * (1.0 - after / before.max(f64::MIN_POSITIVE))
    );
    Ok(())
}

/// Messages per kind of topic over `window`, with `publish` as every device's default.
async fn count(publish: Option<&str>, window: Duration) -> anyhow::Result<BTreeMap<String, u64>> {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(true)?;
    sim::lock(&plant.dust_collector).set_power(true);
    let files = tempfile::tempdir()?;
    let config_path = files.path().join("rtu2mqtt.toml");
    let mut text = PlantConfig {
        explicit_serial: true,
        dust_collector_keys: "poll_interval = \"1s\"",
        ..PlantConfig::default()
    }
    .text(&broker, &plant, "publish-rate");
    if let Some(publish) = publish {
        text = with_device_default(&text, publish);
    }
    std::fs::write(
        &config_path,
        format!("{text}\n[health]\nstatus_file = \"\"\n"),
    )?;
    let mut gateway = GatewayProcess::start(
        Path::new(env!("CARGO_BIN_EXE_rtu2mqtt")),
        &config_path,
        "error",
    )?;
    let mut subscriber = TestClient::connect(broker.port, "publish-rate-counter").await;
    subscriber.subscribe("#").await;
    subscriber.settle(WARM_UP).await;
    subscriber.forget();
    subscriber.settle(window).await;
    gateway.stop();
    let mut counts = BTreeMap::new();
    for message in &subscriber.received {
        *counts.entry(kind_of(&message.topic)).or_insert(0) += 1;
    }
    Ok(counts)
}

/// `text` with `publish` added to every `[[lines.devices]]` entry (after its `address`).
fn with_device_default(text: &str, publish: &str) -> String {
    let mut out = String::new();
    for line in text.lines() {
        out.push_str(line);
        out.push('\n');
        if line.starts_with("address = ") {
            out.push_str(publish);
            out.push('\n');
        }
    }
    out
}

/// A topic's kind: a device's field values by device, the rest by its last level.
fn kind_of(topic: &str) -> String {
    let levels: Vec<&str> = topic.split('/').collect();
    match levels.as_slice() {
        ["plant", "gateway", .., last] => format!("plant/gateway/…/{last}"),
        ["plant", device, "availability"] => format!("plant/{device}/availability"),
        ["plant", device, _field] => format!("plant/{device}/<field>"),
        ["plant", device] => format!("plant/{device} (JSON view)"),
        _ => levels
            .first()
            .map_or_else(String::new, |first| format!("{first}/…")),
    }
}
