//! The gateway as a Sparkplug B edge node, end to end: the simulated seed plant on pty lines,
//! a real mosquitto, and every message the node publishes decoded by `pysparkplug` (a decoder
//! not written in this project, through `tests/sparkplug/decode.py`). Births carry every
//! field typed and valued as the plain topics show it, `seq` counts across all messages, a
//! DCMD writes the golden frame and is confirmed by DDATA, one out of range writes nothing,
//! NCMD rebirth re-publishes the births, a silent device dies and is born again, and killing
//! the gateway process leaves the broker's NDEATH with the NBIRTH's `bdSeq`. The plain topics
//! and Home Assistant discovery are the same with and without `[sparkplug]`.
//!
//! Needs `python3` with `pysparkplug` (`pip install pysparkplug==0.6.1`).

use crate::support;
use crate::support::pysparkplug;

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::time::Duration;

use pysparkplug::decode_with_pysparkplug;
use rtu2mqtt::config::{self, Config};
use rtu2mqtt::sparkplug::core::metrics::datatype_for;
use rtu2mqtt::sparkplug::core::protobuf::{DataType, Metric, MetricValue, Payload};
use rtu2mqtt_profile::registry;
use rtu2mqtt_sim::{self as sim, SeedPlant};
use serde_json::{json, Value as Json};
use support::child::{self, KillOnDrop};
use support::hex::writes;
use support::{Gateway, Message, Mosquitto, PlantConfig, TestClient};

/// Generous bounds for a busy 2-core machine: they only fail when something is broken.
const ANSWER: Duration = Duration::from_secs(20);
const DUST: u8 = 1;
/// Air shower coil 4: breeze (docs/devices.md §3).
const COIL_BREEZE: usize = 4;
const GROUP: &str = "plant";
const DEVICES: [(&str, &str); 3] = [
    ("dust_collector", "ruiwan-dust-collector"),
    ("air_shower", "lixian-air-shower"),
    ("valve", "wuzhou-valve"),
];
/// Gear 8 to the dust collector: FC06 at the table address 0x1002 (docs/devices.md §2).
const GEAR_8: &str = "01 06 10 02 00 08 2D 0C";

/// The seed plant's configuration, `[sparkplug]` appended when `sparkplug` (the edge node id
/// is the client id).
fn plant_text(broker: &Mosquitto, plant: &SeedPlant, client_id: &str, sparkplug: bool) -> String {
    let mut text = PlantConfig {
        discovery: true,
        gateway: "stats_interval = \"1s\"",
        explicit_serial: true,
        line_keys: "retries = 1\noffline_after = 2",
        ..PlantConfig::default()
    }
    .text(broker, plant, client_id);
    text.push_str("\n[health]\nstatus_file = \"\"\n");
    if sparkplug {
        text.push_str(&format!("\n[sparkplug]\ngroup_id = \"{GROUP}\"\n"));
    }
    text
}

/// Validated as a user's file would be, then polled faster than the profiles' minimums.
fn fast(text: &str) -> Config {
    let mut config = config::from_str(text, Path::new("."))
        .unwrap_or_else(|problems| panic!("{problems}\n{text}"));
    for line in &mut config.lines {
        for device in &mut line.devices {
            device.poll_interval = Duration::from_millis(300);
        }
    }
    config
}

// ----- the Sparkplug side -----

/// `spBv1.0/<group>/<kind>/<node>[/<device>]` split into kind and device.
fn kind_and_device(topic: &str) -> Option<(&str, Option<&str>)> {
    let mut levels = topic.split('/');
    let (Some("spBv1.0"), Some(_group), Some(kind), Some(_node)) =
        (levels.next(), levels.next(), levels.next(), levels.next())
    else {
        return None;
    };
    Some((kind, levels.next()))
}

/// A message the edge node published (not a command the test sent, not a host's STATE).
fn from_node(message: &Message) -> bool {
    matches!(
        kind_and_device(&message.topic),
        Some((
            "NBIRTH" | "NDATA" | "NDEATH" | "DBIRTH" | "DDATA" | "DDEATH",
            _
        ))
    )
}

fn is(message: &Message, kind: &str, device: Option<&str>) -> bool {
    kind_and_device(&message.topic) == Some((kind, device))
}

