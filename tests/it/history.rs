//! The history stream against a real mosquitto: values measured while the broker is away are
//! journaled and come out, in order and with the instant they were read, after it is back;
//! a gateway killed (SIGKILL) in the middle of an outage replays them after its restart; with
//! `[sparkplug]` they also come as historical DDATA (decoded by pysparkplug) after the rebirth.

use crate::support;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, SystemTime};

use rtu2mqtt::history::document::epoch_ms;
use rtu2mqtt::sim::{self, SeedPlant};
use serde_json::{Map, Value as Json};
use support::child::{gateway_run, KillOnDrop};
use support::pysparkplug::decode_with_pysparkplug;
use support::{Gateway, Message, Mosquitto, PlantConfig, TestClient};

const ANSWER: Duration = Duration::from_secs(15);
const DUST_HISTORY: &str = "plant/dust_collector/history";
/// Each alarm state is held for two polls of the status block (the profile's minimum, 1 s).
const HOLD: Duration = Duration::from_millis(2200);

fn config_text(broker: &Mosquitto, plant: &SeedPlant, client_id: &str, journal: &Path) -> String {
    let text = PlantConfig {
        gateway: "stats_interval = \"1s\"",
        ..PlantConfig::default()
    }
    .text(broker, plant, client_id);
    format!("{text}\n[history]\npath = \"{}\"\n", journal.display())
}

/// The alarm bits as the three fields the profile decodes them into, after each history
/// document of the dust collector (folding the change sets), with repeats collapsed.
fn alarm_states(messages: &[Message]) -> Vec<(bool, bool, bool)> {
    let mut state = Map::new();
    let mut states = Vec::new();
    for message in messages {
        let document = message.json();
        if let Some(values) = document["values"].as_object() {
            state.extend(values.clone());
        }
        let bit = |name: &str| state.get(name).and_then(Json::as_bool).unwrap_or(false);
        let now = (
            bit("fan_alarm"),
            bit("filter_alarm"),
            bit("temperature_alarm"),
        );
        if states.last() != Some(&now) {
            states.push(now);
        }
    }
    states
}

fn alarm_triple(alarms: u16) -> (bool, bool, bool) {
    (alarms & 4 != 0, alarms & 2 != 0, alarms & 1 != 0)
}

/// Every document of the stream has the contract's shape and the stream's `ts` never goes
/// backwards.
fn assert_in_order(messages: &[Message]) {
    let mut last = String::new();
    for message in messages {
        assert!(!message.retain, "history is not retained");
        let document = message.json();
        let ts = document["ts"].as_str().unwrap_or_default().to_string();
        assert!(
            ts.len() == "2026-12-02T15:00:01.123Z".len() && ts.ends_with('Z'),
            "{document}"
        );
        assert!(document["values"].is_object(), "{document}");
        assert!(ts >= last, "history out of order: {last} then {ts}");
        last = ts;
    }
}

/// Waits until the gateway's plain MQTT link is `up` (or down).
async fn link_is(gateway: &Gateway, up: bool) {
    let mut connected = gateway.running.bridge.connected.clone();
    tokio::time::timeout(ANSWER, connected.wait_for(|now| *now == up))
        .await
        .unwrap_or_else(|_| panic!("the gateway's link never became up = {up}"))
        .expect("bridge gone");
}

/// Sets the alarm bits through `sequence`, holding each long enough to be polled.
async fn walk_alarms(plant: &SeedPlant, sequence: &[u16]) {
    for &alarms in sequence {
        sim::lock(&plant.dust_collector).set_alarms(alarms);
        tokio::time::sleep(HOLD).await;
    }
}

/// A subscriber to every device's history stream.
async fn historian(port: u16) -> TestClient {
    let mut observer = TestClient::connect(port, "historian").await;
    observer.subscribe("plant/+/history").await;
    observer
}

/// The dust collector's first history document: the gateway is connected and journaling.
async fn first_history(port: u16) -> Message {
    historian(port)
        .await
        .wait_for(DUST_HISTORY, ANSWER, |m| m.json()["ts"].is_string())
        .await
}

