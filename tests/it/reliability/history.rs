//! The history stream against a real mosquitto: values measured while the broker is away are
//! journaled and come out, in order and with the instant they were read, after it is back;
//! a gateway killed (SIGKILL) in the middle of an outage replays them after its restart; with
//! `[sparkplug]` they also come as historical DDATA (decoded by pysparkplug) after the rebirth.

use crate::support;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, SystemTime};

use rtu2mqtt::history::document::epoch_ms;
use rtu2mqtt_sim::{self as sim, SeedPlant};
use serde_json::{Map, Value as Json};
use support::child::{gateway_run, KillOnDrop};
use support::pysparkplug::decode_with_pysparkplug;
use support::{Gateway, Message, Mosquitto, PlantConfig, SmallDisk, TestClient};

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

/// A subscriber to every device's history stream, under a client id of its own: an earlier
/// one still alive would take the session over at each reconnect, and lose what the broker
/// delivers meanwhile.
async fn historian(port: u16) -> TestClient {
    static HISTORIANS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = HISTORIANS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut observer = TestClient::connect(port, &format!("historian-{n}")).await;
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
    let stats = observer_stats(&mut observer, "hist-gw").await;
    assert_eq!(stats["history"]["records_waiting"], 0, "{stats}");
    gateway.stop().await;
}

