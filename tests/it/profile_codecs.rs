//! The profile language's codecs end to end: a profile file of a device of one's own (64-bit
//! counters, a SunSpec-style scale factor, "not available" marks, a model name as text, a
//! temperature with an offset, 64-bit setpoints), a generic simulated device holding a register
//! image written by hand, on a real pseudo-terminal, the gateway and a real mosquitto.
//!
//! - The u64 counter above i64::MAX is published digit for digit on its topic and in the JSON
//!   view; the scaled power is 12345 × 10^-1; the `invalid` field is `null` in the JSON view
//!   and its topic is never published; the model name is text.
//! - An i64 setpoint (low word first) and an f64 limit are written with FC16, the frames golden
//!   byte for byte, and read back.

use std::time::Duration;

use rtu2mqtt::profile::Profile;
use rtu2mqtt::sim::{lock, share, GenericDevice, ServeOptions, VirtualLine};
use rtu2mqtt_modbus::timing::Parity;

use crate::support::{fast_config, hex, Gateway, Mosquitto, TestClient};

const WAIT: Duration = Duration::from_secs(10);

const PROFILE: &str = r#"
[device]
name = "own-meter"
manufacturer = "Example"
model = "M64"

[line]
baud = 9600

[[blocks]]
name = "main"
function = 3
start = 0
count = 24

[[fields]]
name = "energy"
block = "main"
offset = 0
codec = { type = "u64" }
unit = "Wh"

[[fields]]
name = "power"
block = "main"
offset = 4
codec = { type = "i16", scale_by = "power_sf" }
unit = "W"

[[fields]]
name = "power_sf"
block = "main"
offset = 5
codec = { type = "i16", invalid = [0x8000] }

[[fields]]
name = "current"
block = "main"
offset = 6
codec = { type = "u16", decimals = 2, invalid = [0xFFFF] }
unit = "A"

[[fields]]
name = "model"
block = "main"
offset = 7
codec = { type = "string", registers = 4 }

[[fields]]
name = "setpoint"
block = "main"
offset = 11
codec = { type = "i64", word_order = "low_first" }
range = [-1e15, 1e15]
write = { function = 16, address = 11 }

[[fields]]
name = "limit"
block = "main"
offset = 15
codec = { type = "f64", decimals = 3 }
range = [-1e6, 1e6]
write = { function = 16, address = 15 }

[[fields]]
name = "temperature"
block = "main"
offset = 19
codec = { type = "u16", decimals = 1, offset = -40 }
unit = "°C"
"#;

/// The device's registers: 0xFFFF_FFFF_FFFF_FFFE Wh, 12345 at 10^-1 W, current not
/// available, "SDM630", setpoint and limit zero, 21.5 °C as 615 − 400 tenths.
const REGISTERS: [(u16, u16); 12] = [
    (0, 0xFFFF),
    (1, 0xFFFF),
    (2, 0xFFFF),
    (3, 0xFFFE),
    (4, 12345),
    (5, 0xFFFF),
    (6, 0xFFFF),
    (7, 0x5344),
    (8, 0x4D36),
    (9, 0x3330),
    (10, 0x0000),
    (19, 615),
];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_of_ones_own_publishes_and_takes_64_bit_values_exactly() {
    let dir = tempfile::tempdir().expect("temp dir");
    let profile_path = dir.path().join("own-meter.toml");
    std::fs::write(&profile_path, PROFILE).expect("write the profile");
    let profile = Profile::from_toml(PROFILE, "own-meter.toml").expect("a valid profile");
    let mut device = GenericDevice::from_blocks(profile.read_blocks(), 1);
    for address in 0..24 {
        device.set_holding(address, 0);
    }
    for (address, value) in REGISTERS {
        device.set_holding(address, value);
    }
    let (device, shared) = share(device);
    let line =
        VirtualLine::spawn(ServeOptions::new(9600, Parity::None), vec![shared]).expect("line");

    let broker = Mosquitto::start();
    let mut client = TestClient::connect(broker.port, "codec-test").await;
    client.subscribe("plant/#").await;
    let config = fast_config(&format!(
        r#"
[mqtt]
url = "{url}"
client_id = "codec-gateway"
prefix = "plant"

[gateway]
json_view = true

[[lines]]
name = "line-a"
port = "{port}"
response_timeout = "150ms"

[[lines.devices]]
name = "meter"
profile = "{profile}"
address = 1
"#,
        url = broker.url(),
        port = line.path().display(),
        profile = profile_path.display(),
    ));
    let gateway = Gateway::start(config).await;

    for (topic, expected) in [
        ("plant/meter/energy", "18446744073709551614"),
        ("plant/meter/power", "1234.5"),
        ("plant/meter/power_sf", "-1"),
        ("plant/meter/model", "SDM630"),
        // 615 tenths − 40.0.
        ("plant/meter/temperature", "21.5"),
    ] {
        let message = client.next_on(topic, WAIT).await;
        assert_eq!(message.text(), expected, "{topic}");
    }
    let view = client
        .wait_for("plant/meter", WAIT, |m| m.json().get("energy").is_some())
        .await;
    // The JSON text itself: the counter is the exact integer, not a rounded double.
    let text = view.text();
    assert!(text.contains(r#""energy":18446744073709551614"#), "{text}");
    assert!(text.contains(r#""current":null"#), "{text}");
    assert!(text.contains(r#""power":1234.5"#), "{text}");
    assert!(text.contains(r#""model":"SDM630""#), "{text}");

    // i64 with the low word first, then f64: one FC16 frame each, golden.
    line.journal().clear();
    client
        .publish("plant/meter/setpoint/set", "-1234567890123", false)
        .await;
    client
        .wait_for("plant/meter/setpoint", WAIT, |m| {
            m.text() == "-1234567890123"
        })
        .await;
    client
        .publish("plant/meter/limit/set", "123.456", false)
        .await;
    client
        .wait_for("plant/meter/limit", WAIT, |m| m.text() == "123.456")
        .await;
    assert_eq!(
        hex::writes(&line.journal().frames(), 1),
        [
            "01 10 00 0B 00 04 08 FB 35 8E 04 FE E0 FF FF A6 D5",
            "01 10 00 0F 00 04 08 40 5E DD 2F 1A 9F BE 77 D8 60",
        ]
    );
    assert_eq!(lock(&device).holding(14), Some(0xFFFF));

    // The exponent changes: the power follows in the same poll.
    lock(&device).set_holding(5, 2);
    client
        .wait_for("plant/meter/power", WAIT, |m| m.text() == "1234500")
        .await;
    // The exponent becomes "not implemented": the power is not published, its view is null.
    lock(&device).set_holding(5, 0x8000);
    let view = client
        .wait_for("plant/meter", WAIT, |m| {
            m.json().get("power") == Some(&serde_json::Value::Null)
        })
        .await;
    assert_eq!(view.json()["power_sf"], serde_json::Value::Null);
    client.settle(Duration::from_millis(500)).await;
    assert!(
        client.on("plant/meter/current").is_empty(),
        "an unavailable value is never published on its topic"
    );
    assert!(client
        .on("plant/meter/power")
        .iter()
        .all(|m| !m.text().is_empty()));
    gateway.stop().await;
}