/// Decoded by this project's own payload code: only to know when to stop waiting; every
/// assertion on content goes through pysparkplug.
fn own_decode(message: &Message) -> Payload {
    Payload::decode_bytes(&message.payload).unwrap_or_default()
}

/// `message` carries `name` = `value`, by name or by the alias its DBIRTH `birth` gave it.
fn carries_alias(message: &Message, birth: &Message, name: &str, value: &MetricValue) -> bool {
    let Some(alias) = own_decode(birth)
        .metrics
        .iter()
        .find(|m| m.name.as_deref() == Some(name))
        .and_then(|m| m.alias)
    else {
        return false;
    };
    own_decode(message).metrics.iter().any(|m| {
        (m.alias == Some(alias) || m.name.as_deref() == Some(name))
            && m.value.as_ref() == Some(value)
    })
}

/// Waits until a message at or after `from` in `client.received` satisfies `accept`; returns
/// its index. Nothing is taken out of `received`: it stays the log in arrival order.
async fn wait_in_log(
    client: &mut TestClient,
    from: usize,
    what: &str,
    accept: impl Fn(&[Message], &Message) -> bool,
) -> usize {
    let deadline = tokio::time::Instant::now() + ANSWER;
    loop {
        if let Some(offset) = client.received[from.min(client.received.len())..]
            .iter()
            .position(|m| accept(&client.received, m))
        {
            return from + offset;
        }
        if tokio::time::Instant::now() >= deadline {
            let seen: Vec<&str> = client.received[from.min(client.received.len())..]
                .iter()
                .map(|m| m.topic.as_str())
                .collect();
            panic!("no {what} within {ANSWER:?}; seen: {seen:?}");
        }
        client.settle(Duration::from_millis(100)).await;
    }
}

/// The last DBIRTH of `device` before `before`.
fn last_birth<'a>(log: &'a [Message], device: &str) -> Option<&'a Message> {
    log.iter().rev().find(|m| is(m, "DBIRTH", Some(device)))
}

fn command_payload(metrics: Vec<Metric>) -> Vec<u8> {
    Payload {
        timestamp: Some(1),
        metrics,
        ..Default::default()
    }
    .encode_to_bytes()
}

fn named(name: &str, datatype: DataType, value: MetricValue) -> Metric {
    Metric {
        name: Some(name.into()),
        datatype: Some(datatype.number()),
        value: Some(value),
        ..Default::default()
    }
}

fn metric<'a>(message: &'a Json, name: &str) -> Option<&'a Json> {
    message["metrics"]
        .as_array()
        .and_then(|metrics| metrics.iter().find(|m| m["name"] == name))
}

/// A decoded metric value as the plain topic would show it (`ON`, `8`, `12.5`, `opening`).
fn same_value(decoded: &Json, plain: &str) -> bool {
    match decoded {
        Json::Bool(on) => plain == if *on { "ON" } else { "OFF" },
        Json::String(text) => text == plain,
        Json::Number(number) => match (number.as_f64(), plain.parse::<f64>()) {
            (Some(a), Ok(b)) => (a - b).abs() <= 1e-3 * b.abs().max(1.0),
            _ => false,
        },
        _ => false,
    }
}

/// Every value the plain topics showed for each field of `device` in `log`.
fn plain_values(log: &[Message], device: &str) -> BTreeMap<String, BTreeSet<String>> {
    let prefix = format!("plant/{device}/");
    let mut values: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for message in log {
        let Some(field) = message.topic.strip_prefix(&prefix) else {
            continue;
        };
        if !field.contains('/') && field != "availability" {
            values
                .entry(field.to_string())
                .or_default()
                .insert(message.text());
        }
    }
    values
}

