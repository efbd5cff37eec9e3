//! The bridge's promises under pressure, on a real mosquitto with the simulated seed plant:
//! every command gets exactly one outcome (floods from several clients, identical commands
//! milliseconds apart, commands for devices that are not configured), statistics are there
//! from the start, and the gateway's own topics are set right when someone overwrites them.
//! Outcomes are counted on the broker by an observing client.

use crate::support;

use std::collections::HashMap;
use std::time::{Duration, Instant};

use nix::sys::signal::{kill, Signal};
use rtu2mqtt_sim::{self as sim, SeedPlant};
use rumqttc::QoS;
use support::child::{self, KillOnDrop};
use support::{Mosquitto, PlantBench, PlantConfig, TestClient};

/// Generous bound for a busy 2-core machine: it only runs out when something is broken.
const ANSWER: Duration = Duration::from_secs(15);

/// The plant bench with `broker_extra`, the gateway as `<name>-gw` configured by `config`, and
/// the observer on `observe` as well as `plant/#`; the dust collector runs.
async fn start(
    broker_extra: &str,
    name: &str,
    config: PlantConfig<'_>,
    observe: &[&str],
) -> PlantBench {
    let mut setup = PlantBench::setup(name)
        .broker_extra(broker_extra)
        .prepare(|plant| sim::lock(&plant.dust_collector).set_power(true))
        .config(move |broker, plant, client_id| config.text(broker, plant, client_id));
    for filter in observe {
        setup = setup.observe(filter);
    }
    setup.start().await
}

