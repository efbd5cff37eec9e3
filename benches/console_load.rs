//! What the console costs the gateway at plant scale: a real mosquitto on a free loopback
//! port, a loopback simulator of N Modbus TCP meters (`scale_sim`: 100 `f32` points each, 1 %
//! of them changing a second; N lines of one device polled every second, as `plant_scale`'s
//! Modbus TCP row), and the built gateway binary as its own process, measured by its pid.
//!
//! In one run it measures the gateway's CPU (% of one core, from /proc) and memory (Anonymous
//! and Pss from smaps_rollup) over the same window length:
//!
//! 1. without `[web]` (no HTTP server at all);
//! 2. with the console on and no browser open;
//! 3. with B headless chromium browsers (Debian's, through chromedriver) on the *Plant* page,
//!    each receiving every value the gateway publishes as server-sent events;
//! 4. with the console on and the browsers closed again.
//!
//! Run: `cargo bench --bench console_load`. Environment: `CONSOLE_LOAD_DEVICES=1000`,
//! `CONSOLE_LOAD_BROWSERS=10`, `CONSOLE_LOAD_WARMUP=20` and `CONSOLE_LOAD_WINDOW=30` (seconds).
//! Asserts nothing; prints a table.

mod gateway_process;
mod scale_sim;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use gateway_process::{GatewayProcess, Memory};
use rtu2mqtt_testkit::{free_port, Browser, Mosquitto};
use scale_sim::{ScalePlant, POINTS};

fn env_number(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|text| text.parse().ok())
        .unwrap_or(default)
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    runtime.block_on(run())
}

/// One measured window.
struct Window {
    label: String,
    cpu_percent: f64,
    memory: Memory,
}

async fn measure(
    gateway: &GatewayProcess,
    label: &str,
    window: Duration,
) -> anyhow::Result<Window> {
    let cpu_before = gateway.cpu_time()?;
    let from = Instant::now();
    let mut memory = Memory::default();
    while from.elapsed() < window {
        tokio::time::sleep(Duration::from_secs(1)).await;
        memory = memory.max(gateway.memory()?);
    }
    let cpu = (gateway.cpu_time()? - cpu_before).as_secs_f64() / from.elapsed().as_secs_f64();
    let measured = Window {
        label: label.to_string(),
        cpu_percent: cpu * 100.0,
        memory,
    };
    println!(
        "{:<44} CPU {:>6.2} % of a core   Anonymous {:>6.1} MiB   Pss {:>6.1} MiB",
        measured.label,
        measured.cpu_percent,
        measured.memory.anonymous_kib as f64 / 1024.0,
        measured.memory.pss_kib as f64 / 1024.0
    );
    Ok(measured)
}

async fn run() -> anyhow::Result<()> {
    let devices = env_number("CONSOLE_LOAD_DEVICES", 1000) as usize;
    let browsers = env_number("CONSOLE_LOAD_BROWSERS", 10) as usize;
    let warm_up = Duration::from_secs(env_number("CONSOLE_LOAD_WARMUP", 20));
    let window = Duration::from_secs(env_number("CONSOLE_LOAD_WINDOW", 30));
    println!(
        "console load: {devices} Modbus TCP devices × {POINTS} points, 1 s polls; {browsers} \
         browsers; windows of {} s after {} s of warm-up",
        window.as_secs(),
        warm_up.as_secs()
    );
    let files = tempfile::tempdir()?;
    let plant = ScalePlant::spawn(devices).await?;
    let binary = rtu2mqtt_testkit::child::gateway_binary();
    let mut windows = Vec::new();

    // 1. No console. Each gateway gets a broker of its own: one that kept the other's session
    // and retained topics would make it start differently.
    let broker = Mosquitto::start();
    let config = write_config(files.path(), &broker, &plant, None)?;
    let mut gateway = GatewayProcess::start(&binary, &config, "warn")?;
    tokio::time::sleep(warm_up).await;
    windows.push(measure(&gateway, "no [web]", window).await?);
    gateway.stop();

    // 2–4. The console on: no browser, B browsers, none again.
    drop(broker);
    let broker = Mosquitto::start();
    let port = free_port();
    let config = write_config(files.path(), &broker, &plant, Some(port))?;
    let mut gateway = GatewayProcess::start(&binary, &config, "warn")?;
    tokio::time::sleep(warm_up).await;
    windows.push(measure(&gateway, "console on, no browser", window).await?);
    let mut open = Vec::new();
    for _ in 0..browsers {
        let browser = Browser::start(1280, 900).await;
        browser
            .goto(&format!("http://127.0.0.1:{port}/#/plant"))
            .await;
        browser.wait_text("#live", |text| text == "live").await;
        open.push(browser);
    }
    // Every page has its snapshot and is following the plant.
    tokio::time::sleep(Duration::from_secs(5)).await;
    let values = open[0]
        .eval("return document.querySelectorAll('[data-device]').length;")
        .await;
    println!("each page lists {values} devices and follows every value");
    windows.push(
        measure(
            &gateway,
            &format!("console on, {browsers} browsers on Plant"),
            window,
        )
        .await?,
    );
    for browser in open {
        browser.close().await;
    }
    tokio::time::sleep(Duration::from_secs(3)).await;
    windows.push(measure(&gateway, "console on, browsers closed again", window).await?);
    gateway.stop();
    plant.stop();

    let without = windows[0].cpu_percent;
    let idle = (windows[1].cpu_percent + windows[3].cpu_percent) / 2.0;
    let watched = windows[2].cpu_percent;
    println!(
        "\nthe console, no browser: {:+.2} % of a core beside no [web]; {browsers} browsers: \
         {:+.2} % beside no browser (the mean of the windows before and after)",
        idle - without,
        watched - idle
    );
    Ok(())
}

/// `plant_scale`'s Modbus TCP configuration, with the console on `port` when given.
fn write_config(
    dir: &Path,
    broker: &Mosquitto,
    plant: &ScalePlant,
    console: Option<u16>,
) -> anyhow::Result<PathBuf> {
    let profile = scale_sim::profile_text(false);
    std::fs::write(dir.join("scale-meter.toml"), profile)?;
    let mut config = format!(
        "[mqtt]\nurl = \"{}\"\nclient_id = \"console-load\"\nprefix = \"plant\"\n\
         discovery = true\n\n[gateway]\njson_view = true\n\n[health]\nstatus_file = \"\"\n\n",
        broker.url()
    );
    if let Some(port) = console {
        let _ = write!(config, "[web]\nlisten = \"127.0.0.1:{port}\"\n\n");
    }
    for (index, addr) in plant.addrs.iter().enumerate() {
        let _ = write!(
            config,
            "[[lines]]\nname = \"line{index:04}\"\nurl = \"modbus-tcp://{addr}\"\n\n\
             [[lines.devices]]\nname = \"d{index:04}\"\nprofile = \"scale-meter.toml\"\n\
             address = 1\npoll_interval = \"1s\"\n\n"
        );
    }
    let path = dir.join("rtu2mqtt.toml");
    std::fs::write(&path, config)?;
    Ok(path)
}