/// Waits until the dust collector's history holds the alarm states the device took during
/// `outage` one after the other (none missing, none in between), then, a little later, checks
/// that the whole stream is in read order.
async fn assert_outage_follows_in_order(observer: &mut TestClient, outage: &[u16]) {
    let expected: Vec<_> = outage.iter().map(|&a| alarm_triple(a)).collect();
    let deadline = tokio::time::Instant::now() + ANSWER;
    loop {
        observer.settle(Duration::from_millis(500)).await;
        let seen: Vec<Message> = observer.on(DUST_HISTORY).into_iter().cloned().collect();
        let states = alarm_states(&seen);
        if states
            .windows(expected.len())
            .any(|window| window == expected)
        {
            observer.settle(Duration::from_millis(500)).await;
            let seen: Vec<Message> = observer.on(DUST_HISTORY).into_iter().cloned().collect();
            assert_in_order(&seen);
            return;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "the values measured during the outage are not all in the stream, in order:\n\
             expected {expected:?}\nin {states:?}\n{:?}",
            seen.iter().map(Message::text).collect::<Vec<_>>()
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_value_measured_while_the_broker_was_away_follows_in_order_after_it_is_back() {
    let mut broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).expect("seed plant");
    let journal = tempfile::tempdir().expect("journal dir");
    let config = support::fast_config(&config_text(&broker, &plant, "hist-gw", journal.path()));
    let gateway = Gateway::start(config).await;
    sim::lock(&plant.dust_collector).set_alarms(0);
    let first = first_history(broker.port).await;
    assert!(
        first.json()["values"]["gear"].is_number(),
        "{}",
        first.text()
    );

    broker.kill();
    // The outage as the gateway sees it: from the moment it knows the broker is gone.
    link_is(&gateway, false).await;
    let outage = [1, 2, 4, 7, 0];
    walk_alarms(&plant, &outage).await;
    broker.restart();
    let mut observer = historian(broker.port).await;

    assert_outage_follows_in_order(&mut observer, &outage).await;
    // The replay is done: the journal is empty and says so.
    let stats = observer_stats(&mut observer).await;
    assert_eq!(stats["history"]["records_waiting"], 0, "{stats}");
    gateway.stop().await;
}

async fn observer_stats(observer: &mut TestClient) -> Json {
    observer.subscribe("plant/gateway/+/stats").await;
    let deadline = tokio::time::Instant::now() + ANSWER;
    loop {
        let message = observer
            .wait_for("plant/gateway/hist-gw/stats", ANSWER, |_| true)
            .await;
        let document = message.json();
        if document["history"]["records_waiting"] == 0 || tokio::time::Instant::now() > deadline {
            return document;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gateway_killed_in_the_middle_of_an_outage_replays_after_its_restart() {
    let mut broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).expect("seed plant");
    let journal = tempfile::tempdir().expect("journal dir");
    let files = tempfile::tempdir().expect("config dir");
    let config = files.path().join("rtu2mqtt.toml");
    let text = config_text(&broker, &plant, "hist-kill", journal.path());
    std::fs::write(&config, &text).expect("write config");
    sim::lock(&plant.dust_collector).set_alarms(0);

    let mut gateway = KillOnDrop::spawn(gateway_run(&config)).expect("start gateway");
    first_history(broker.port).await;

    broker.kill();
    // The gateway notices at once (its socket closed with the broker).
    tokio::time::sleep(Duration::from_secs(1)).await;
    let outage = [5, 6, 7];
    walk_alarms(&plant, &outage).await;
    // More than a second after the last change: it is synced. SIGKILL, no goodbye.
    nix::sys::signal::kill(gateway.pid(), nix::sys::signal::Signal::SIGKILL).expect("kill");
    let _ = gateway.0.wait();
    assert!(!gateway.is_running());
    sim::lock(&plant.dust_collector).set_alarms(0);

    broker.restart();
    let mut observer = historian(broker.port).await;
    let _gateway = KillOnDrop::spawn(gateway_run(&config)).expect("restart gateway");
    assert_outage_follows_in_order(&mut observer, &outage).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn what_the_broker_never_acknowledged_is_journaled_and_follows_in_order() {
    let mut broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).expect("seed plant");
    let journal = tempfile::tempdir().expect("journal dir");
    let mut config =
        support::fast_config(&config_text(&broker, &plant, "hist-ack", journal.path()));
    // The stalled broker is noticed after two keep-alive periods without a PINGRESP.
    config.mqtt.keep_alive = Duration::from_secs(2);
    sim::lock(&plant.dust_collector).set_alarms(0);
    let gateway = Gateway::start(config).await;
    first_history(broker.port).await;

    // The broker stops answering: its socket takes the publishes, no PUBACK comes back.
    broker.signal(nix::sys::signal::Signal::SIGSTOP);
    let outage = [3, 1, 6, 2, 5, 4, 0];
    walk_alarms(&plant, &outage).await;
    link_is(&gateway, false).await;
    // A new broker on the same port: nothing of the old one's session survives.
    broker.restart();
    let mut observer = historian(broker.port).await;

    assert_outage_follows_in_order(&mut observer, &outage).await;
    gateway.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn what_the_broker_never_acknowledged_before_a_stop_follows_after_the_next_start() {
    let mut broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).expect("seed plant");
    let journal = tempfile::tempdir().expect("journal dir");
    let text = config_text(&broker, &plant, "hist-stop", journal.path());
    // A keep-alive long enough that the gateway still trusts the stalled broker at its stop.
    let config = || {
        let mut config = support::fast_config(&text);
        config.mqtt.keep_alive = Duration::from_secs(60);
        config
    };
    sim::lock(&plant.dust_collector).set_alarms(0);
    let gateway = Gateway::start(config()).await;
    first_history(broker.port).await;

    broker.signal(nix::sys::signal::Signal::SIGSTOP);
    let outage = [5, 3, 6];
    walk_alarms(&plant, &outage).await;
    assert!(
        *gateway.running.bridge.connected.borrow(),
        "the gateway should still be connected: the test is about an orderly stop"
    );
    gateway.stop().await;
    broker.restart();
    let mut observer = historian(broker.port).await;
    let gateway = Gateway::start(config()).await;
    assert_outage_follows_in_order(&mut observer, &outage).await;
    gateway.stop().await;
}

/// The node's messages in `log`, decoded by pysparkplug in publishing order.
fn decoded_node_messages(log: &[Message]) -> Vec<Json> {
    let node: Vec<&Message> = log
        .iter()
        .filter(|m| m.topic.starts_with("spBv1.0/plant/") && !m.topic.contains("CMD"))
        .collect();
    decode_with_pysparkplug(
        node.iter()
            .map(|m| (m.topic.as_str(), m.payload.as_slice())),
    )
}

fn is_kind(message: &Json, kind: &str, device: Option<&str>) -> bool {
    message["type"] == kind && message["device"].as_str() == device
}

/// The alarm states the dust collector's historical DDATA walk through, folded as a host
/// folds them, with the read instant of each change set.
fn historical_alarm_states(messages: &[Json]) -> Vec<((bool, bool, bool), u64)> {
    let mut state = Map::new();
    let mut states: Vec<((bool, bool, bool), u64)> = Vec::new();
    for message in messages {
        let metrics = message["metrics"].as_array().cloned().unwrap_or_default();
        let read_at = message["timestamp"].as_u64().unwrap_or_default();
        for metric in metrics {
            if let Some(name) = metric["name"].as_str() {
                state.insert(name.to_string(), metric["value"].clone());
            }
        }
        let bit = |name: &str| state.get(name).and_then(Json::as_bool).unwrap_or(false);
        let now = (
            bit("fan_alarm"),
            bit("filter_alarm"),
            bit("temperature_alarm"),
        );
        if states.last().map(|(last, _)| last) != Some(&now) {
            states.push((now, read_at));
        }
    }
    states
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_sparkplug_the_outage_is_forwarded_as_historical_ddata_after_the_rebirth() {
    let mut broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).expect("seed plant");
    let journal = tempfile::tempdir().expect("journal dir");
    let text = config_text(&broker, &plant, "hist-sp", journal.path());
    let config = support::fast_config(&format!("{text}\n[sparkplug]\ngroup_id = \"plant\"\n"));
    sim::lock(&plant.dust_collector).set_alarms(0);
    let gateway = Gateway::start(config).await;
    let mut observer = TestClient::connect(broker.port, "sp-historian").await;
    observer.subscribe("spBv1.0/#").await;
    observer
        .wait_for(
            "spBv1.0/plant/DBIRTH/hist-sp/dust_collector",
            ANSWER,
            |_| true,
        )
        .await;
    drop(observer);

    // What was read within a round trip before the kill can still lack its PUBACK: it is
    // history too.
    let outage_from = epoch_ms(SystemTime::now()) - 1_000;
    broker.kill();
    link_is(&gateway, false).await;
    let outage = [1, 2, 4, 7, 0];
    walk_alarms(&plant, &outage).await;
    broker.restart();
    let mut observer = TestClient::connect(broker.port, "sp-historian").await;
    observer.subscribe("spBv1.0/#").await;
    // The outage ends when the gateway is connected again: what it read until then is history.
    link_is(&gateway, true).await;
    let reconnect_at = epoch_ms(SystemTime::now());

    let expected: Vec<_> = outage.iter().map(|&a| alarm_triple(a)).collect();
    let deadline = tokio::time::Instant::now() + ANSWER;
    let (decoded, states, replayed_by) = loop {
        observer.settle(Duration::from_millis(500)).await;
        let decoded = decoded_node_messages(&observer.received);
        let historical: Vec<Json> = decoded
            .iter()
            .filter(|m| is_kind(m, "DDATA", Some("dust_collector")))
            .filter(|m| {
                m["metrics"].as_array().is_some_and(|metrics| {
                    metrics.iter().any(|metric| metric["is_historical"] == true)
                })
            })
            .cloned()
            .collect();
        let states = historical_alarm_states(&historical);
        let walked: Vec<_> = states.iter().map(|(state, _)| *state).collect();
        if walked
            .windows(expected.len())
            .any(|window| window == expected)
        {
            break (decoded, states, epoch_ms(SystemTime::now()));
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "the outage did not come as historical DDATA:\nexpected {expected:?}\nin {walked:?}\n{decoded:#?}"
        );
    };

    // The rebirth first: NBIRTH, then the dust collector's DBIRTH, then its history.
    let nbirth = decoded
        .iter()
        .position(|m| is_kind(m, "NBIRTH", None))
        .expect("no NBIRTH after the reconnect");
    let dbirth = decoded
        .iter()
        .position(|m| is_kind(m, "DBIRTH", Some("dust_collector")))
        .expect("no DBIRTH after the reconnect");
    assert!(nbirth < dbirth, "{decoded:#?}");
    let mut last_read: BTreeMap<String, u64> = BTreeMap::new();
    for (index, message) in decoded.iter().enumerate() {
        let metrics = message["metrics"].as_array().cloned().unwrap_or_default();
        let historical = metrics
            .iter()
            .filter(|m| m["is_historical"] == true)
            .count();
        if historical == 0 {
            continue;
        }
        assert!(
            index > dbirth,
            "historical data before the births: {message}"
        );
        assert_eq!(message["type"], "DDATA", "{message}");
        assert_eq!(
            historical,
            metrics.len(),
            "live and historical mixed: {message}"
        );
        let read_at = message["timestamp"].as_u64().expect("payload timestamp");
        for metric in &metrics {
            assert_eq!(metric["timestamp"].as_u64(), Some(read_at), "{message}");
            assert!(
                metric["name"].is_string(),
                "not declared by the DBIRTH: {message}"
            );
        }
        // What is read while the journal is still being replayed is appended behind it, in
        // order, and comes as history too; nothing read before the outage does.
        assert!(
            (outage_from..replayed_by).contains(&read_at),
            "read at {read_at}, outage {outage_from}..{reconnect_at}, replayed by \
             {replayed_by}: {message}"
        );
        let device = message["device"].as_str().unwrap_or_default().to_string();
        let before = last_read.insert(device, read_at).unwrap_or(0);
        assert!(read_at >= before, "history out of order: {message}");
    }
    // Each state was read while the device held it, in the order it took them.
    let stamps: Vec<u64> = states.iter().map(|(_, at)| *at).collect();
    assert!(
        stamps.windows(2).all(|pair| pair[0] < pair[1]),
        "{states:?}"
    );
    gateway.stop().await;
}
