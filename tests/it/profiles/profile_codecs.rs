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

use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_profile::Profile;
use rtu2mqtt_sim::{lock, share, GenericDevice, ServeOptions, VirtualLine};

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
    // The exponent becomes "not implemented": the power is unavailable, on its topic as in
    // its view (null), never a stale number or an empty payload.
    lock(&device).set_holding(5, 0x8000);
    let view = client
        .wait_for("plant/meter", WAIT, |m| {
            m.json().get("power") == Some(&serde_json::Value::Null)
        })
        .await;
    assert_eq!(view.json()["power_sf"], serde_json::Value::Null);
    client
        .wait_for("plant/meter/power", WAIT, |m| m.text() == "unavailable")
        .await;
    client.settle(Duration::from_millis(500)).await;
    assert!(client
        .on("plant/meter/power")
        .iter()
        .all(|m| !m.text().is_empty()));
    gateway.stop().await;
}

/// A profile with `fields` (TOML `[[fields]]` tables) on a holding block of 12 registers and a
/// slow input block of 2 (whose second register is a serial number).
fn profile_with(fields: &str) -> Result<Profile, rtu2mqtt_profile::ProfileErrors> {
    let text = format!(
        r#"
[device]
name = "codecs"
manufacturer = "Test"
model = "C1"

[line]

[[blocks]]
name = "main"
function = 3
start = 0
count = 12

[[blocks]]
name = "nameplate"
function = 4
start = 0x100
count = 2
poll = "slow"

[[fields]]
name = "serial"
block = "nameplate"
offset = 1
codec = {{ type = "u16" }}
{fields}"#
    );
    Profile::from_toml(&text, "codecs.toml")
}

fn refused_with(fields: &str, fragment: &str) {
    match profile_with(fields) {
        Ok(_) => panic!("accepted:\n{fields}"),
        Err(errors) => assert!(
            errors.to_string().contains(fragment),
            "expected {fragment:?} in:\n{errors}"
        ),
    }
}

fn field(name: &str, block: &str, offset: u16, codec: &str) -> String {
    format!("\n[[fields]]\nname = \"{name}\"\nblock = \"{block}\"\noffset = {offset}\ncodec = {codec}\n")
}