/// The next result of a gear command at or after `from`.
async fn gear_result(client: &mut TestClient, from: usize) -> Json {
    let at = wait_in_log(client, from, "a gear result", |_, m| {
        m.topic == "plant/dust_collector/gear/result"
    })
    .await;
    client.received[at].json()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_seed_plant_is_born_commanded_reborn_and_mourned() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap_or_else(|error| panic!("{error}"));
    sim::lock(&plant.dust_collector).set_power(true);
    let mut client = TestClient::connect(broker.port, "sp-observer").await;
    client.subscribe("spBv1.0/#").await;
    client.subscribe("plant/#").await;
    let node = "sp-gw";
    let gateway = Gateway::start(fast(&plant_text(&broker, &plant, node, true))).await;
    let node_topic = |kind: &str| format!("spBv1.0/{GROUP}/{kind}/{node}");
    let device_topic = |kind: &str, device: &str| format!("{}/{device}", node_topic(kind));

    // Births: the NBIRTH, then a DBIRTH per device once it has answered.
    let nbirth = wait_in_log(&mut client, 0, "NBIRTH", |_, m| is(m, "NBIRTH", None)).await;
    for (device, _) in DEVICES {
        wait_in_log(&mut client, nbirth, &format!("DBIRTH {device}"), |_, m| {
            is(m, "DBIRTH", Some(device))
        })
        .await;
    }
    client.drain();
    let snapshot = client.received.len();

    // A change on the device: DDATA.
    sim::lock(&plant.air_shower).set_coil(COIL_BREEZE, true);
    let breeze_on = MetricValue::Boolean(true);
    wait_in_log(&mut client, snapshot, "DDATA breeze", |log, m| {
        is(m, "DDATA", Some("air_shower"))
            && last_birth(log, "air_shower")
                .is_some_and(|birth| carries_alias(m, birth, "breeze", &breeze_on))
    })
    .await;

    // A DCMD on the gear: the golden frame, the plain result, the DDATA confirming it.
    plant.line_a.journal().clear();
    let gear = |value| command_payload(vec![named("gear", DataType::UInt8, value)]);
    let before = client.received.len();
    client
        .publish(
            &device_topic("DCMD", "dust_collector"),
            gear(MetricValue::Int(8)),
            false,
        )
        .await;
    let eight = MetricValue::Int(8);
    wait_in_log(&mut client, before, "DDATA gear 8", |log, m| {
        is(m, "DDATA", Some("dust_collector"))
            && last_birth(log, "dust_collector")
                .is_some_and(|birth| carries_alias(m, birth, "gear", &eight))
    })
    .await;
    let frames = plant.line_a.journal().frames();
    assert_eq!(writes(&frames, DUST), vec![GEAR_8.to_string()]);
    assert_eq!(sim::lock(&plant.dust_collector).gear(), 8);
    let result = gear_result(&mut client, before).await;
    assert_eq!(
        (&result["value"], &result["outcome"]),
        (&json!("8"), &json!("applied")),
        "{result}"
    );

    // Out of range: rejected like `…/set` would be, nothing written, the true gear again.
    plant.line_a.journal().clear();
    let before = client.received.len();
    client
        .publish(
            &device_topic("DCMD", "dust_collector"),
            gear(MetricValue::Int(11)),
            false,
        )
        .await;
    let result = gear_result(&mut client, before).await;
    assert_eq!(
        (&result["value"], &result["outcome"]),
        (&json!("11"), &json!("rejected")),
        "{result}"
    );
    let republished = wait_in_log(&mut client, before, "DDATA gear 8 again", |log, m| {
        is(m, "DDATA", Some("dust_collector"))
            && last_birth(log, "dust_collector")
                .is_some_and(|birth| carries_alias(m, birth, "gear", &eight))
    })
    .await;
    client.settle(Duration::from_secs(1)).await;
    assert_eq!(
        writes(&plant.line_a.journal().frames(), DUST),
        Vec::<String>::new()
    );

    // NCMD rebirth: the NBIRTH and every DBIRTH again.
    let rebirth = command_payload(vec![named(
        "Node Control/Rebirth",
        DataType::Boolean,
        MetricValue::Boolean(true),
    )]);
    client.publish(&node_topic("NCMD"), rebirth, false).await;
    let reborn = wait_in_log(&mut client, republished + 1, "NBIRTH again", |_, m| {
        is(m, "NBIRTH", None)
    })
    .await;
    for (device, _) in DEVICES {
        wait_in_log(
            &mut client,
            reborn,
            &format!("DBIRTH {device} again"),
            |_, m| is(m, "DBIRTH", Some(device)),
        )
        .await;
    }

    // A silent device dies; answering again, it is born again.
    plant.line_a.faults().silence(DUST, true);
    let death = wait_in_log(&mut client, reborn, "DDEATH", |_, m| {
        is(m, "DDEATH", Some("dust_collector"))
    })
    .await;
    plant.line_a.faults().silence(DUST, false);
    let back = wait_in_log(&mut client, death, "DBIRTH after DDEATH", |_, m| {
        is(m, "DBIRTH", Some("dust_collector"))
    })
    .await;
    gateway.stop().await;
    client.settle(Duration::from_millis(500)).await;

    // Everything the node said, through pysparkplug.
    let log: Vec<&Message> = client.received.iter().filter(|m| from_node(m)).collect();
    let decoded = decode_with_pysparkplug(log.iter().map(|m| (m.topic.as_str(), &m.payload[..])));
    // Node messages before the first change the test makes.
    let cut = client.received[..snapshot]
        .iter()
        .filter(|m| from_node(m))
        .count();
    let index_of = |wanted: usize| {
        let message = &client.received[wanted];
        log.iter()
            .position(|m| std::ptr::eq(*m, message))
            .unwrap_or_else(|| panic!("{} not in the log", message.topic))
    };

    // seq: 0 at every NBIRTH, then +1 (mod 256) on every message of the node.
    let mut previous: Option<u64> = None;
    for entry in &decoded {
        if entry["type"] == "NDEATH" {
            continue;
        }
        let seq = entry["seq"].as_u64().unwrap_or(u64::MAX);
        let expected = match (entry["type"].as_str(), previous) {
            (Some("NBIRTH"), _) => 0,
            (_, Some(previous)) => (previous + 1) % 256,
            (_, None) => panic!("a message before the first NBIRTH: {entry}"),
        };
        assert_eq!(seq, expected, "{entry}");
        previous = Some(seq);
    }

    // The first births: every field of every device, typed, with a value the plain topics
    // showed too (some figures, such as the fan speed, move all the time).
    let first = &decoded[index_of(nbirth)];
    let bd_seq = metric(first, "bdSeq").map(|m| m["value"].clone());
    assert_eq!(
        metric(first, "Node Control/Rebirth").map(|m| &m["value"]),
        Some(&json!(false))
    );
    assert!(metric(first, "Lines/line-a/Bus Load").is_some(), "{first}");
    for (device, profile_name) in DEVICES {
        let profile = registry::built_in(profile_name).unwrap_or_else(|e| panic!("{e}"));
        let birth = decoded
            .iter()
            .find(|m| m["type"] == "DBIRTH" && m["device"] == device)
            .unwrap_or_else(|| panic!("no DBIRTH for {device}"));
        assert_eq!(
            birth["metrics"].as_array().map(Vec::len),
            Some(profile.fields().len()),
            "{device}: one metric per field"
        );
        let plain = plain_values(&client.received, device);
        for info in profile.fields() {
            let born = metric(birth, &info.name)
                .unwrap_or_else(|| panic!("{device}.{} missing in {birth}", info.name));
            assert_eq!(
                born["datatype"],
                datatype_for(info).number(),
                "{device}.{}",
                info.name
            );
            assert_eq!(born["is_null"], false, "{device}.{}", info.name);
            let shown = plain
                .get(&info.name)
                .unwrap_or_else(|| panic!("no plain state for {device}.{}", info.name));
            let said = &born["value"];
            assert!(
                shown.iter().any(|text| same_value(said, text)),
                "{device}.{}: Sparkplug says {said}, the plain topic {shown:?}",
                info.name
            );
        }
    }

    // The change: DDATA with only what changed (the breeze), by alias, named via the birth.
    let change = decoded
        .iter()
        .skip(cut)
        .find(|m| m["type"] == "DDATA" && m["device"] == "air_shower")
        .unwrap_or_else(|| panic!("no DDATA for the air shower"));
    assert_eq!(
        metric(change, "breeze").map(|m| &m["value"]),
        Some(&json!(true))
    );
    assert!(
        change["metrics"].as_array().map_or(0, Vec::len) < 4,
        "only changes: {change}"
    );
    // The refused command's true value, re-published.
    assert_eq!(
        metric(&decoded[index_of(republished)], "gear").map(|m| &m["value"]),
        Some(&json!(8))
    );
    // The rebirth keeps the connection's bdSeq; the rebirths name every field again.
    let again = &decoded[index_of(reborn)];
    assert_eq!(metric(again, "bdSeq").map(|m| m["value"].clone()), bd_seq);
    assert_eq!(decoded[index_of(death)]["type"], "DDEATH");
    let returned = &decoded[index_of(back)];
    assert_eq!(
        metric(returned, "gear").map(|m| &m["value"]),
        Some(&json!(8))
    );
    // The orderly stop: the node's own NDEATH with the same bdSeq.
    let ndeath = decoded
        .iter()
        .rev()
        .find(|m| m["type"] == "NDEATH")
        .unwrap_or_else(|| panic!("no NDEATH at shutdown"));
    assert_eq!(metric(ndeath, "bdSeq").map(|m| m["value"].clone()), bd_seq);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killing_the_gateway_leaves_the_ndeath_of_its_last_birth() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap_or_else(|error| panic!("{error}"));
    let mut client = TestClient::connect(broker.port, "kill-observer").await;
    client.subscribe("spBv1.0/#").await;
    let dir = tempfile::tempdir().unwrap_or_else(|error| panic!("{error}"));
    let path = dir.path().join("config.toml");
    std::fs::write(&path, plant_text(&broker, &plant, "kill-gw", true))
        .unwrap_or_else(|error| panic!("{error}"));
    let mut daemon = KillOnDrop::spawn(child::gateway_run(&path))
        .unwrap_or_else(|error| panic!("starting rtu2mqtt: {error}"));
    let nbirth = wait_in_log(&mut client, 0, "NBIRTH", |_, m| is(m, "NBIRTH", None)).await;
    wait_in_log(&mut client, nbirth, "a DBIRTH", |_, m| {
        is(m, "DBIRTH", Some("valve"))
    })
    .await;
    // SIGKILL: no orderly NDEATH; the broker publishes the connection's Will.
    daemon.0.kill().unwrap_or_else(|error| panic!("{error}"));
    let _ = daemon.0.wait();
    let death = wait_in_log(&mut client, nbirth, "NDEATH", |_, m| is(m, "NDEATH", None)).await;
    let birth = &client.received[nbirth];
    let will = &client.received[death];
    let decoded =
        decode_with_pysparkplug([birth, will].map(|m| (m.topic.as_str(), &m.payload[..])));
    let bd_seq = |entry: &Json| metric(entry, "bdSeq").map(|m| m["value"].clone());
    assert_eq!(decoded[1]["type"], "NDEATH");
    assert!(bd_seq(&decoded[0]).is_some(), "{}", decoded[0]);
    assert_eq!(bd_seq(&decoded[1]), bd_seq(&decoded[0]));
}