async fn observer_stats(observer: &mut TestClient, client_id: &str) -> Json {
    observer.subscribe("plant/gateway/+/stats").await;
    let deadline = tokio::time::Instant::now() + ANSWER;
    loop {
        let message = observer
            .wait_for(&format!("plant/gateway/{client_id}/stats"), ANSWER, |_| {
                true
            })
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

/// A segment of an earlier run holding `count` dust collector documents whose `marker` is
/// their number, read `age` ago; the length field of record `flipped` has one bit flipped.
fn earlier_segment(count: u64, flipped: u64) -> Vec<u8> {
    use rtu2mqtt::history::record::MAGIC;
    use rtu2mqtt::history::Record;
    let read_at = epoch_ms(SystemTime::now()) - 600_000;
    let mut bytes = MAGIC.to_vec();
    for n in 0..count {
        let at_ms = read_at + n * 1000;
        let ts =
            humantime::format_rfc3339_millis(SystemTime::UNIX_EPOCH + Duration::from_millis(at_ms));
        let record = Record {
            at_ms,
            device: "dust_collector".to_string(),
            document: format!("{{\"ts\":\"{ts}\",\"values\":{{\"marker\":{n}}}}}"),
        };
        let mut encoded = record.encode().expect("encodable");
        if n == flipped {
            encoded[1] ^= 0x02;
        }
        bytes.extend(encoded);
    }
    bytes
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn damage_a_fifo_and_a_stray_largest_number_in_the_journal_cost_only_the_damaged_record() {
    let mut broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).expect("seed plant");
    let journal = tempfile::tempdir().expect("journal dir");
    // What an earlier run left, with one length byte flipped in its middle record; a FIFO
    // named like a segment (opening it for reading would block until a writer comes); a stray
    // file of the largest sequence number.
    std::fs::write(
        journal.path().join("00000000000000000001.journal"),
        earlier_segment(31, 15),
    )
    .expect("segment");
    nix::unistd::mkfifo(
        &journal.path().join("00000000000000000002.journal"),
        nix::sys::stat::Mode::S_IRWXU,
    )
    .expect("fifo");
    std::fs::write(
        journal.path().join("18446744073709551615.journal"),
        "left here by someone else\n",
    )
    .expect("stray file");
    let mut observer = historian(broker.port).await;
    let config = support::fast_config(&config_text(&broker, &plant, "hist-damage", journal.path()));
    sim::lock(&plant.dust_collector).set_alarms(0);
    let gateway = Gateway::start(config).await;

    // The earlier run's records come out, all but the damaged one, and then the first
    // values this run read.
    let deadline = tokio::time::Instant::now() + ANSWER;
    let markers = loop {
        observer.settle(Duration::from_millis(500)).await;
        let seen = observer.on(DUST_HISTORY);
        let markers: Vec<u64> = seen
            .iter()
            .filter_map(|m| m.json()["values"]["marker"].as_u64())
            .collect();
        let live = seen.iter().any(|m| m.json()["values"]["gear"].is_number());
        if live || tokio::time::Instant::now() > deadline {
            break markers;
        }
    };
    let expected: Vec<u64> = (0..31).filter(|&n| n != 15).collect();
    assert_eq!(markers, expected, "the damaged record alone is lost");
    // The next historian takes its client id.
    drop(observer);

    // An outage: every change read during it comes out, in order, after it.
    broker.kill();
    link_is(&gateway, false).await;
    let outage = [1, 2, 4, 7, 0];
    walk_alarms(&plant, &outage).await;
    broker.restart();
    let mut observer = historian(broker.port).await;
    assert_outage_follows_in_order(&mut observer, &outage).await;
    let stats = observer_stats(&mut observer, "hist-damage").await;
    let history = &stats["history"];
    // The damaged record alone: the stray file (a regular file that is no segment) and the
    // FIFO are no damage, only skipped and left alone.
    assert_eq!(history["damaged"], 1, "{stats}");
    assert_eq!(history["write_failures"], 0, "{stats}");
    assert_eq!(history["writable"], true, "{stats}");
    for name in [
        "00000000000000000002.journal",
        "18446744073709551615.journal",
    ] {
        assert!(
            std::fs::symlink_metadata(journal.path().join(name)).is_ok(),
            "{name} is not ours: left alone"
        );
    }
    gateway.stop().await;
}

/// `rtu2mqtt health` on `status_file`: (healthy, what it printed).
fn health(status_file: &Path) -> (bool, String) {
    let output = std::process::Command::new(support::child::gateway_binary())
        .args(["health", "--status-file"])
        .arg(status_file)
        .args(["--max-age", "10s"])
        .output()
        .expect("rtu2mqtt health runs");
    (
        output.status.success(),
        String::from_utf8_lossy(&output.stdout).into_owned(),
    )
}

/// The Prometheus exposition of the endpoint on `port`.
fn scrape(port: u16) -> String {
    use std::io::{Read, Write};
    let mut stream = std::net::TcpStream::connect(("127.0.0.1", port)).expect("metrics endpoint");
    stream
        .write_all(b"GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n")
        .expect("request");
    let mut text = String::new();
    let _ = stream.read_to_string(&mut text);
    text
}

/// Waits until `rtu2mqtt health`, the stats topic and Prometheus all say the journal is
/// `writable` (and the gateway healthy when it is); returns what `health` printed.
async fn wait_for_journal(
    observer: &mut TestClient,
    status_file: &Path,
    metrics_port: u16,
    writable: bool,
) -> String {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
    loop {
        let (healthy, said) = health(status_file);
        let stats = observer
            .wait_for_new("plant/gateway/hist-path/stats", ANSWER, |_| true)
            .await
            .json();
        let exposition = scrape(metrics_port);
        let sample = format!("rtu2mqtt_history_writable {}", u8::from(writable));
        if healthy == writable
            && stats["history"]["writable"] == writable
            && exposition.lines().any(|line| line == sample)
        {
            return said;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "the journal never became writable = {writable}: {said}\n{stats}\n{exposition}"
        );
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_history_path_that_cannot_be_written_makes_the_gateway_unhealthy_never_stops_it() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).expect("seed plant");
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("history");
    std::fs::write(&path, "a file where the journal's directory should be").expect("file");
    let metrics_port = support::free_port();
    let gateway_keys =
        format!("stats_interval = \"1s\"\nmetrics_listen = \"127.0.0.1:{metrics_port}\"");
    let text = PlantConfig {
        gateway: &gateway_keys,
        ..PlantConfig::default()
    }
    .text(&broker, &plant, "hist-path");
    let config = dir.path().join("rtu2mqtt.toml");
    std::fs::write(
        &config,
        format!("{text}\n[history]\npath = \"{}\"\n", path.display()),
    )
    .expect("config");
    let status_file = dir.path().join("status");
    let log = dir.path().join("log");
    let mut command = gateway_run(&config);
    command
        .env("RTU2MQTT__HEALTH__STATUS_FILE", &status_file)
        .env("RTU2MQTT__HEALTH__INTERVAL", "1s")
        .env("RUST_LOG", "info")
        .stderr(std::fs::File::create(&log).expect("log file"));
    let mut gateway = KillOnDrop::spawn(command).expect("start gateway");

    // Live values are served.
    let mut observer = TestClient::connect(broker.port, "path-observer").await;
    observer.subscribe("plant/dust_collector/gear").await;
    observer.subscribe("plant/gateway/+/stats").await;
    observer
        .wait_for("plant/dust_collector/gear", ANSWER, |_| true)
        .await;
    // And the gateway says it is unhealthy, everywhere, with the place.
    let said = wait_for_journal(&mut observer, &status_file, metrics_port, false).await;
    assert_eq!(
        said.trim(),
        format!(
            "unhealthy: history journal cannot be written: {}: is not a directory (the journal \
             needs one)",
            path.display()
        )
    );
    assert!(gateway.is_running(), "it never exits for it");

    // The path becomes a directory: healthy again, by itself.
    std::fs::remove_file(&path).expect("remove the file");
    let said = wait_for_journal(&mut observer, &status_file, metrics_port, true).await;
    assert!(said.starts_with("healthy: 2 line(s) alive"), "{said}");
    assert!(path.is_dir());
    let logged = std::fs::read_to_string(&log).unwrap_or_default();
    assert_eq!(
        logged.matches("history journal cannot be written").count(),
        1,
        "the cause is logged once:\n{logged}"
    );
    assert_eq!(
        logged.matches("history journal writable again").count(),
        1,
        "{logged}"
    );
    assert!(gateway.is_running());
}

/// Waits until the gateway's journal is said writable (`problem` None) or not.
async fn journal_problem_is(gateway: &Gateway, failing: bool) -> Option<String> {
    let mut problem = gateway.running.bridge.history_problem.clone();
    let said = tokio::time::timeout(ANSWER, problem.wait_for(|now| now.is_some() == failing))
        .await
        .unwrap_or_else(|_| panic!("the journal never became failing = {failing}"))
        .expect("bridge gone")
        .clone();
    said
}

/// The gateway over the seed plant with its journal on a small tmpfs; None where mounting
/// one needs a root this test does not have.
async fn on_a_small_disk(client_id: &str) -> Option<(SmallDisk, Mosquitto, SeedPlant, Gateway)> {
    let Some(disk) = SmallDisk::mount("256k") else {
        eprintln!("a full disk is tested on a tmpfs: mounting one needs root");
        return None;
    };
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).expect("seed plant");
    let journal = disk.path().join("history");
    let config = support::fast_config(&config_text(&broker, &plant, client_id, &journal));
    sim::lock(&plant.dust_collector).set_alarms(0);
    sim::lock(&plant.air_shower).set_emergency_stop(false);
    let gateway = Gateway::start(config).await;
    first_history(broker.port).await;
    Some((disk, broker, plant, gateway))
}

/// An outage on a full disk, room again during it ("writable again"), the broker back: every
/// alarm state read meanwhile arrives, in order.
async fn full_disk_outage(
    disk: &SmallDisk,
    broker: &mut Mosquitto,
    plant: &SeedPlant,
    gateway: &Gateway,
) {
    let filler = disk.fill();
    broker.kill();
    link_is(gateway, false).await;
    let outage = [1, 2, 4, 7, 0];
    walk_alarms(plant, &outage[..3]).await;
    let problem = journal_problem_is(gateway, true).await.unwrap_or_default();
    assert!(problem.contains("No space left on device"), "{problem}");
    // Room again: the journal resumes by itself, the outage goes on.
    std::fs::remove_file(filler).expect("remove the filler");
    journal_problem_is(gateway, false).await;
    walk_alarms(plant, &outage[3..]).await;
    broker.restart();
    let mut observer = historian(broker.port).await;
    assert_outage_follows_in_order(&mut observer, &outage).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_during_an_outage_is_a_pause_and_nothing_read_is_lost() {
    let Some((disk, mut broker, plant, gateway)) = on_a_small_disk("hist-full").await else {
        return;
    };
    full_disk_outage(&disk, &mut broker, &plant, &gateway).await;
    gateway.stop().await;
    drop(disk);
}

const SHOWER_HISTORY: &str = "plant/air_shower/history";

/// The air shower's e-stop after each of its history documents (folding the change sets),
/// with repeats collapsed.
fn estop_states(messages: &[Message]) -> Vec<bool> {
    let mut state = None;
    let mut states = Vec::new();
    for message in messages {
        if let Some(estop) = message.json()["values"]["emergency_stop"].as_bool() {
            state = Some(estop);
        }
        if let Some(now) = state {
            if states.last() != Some(&now) {
                states.push(now);
            }
        }
    }
    states
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn after_a_full_disk_has_room_again_a_later_outage_loses_nothing() {
    let Some((disk, mut broker, plant, gateway)) = on_a_small_disk("hist-later").await else {
        return;
    };
    full_disk_outage(&disk, &mut broker, &plant, &gateway).await;

    // The next outage, ten seconds, on a disk full again: five changes of the air shower,
    // waiting in memory with everything else read meanwhile; the broker is back while they
    // wait there, and the disk has room again a little later.
    let filler = disk.fill();
    broker.kill();
    link_is(&gateway, false).await;
    let changes = [true, false, true, false, true];
    for &estop in &changes {
        sim::lock(&plant.air_shower).set_emergency_stop(estop);
        tokio::time::sleep(Duration::from_millis(2000)).await;
    }
    journal_problem_is(&gateway, true).await;
    broker.restart();
    let mut observer = historian(broker.port).await;
    link_is(&gateway, true).await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    std::fs::remove_file(filler).expect("remove the filler");
    journal_problem_is(&gateway, false).await;
    let deadline = tokio::time::Instant::now() + ANSWER;
    loop {
        observer.settle(Duration::from_millis(500)).await;
        let seen: Vec<Message> = observer.on(SHOWER_HISTORY).into_iter().cloned().collect();
        let states = estop_states(&seen);
        if states.windows(changes.len()).any(|w| w == changes) {
            assert_in_order(&seen);
            break;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "a change of the air shower read during the outage is missing: expected {changes:?} \
             in {states:?}\n{:?}",
            seen.iter().map(Message::text).collect::<Vec<_>>()
        );
    }
    gateway.stop().await;
    drop(disk);
}
