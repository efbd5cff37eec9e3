//! Acceptance checks found by driving the gateway as a user would: the seed plant on pty lines,
//! a real mosquitto, commands published by an MQTT client or `mosquitto_pub`, configurations
//! checked with the `rtu2mqtt check` binary. Each test was written failing, against a bug seen
//! that way, and stays as its regression test.

use crate::support;

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use rtu2mqtt::config::{self, Config};
use rtu2mqtt_sim::{self as sim, SeedPlant};
use support::child::{self, KillOnDrop};
use support::{Gateway, Mosquitto, PlantConfig, TestClient};

/// Generous bound for a busy 2-core machine: it only runs out when something is broken.
const ANSWER: Duration = Duration::from_secs(15);

/// Over the gateway's 1 MiB incoming packet limit, far under mosquitto's own limit.
const OVERSIZED: usize = 2 * 1024 * 1024;

fn plant_config(broker: &Mosquitto, plant: &SeedPlant, client_id: &str) -> Config {
    let text = PlantConfig {
        line_keys: "offline_after = 2",
        ..PlantConfig::default()
    }
    .text(broker, plant, client_id);
    config::from_str(&text, Path::new(".")).unwrap()
}

/// Publishes `payload` with `mosquitto_pub` (QoS 1), as a user or a misbehaving client would.
fn mosquitto_pub(port: u16, topic: &str, payload: &[u8], retain: bool) {
    let mut args = vec![
        "-p".to_string(),
        port.to_string(),
        "-q".to_string(),
        "1".to_string(),
        "-t".to_string(),
        topic.to_string(),
        "-s".to_string(),
    ];
    if retain {
        args.push("-r".to_string());
    }
    let mut child = Command::new("mosquitto_pub")
        .args(&args)
        .stdin(Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(payload).unwrap();
    assert!(child.wait().unwrap().success());
}

/// The seed plant with the dust collector powered on, a broker, the gateway, and an observer
/// subscribed to results and availability only (not to `…/set`, so that an oversized command
/// cannot disturb the observer itself).
async fn plant_with_gateway(name: &str) -> (Mosquitto, SeedPlant, TestClient, Gateway) {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap();
    sim::lock(&plant.dust_collector).set_power(true);
    let mut observer = TestClient::connect(broker.port, &format!("{name}-observer")).await;
    observer.subscribe("plant/+/+/result").await;
    observer.subscribe("plant/+/availability").await;
    let gateway = Gateway::start(plant_config(&broker, &plant, &format!("{name}-gw"))).await;
    observer
        .wait_for("plant/dust_collector/availability", ANSWER, |m| {
            m.text() == "online"
        })
        .await;
    (broker, plant, observer, gateway)
}

/// A command after the oversized one is still executed: the link to the broker works.
async fn gear_command_is_applied(observer: &mut TestClient, gear: &str) {
    observer
        .publish(
            "plant/dust_collector/gear/set",
            gear.as_bytes().to_vec(),
            false,
        )
        .await;
    let result = observer
        .next_on("plant/dust_collector/gear/result", ANSWER)
        .await
        .json();
    assert_eq!(result["outcome"], "applied", "{result}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_oversized_retained_command_does_not_cut_the_gateway_off() {
    let (broker, _plant, mut observer, gateway) = plant_with_gateway("oversized-retained").await;
    mosquitto_pub(
        broker.port,
        "plant/dust_collector/pulse_duration/set",
        &vec![b'5'; OVERSIZED],
        true,
    );
    // docs/reliability.md B5/B7: refused with a reason, not a disconnect.
    let result = observer
        .next_on("plant/dust_collector/pulse_duration/result", ANSWER)
        .await
        .json();
    assert_eq!(result["outcome"], "rejected", "{result}");
    gear_command_is_applied(&mut observer, "8").await;
    gateway.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_oversized_qos1_command_does_not_cut_the_gateway_off() {
    let (broker, _plant, mut observer, gateway) = plant_with_gateway("oversized-qos1").await;
    mosquitto_pub(
        broker.port,
        "plant/dust_collector/pulse_duration/set",
        &vec![b'5'; OVERSIZED],
        false,
    );
    // Give the broker time to offer it (and the gateway time to fall over if it does).
    tokio::time::sleep(Duration::from_secs(3)).await;
    gear_command_is_applied(&mut observer, "7").await;
    gateway.stop().await;
}

fn check(config_text: &str) -> (bool, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("config.toml");
    std::fs::write(&path, config_text).unwrap();
    let output = Command::new(child::gateway_binary())
        .arg("check")
        .arg("--config")
        .arg(&path)
        .env_remove("RTU2MQTT_CONFIG")
        .output()
        .unwrap();
    let mut text = String::from_utf8_lossy(&output.stdout).into_owned();
    text.push_str(&String::from_utf8_lossy(&output.stderr));
    (output.status.success(), text)
}

const SEED_CONFIG: &str = include_str!("../../../config/rtu2mqtt.toml");

#[test]
fn check_lists_an_unknown_key_and_a_wrong_type_together() {
    let text = SEED_CONFIG
        .replacen("prefix = \"plant\"", "prefix = \"plant\"\ncolour = 1", 1)
        .replacen("baud = 9600", "baud = \"fast\"", 1);
    let (ok, output) = check(&text);
    assert!(!ok, "{output}");
    assert!(output.contains("mqtt.colour"), "{output}");
    assert!(output.contains("lines[0].baud"), "{output}");
}

#[test]
fn a_wrong_typed_value_names_its_place_like_every_other_error() {
    let text = SEED_CONFIG.replacen("baud = 9600", "baud = \"fast\"", 1);
    let (ok, output) = check(&text);
    assert!(!ok, "{output}");
    assert!(output.contains("lines[0].baud"), "{output}");
    let text = SEED_CONFIG.replacen("parity = \"even\"", "parity = \"mark\"", 1);
    let (ok, output) = check(&text);
    assert!(!ok, "{output}");
    assert!(output.contains("lines[1].parity"), "{output}");
    assert!(!output.contains("variant constructor"), "{output}");
}

#[test]
fn every_broken_configuration_is_an_error_naming_its_place() {
    let cases: &[(&str, &str, &str)] = &[
        (
            "prefix = \"plant\"",
            "prefix = \"plant\"\ncolour = \"red\"",
            "mqtt.colour",
        ),
        (
            "name = \"air_shower\"",
            "name = \"dust_collector\"",
            "lines[0].devices[1].name",
        ),
        ("address = 1", "address = 0", "lines[0].devices[0].address"),
        (
            "address = 1",
            "address = 248",
            "lines[0].devices[0].address",
        ),
        (
            "address = 0x81",
            "address = 1",
            "lines[0].devices[1].address",
        ),
        (
            "poll_interval = \"1s\"",
            "poll_interval = \"500ms\"",
            "lines[0].devices[0].poll_interval",
        ),
        ("baud = 9600", "baud = 12345", "lines[0].baud"),
        ("prefix = \"plant\"", "prefix = \"pl#ant\"", "mqtt.prefix"),
        (
            "prefix = \"plant\"",
            "prefix = \"plant\"\nkeep_alive = \"0.5s\"",
            "mqtt.keep_alive",
        ),
        (
            "prefix = \"plant\"",
            "prefix = \"plant\"\ninflight = 0",
            "mqtt.inflight",
        ),
        (
            "profile = \"wuzhou-valve\"",
            "profile = \"profiles/missing.toml\"",
            "lines[1].devices[0].profile",
        ),
        ("prefix = \"plant\"", "prefix = \"plant", "line 8"),
    ];
    for (from, to, place) in cases {
        assert!(SEED_CONFIG.contains(from), "{from}");
        let (ok, output) = check(&SEED_CONFIG.replacen(from, to, 1));
        assert!(!ok, "{to}: accepted\n{output}");
        assert!(output.contains(place), "{to}: {place} not named\n{output}");
        assert!(!output.contains("panicked"), "{to}: {output}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_on_a_shared_broker_leaves_a_running_gateway_alone() {
    use nix::sys::signal::{kill, Signal};

    let (broker, _plant, _observer, gateway) = plant_with_gateway("demo-shared").await;
    let mut command = Command::new(child::binary("rtu2mqtt-demo"));
    command
        .args(["--log", "--broker", &broker.url()])
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    let mut demo = KillOnDrop::spawn(command).expect("rtu2mqtt-demo starts");
    // Long enough for the demo's devices to come online and publish their state.
    tokio::time::sleep(Duration::from_secs(6)).await;
    kill(demo.pid(), Signal::SIGINT).unwrap();
    let deadline = std::time::Instant::now() + ANSWER;
    while demo.0.try_wait().unwrap().is_none() {
        assert!(std::time::Instant::now() < deadline, "demo did not stop");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }

    // What a client connecting now is told about the real gateway's devices.
    let mut fresh = TestClient::connect(broker.port, "demo-shared-fresh").await;
    fresh.subscribe("plant/+/availability").await;
    fresh.settle(Duration::from_secs(2)).await;
    for device in ["dust_collector", "air_shower", "valve"] {
        let topic = format!("plant/{device}/availability");
        let last = fresh.on(&topic).last().map(|m| m.text());
        assert_eq!(last.as_deref(), Some("online"), "{topic}");
    }
    gateway.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn home_assistant_numbers_can_hold_the_values_the_gateway_publishes() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap();
    let mut config = plant_config(&broker, &plant, "ha-range-gw");
    config.mqtt.discovery = true;
    let mut observer = TestClient::connect(broker.port, "ha-range-observer").await;
    observer.subscribe("homeassistant/device/+/config").await;
    observer.subscribe("plant/valve/+").await;
    let gateway = Gateway::start(config).await;
    let document = observer
        .next_on("homeassistant/device/ha-range-gw_valve/config", ANSWER)
        .await
        .json();
    // The slow configuration block holds the alarm openings and ratios; its last number is the
    // regulation ratio.
    observer
        .wait_for("plant/valve/regulation_ratio", ANSWER, |_| true)
        .await;
    let components = document["cmps"].as_object().unwrap();
    let mut checked = 0;
    for (field, component) in components {
        // A select of integers (the alarm openings: 0–100 or 255) must list every state.
        if component["p"] == "select" {
            let topic = format!("plant/valve/{field}");
            if let Some(state) = observer.on(&topic).last().map(|m| m.text()) {
                let options = component["options"].as_array().unwrap();
                assert!(
                    options.iter().any(|option| option == state.as_str()),
                    "{topic} = {state}, not an option of the entity"
                );
            }
            continue;
        }
        if component["p"] != "number" {
            continue;
        }
        let topic = format!("plant/valve/{field}");
        let Some(state) = observer.on(&topic).last().map(|m| m.text()) else {
            continue;
        };
        let value: f64 = state.parse().unwrap();
        let min = component["min"].as_f64().unwrap();
        let max = component["max"].as_f64().unwrap();
        assert!(
            (min..=max).contains(&value),
            "{topic} = {value}, outside the entity's {min}–{max}"
        );
        checked += 1;
    }
    assert!(checked > 10, "only {checked} number states seen");
    gateway.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_valve_target_during_a_settling_move_is_not_reported_as_offline() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap();
    let mut config = plant_config(&broker, &plant, "settle-gw");
    config.gateway.command_ttl = Duration::from_secs(3);
    let mut observer = TestClient::connect(broker.port, "settle-observer").await;
    observer.subscribe("plant/valve/opening/result").await;
    observer.subscribe("plant/valve/availability").await;
    let gateway = Gateway::start(config).await;
    observer
        .wait_for("plant/valve/availability", ANSWER, |m| m.text() == "online")
        .await;
    // The simulated motor needs several seconds from 30 % to 100 %.
    observer
        .publish("plant/valve/opening/set", b"100".to_vec(), false)
        .await;
    tokio::time::sleep(Duration::from_secs(1)).await;
    observer
        .publish("plant/valve/opening/set", b"50".to_vec(), false)
        .await;
    let result = observer
        .wait_for("plant/valve/opening/result", Duration::from_secs(90), |m| {
            m.json()["value"] == "50"
        })
        .await
        .json();
    assert_eq!(result["outcome"], "applied", "{result}");
    gateway.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_statistics_document_is_retained() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap();
    let mut config = plant_config(&broker, &plant, "stats-gw");
    config.gateway.stats_interval = Duration::from_secs(1);
    let mut observer = TestClient::connect(broker.port, "stats-observer").await;
    observer.subscribe("plant/gateway/stats-gw/stats").await;
    let gateway = Gateway::start(config).await;
    observer
        .wait_for("plant/gateway/stats-gw/stats", ANSWER, |_| true)
        .await;
    // A client arriving later gets the last document at once, as a retained message.
    let mut late = TestClient::connect(broker.port, "stats-late").await;
    late.subscribe("plant/gateway/stats-gw/stats").await;
    let first = late
        .wait_for("plant/gateway/stats-gw/stats", ANSWER, |_| true)
        .await;
    assert!(
        first.retain,
        "the first statistics document came live, not retained"
    );
    gateway.stop().await;
}
