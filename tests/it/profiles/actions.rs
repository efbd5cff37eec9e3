//! Actions (a profile's command interfaces) end to end: a profile written here with a tariff
//! command (command number, a reserved word, the tariff; a result register read after) and a
//! reset without parameters or result register, a generic simulated device with a command
//! interface that answers like a meter (0 ok, 3001 for a tariff it has not), on a real
//! pseudo-terminal, the gateway and a real mosquitto.
//!
//! - On `…/set_tariff/set`, `{"tariff": 2}` (sent retained) is cleared from the broker, then
//!   written as one FC16 frame byte for byte, the result register read right after it, and
//!   `applied` naming the code comes on `…/set_tariff/result`; the device ran it once.
//! - `{"tariff": 9}` is outside the profile's range: `rejected`, nothing on the wire.
//! - `6` (a bare value) is in the profile's range but not the device's: its code 3001 comes
//!   back as `not_applied` naming the code and its name.
//! - `PRESS` on `…/reset_partial/set` writes its frame and, with no result register to read,
//!   is `applied` once acknowledged.
//! - Home Assistant gets a number and a button sending on those topics; Sparkplug a UInt8 and a
//!   Boolean metric (decoded by pysparkplug), which DCMDs run like `…/set` does.

use std::time::Duration;

use rtu2mqtt::sparkplug::core::protobuf::{DataType, MetricValue, Payload};
use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_profile::Profile;
use rtu2mqtt_sim::command_interface::INVALID_PARAMETER;
use rtu2mqtt_sim::{lock, share, CommandInterface, GenericDevice, ServeOptions, VirtualLine};
use serde_json::{json, Value as Json};

use crate::sparkplug::sparkplug_node::command;
use crate::support::pysparkplug::decode_with_pysparkplug;
use crate::support::{fast_config, hex, Gateway, Mosquitto, TestClient};

const WAIT: Duration = Duration::from_secs(20);

const PROFILE: &str = r#"
[device]
name = "tariff-meter"
manufacturer = "Example"
model = "T4"

[line]

[[blocks]]
name = "main"
function = 3
start = 0
count = 2

[[fields]]
name = "energy"
block = "main"
offset = 0
codec = { type = "u32" }
unit = "Wh"

[[actions]]
name = "set_tariff"
description = "Selects the active tariff"
address = 5249
registers = [2060, 0, "tariff"]
params = { tariff = { range = [1, 8] } }
result = { address = 5375, codes = { 0 = "ok", 3000 = "invalid command", 3001 = "invalid parameter" } }

[[actions]]
name = "reset_partial"
address = 5249
registers = [2020, 0]
"#;

/// Tariff 2: FC16 of 3 registers at 5249 (0x1481): 2060 (0x080C), 0, 2.
const TARIFF_2: &str = "01 10 14 81 00 03 06 08 0C 00 00 00 02 61 D5";
/// Tariff 6, which the device does not have.
const TARIFF_6: &str = "01 10 14 81 00 03 06 08 0C 00 00 00 06 60 16";
/// Tariff 3, from a Sparkplug DCMD.
const TARIFF_3: &str = "01 10 14 81 00 03 06 08 0C 00 00 00 03 A0 15";
/// The read of the result register 5375 (0x14FF).
const RESULT_READ: &str = "01 03 14 FF 00 01 B1 CA";
/// Reset: FC16 of 2 registers at 5249: 2020 (0x07E4), 0.
const RESET: &str = "01 10 14 81 00 02 04 07 E4 00 00 84 40";

/// A meter with tariffs 1–4 and the reset, on a pty of its own.
struct Bench {
    device: std::sync::Arc<std::sync::Mutex<GenericDevice>>,
    line: VirtualLine,
    broker: Mosquitto,
    client: TestClient,
    gateway: Gateway,
    _dir: tempfile::TempDir,
}

impl Bench {
    async fn start(client_id: &str, extra: &str) -> Bench {
        let dir = tempfile::tempdir().expect("temp dir");
        let profile_path = dir.path().join("tariff-meter.toml");
        std::fs::write(&profile_path, PROFILE).expect("write the profile");
        let profile = Profile::from_toml(PROFILE, "tariff-meter.toml").expect("a valid profile");
        let interface = CommandInterface::new(5249, 5375)
            .command(2060, vec![0..=0, 1..=4])
            .command(2020, vec![0..=0]);
        let device =
            GenericDevice::from_blocks(profile.read_blocks(), 1).with_command_interface(interface);
        let (device, shared) = share(device);
        let line =
            VirtualLine::spawn(ServeOptions::new(9600, Parity::None), vec![shared]).expect("line");
        let broker = Mosquitto::start();
        let mut client = TestClient::connect(broker.port, &format!("{client_id}-observer")).await;
        client.subscribe("plant/#").await;
        client.subscribe("homeassistant/#").await;
        client.subscribe("spBv1.0/#").await;
        let config = fast_config(&format!(
            r#"
[mqtt]
url = "{url}"
client_id = "{client_id}"
prefix = "plant"

[[lines]]
name = "line-a"
port = "{port}"
response_timeout = "150ms"

[[lines.devices]]
name = "meter"
profile = "{profile}"
address = 1
{extra}"#,
            url = broker.url(),
            port = line.path().display(),
            profile = profile_path.display(),
        ));
        let gateway = Gateway::start(config).await;
        client
            .wait_for("plant/meter/availability", WAIT, |m| m.text() == "online")
            .await;
        Bench {
            device,
            line,
            broker,
            client,
            gateway,
            _dir: dir,
        }
    }

