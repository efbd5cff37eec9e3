//! Publishing by exception, as users meet it: `publish` settings in a profile's field and as a
//! device's default in the configuration are checked with their place; end to end (the
//! simulated seed plant on ptys, a real mosquitto, the Sparkplug node decoded by pysparkplug),
//! a value with a deadband is not republished for a small move, is for a large one, goes out
//! again unchanged every `max_interval`, and Sparkplug DDATA carries the same series as the
//! plain topic.

use crate::support;
use crate::support::pysparkplug::decode_with_pysparkplug;

use std::path::Path;
use std::time::{Duration, Instant};

use rtu2mqtt::config;
use rtu2mqtt_profile::Profile;
use rtu2mqtt_sim::{self as sim, SeedPlant};
use serde_json::Value as Json;
use support::{Gateway, Message, Mosquitto, PlantConfig, TestClient};

/// Generous bound for a busy 2-core machine: it only runs out when something is broken.
const ANSWER: Duration = Duration::from_secs(20);
/// The valve's heartbeat in the end-to-end test.
const HEARTBEAT: Duration = Duration::from_secs(5);

const PROFILE: &str = r#"
[device]
name = "publish-test"
manufacturer = "Test"
model = "T1"

[line]

[[blocks]]
name = "main"
function = 3
start = 0
count = 3

[[fields]]
name = "running"
block = "main"
offset = 0
codec = { type = "bit", bit = 1 }

[[fields]]
name = "level"
block = "main"
offset = 1
codec = { type = "u16", decimals = 1 }
"#;

fn profile_problems(status: &str, level: &str) -> String {
    let text = PROFILE
        .replace(
            "codec = { type = \"bit\", bit = 1 }",
            &format!("codec = {{ type = \"bit\", bit = 1 }}\n{status}"),
        )
        .replace(
            "codec = { type = \"u16\", decimals = 1 }",
            &format!("codec = {{ type = \"u16\", decimals = 1 }}\n{level}"),
        );
    match Profile::from_toml(&text, "test.toml") {
        Ok(_) => String::new(),
        Err(problems) => problems.to_string(),
    }
}

#[test]
fn a_fields_publish_settings_are_checked_with_their_place() {
    let good = "publish = { deadband = 0.5, deadband_percent = 1.0, min_interval = \"5s\", \
                max_interval = \"60s\" }";
    assert_eq!(
        profile_problems("publish = { min_interval = \"1s\" }", good),
        ""
    );
    let level = Profile::from_toml(
        &PROFILE.replace(
            "codec = { type = \"u16\", decimals = 1 }",
            &format!("codec = {{ type = \"u16\", decimals = 1 }}\n{good}"),
        ),
        "test.toml",
    )
    .unwrap();
    let publish = level.field("level").unwrap().publish;
    assert_eq!(
        publish.deadband.map(|d| d.to_string()).as_deref(),
        Some("0.5")
    );
    assert_eq!(publish.max_interval, Some(Duration::from_secs(60)));

    let found = profile_problems(
        "publish = { deadband = 1 }",
        "publish = { deadband = -0.5, min_interval = \"90s\", max_interval = \"1m\" }",
    );
    for expected in [
        "test.toml: fields[0] (running).publish.deadband: a deadband needs a number",
        "test.toml: fields[1] (level).publish.deadband: -0.5 is not a number of at least 0",
        "test.toml: fields[1] (level).publish.min_interval: min_interval 1m 30s is over \
         max_interval 1m",
    ] {
        assert!(found.contains(expected), "{expected:?} not in:\n{found}");
    }
    let found = profile_problems("", "publish = { deadbnd = 1 }");
    assert!(found.contains("unknown field `deadbnd`"), "{found}");
    let found = profile_problems("", "publish = { max_interval = \"100ms\" }");
    assert!(
        found.contains("fields[1] (level).publish.max_interval: 100ms is under the shortest"),
        "{found}"
    );
}

const CONFIG: &str = r#"
[mqtt]
url = "mqtt://127.0.0.1:1883"
client_id = "edge1"

[[lines]]
name = "a"
port = "/dev/ttyS0"

[[lines.devices]]
name = "dust"
profile = "ruiwan-dust-collector"
address = 1
"#;

fn config_problems(publish: &str) -> String {
    match config::from_str(&format!("{CONFIG}{publish}\n"), Path::new(".")) {
        Ok(_) => String::new(),
        Err(problems) => problems.to_string(),
    }
}