/// The retained message on `topic` as a new subscriber gets it (None when there is none).
async fn retained(port: u16, id: &str, topic: &str) -> Option<String> {
    let mut client = TestClient::connect(port, id).await;
    client.subscribe(topic).await;
    client.settle(Duration::from_millis(500)).await;
    client.on(topic).iter().find(|m| m.retain).map(|m| m.text())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_command_of_a_three_client_qos0_flood_gets_exactly_one_outcome() {
    // A stock mosquitto: its queue bound for a subscriber that falls behind is not reached.
    let mut bench = start("", "flood3", PlantConfig::default(), &[]).await;
    const CLIENTS: usize = 3;
    const EACH: usize = 1_000;
    let result_topic = "plant/dust_collector/gear/result";
    let mut counter = TestClient::connect(bench.broker.port, "flood3-counter").await;
    counter.subscribe(result_topic).await;
    let mut senders = Vec::new();
    for client in 0..CLIENTS {
        senders
            .push(TestClient::connect(bench.broker.port, &format!("flood3-sender-{client}")).await);
    }
    let started = Instant::now();
    let mut floods = Vec::new();
    for (client, sender) in senders.iter().enumerate() {
        let mqtt = sender.client.clone();
        floods.push(tokio::spawn(async move {
            for index in 0..EACH {
                mqtt.publish(
                    "plant/dust_collector/gear/set",
                    QoS::AtMostOnce,
                    false,
                    format!("bad-{client}-{index}").into_bytes(),
                )
                .await
                .expect("publish");
            }
        }));
    }
    for flood in floods {
        flood.await.expect("flood task");
    }
    let total = CLIENTS * EACH;
    let mut seen: HashMap<String, Vec<String>> = HashMap::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut outcomes = 0;
    while outcomes < total && Instant::now() < deadline {
        let Some(message) = counter
            .try_wait_for(result_topic, Duration::from_secs(10), |_| true)
            .await
        else {
            break;
        };
        let json = message.json();
        let value = json["value"].as_str().unwrap_or_default().to_string();
        let outcome = json["outcome"].as_str().unwrap_or_default().to_string();
        seen.entry(value).or_default().push(outcome);
        outcomes += 1;
    }
    let elapsed = started.elapsed();
    // Nothing more after the last one: exactly one each.
    counter.settle(Duration::from_secs(1)).await;
    let late = counter.on(result_topic).len();
    eprintln!(
        "figure: {total} commands from {CLIENTS} clients, {outcomes} outcomes in {elapsed:?} ({:.0} commands/s)",
        total as f64 / elapsed.as_secs_f64()
    );
    assert_eq!(late, 0, "outcomes beyond one per command");
    assert_eq!(outcomes, total, "every command has its outcome");
    for client in 0..CLIENTS {
        for index in 0..EACH {
            let value = format!("bad-{client}-{index}");
            let outcomes = seen.get(&value).cloned().unwrap_or_default();
            assert_eq!(outcomes, ["rejected"], "{value}");
        }
    }
    // The line kept working: a real command still runs.
    bench.observer.forget();
    bench
        .observer
        .publish("plant/dust_collector/gear/set", "4", false)
        .await;
    let applied = bench
        .observer
        .wait_for(result_topic, ANSWER, |m| m.json()["value"] == "4")
        .await
        .json();
    assert_eq!(applied["outcome"], "applied", "{applied}");
    bench.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn five_identical_commands_within_10_ms_get_five_outcomes() {
    let mut bench = start("", "five", PlantConfig::default(), &[]).await;
    let result_topic = "plant/dust_collector/gear/result";
    bench.observer.forget();
    let started = Instant::now();
    for _ in 0..5 {
        bench
            .observer
            .publish("plant/dust_collector/gear/set", "6", false)
            .await;
    }
    assert!(started.elapsed() < Duration::from_millis(10) * 5);
    let mut outcomes = Vec::new();
    for _ in 0..5 {
        let result = bench.observer.next_on(result_topic, ANSWER).await.json();
        assert_eq!(result["value"], "6");
        outcomes.push(result["outcome"].as_str().unwrap_or_default().to_string());
    }
    bench.observer.settle(Duration::from_secs(1)).await;
    assert!(bench.observer.on(result_topic).is_empty(), "exactly five");
    outcomes.sort();
    assert!(
        outcomes.iter().all(|o| o == "applied" || o == "superseded"),
        "{outcomes:?}"
    );
    assert!(outcomes.contains(&"applied".to_string()), "{outcomes:?}");
    assert_eq!(sim::lock(&bench.plant.dust_collector).gear(), 6);
    // The commands were not retained, yet each outcome is followed by an empty retained
    // message on `…/set` (MQTT 3.1.1 does not say whether a live message was retained): no
    // retained command is left behind.
    assert!(!bench
        .observer
        .on("plant/dust_collector/gear/set")
        .is_empty());
    assert_eq!(
        retained(
            bench.broker.port,
            "five-late",
            "plant/dust_collector/gear/set"
        )
        .await,
        None
    );
    bench.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_command_for_an_unknown_device_is_rejected_naming_the_configured_ones() {
    let mut bench = start("", "unknown", PlantConfig::default(), &[]).await;
    bench
        .observer
        .publish("plant/dust_colector/gear/set", "5", false)
        .await;
    let result = bench
        .observer
        .next_on("plant/dust_colector/gear/result", ANSWER)
        .await
        .json();
    assert_eq!(result["outcome"], "rejected", "{result}");
    assert_eq!(result["value"], "5");
    let detail = result["detail"].as_str().unwrap_or_default();
    for device in ["dust_collector", "air_shower", "valve"] {
        assert!(detail.contains(device), "{detail}");
    }
    bench.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn statistics_are_published_at_start_and_when_home_assistant_comes_online() {
    // The default statistics interval (a minute) is far longer than this test.
    let config = PlantConfig {
        discovery: true,
        ..PlantConfig::default()
    };
    let stats = "plant/gateway/stats-gw/stats";
    let mut bench = start("", "stats", config, &[]).await;
    let first = bench.observer.next_on(stats, Duration::from_secs(5)).await;
    assert!(first.json().is_object(), "{}", first.text());
    bench.observer.settle(Duration::from_millis(300)).await;
    bench.observer.forget();
    bench
        .observer
        .publish("homeassistant/status", "online", false)
        .await;
    // Home Assistant's birth: discovery, state and statistics follow within its delay.
    bench.observer.next_on(stats, Duration::from_secs(10)).await;
    // And after a reconnect.
    bench.broker.kill();
    bench.broker.restart();
    let mut again = TestClient::connect(bench.broker.port, "stats-after").await;
    again.subscribe(stats).await;
    again.next_on(stats, ANSWER).await;
    bench.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_gateway_sets_its_overwritten_topics_right() {
    let mut bench = start("", "guard", PlantConfig::default(), &[]).await;
    bench.wait_text("plant/dust_collector/power", "ON").await;
    let gear = sim::lock(&bench.plant.dust_collector).gear().to_string();
    bench.wait_text("plant/dust_collector/gear", &gear).await;
    let port = bench.broker.port;
    let intruder = TestClient::connect(port, "guard-intruder").await;
    let cases = [
        (
            "plant/gateway/guard-gw/status",
            "offline",
            "online".to_string(),
        ),
        ("plant/valve/availability", "offline", "online".to_string()),
        ("plant/dust_collector/gear", "99", gear.clone()),
    ];
    for (topic, fake, truth) in cases {
        bench.observer.drain();
        bench.observer.forget();
        intruder.publish(topic, fake, true).await;
        bench.wait_text(topic, fake).await;
        bench.wait_text(topic, &truth).await;
        assert_eq!(
            retained(port, &format!("guard-late-{fake}"), topic)
                .await
                .as_deref(),
            Some(truth.as_str()),
            "{topic}"
        );
    }
    // No loop: once set right, the topic stays quiet.
    bench.observer.settle(Duration::from_secs(2)).await;
    bench.observer.forget();
    bench.observer.settle(Duration::from_secs(2)).await;
    assert!(
        bench
            .observer
            .on("plant/gateway/guard-gw/status")
            .is_empty(),
        "no loop"
    );
    // It found the fake state by auditing the device's topics in its turn, never by
    // subscribing to every device's state (which would bring all of its own traffic back).
    let filters = subscriptions(&bench.broker.log(), "guard-gw");
    assert!(
        filters.iter().any(|f| f == "plant/dust_collector/+"),
        "{filters:?}"
    );
    assert!(!filters.iter().any(|f| f == "plant/+/+"), "{filters:?}");
    assert!(
        bench
            .broker
            .log()
            .contains("Received UNSUBSCRIBE from guard-gw"),
        "every audit ends"
    );
    // Another gateway's status is its own business.
    intruder
        .publish("plant/gateway/other-gw/status", "offline", true)
        .await;
    bench.observer.settle(Duration::from_secs(2)).await;
    let other: Vec<String> = bench
        .observer
        .on("plant/gateway/other-gw/status")
        .iter()
        .map(|m| m.text())
        .collect();
    assert_eq!(other, ["offline"]);
    bench.stop().await;
}

/// Every filter `client_id` subscribed to, as mosquitto's log (`log_type all`) tells them: the
/// line `Received SUBSCRIBE from <client_id>` is followed by one tab-indented line per filter.
fn subscriptions(log: &str, client_id: &str) -> Vec<String> {
    let header = format!("Received SUBSCRIBE from {client_id}");
    let mut filters = Vec::new();
    let mut in_subscribe = false;
    for line in log.lines() {
        let text = line.split_once(": ").map_or(line, |(_, text)| text);
        if text == header {
            in_subscribe = true;
        } else if let Some(filter) = text.strip_prefix('\t').filter(|_| in_subscribe) {
            let filter = filter.split(" (QoS").next().unwrap_or(filter);
            filters.push(filter.to_string());
        } else if !text.starts_with(&format!("{client_id} ")) {
            in_subscribe = false;
        }
    }
    filters
}

/// A gateway binary with its stderr in `<name>.log`; killed when dropped.
fn spawn_daemon(dir: &std::path::Path, name: &str, config: &str) -> KillOnDrop {
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, config).expect("write config");
    let log = std::fs::File::create(dir.join(format!("{name}.log"))).expect("log file");
    let mut command = child::gateway_run(&path);
    command
        .env(
            "RTU2MQTT__HEALTH__STATUS_FILE",
            dir.join(format!("{name}.health")),
        )
        .env("RUST_LOG", "warn")
        .stderr(log);
    KillOnDrop::spawn(command).expect("rtu2mqtt run starts")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_gateways_with_one_client_id_say_so_once() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let plants = [
        SeedPlant::spawn(false).unwrap(),
        SeedPlant::spawn(false).unwrap(),
    ];
    let daemons: Vec<KillOnDrop> = plants
        .iter()
        .enumerate()
        .map(|(index, plant)| {
            let text = PlantConfig::default().text(&broker, plant, "twin-gw");
            spawn_daemon(dir.path(), &format!("twin-{index}"), &text)
        })
        .collect();
    let said = "another client probably uses the same client id";
    let read_logs = || -> Vec<String> {
        (0..2)
            .map(|index| {
                std::fs::read_to_string(dir.path().join(format!("twin-{index}.log")))
                    .unwrap_or_default()
            })
            .collect()
    };
    let deadline = Instant::now() + Duration::from_secs(40);
    while !read_logs().iter().any(|log| log.contains(said)) && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // Some more turns of the clash: still said once per gateway.
    tokio::time::sleep(Duration::from_secs(3)).await;
    drop(daemons);
    let logs = read_logs();
    eprintln!("{}", logs.join("\n---\n"));
    let counts: Vec<usize> = logs.iter().map(|log| log.matches(said).count()).collect();
    assert!(counts.contains(&1), "{counts:?}: {logs:?}");
    assert!(counts.iter().all(|n| *n <= 1), "{counts:?}");
    assert!(
        logs.iter().any(|log| log.contains("twin-gw")),
        "names the client id"
    );
}

/// After a clean stop the broker keeps the gateway's own retained `offline`; the next start
/// receives it when it subscribes, just before its `online` replaces it. That is the
/// gateway's earlier word, not another client's, and is not reported as one.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restart_does_not_take_its_own_earlier_offline_for_another_client() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let plant = SeedPlant::spawn(false).unwrap();
    let text = PlantConfig::default().text(&broker, &plant, "again-gw");
    let status = "plant/gateway/again-gw/status";
    let mut observer = TestClient::connect(broker.port, "again-observer").await;
    observer.subscribe(status).await;
    for run in ["first", "second"] {
        let mut daemon = spawn_daemon(dir.path(), run, &text);
        observer
            .wait_for(status, ANSWER, |m| m.text() == "online")
            .await;
        // Long enough for the stored message, the echo and any re-assertion.
        observer.settle(Duration::from_secs(2)).await;
        kill(daemon.pid(), Signal::SIGTERM).expect("SIGTERM");
        let deadline = Instant::now() + Duration::from_secs(15);
        while daemon.is_running() {
            assert!(Instant::now() < deadline, "{run} run did not stop");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        observer
            .wait_for(status, ANSWER, |m| m.text() == "offline")
            .await;
        observer.forget();
    }
    assert_eq!(
        retained(broker.port, "again-late", status).await.as_deref(),
        Some("offline")
    );
    let second = std::fs::read_to_string(dir.path().join("second.log")).unwrap_or_default();
    assert!(
        !second.contains("another client overwrote"),
        "a false alarm:\n{second}"
    );
}
