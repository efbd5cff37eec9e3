//! "No value" end to end: a meter on a real pty whose float reads NaN, whose float holds a
//! listed "not available" value, whose enum holds a code the profile does not name and whose
//! integer holds an `invalid` mark. Every consumer on a real mosquitto sees the field as
//! unavailable (the plain topic says `unavailable`, the JSON view `null`, Home Assistant's
//! template turns it into unknown), the episode is counted once in the line's statistics, and
//! the values coming back are published again.

use crate::support;

use std::time::Duration;

use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_profile::Profile;
use rtu2mqtt_sim::{self as sim, share, GenericDevice, ServeOptions, VirtualLine};
use serde_json::Value as Json;
use support::{Gateway, Mosquitto, TestClient};

const ANSWER: Duration = Duration::from_secs(15);
const ADDRESS: u8 = 7;

const PROFILE: &str = r#"
[device]
name = "nan-meter"
manufacturer = "Test"
model = "N1"

[line]
min_poll_interval = "100ms"

[[blocks]]
name = "b"
function = 3
start = 0
count = 6

[[fields]]
name = "frequency"
block = "b"
offset = 0
codec = { type = "f32", invalid = ["nan", -1.0], decimals = 2 }

[[fields]]
name = "run_state"
block = "b"
offset = 2
codec = { type = "enum", values = { 0 = "waiting", 1 = "normal", 3 = "fault" }, unknown = "invalid" }

[[fields]]
name = "fault_code"
block = "b"
offset = 3
codec = { type = "enum", values = { 0 = "none", 5 = "overheat" }, unknown = "publish_number" }

[[fields]]
name = "temperature"
block = "b"
offset = 4
codec = { type = "i16", invalid = [0x8000], decimals = 1 }
"#;

fn set_float(device: &std::sync::Mutex<GenericDevice>, address: u16, value: f32) {
    let bits = value.to_bits();
    let mut device = sim::lock(device);
    device.set_holding(address, (bits >> 16) as u16);
    device.set_holding(address + 1, bits as u16);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_value_the_device_does_not_have_is_unavailable_for_every_consumer_and_counted_once() {
    let dir = tempfile::tempdir().unwrap();
    let profile_path = dir.path().join("nan-meter.toml");
    std::fs::write(&profile_path, PROFILE).unwrap();
    let profile = Profile::from_toml(PROFILE, "nan-meter.toml").unwrap();
    let (meter, shared) = share(GenericDevice::from_profile(&profile, ADDRESS));
    set_float(&meter, 0, 50.02);
    sim::lock(&meter).set_holding(2, 1);
    sim::lock(&meter).set_holding(3, 5);
    sim::lock(&meter).set_holding(4, 215);
    let line = VirtualLine::spawn(ServeOptions::new(9600, Parity::None), vec![shared]).unwrap();
    let broker = Mosquitto::start();
    let mut observer = TestClient::connect(broker.port, "nan-observer").await;
    observer.subscribe("plant/#").await;
    observer.subscribe("homeassistant/#").await;

    let text = format!(
        r#"
[mqtt]
url = "{url}"
client_id = "nan-gw"
prefix = "plant"
discovery = true

[gateway]
json_view = true
stats_interval = "1s"

[[lines]]
name = "line-n"
port = "{port}"
baud = 9600
parity = "none"
response_timeout = "150ms"

[[lines.devices]]
name = "meter"
profile = "{profile}"
address = {ADDRESS}
poll_interval = "200ms"
"#,
        url = broker.url(),
        port = line.path().display(),
        profile = profile_path.display(),
    );
    let config = rtu2mqtt::config::from_str(&text, dir.path()).expect("valid configuration");
    let gateway = Gateway::start(config).await;

    let wait_text = |topic: &'static str, want: &'static str| (topic, want);
    for (topic, want) in [
        wait_text("plant/meter/frequency", "50.02"),
        wait_text("plant/meter/run_state", "normal"),
        wait_text("plant/meter/fault_code", "overheat"),
        wait_text("plant/meter/temperature", "21.5"),
    ] {
        observer.wait_for(topic, ANSWER, |m| m.text() == want).await;
    }

    // Home Assistant is told how to read `unavailable`: as unknown, never as a number; the
    // enum publishing unnamed codes is no closed list.
    let discovery = observer
        .wait_for("homeassistant/device/nan-gw_meter/config", ANSWER, |_| true)
        .await
        .json();
    let components = &discovery["cmps"];
    let frequency = &components["frequency"];
    assert_eq!(
        frequency["value_template"],
        rtu2mqtt::bridge::core::discovery::UNAVAILABLE_AS_UNKNOWN,
        "{frequency}"
    );
    assert_eq!(
        components["run_state"]["options"],
        serde_json::json!(["waiting", "normal", "fault"])
    );
    assert_eq!(
        components["fault_code"].get("options"),
        None,
        "{}",
        components["fault_code"]
    );
    assert_eq!(components["fault_code"].get("device_class"), None);

    // NaN, a listed value, an unnamed code, an invalid mark: unavailable, and a code published
    // as its number.
    set_float(&meter, 0, f32::NAN);
    sim::lock(&meter).set_holding(2, 2);
    sim::lock(&meter).set_holding(3, 9);
    sim::lock(&meter).set_holding(4, 0x8000);
    for (topic, want) in [
        wait_text("plant/meter/frequency", "unavailable"),
        wait_text("plant/meter/run_state", "unavailable"),
        wait_text("plant/meter/fault_code", "9"),
        wait_text("plant/meter/temperature", "unavailable"),
    ] {
        let message = observer.wait_for(topic, ANSWER, |m| m.text() == want).await;
        assert!(message.retain || message.text() == want);
    }
    let view = observer
        .wait_for("plant/meter", ANSWER, |m| {
            m.json().get("frequency").is_some_and(Json::is_null)
        })
        .await
        .json();
    assert_eq!(view["run_state"], Json::Null, "{view}");
    assert_eq!(view["temperature"], Json::Null, "{view}");
    assert_eq!(view["fault_code"], 9, "{view}");

    // The listed float value is no value either; the episode of `frequency` goes on.
    set_float(&meter, 0, -1.0);
    observer.settle(Duration::from_millis(800)).await;
    assert!(
        observer
            .on("plant/meter/frequency")
            .iter()
            .all(|m| m.text() == "unavailable"),
        "{:?}",
        observer.on("plant/meter/frequency")
    );

    // One episode per field, however many polls: three fields turned unavailable once.
    let stats = observer
        .wait_for_new("plant/gateway/nan-gw/stats/line-n", ANSWER, |m| {
            m.json()["devices"]["meter"]["unavailable_episodes"] == 3
        })
        .await
        .json();
    assert_eq!(stats["devices"]["meter"]["unavailable_episodes"], 3);

    // The values come back.
    set_float(&meter, 0, 49.98);
    sim::lock(&meter).set_holding(2, 3);
    sim::lock(&meter).set_holding(4, 200);
    for (topic, want) in [
        wait_text("plant/meter/frequency", "49.98"),
        wait_text("plant/meter/run_state", "fault"),
        wait_text("plant/meter/temperature", "20.0"),
    ] {
        observer.wait_for(topic, ANSWER, |m| m.text() == want).await;
    }
    gateway.stop().await;
}