#[test]
fn a_devices_publish_default_is_checked_with_its_place() {
    assert_eq!(
        config_problems("publish = { deadband_percent = 1.0, max_interval = \"60s\" }"),
        ""
    );
    let config = config::from_str(
        &format!("{CONFIG}publish = {{ deadband_percent = 1, max_interval = \"60s\" }}\n"),
        Path::new("."),
    )
    .unwrap();
    let device = &config.lines[0].devices[0];
    assert_eq!(
        device
            .publish
            .deadband_percent
            .map(|d| d.to_string())
            .as_deref(),
        Some("1")
    );
    // A device default deadband is fine on a device with ON/OFF fields: it applies to numbers.
    assert_eq!(config_problems("publish = { deadband = 2 }"), "");

    let found = config_problems(
        "publish = { deadband = -1, deadband_percent = -0.1, min_interval = \"2m\", \
         max_interval = \"1m\" }",
    );
    for expected in [
        "lines[0].devices[0].publish.deadband: -1 is not a number of at least 0",
        "lines[0].devices[0].publish.deadband_percent: -0.1 is not a number of at least 0",
        "lines[0].devices[0].publish.min_interval: min_interval 2m is over max_interval 1m",
    ] {
        assert!(found.contains(expected), "{expected:?} not in:\n{found}");
    }
    let found = config_problems("publish = { deadbnad = 1 }");
    assert!(
        found.contains(
            "lines[0].devices[0].publish.deadbnad: unknown key, did you mean `deadband`?"
        ),
        "{found}"
    );
    let found = config_problems("publish = { min_interval = \"soon\" }");
    assert!(
        found.contains("lines[0].devices[0].publish.min_interval: \"soon\" is not a duration"),
        "{found}"
    );
    let found = config_problems("publish = { deadband = \"0.5\" }");
    assert!(
        found.contains("lines[0].devices[0].publish.deadband: \"0.5\" is not a number"),
        "{found}"
    );
}

#[test]
fn a_fields_own_keys_and_its_devices_must_hold_together() {
    let files = tempfile::tempdir().unwrap();
    let profile = files.path().join("publish-test.toml");
    let text = PROFILE.replace(
        "codec = { type = \"u16\", decimals = 1 }",
        "codec = { type = \"u16\", decimals = 1 }\npublish = { min_interval = \"90s\" }",
    );
    std::fs::write(&profile, text).unwrap();
    let config = CONFIG.replace(
        "profile = \"ruiwan-dust-collector\"",
        &format!("profile = {:?}", profile.display().to_string()),
    );
    let load = |publish: &str| match config::from_str(&format!("{config}{publish}\n"), files.path())
    {
        Ok(_) => String::new(),
        Err(problems) => problems.to_string(),
    };
    assert_eq!(load("publish = { max_interval = \"2m\" }"), "");
    let found = load("publish = { max_interval = \"1m\" }");
    assert!(
        found.contains(
            "lines[0].devices[0].publish: field `level` of profile publish-test: min_interval \
             1m 30s is over max_interval 1m"
        ),
        "{found}"
    );
}

// ----- end to end -----

/// `spBv1.0/<group>/<kind>/<node>/<device>` is a `kind` message of `device`.
fn sparkplug_is(message: &Message, kind: &str, device: &str) -> bool {
    let levels: Vec<&str> = message.topic.split('/').collect();
    levels.len() == 5 && levels[0] == "spBv1.0" && levels[2] == kind && levels[4] == device
}

/// The valve's `opening` as pysparkplug decodes it from the DBIRTH and every DDATA of `log`,
/// in order (DDATA without it left out).
fn sparkplug_openings(log: &[Message]) -> Vec<String> {
    let messages: Vec<&Message> = log
        .iter()
        .filter(|m| sparkplug_is(m, "DBIRTH", "valve") || sparkplug_is(m, "DDATA", "valve"))
        .collect();
    let decoded =
        decode_with_pysparkplug(messages.iter().map(|m| (m.topic.as_str(), &m.payload[..])));
    decoded
        .iter()
        .filter_map(|message| {
            message["metrics"]
                .as_array()?
                .iter()
                .find(|metric| metric["name"] == "opening")
        })
        .map(|metric| match &metric["value"] {
            Json::Number(number) => number.to_string(),
            other => format!("{other}"),
        })
        .collect()
}

/// The plain topic's series of the valve's `opening` in `log`.
fn plain_openings(log: &[Message]) -> Vec<String> {
    log.iter()
        .filter(|m| m.topic == "plant/valve/opening")
        .map(Message::text)
        .collect()
}