/// What a plain topic carries, without the values that change from run to run: the keys of a
/// JSON object (recursively), or the kind of a scalar.
fn shape(payload: &[u8]) -> String {
    fn of(value: &Json) -> String {
        match value {
            Json::Object(map) => {
                let inner: Vec<String> =
                    map.iter().map(|(k, v)| format!("{k}:{}", of(v))).collect();
                format!("{{{}}}", inner.join(","))
            }
            Json::Array(items) => {
                let kinds: BTreeSet<String> = items.iter().map(of).collect();
                format!("[{}]", kinds.into_iter().collect::<Vec<_>>().join("|"))
            }
            // Figures are null until first measured: only the keys are the contract here.
            _ => "value".into(),
        }
    }
    match serde_json::from_slice::<Json>(payload) {
        Ok(json @ (Json::Object(_) | Json::Array(_))) => of(&json),
        _ if payload.is_empty() => "empty".into(),
        _ => "text".into(),
    }
}

/// Every plain and discovery topic the gateway publishes in its first seconds, with its shape.
async fn plain_surface(sparkplug: bool) -> BTreeSet<(String, String)> {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap_or_else(|error| panic!("{error}"));
    let mut client = TestClient::connect(broker.port, "surface-observer").await;
    client.subscribe("plant/#").await;
    client.subscribe("homeassistant/#").await;
    let gateway = Gateway::start(fast(&plant_text(&broker, &plant, "surface-gw", sparkplug))).await;
    for (device, _) in DEVICES {
        let topic = format!("plant/{device}/availability");
        wait_in_log(&mut client, 0, &topic, |_, m| {
            m.topic == topic && m.text() == "online"
        })
        .await;
    }
    client.settle(Duration::from_secs(3)).await;
    gateway.stop().await;
    client.settle(Duration::from_millis(500)).await;
    client
        .received
        .iter()
        .map(|m| (m.topic.clone(), shape(&m.payload)))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plain_topics_and_discovery_are_the_same_with_and_without_sparkplug() {
    let without = plain_surface(false).await;
    let with = plain_surface(true).await;
    assert!(
        without
            .iter()
            .any(|(topic, _)| topic.starts_with("homeassistant/")),
        "discovery published: {without:?}"
    );
    let only_without: Vec<_> = without.difference(&with).collect();
    let only_with: Vec<_> = with.difference(&without).collect();
    assert!(
        only_without.is_empty() && only_with.is_empty(),
        "only without [sparkplug]: {only_without:#?}\nonly with: {only_with:#?}"
    );
}

/// A bdSeq that cannot be kept is said once, at start, naming the fix, however many reconnect
/// attempts an outage brings; the node connects all the same. Without a state directory at
/// all, that is said once too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bd_seq_that_cannot_be_kept_is_a_single_warning_at_start() {
    let mut broker = Mosquitto::not_started();
    let dir = tempfile::tempdir().expect("temp dir");
    // A "state directory" under a plain file can never be made, whoever runs the test.
    let blocker = dir.path().join("not-a-directory");
    std::fs::write(&blocker, "").expect("write");
    let config = format!(
        "[mqtt]\nurl = \"{}\"\nclient_id = \"kept-gw\"\nprefix = \"plant\"\n\n\
         [health]\nstatus_file = \"\"\n\n[sparkplug]\ngroup_id = \"{GROUP}\"\n\n\
         [[lines]]\nname = \"line-b\"\nurl = \"tcp://127.0.0.1:{}\"\n\n\
         [[lines.devices]]\nname = \"valve\"\nprofile = \"wuzhou-valve\"\naddress = 1\n",
        broker.url(),
        support::free_port()
    );
    let config_path = dir.path().join("config.toml");
    std::fs::write(&config_path, config).expect("write config");
    let start = |state: Option<&Path>, log: &Path| {
        let mut command = child::gateway_run(&config_path);
        command
            .env("RUST_LOG", "warn")
            .stderr(std::fs::File::create(log).expect("log file"));
        match state {
            Some(state) => command.env("STATE_DIRECTORY", state),
            None => command.env_remove("STATE_DIRECTORY"),
        };
        KillOnDrop::spawn(command).expect("rtu2mqtt run starts")
    };

    let unwritable_log = dir.path().join("unwritable.log");
    let gateway = start(Some(&blocker.join("state")), &unwritable_log);
    // Refused attempts meanwhile: the back-off starts at 250 ms.
    tokio::time::sleep(Duration::from_secs(4)).await;
    broker.restart();
    let mut host = TestClient::connect(broker.port, "kept-host").await;
    host.subscribe("spBv1.0/#").await;
    host.wait_for(&format!("spBv1.0/{GROUP}/NBIRTH/kept-gw"), ANSWER, |_| true)
        .await;
    drop(gateway);
    let said = std::fs::read_to_string(&unwritable_log).unwrap_or_default();
    let warnings: Vec<&str> = said
        .lines()
        .filter(|line| line.contains("Sparkplug bdSeq"))
        .collect();
    assert_eq!(warnings.len(), 1, "{said}");
    assert!(warnings[0].contains("cannot be kept"), "{said}");
    assert!(
        warnings[0].contains("STATE_DIRECTORY"),
        "names the fix: {said}"
    );

    let nowhere_log = dir.path().join("nowhere.log");
    let gateway = start(None, &nowhere_log);
    host.wait_for(&format!("spBv1.0/{GROUP}/NBIRTH/kept-gw"), ANSWER, |_| true)
        .await;
    drop(gateway);
    let said = std::fs::read_to_string(&nowhere_log).unwrap_or_default();
    let warnings: Vec<&str> = said
        .lines()
        .filter(|line| line.contains("Sparkplug bdSeq"))
        .collect();
    assert_eq!(warnings.len(), 1, "{said}");
    assert!(warnings[0].contains("not kept across restarts"), "{said}");
}