    /// Sends `payload` on the action's `…/set` and waits for its result.
    async fn command(&mut self, action: &str, payload: &str, retain: bool) -> Json {
        let result = format!("plant/meter/{action}/result");
        self.client.drain();
        self.client.received.retain(|m| m.topic != result);
        self.client
            .publish(&format!("plant/meter/{action}/set"), payload, retain)
            .await;
        self.client.next_on(&result, WAIT).await.json()
    }

    /// The frames the line heard since the journal was last cleared, as hex.
    fn frames(&self) -> Vec<String> {
        let frames = self.line.journal().frames();
        frames.iter().map(|frame| hex::encode(frame)).collect()
    }

    /// The commands the device carried out.
    fn executed(&self) -> Vec<(u16, Vec<u16>)> {
        lock(&self.device)
            .command_interface()
            .map(|interface| interface.executed().to_vec())
            .unwrap_or_default()
    }
}

/// The frame right after `frame` in `frames` (None when `frame` is missing or last).
fn after<'a>(frames: &'a [String], frame: &str) -> Option<&'a str> {
    let at = frames.iter().position(|f| f == frame)?;
    frames.get(at + 1).map(String::as_str)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_action_is_one_frame_its_result_read_and_one_outcome() {
    let mut bench = Bench::start("actions-gw", "").await;

    // Discovery: a number for the tariff (its range from the profile), a button for the
    // reset, and the command-result event.
    let config = bench
        .client
        .wait_for("homeassistant/device/actions-gw_meter/config", WAIT, |m| {
            !m.payload.is_empty()
        })
        .await
        .json();
    let tariff = &config["cmps"]["set_tariff"];
    assert_eq!(
        (
            &tariff["p"],
            &tariff["min"],
            &tariff["max"],
            &tariff["command_topic"]
        ),
        (
            &json!("number"),
            &json!(1),
            &json!(8),
            &json!("plant/meter/set_tariff/set")
        ),
        "{config}"
    );
    let reset = &config["cmps"]["reset_partial"];
    assert_eq!(
        (
            &reset["p"],
            &reset["payload_press"],
            &reset["command_topic"]
        ),
        (
            &json!("button"),
            &json!("PRESS"),
            &json!("plant/meter/reset_partial/set")
        ),
        "{config}"
    );
    assert_eq!(config["cmps"]["command-result"]["p"], "event", "{config}");

    // A retained command: cleared first, then one frame and the result read, applied.
    bench.line.journal().clear();
    let result = bench.command("set_tariff", r#"{"tariff": 2}"#, true).await;
    assert_eq!(
        result,
        json!({
            "value": r#"{"tariff": 2}"#,
            "outcome": "applied",
            "detail": "the device reports result code 0 (ok)",
        })
    );
    let frames = bench.frames();
    assert_eq!(hex::writes(&bench.line.journal().frames(), 1), [TARIFF_2]);
    assert_eq!(after(&frames, TARIFF_2), Some(RESULT_READ), "{frames:?}");
    assert!(
        bench
            .client
            .on("plant/meter/set_tariff/set")
            .iter()
            .any(|m| m.payload.is_empty()),
        "the retained command is cleared"
    );
    assert_eq!(bench.executed(), [(2060, vec![0, 2])]);

    // Outside the profile's range: refused before the bus.
    bench.line.journal().clear();
    let result = bench.command("set_tariff", r#"{"tariff": 9}"#, false).await;
    assert_eq!(
        (&result["outcome"], &result["detail"]),
        (
            &json!("rejected"),
            &json!("set_tariff: tariff must be an integer 1–8, got 9")
        )
    );
    let result = bench.command("set_tariff", r#"{"rate": 2}"#, false).await;
    assert_eq!(
        result["detail"],
        "set_tariff has no parameter \"rate\" (its parameters: tariff)"
    );
    assert!(hex::writes(&bench.line.journal().frames(), 1).is_empty());

    // Inside the profile's range, not the device's: its code, named.
    let result = bench.command("set_tariff", "6", false).await;
    assert_eq!(
        result,
        json!({
            "value": "6",
            "outcome": "not_applied",
            "detail": format!(
                "set_tariff: the device reports result code {INVALID_PARAMETER} (invalid parameter)"
            ),
        })
    );
    assert_eq!(hex::writes(&bench.line.journal().frames(), 1), [TARIFF_6]);
    assert_eq!(after(&bench.frames(), TARIFF_6), Some(RESULT_READ));

    // Without parameters and result register: the acknowledged frame is the outcome.
    bench.line.journal().clear();
    let result = bench.command("reset_partial", "PRESS", false).await;
    assert_eq!(
        (&result["outcome"], &result["detail"]),
        (
            &json!("applied"),
            &json!("the device acknowledged the frame (the action has no result register to read)")
        )
    );
    let frames = bench.frames();
    assert_eq!(hex::writes(&bench.line.journal().frames(), 1), [RESET]);
    assert!(!frames.iter().any(|f| f == RESULT_READ), "{frames:?}");
    assert_eq!(bench.executed(), [(2060, vec![0, 2]), (2020, vec![0])]);

    bench.gateway.stop().await;
    drop(bench.broker);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sparkplug_runs_an_action_from_its_metric() {
    let mut bench = Bench::start("actions-sp", "\n[sparkplug]\ngroup_id = \"plant\"\n").await;
    let dcmd = "spBv1.0/plant/DCMD/actions-sp/meter";
    let birth = bench
        .client
        .wait_for("spBv1.0/plant/DBIRTH/actions-sp/meter", WAIT, |_| true)
        .await;

    // Born after the fields: a UInt8 for the tariff, a Boolean for the reset, both null.
    let decoded = decode_with_pysparkplug([(birth.topic.as_str(), &birth.payload[..])]);
    let metrics = decoded[0]["metrics"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    let shape: Vec<(Json, Json, Json)> = metrics
        .iter()
        .map(|m| {
            (
                m["name"].clone(),
                m["datatype"].clone(),
                m["is_null"].clone(),
            )
        })
        .collect();
    assert_eq!(
        shape,
        [
            (
                json!("energy"),
                json!(DataType::UInt32.number()),
                json!(false)
            ),
            (
                json!("set_tariff"),
                json!(DataType::UInt8.number()),
                json!(true)
            ),
            (
                json!("reset_partial"),
                json!(DataType::Boolean.number()),
                json!(true)
            ),
        ],
        "{}",
        decoded[0]
    );
    assert_eq!(
        metrics[1]["properties"]["description"],
        "Selects the active tariff"
    );

    // The tariff as an integer: the frame, the result read, the plain result.
    bench.line.journal().clear();
    bench.client.drain();
    bench
        .client
        .publish(
            dcmd,
            command("set_tariff", DataType::UInt8, MetricValue::Int(3)),
            false,
        )
        .await;
    let result = bench
        .client
        .next_on("plant/meter/set_tariff/result", WAIT)
        .await
        .json();
    assert_eq!(
        (&result["value"], &result["outcome"]),
        (&json!("3"), &json!("applied")),
        "{result}"
    );
    assert_eq!(hex::writes(&bench.line.journal().frames(), 1), [TARIFF_3]);
    assert_eq!(after(&bench.frames(), TARIFF_3), Some(RESULT_READ));

    // The reset runs on true; false is refused without a frame, the metric null again.
    let press = |on: bool| command("reset_partial", DataType::Boolean, MetricValue::Boolean(on));
    bench.line.journal().clear();
    bench.client.publish(dcmd, press(false), false).await;
    let reset_alias = Payload::decode_bytes(&birth.payload)
        .unwrap_or_default()
        .metrics
        .iter()
        .find(|m| m.name.as_deref() == Some("reset_partial"))
        .and_then(|m| m.alias);
    let ddata = bench
        .client
        .wait_for("spBv1.0/plant/DDATA/actions-sp/meter", WAIT, |m| {
            let payload = Payload::decode_bytes(&m.payload).unwrap_or_default();
            payload
                .metrics
                .iter()
                .any(|metric| metric.alias == reset_alias)
        })
        .await;
    let decoded = decode_with_pysparkplug([
        (birth.topic.as_str(), &birth.payload[..]),
        (ddata.topic.as_str(), &ddata.payload[..]),
    ]);
    let again = decoded[1]["metrics"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    assert!(
        again
            .iter()
            .any(|m| m["name"] == "reset_partial" && m["is_null"] == true),
        "{}",
        decoded[1]
    );
    assert!(hex::writes(&bench.line.journal().frames(), 1).is_empty());
    bench.client.publish(dcmd, press(true), false).await;
    let result = bench
        .client
        .next_on("plant/meter/reset_partial/result", WAIT)
        .await
        .json();
    assert_eq!(result["outcome"], "applied", "{result}");
    assert_eq!(hex::writes(&bench.line.journal().frames(), 1), [RESET]);
    assert_eq!(bench.executed(), [(2060, vec![0, 3]), (2020, vec![0])]);

    bench.gateway.stop().await;
    drop(bench.broker);
}