/// Collects until `done` holds for what was received, or panics after [`ANSWER`].
async fn collect_until(client: &mut TestClient, what: &str, done: impl Fn(&[Message]) -> bool) {
    let deadline = tokio::time::Instant::now() + ANSWER;
    while !done(&client.received) {
        assert!(
            tokio::time::Instant::now() < deadline,
            "no {what} within {ANSWER:?}: plain {:?}",
            plain_openings(&client.received)
        );
        client.settle(Duration::from_millis(100)).await;
    }
}

/// Frames on the valve's line so far (requests and answers).
fn valve_frames(plant: &SeedPlant) -> usize {
    plant.line_b.journal().frames().len()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_deadband_holds_small_moves_a_heartbeat_repeats_and_sparkplug_follows_the_same_series() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap_or_else(|error| panic!("{error}"));
    sim::lock(&plant.valve).set_opening(40);
    let mut client = TestClient::connect(broker.port, "publish-observer").await;
    client.subscribe("plant/valve/opening").await;
    client.subscribe("spBv1.0/+/DBIRTH/+/valve").await;
    client.subscribe("spBv1.0/+/DDATA/+/valve").await;
    let mut text = PlantConfig {
        gateway: "stats_interval = \"1s\"",
        explicit_serial: true,
        line_keys: "retries = 1\noffline_after = 2",
        ..PlantConfig::default()
    }
    .text(&broker, &plant, "publish-gw");
    let valve = "profile = \"wuzhou-valve\"\naddress = 1\n";
    assert!(text.contains(valve));
    text = text.replace(
        valve,
        &format!(
            "{valve}publish = {{ deadband = 5, max_interval = \"{}s\" }}\n",
            HEARTBEAT.as_secs()
        ),
    );
    text.push_str("\n[health]\nstatus_file = \"\"\n\n[sparkplug]\ngroup_id = \"plant\"\n");
    let gateway = Gateway::start(support::fast_config(&text)).await;

    // The first value goes out as read, on both sides.
    collect_until(&mut client, "first opening and DBIRTH", |log| {
        plain_openings(log) == ["40"] && log.iter().any(|m| sparkplug_is(m, "DBIRTH", "valve"))
    })
    .await;

    // A move of 20 from the last published 40: published at once.
    sim::lock(&plant.valve).set_opening(60);
    collect_until(&mut client, "opening 60", |log| {
        plain_openings(log).last().map(String::as_str) == Some("60")
    })
    .await;
    let published_at = Instant::now();

    // Unchanged: the heartbeat publishes 60 again, not sooner than its interval.
    collect_until(&mut client, "the heartbeat", |log| {
        plain_openings(log).len() >= 3
    })
    .await;
    let beat_at = Instant::now();
    assert!(
        beat_at - published_at + Duration::from_secs(1) >= HEARTBEAT,
        "the heartbeat came after {:?}",
        beat_at - published_at
    );
    assert_eq!(plain_openings(&client.received), ["40", "60", "60"]);

    // A move of 2 (inside the deadband of 5): read over several poll cycles, not published.
    sim::lock(&plant.valve).set_opening(62);
    let frames = valve_frames(&plant);
    while valve_frames(&plant) < frames + 12 {
        client.settle(Duration::from_millis(100)).await;
    }
    client.settle(Duration::from_millis(300)).await;
    assert!(
        beat_at.elapsed() < HEARTBEAT,
        "the machine is too slow for this test: the next heartbeat is due"
    );
    assert_eq!(
        plain_openings(&client.received),
        ["40", "60", "60"],
        "62 was held back"
    );
    // A move of 18 from the last published 60: published with the next poll.
    sim::lock(&plant.valve).set_opening(78);
    collect_until(&mut client, "opening 78", |log| {
        plain_openings(log).last().map(String::as_str) == Some("78")
    })
    .await;
    assert_eq!(plain_openings(&client.received), ["40", "60", "60", "78"]);

    // Sparkplug: the same series, birth then DDATA, the heartbeat included.
    let deadline = tokio::time::Instant::now() + ANSWER;
    loop {
        let ddata = client
            .received
            .iter()
            .filter(|m| sparkplug_is(m, "DDATA", "valve"))
            .count();
        if ddata >= 3 || tokio::time::Instant::now() >= deadline {
            break;
        }
        client.settle(Duration::from_millis(100)).await;
    }
    let plain = plain_openings(&client.received);
    let sparkplug = sparkplug_openings(&client.received);
    assert_eq!(sparkplug, plain, "DBIRTH and DDATA against the plain topic");
    gateway.stop().await;
}
