//! `rtu2mqtt run` reloading its configuration on SIGHUP, as a child process: the seed plant is
//! simulated on ptys, the broker is a real mosquitto. One line's configuration changes (the
//! dust collector is removed from line-a) while line-b keeps its poll cadence and its task; the
//! changed line restarts; a command waiting for an offline device (the air shower) survives the
//! reload and runs once the device answers; the removed device's retained state, availability
//! and discovery document are cleared. An invalid configuration on SIGHUP is refused with its
//! problems logged and the running one kept.

use crate::support;

use std::path::Path;
use std::time::{Duration, Instant};

use nix::sys::signal::{kill, Signal};
use rtu2mqtt::topics::Topics;
use rtu2mqtt_sim::SeedPlant;
use support::child::{self, KillOnDrop};
use support::{Mosquitto, PlantConfig, TestClient};

const CLIENT_ID: &str = "reload-test";
/// The valve's poll interval (the profile's default), line-b's cadence.
const VALVE_POLL: Duration = Duration::from_secs(1);
/// Timer and scheduling jitter on a busy shared machine, on top of the poll interval. A line
/// restart also shows in the log (a second "starting line"), which is asserted separately.
const JITTER: Duration = Duration::from_millis(100);
const AIR_SHOWER: u8 = 0x81;
/// Bound for the daemon to start and reach the broker on a busy machine.
const START: Duration = Duration::from_secs(30);