#[test]
fn codec_keys_are_checked_at_load() {
    let scaled = field("power", "main", 0, r#"{ type = "i16", scale_by = "sf" }"#);
    refused_with(&scaled, "no field named `sf`");
    refused_with(
        &(scaled.clone() + &field("sf", "main", 1, r#"{ type = "f32" }"#)),
        "must be a whole-number field",
    );
    refused_with(
        &(scaled.clone() + &field("sf", "main", 1, r#"{ type = "i16", decimals = 1 }"#)),
        "must be a whole-number field",
    );
    refused_with(
        &(scaled.clone() + &field("sf", "nameplate", 0, r#"{ type = "i16" }"#)),
        "polled less often than this field's block `main`",
    );
    // A slow value may take its exponent from a fast block.
    let slow_user = field(
        "rating",
        "nameplate",
        0,
        r#"{ type = "u16", scale_by = "sf" }"#,
    ) + &field("sf", "main", 1, r#"{ type = "i16", invalid = [0x8000] }"#);
    assert!(profile_with(&slow_user).is_ok());
    refused_with(
        &field("b", "main", 0, r#"{ type = "u8" }"#),
        "an 8-bit codec names its byte",
    );
    refused_with(
        &field(
            "w",
            "main",
            0,
            r#"{ type = "u16", word_order = "low_first" }"#,
        ),
        "`word_order` is for codecs over several registers",
    );
    refused_with(
        &field("f", "main", 0, r#"{ type = "f32", invalid = ["none"] }"#),
        "`none` is not a value of this float",
    );
    refused_with(
        &field("i", "main", 0, r#"{ type = "u16", invalid = [0x10000] }"#),
        "65536 is not a raw value of this codec",
    );
    refused_with(
        &field(
            "t",
            "main",
            0,
            r#"{ type = "u16", decimals = 1, offset = 0.05 }"#,
        ),
        "offset 0.05 is not a whole number of the last shown place",
    );
    refused_with(
        &(field("s", "main", 0, r#"{ type = "string", registers = 4 }"#)
            + "write = { function = 16, address = 0 }\n"),
        "cannot be written",
    );
    refused_with(
        &field("x", "main", 0, r#"{ type = "u64", encoding = "ascii" }"#),
        "unknown field `encoding`",
    );
}

fn fresh(words: &[u16]) -> rtu2mqtt_modbus::Response {
    rtu2mqtt_modbus::Response::HoldingRegisters(words.to_vec())
}

#[test]
fn a_byte_is_written_with_the_other_byte_as_freshly_read() {
    let profile = profile_with(
        &(field("mode", "main", 0, r#"{ type = "u8", byte = "high" }"#)
            + "range = [0, 255]\nwrite = { function = 6, address = 0 }\n"
            + &field("flags", "main", 0, r#"{ type = "i8", byte = "low" }"#)),
    )
    .expect("valid");
    let state = Default::default();
    let plan = profile
        .plan_command("mode", "200", &state)
        .expect("planned");
    assert_eq!(plan.reads_before().len(), 1);
    let writes = plan.writes(&[fresh(&[0x12FE])]).expect("writes");
    assert_eq!(
        writes,
        [rtu2mqtt_modbus::Request::WriteSingleRegister {
            address: 0,
            value: 0xC8FE
        }]
    );
    let values = profile.decode_block(0, &fresh(&[0xC8FE; 12]));
    assert_eq!(values[0].field, "mode");
    assert_eq!(values[0].value, Ok(rtu2mqtt_profile::Value::Int(200)));
    assert_eq!(values[1].value, Ok(rtu2mqtt_profile::Value::Int(-2)));
}

#[test]
fn a_scaled_write_uses_the_exponent_read_in_its_slot() {
    let profile = profile_with(
        &(field(
            "limit",
            "main",
            0,
            r#"{ type = "u16", scale_by = "limit_sf" }"#,
        ) + "range = [0, 10000]\nwrite = { function = 6, address = 0 }\n"
            + &field("limit_sf", "main", 1, r#"{ type = "i16" }"#)),
    )
    .expect("valid");
    let plan = profile
        .plan_command("limit", "1234.5", &Default::default())
        .expect("planned");
    // The exponent is part of what the slot reads before writing and when reading back.
    assert_eq!(
        plan.reads_before(),
        [rtu2mqtt_modbus::Request::ReadHoldingRegisters {
            start: 0,
            quantity: 2
        }]
    );
    assert_eq!(
        plan.readback(),
        [rtu2mqtt_modbus::Request::ReadHoldingRegisters {
            start: 0,
            quantity: 2
        }]
    );
    // Exponent -1: 1234.5 is raw 12345.
    assert_eq!(
        plan.writes(&[fresh(&[0, 0xFFFF])]),
        Ok(vec![rtu2mqtt_modbus::Request::WriteSingleRegister {
            address: 0,
            value: 12345
        }])
    );
    assert_eq!(
        plan.verify(&[fresh(&[12345, 0xFFFF])]),
        rtu2mqtt_profile::Verification::Applied
    );
    // Exponent 0 cannot hold a half: refused, nothing written.
    let refusal = plan.writes(&[fresh(&[0, 0])]).expect_err("refused");
    assert!(refusal.0.contains("too many decimals"), "{refusal}");
}

#[test]
fn registers_are_written_one_by_one_in_the_codec_order_with_fc06() {
    let profile = profile_with(
        &(field(
            "total",
            "main",
            2,
            r#"{ type = "u32", word_order = "low_first", byte_order = "low_first" }"#,
        ) + "range = [0, 4000000000]\nwrite = { function = 6, address = 2 }\n"),
    )
    .expect("valid");
    let plan = profile
        .plan_command("total", "123456789", &Default::default())
        .expect("planned");
    // 123456789 = 0x075BCD15, DCBA: 15 CD 5B 07.
    assert_eq!(
        plan.writes(&[]),
        Ok(vec![
            rtu2mqtt_modbus::Request::WriteSingleRegister {
                address: 2,
                value: 0x15CD
            },
            rtu2mqtt_modbus::Request::WriteSingleRegister {
                address: 3,
                value: 0x5B07
            },
        ])
    );
}

/// pymodbus's own register conversion (`convert_to_registers`, pymodbus 3.16.1), for both of its
/// word orders: every case as (codec type, word order, value text, registers).
const PYMODBUS_CASES: &str = r#"
import json
from pymodbus.client.mixin import ModbusClientMixin as M
D = M.DATATYPE
cases = [
    ("u16", D.UINT16, 65535), ("i16", D.INT16, -2),
    ("u32", D.UINT32, 123456789), ("i32", D.INT32, -123456789),
    ("u64", D.UINT64, 18446744073709551614), ("i64", D.INT64, -1234567890123),
    ("f32", D.FLOAT32, 123.456), ("f64", D.FLOAT64, -98765.4321),
]
out = []
for name, datatype, value in cases:
    for order in ("big", "little"):
        registers = M.convert_to_registers(value, datatype, word_order=order)
        out.append([name, order, str(value), registers])
out.append(["string", "big", "SDM630", M.convert_to_registers("SDM630", D.STRING)])
print(json.dumps(out))
"#;

#[test]
fn the_codecs_read_what_pymodbus_writes_and_write_what_it_would() {
    let output = crate::support::pymodbus::run_snippet(PYMODBUS_CASES);
    let cases: Vec<(String, String, String, Vec<u16>)> =
        serde_json::from_slice(&output).expect("the cases as JSON");
    assert_eq!(cases.len(), 17);
    for (codec, order, value, registers) in cases {
        let word_order = if order == "big" {
            "high_first"
        } else {
            "low_first"
        };
        let keys = match codec.as_str() {
            "string" => format!(r#"{{ type = "string", registers = {} }}"#, registers.len()),
            "u16" | "i16" => format!(r#"{{ type = "{codec}" }}"#),
            "f32" | "f64" => {
                format!(r#"{{ type = "{codec}", word_order = "{word_order}", decimals = 4 }}"#)
            }
            _ => format!(r#"{{ type = "{codec}", word_order = "{word_order}" }}"#),
        };
        let profile = profile_with(&field("value", "main", 0, &keys)).expect("valid");
        let mut image = registers.clone();
        image.resize(12, 0);
        let read = profile.decode_block(0, &fresh(&image));
        let shown = match &read[0].value {
            Ok(value) => value.to_text(),
            Err(error) => panic!("{codec} {order}: {error}"),
        };
        let expected = match codec.as_str() {
            "f32" => "123.4560".to_string(),
            "f64" => "-98765.4321".to_string(),
            _ => value.clone(),
        };
        assert_eq!(shown, expected, "{codec} {order} {registers:04X?}");
        if codec != "string" {
            let parsed = profile.parse_value("value", &value).expect("a value");
            let (_, patches) = profile.encode_value_raw("value", &parsed).expect("encoded");
            let written: Vec<u16> = patches.iter().map(|patch| patch.bits).collect();
            assert_eq!(written, registers, "{codec} {order} {value}");
        }
    }
}

#[test]
fn a_scaled_write_reads_an_exponent_held_in_another_block_in_its_slot() {
    let profile = Profile::from_toml(
        r#"
[device]
name = "split"
manufacturer = "Test"
model = "S2"

[line]

[[blocks]]
name = "settings"
function = 3
start = 0
count = 2

[[blocks]]
name = "factors"
function = 3
start = 100
count = 1

[[fields]]
name = "limit"
block = "settings"
offset = 1
codec = { type = "u16", scale_by = "limit_sf" }
range = [0, 100000]
write = { function = 6, address = 1 }

[[fields]]
name = "limit_sf"
block = "factors"
offset = 0
codec = { type = "i16" }
"#,
        "split.toml",
    )
    .expect("valid");
    let plan = profile
        .plan_command("limit", "42000", &Default::default())
        .expect("planned");
    let exponent_read = rtu2mqtt_modbus::Request::ReadHoldingRegisters {
        start: 100,
        quantity: 1,
    };
    assert_eq!(plan.reads_before().len(), 2);
    assert_eq!(plan.reads_before()[1], exponent_read);
    // The exponent is read back before the value it judges.
    assert_eq!(plan.readback()[0], exponent_read);
    // Exponent 3: 42000 is raw 42.
    assert_eq!(
        plan.writes(&[fresh(&[0, 0]), fresh(&[3])]),
        Ok(vec![rtu2mqtt_modbus::Request::WriteSingleRegister {
            address: 1,
            value: 42
        }])
    );
    assert_eq!(
        plan.verify(&[fresh(&[3]), fresh(&[42])]),
        rtu2mqtt_profile::Verification::Applied
    );
    // Without the exponent's answer nothing is written.
    assert!(plan.writes(&[fresh(&[0, 0])]).is_err());
}

#[test]
fn sixty_four_bit_commands_are_read_exactly() {
    let profile = profile_with(
        &(field("counter", "main", 0, r#"{ type = "u64" }"#)
            + "range = [0, 1.8446744073709552e19]\nwrite = { function = 16, address = 0 }\n"
            + &field(
                "offset_count",
                "main",
                4,
                r#"{ type = "i64", word_order = "low_first" }"#,
            )
            + "range = [-9.223372036854775808e18, 9.223372036854775807e18]\n"
            + "write = { function = 16, address = 4 }\n"),
    )
    .expect("valid");
    let state = Default::default();
    let plan = profile
        .plan_command("counter", "18446744073709551615", &state)
        .expect("u64::MAX is a command");
    assert_eq!(
        plan.writes(&[]),
        Ok(vec![rtu2mqtt_modbus::Request::WriteMultipleRegisters {
            start: 0,
            values: vec![0xFFFF; 4]
        }])
    );
    for refused in [
        "18446744073709551616",
        "-1",
        "1e19",
        "18446744073709551615.5",
    ] {
        assert!(
            profile.plan_command("counter", refused, &state).is_err(),
            "{refused}"
        );
    }
    let plan = profile
        .plan_command("offset_count", "-9223372036854775808", &state)
        .expect("i64::MIN is a command");
    assert_eq!(
        plan.writes(&[]),
        Ok(vec![rtu2mqtt_modbus::Request::WriteMultipleRegisters {
            start: 4,
            values: vec![0, 0, 0, 0x8000]
        }])
    );
    // One above i64::MAX: refused, not rounded to a neighbour.
    assert!(profile
        .plan_command("offset_count", "9223372036854775808", &state)
        .is_err());
}

#[test]
fn a_generic_simulator_seeds_a_string_with_its_name() {
    let profile = profile_with(&field(
        "model",
        "main",
        0,
        r#"{ type = "string", registers = 2 }"#,
    ))
    .expect("valid");
    let image = profile.initial_image(0).expect("an image");
    let rtu2mqtt_profile::BlockImage::Words(words) = image else {
        panic!("a register block");
    };
    assert_eq!(&words[..2], [0x4D4F, 0x4445]);
    let values = profile.decode_block(0, &fresh(&words));
    assert_eq!(
        values[0].value,
        Ok(rtu2mqtt_profile::Value::Text("MODE".into()))
    );
    // Still no command: a string is read-only.
    assert!(profile
        .plan_command("model", "X", &Default::default())
        .is_err());
}

/// A device whose exponent and value sit in blocks of every cadence: `exponent_block` holds
/// `sf`, `user_block` holds the value it scales; every other block holds a word of its own.
fn cadence_pair(exponent_block: &str, user_block: &str) -> Result<Profile, String> {
    let blocks = [
        ("fast", "fast"),
        ("quick", "250ms"),
        ("minute", "1min"),
        ("slow", "slow"),
        ("once", "once"),
    ];
    let mut text = String::from(
        "[device]\nname = \"cadences\"\nmanufacturer = \"Test\"\nmodel = \"C2\"\n\n[line]\nmin_poll_interval = \"100ms\"\npoll_interval = \"1s\"\nslow_interval = \"5min\"\n",
    );
    for (index, (name, poll)) in blocks.iter().enumerate() {
        text += &format!(
            "\n[[blocks]]\nname = \"{name}\"\nfunction = 3\nstart = {}\ncount = 2\npoll = \"{poll}\"\n",
            index * 0x10
        );
    }
    text += &field("sf", exponent_block, 0, r#"{ type = "i16" }"#);
    text += &field(
        "value",
        user_block,
        1,
        r#"{ type = "u16", scale_by = "sf" }"#,
    );
    // Every block is used by some field.
    for (name, _) in blocks.iter().filter(|(name, _)| *name != user_block) {
        text += &field(&format!("{name}_word"), name, 1, r#"{ type = "u16" }"#);
    }
    Profile::from_toml(&text, "cadences.toml").map_err(|errors| errors.to_string())
}

#[test]
fn an_exponent_must_be_read_at_least_as_often_as_the_values_it_scales_at_every_cadence() {
    // (exponent's block, value's block, accepted)
    let cases = [
        ("fast", "fast", true),
        ("fast", "slow", true),
        ("fast", "minute", true),
        ("fast", "once", true),
        ("fast", "quick", false),
        ("quick", "fast", true),
        ("minute", "fast", false),
        ("minute", "slow", true),
        ("slow", "minute", false),
        ("once", "once", true),
        ("once", "slow", false),
        ("once", "fast", false),
        ("slow", "once", true),
    ];
    for (exponent, user, accepted) in cases {
        let result = cadence_pair(exponent, user);
        if accepted {
            assert!(result.is_ok(), "{exponent} → {user}: {result:?}");
        } else {
            let error = result.expect_err(&format!("{exponent} → {user} accepted"));
            assert!(
                error.contains(&format!(
                    "is in block `{exponent}`, polled less often than this field's block `{user}`"
                )),
                "{exponent} → {user}: {error}"
            );
        }
    }
}