/// Waits until the log at `path` contains `wanted`; the log so far.
async fn wait_for_log(path: &Path, wanted: &str, timeout: Duration) -> String {
    let deadline = Instant::now() + timeout;
    loop {
        let log = std::fs::read_to_string(path).unwrap_or_default();
        if log.contains(wanted) {
            return log;
        }
        assert!(
            Instant::now() < deadline,
            "no {wanted:?} in the log:\n{log}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Lines of `log` that contain every word of `words`.
fn count_lines(log: &str, words: &[&str]) -> usize {
    log.lines()
        .filter(|line| words.iter().all(|word| line.contains(word)))
        .count()
}

/// The retained messages a fresh client gets on `filter` (non-empty payloads only).
async fn retained(port: u16, id: &str, filter: &str) -> Vec<String> {
    let mut client = TestClient::connect(port, id).await;
    client.subscribe(filter).await;
    client.settle(Duration::from_millis(800)).await;
    client
        .received
        .iter()
        .filter(|message| message.retain && !message.payload.is_empty())
        .map(|message| format!("{} = {}", message.topic, message.text()))
        .collect()
}

/// The body of `GET path` on the metrics endpoint (empty when it cannot be reached).
async fn http_get(port: u16, path: &str) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let Ok(mut stream) = tokio::net::TcpStream::connect(("127.0.0.1", port)).await else {
        return String::new();
    };
    let request = format!("GET {path} HTTP/1.1\r\nHost: test\r\n\r\n");
    if stream.write_all(request.as_bytes()).await.is_err() {
        return String::new();
    }
    let mut response = String::new();
    let _ = stream.read_to_string(&mut response).await;
    response
}

/// The longest gap between two valve requests seen on line-b from `from` to `to`.
fn longest_gap(plant: &SeedPlant, from: Instant, to: Instant) -> Duration {
    let arrivals: Vec<Instant> = plant
        .line_b
        .journal()
        .requests()
        .into_iter()
        .map(|record| record.arrived)
        .filter(|arrived| *arrived >= from && *arrived <= to)
        .collect();
    assert!(
        arrivals.len() >= 3,
        "line-b was hardly polled: {arrivals:?}"
    );
    arrivals
        .windows(2)
        .map(|pair| pair[1].duration_since(pair[0]))
        .max()
        .unwrap_or_default()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_reloads_one_line_and_keeps_the_other_polling() {
    let plant = SeedPlant::spawn(false).expect("simulated plant");
    // Offline from the start: its command has to wait.
    plant.line_a.faults().silence(AIR_SHOWER, true);
    let mosquitto = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let config_path = dir.path().join("config.toml");
    let log_path = dir.path().join("rtu2mqtt.log");
    let metrics_port = support::free_port();
    let gateway = format!("metrics_listen = \"127.0.0.1:{metrics_port}\"");
    let first = PlantConfig {
        discovery: true,
        gateway: &gateway,
        ..PlantConfig::default()
    }
    .text(&mosquitto, &plant, CLIENT_ID);
    std::fs::write(&config_path, &first).expect("write config");

    let log = std::fs::File::create(&log_path).expect("log file");
    let mut command = child::gateway_run(&config_path);
    command.env("RUST_LOG", "info").stderr(log);
    let mut daemon = KillOnDrop::spawn(command).expect("rtu2mqtt run starts");

    let port = mosquitto.port;
    let topics = Topics::new(CLIENT_ID, "plant");
    let mut client = TestClient::connect(port, "reload-observer").await;
    client.subscribe("plant/#").await;
    client.subscribe("homeassistant/#").await;
    client
        .wait_for("plant/dust_collector/availability", START, |m| {
            m.text() == "online"
        })
        .await;
    client
        .wait_for("plant/valve/availability", START, |m| m.text() == "online")
        .await;
    client
        .wait_for("plant/air_shower/availability", START, |m| {
            m.text() == "offline"
        })
        .await;
    assert!(
        !retained(port, "before", "plant/dust_collector/#")
            .await
            .is_empty(),
        "no retained state of the dust collector before the reload"
    );
    let dust_config = topics.config_topic("dust_collector");
    assert_eq!(retained(port, "config-before", &dust_config).await.len(), 1);

    // A command for the offline air shower waits in the gateway (not retained: only the
    // gateway's memory keeps it).
    client
        .publish("plant/air_shower/light/set", "ON", false)
        .await;
    tokio::time::sleep(Duration::from_millis(500)).await;

    // SIGHUP never ends the process, even before any change.
    kill(daemon.pid(), Signal::SIGHUP).expect("SIGHUP");
    wait_for_log(&log_path, "configuration reloaded", Duration::from_secs(10)).await;
    assert!(daemon.is_running(), "SIGHUP ended the daemon");

    // Line-a loses the dust collector; line-b is unchanged.
    let dust_block = "[[lines.devices]]\nname = \"dust_collector\"\nprofile = \"ruiwan-dust-collector\"\naddress = 1\n";
    assert!(
        first.contains(dust_block),
        "the plant configuration changed shape"
    );
    let second = first.replace(dust_block, "");
    std::fs::write(&config_path, &second).expect("write config");
    let reload_at = Instant::now();
    kill(daemon.pid(), Signal::SIGHUP).expect("SIGHUP");
    let log = wait_for_log(
        &log_path,
        "kept=1 restarted=1 started=0 stopped=0",
        Duration::from_secs(10),
    )
    .await;
    // The dust collector's retained topics and discovery document are cleared.
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let left = retained(port, "after", "plant/dust_collector/#").await;
        let config = retained(port, "config-after", &dust_config).await;
        if left.is_empty() && config.is_empty() {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "left after the reload: {left:?} {config:?}"
        );
    }
    // The metrics endpoint follows: the restarted line-a without the dust collector.
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let metrics = http_get(metrics_port, "/metrics").await;
        if !metrics.contains("device=\"dust_collector\"")
            && metrics.contains("device=\"air_shower\"")
            && metrics.contains("device=\"valve\"")
        {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "stale metrics after the reload:\n{metrics}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    tokio::time::sleep(Duration::from_secs(2)).await;
    // Line-b polled on without a gap longer than its poll interval, on its first task.
    let gap = longest_gap(&plant, reload_at - Duration::from_secs(2), Instant::now());
    eprintln!("line-b's longest pause between requests over the reload: {gap:?}");
    assert!(
        gap <= VALVE_POLL + JITTER,
        "line-b paused {gap:?} over the reload"
    );
    let log_now = std::fs::read_to_string(&log_path).unwrap_or(log);
    assert_eq!(
        count_lines(&log_now, &["starting line", "line=line-b"]),
        1,
        "line-b was restarted:\n{log_now}"
    );
    assert_eq!(
        count_lines(&log_now, &["starting line", "line=line-a"]),
        2,
        "line-a was not restarted:\n{log_now}"
    );
    // Line-a no longer asks the dust collector anything.
    let since_reload = Instant::now();
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let asked_dust_collector = plant
        .line_a
        .journal()
        .requests()
        .into_iter()
        .filter(|record| record.arrived >= since_reload && record.frame.first() == Some(&1))
        .count();
    assert_eq!(
        asked_dust_collector, 0,
        "the removed device is still polled"
    );

    // The waiting command survived: the air shower answers again and it runs.
    client.forget();
    plant.line_a.faults().silence(AIR_SHOWER, false);
    let result = client
        .next_on("plant/air_shower/light/result", Duration::from_secs(20))
        .await;
    assert_eq!(result.json()["outcome"], "applied", "{}", result.text());

    // An invalid configuration is refused, every problem logged; the running one is kept.
    let invalid = second.replace("address = 0x81", "address = 300");
    assert_ne!(invalid, second);
    std::fs::write(&config_path, &invalid).expect("write config");
    kill(daemon.pid(), Signal::SIGHUP).expect("SIGHUP");
    let log = wait_for_log(&log_path, "reload refused", Duration::from_secs(10)).await;
    assert!(
        count_lines(&log, &["configuration problem", "address", "300"]) >= 1,
        "{log}"
    );
    assert!(daemon.is_running(), "an invalid reload ended the daemon");
    let before = Instant::now();
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let gap = longest_gap(&plant, before, Instant::now());
    assert!(
        gap <= VALVE_POLL + JITTER,
        "line-b paused {gap:?} after a refused reload"
    );

    kill(daemon.pid(), Signal::SIGTERM).expect("SIGTERM");
    let deadline = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Ok(Some(status)) = daemon.0.try_wait() {
            break status;
        }
        assert!(Instant::now() < deadline, "no stop within 20 s of SIGTERM");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert!(status.success(), "{status:?}");
}

/// A fresh installation: the packaged configuration has no lines. The daemon runs idle (its
/// status online, nothing polled), and the administrator's lines start polling on SIGHUP,
/// without a restart.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_idle_gateway_without_lines_starts_polling_when_a_reload_adds_them() {
    let plant = SeedPlant::spawn(false).expect("simulated plant");
    let mosquitto = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let config_path = dir.path().join("config.toml");
    let log_path = dir.path().join("rtu2mqtt.log");
    let full = PlantConfig::default().text(&mosquitto, &plant, CLIENT_ID);
    let idle = full
        .split("[[lines]]")
        .next()
        .expect("the [mqtt] table")
        .to_string();
    assert!(!idle.contains("devices"), "{idle}");
    std::fs::write(&config_path, &idle).expect("write config");

    let log = std::fs::File::create(&log_path).expect("log file");
    let mut command = child::gateway_run(&config_path);
    command.env("RUST_LOG", "info").stderr(log);
    let mut daemon = KillOnDrop::spawn(command).expect("rtu2mqtt run starts");
    let mut client = TestClient::connect(mosquitto.port, "idle-observer").await;
    client.subscribe("plant/#").await;
    client
        .wait_for(&format!("plant/gateway/{CLIENT_ID}/status"), START, |m| {
            m.text() == "online"
        })
        .await;
    wait_for_log(
        &log_path,
        "no [[lines]] configured",
        Duration::from_secs(10),
    )
    .await;
    client.settle(Duration::from_secs(1)).await;
    assert!(
        plant.line_a.journal().frames().is_empty() && plant.line_b.journal().frames().is_empty(),
        "an idle gateway polled a port"
    );
    assert!(client.on("plant/valve/availability").is_empty());

    std::fs::write(&config_path, &full).expect("write config");
    kill(daemon.pid(), Signal::SIGHUP).expect("SIGHUP");
    wait_for_log(&log_path, "started=2", Duration::from_secs(10)).await;
    client
        .wait_for("plant/valve/availability", START, |m| m.text() == "online")
        .await;
    client
        .wait_for("plant/dust_collector/availability", START, |m| {
            m.text() == "online"
        })
        .await;
    assert!(daemon.is_running(), "the reload ended the daemon");
}
