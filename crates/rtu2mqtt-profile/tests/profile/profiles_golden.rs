//! Golden encode/decode tests of the built-in profiles against `docs/devices.md`:
//! commands become exactly the documented requests (and bytes), raw answers become exactly the
//! documented values, and the device-protecting rules hold (read-modify-write, toggle,
//! momentary, forbidden combinations, refusals with reasons).

use rtu2mqtt_modbus::{Request, Response};
use rtu2mqtt_profile::registry::built_in;
use rtu2mqtt_profile::{
    BlockImage, CommandPlan, DeviceState, FieldError, Profile, Rejection, Value, Verification,
};

use crate::support::{refused, PROFILE_DIR};

fn dust() -> Profile {
    built_in("ruiwan-dust-collector").unwrap()
}
fn valve() -> Profile {
    built_in("wuzhou-valve").unwrap()
}
fn shower() -> Profile {
    built_in("lixian-air-shower").unwrap()
}

fn state(pairs: &[(&str, Value)]) -> DeviceState {
    pairs
        .iter()
        .map(|(name, value)| (name.to_string(), value.clone()))
        .collect()
}

fn plan(profile: &Profile, field: &str, text: &str) -> CommandPlan {
    profile
        .plan_command(field, text, &DeviceState::new())
        .unwrap_or_else(|r| panic!("{field}={text} rejected: {r}"))
}

/// Coils 0..22 of the air shower with the given coils set.
fn coils(set: &[usize]) -> Response {
    let mut bits = vec![false; 22];
    for &i in set {
        bits[i] = true;
    }
    Response::Coils(bits)
}

/// The 12-bit coil frame `81 0F 00 00 00 0C 02 b0 b1` as a request.
fn coil_frame(b0: u8, b1: u8) -> Request {
    let values = (0..12)
        .map(|i| {
            let byte = if i < 8 { b0 } else { b1 };
            byte >> (i % 8) & 1 == 1
        })
        .collect();
    Request::WriteMultipleCoils { start: 0, values }
}

fn reading(profile: &Profile, block: usize, answer: &Response, field: &str) -> Value {
    profile
        .decode_block(block, answer)
        .into_iter()
        .find(|r| r.field == field)
        .unwrap_or_else(|| panic!("no field {field} in block {block}"))
        .value
        .unwrap_or_else(|e| panic!("{field}: {e}"))
}

/// Every read block's image, seeded from the profile's plausible values.
fn seeded_images(profile: &Profile) -> Vec<BlockImage> {
    (0..profile.read_blocks().len())
        .map(|b| profile.initial_image(b).unwrap())
        .collect()
}

/// The answers the profile's device side gives to `reads` from `images`.
fn answers_from_images(
    profile: &Profile,
    images: &[BlockImage],
    reads: &[Request],
) -> Vec<Response> {
    reads
        .iter()
        .map(|read| profile.answer_read(images, read).unwrap())
        .collect()
}

// --- dust collector -----------------------------------------------------------------------

#[test]
fn dust_read_block_is_the_documented_read() {
    let profile = dust();
    let blocks = profile.read_blocks();
    assert_eq!(blocks.len(), 1);
    assert_eq!(
        blocks[0].request,
        Request::ReadHoldingRegisters {
            start: 0x1000,
            quantity: 6
        }
    );
    assert_eq!(blocks[0].used_runs, vec![(0, 6)]);
    assert_eq!(profile.limits().min_poll_interval.as_millis(), 1000);
    assert_eq!(profile.limits().startup_delay.as_secs(), 3);
}

#[test]
fn dust_gear_8_is_a_single_fc06_at_the_table_address() {
    let plan = plan(&dust(), "gear", "8");
    assert!(plan.reads_before().is_empty());
    assert_eq!(
        plan.writes(&[]).unwrap(),
        vec![Request::WriteSingleRegister {
            address: 0x1002,
            value: 8
        }]
    );
    // Read-back: the whole block; word 1 is the gear.
    assert_eq!(
        plan.readback(),
        &[Request::ReadHoldingRegisters {
            start: 0x1000,
            quantity: 6
        }]
    );
    let applied = Response::HoldingRegisters(vec![0x0200, 8, 2, 10, 1450, 35]);
    assert_eq!(plan.verify(&[applied]), Verification::Applied);
    // In standby the device acknowledges but keeps the old gear.
    let standby = Response::HoldingRegisters(vec![0x0000, 3, 2, 10, 0, 20]);
    match plan.verify(&[standby]) {
        Verification::NotApplied(detail) => assert!(detail.contains("gear reads 3"), "{detail}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn dust_power_on_keeps_the_internal_bits_as_read() {
    let plan = plan(&dust(), "power", "ON");
    assert_eq!(
        plan.reads_before(),
        &[Request::ReadHoldingRegisters {
            start: 0x1000,
            quantity: 6
        }]
    );
    // Status word with internal bits 0x40F0 set, the filter alarm on, power off.
    let fresh = Response::HoldingRegisters(vec![0x40F2, 5, 2, 10, 0, 25]);
    assert_eq!(
        plan.writes(&[fresh]).unwrap(),
        vec![Request::WriteSingleRegister {
            address: 0x1000,
            value: 0x42F2
        }]
    );
    let plan = self::plan(&dust(), "pulse_cleaning", "off");
    let fresh = Response::HoldingRegisters(vec![0xA3FF, 5, 2, 10, 0, 25]);
    assert_eq!(
        plan.writes(&[fresh]).unwrap(),
        vec![Request::WriteSingleRegister {
            address: 0x1000,
            value: 0xA2FF
        }]
    );
}

#[test]
fn dust_power_without_a_fresh_read_is_refused() {
    let plan = plan(&dust(), "power", "ON");
    assert!(plan.writes(&[]).is_err());
    assert!(plan
        .writes(&[Response::HoldingRegisters(vec![0x0000])])
        .is_err());
}

#[test]
fn dust_decodes_every_field() {
    let profile = dust();
    // Power on, pulse on, fan alarm; gear 5, PV 2, SV 10, fan 1450, temperature 35.
    let answer = Response::HoldingRegisters(vec![0x0304, 5, 2, 10, 1450, 35]);
    let readings = profile.decode_block(0, &answer);
    assert_eq!(readings.len(), profile.fields().len());
    let text: Vec<(String, String)> = readings
        .into_iter()
        .map(|r| (r.field, r.value.unwrap().to_text()))
        .collect();
    let expect = [
        ("power", "ON"),
        ("pulse_cleaning", "ON"),
        ("fan_alarm", "ON"),
        ("filter_alarm", "OFF"),
        ("temperature_alarm", "OFF"),
        ("gear", "5"),
        ("pulse_interval", "2"),
        ("pulse_duration", "10"),
        ("fan_speed", "1450"),
        ("temperature", "35"),
    ];
    let expect: Vec<(String, String)> = expect
        .iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    assert_eq!(text, expect);
}

#[test]
fn dust_gear_refusals_name_the_field_and_range() {
    let profile = dust();
    assert_eq!(
        refused(&profile, "gear", "11"),
        "gear must be an integer 1–10, got 11"
    );
    assert_eq!(
        refused(&profile, "gear", "abc"),
        "gear must be an integer 1–10, got \"abc\""
    );
    assert_eq!(
        refused(&profile, "gear", "8.5"),
        "gear must be an integer 1–10, got 8.5"
    );
    for bad in [
        "0",
        "-1",
        "NaN",
        "inf",
        "",
        " ",
        "1e3",
        "99999999999999999999",
    ] {
        let reason = refused(&profile, "gear", bad);
        assert!(
            reason.starts_with("gear must be an integer 1–10"),
            "{reason}"
        );
    }
    assert!(refused(&profile, "fan_speed", "5").contains("read-only"));
    assert!(refused(&profile, "nonexistent", "5").contains("unknown field"));
    assert!(refused(&profile, "power", "maybe").starts_with("power must be ON or OFF"));
    // Accepted spellings.
    assert_eq!(plan(&profile, "gear", " 8 ").target(), &Value::Int(8));
    assert_eq!(plan(&profile, "gear", "8.0").target(), &Value::Int(8));
    for on in ["ON", "on", "On", "true", "1", " ON\n"] {
        assert_eq!(plan(&profile, "power", on).target(), &Value::Bool(true));
    }
    for off in ["OFF", "off", "false", "0"] {
        assert_eq!(plan(&profile, "power", off).target(), &Value::Bool(false));
    }
}

// --- valve ----------------------------------------------------------------------------------

#[test]
fn valve_setpoint_is_two_fc06_integer_then_fraction() {
    let plan = plan(&valve(), "setpoint", "45.67");
    assert!(plan.reads_before().is_empty());
    assert_eq!(
        plan.writes(&[]).unwrap(),
        vec![
            Request::WriteSingleRegister {
                address: 0x00B2,
                value: 0x0045
            },
            Request::WriteSingleRegister {
                address: 0x00B3,
                value: 0x0067
            },
        ]
    );
    // The read-back reads only the run the setpoint is in: the device may refuse the merged
    // configuration block (its gaps are unmapped).
    assert_eq!(
        plan.readback(),
        &[Request::ReadHoldingRegisters {
            start: 0xB2,
            quantity: 2
        }]
    );
    let readback = Response::HoldingRegisters(vec![0x0045, 0x0067]);
    assert_eq!(plan.verify(&[readback]), Verification::Applied);
    let stale = Response::HoldingRegisters(vec![0x0045, 0x0012]);
    match plan.verify(&[stale]) {
        Verification::NotApplied(detail) => {
            assert_eq!(detail, "setpoint reads 45.12 after writing 45.67")
        }
        other => panic!("{other:?}"),
    }
    let plan = self::plan(&valve(), "high_alarm_ratio_2", "1234.5");
    assert_eq!(
        plan.writes(&[]).unwrap(),
        vec![
            Request::WriteSingleRegister {
                address: 0x00D6,
                value: 0x1234
            },
            Request::WriteSingleRegister {
                address: 0x00D7,
                value: 0x0050
            },
        ]
    );
}

#[test]
fn valve_setpoint_refusals() {
    let profile = valve();
    let reason = refused(&profile, "setpoint", "45.678");
    assert!(reason.contains("at most 2 decimals"), "{reason}");
    let reason = refused(&profile, "setpoint", "10000");
    assert!(reason.contains("0.00–9999.99"), "{reason}");
    for bad in ["-1", "NaN", "inf", "-inf", "abc", ""] {
        let reason = refused(&profile, "setpoint", bad);
        assert!(reason.starts_with("setpoint must be"), "{bad}: {reason}");
    }
}

/// Found by fuzzing (`fuzz/`, served_request): a value outside the range that `also` allows
/// (255 disables the valve's low alarm) was accepted by a command but refused by
/// `parse_value`, whose rules are the commands'.
#[test]
fn valve_alarm_disabled_by_an_also_value_parses_like_its_command() {
    let profile = valve();
    plan(&profile, "low_alarm_opening_2", "255");
    assert_eq!(
        profile.parse_value("low_alarm_opening_2", "255"),
        Ok(Value::Int(255))
    );
    let reason = refused(&profile, "low_alarm_opening_2", "101");
    assert_eq!(
        profile.parse_value("low_alarm_opening_2", "101"),
        Err(Rejection(reason))
    );
}

#[test]
fn valve_opening_settles_within_a_window() {
    let plan = plan(&valve(), "opening", "60");
    assert_eq!(
        plan.writes(&[]).unwrap(),
        vec![Request::WriteSingleRegister {
            address: 0x74,
            value: 60
        }]
    );
    assert_eq!(plan.settle_window().map(|d| d.as_secs()), Some(60));
    // The status run (motor bits 2–3) first, then the opening: a motor seen stopped is never
    // older than the opening judged.
    assert_eq!(
        plan.readback(),
        &[
            Request::ReadHoldingRegisters {
                start: 0x90,
                quantity: 4
            },
            Request::ReadHoldingRegisters {
                start: 0x74,
                quantity: 1
            }
        ]
    );
    let status = |motor: u16| Response::HoldingRegisters(vec![motor << 2 | 0x30, 0, 0, 0]);
    let (stopped, opening, closing) = (0, 1, 2);
    // The read-back right after the write may come before the motor starts: a stopped motor
    // there proves nothing, and the value keeps settling. From the next read-back on it counts.
    let fresh = self::plan(&valve(), "opening", "60");
    let stopped_short = [status(stopped), Response::HoldingRegisters(vec![35])];
    assert_eq!(fresh.verify(&stopped_short), Verification::Settling);
    assert!(matches!(
        fresh.verify(&stopped_short),
        Verification::NotApplied(_)
    ));
    assert_eq!(
        plan.verify(&[status(opening), Response::HoldingRegisters(vec![35])]),
        Verification::Settling
    );
    assert_eq!(
        plan.verify(&[status(stopped), Response::HoldingRegisters(vec![60])]),
        Verification::Applied
    );
    assert_eq!(
        plan.verify(&[status(opening), Response::HoldingRegisters(vec![60])]),
        Verification::Applied
    );
    // Stopped short: final at once, naming the opening reached.
    match plan.verify(&[status(stopped), Response::HoldingRegisters(vec![35])]) {
        Verification::NotApplied(detail) => {
            assert!(
                detail.contains("opening reads 35 after writing 60"),
                "{detail}"
            );
            assert!(detail.contains("motor reads stopped"), "{detail}");
        }
        other => panic!("a stopped motor short of the target gave {other:?}"),
    }
    // Moving the other way still counts as moving.
    assert_eq!(
        plan.verify(&[status(closing), Response::HoldingRegisters(vec![70])]),
        Verification::Settling
    );
    // An unreadable motor state (raw 3) or a missing status answer never ends it early.
    assert_eq!(
        plan.verify(&[status(3), Response::HoldingRegisters(vec![35])]),
        Verification::Settling
    );
    assert_eq!(
        plan.verify(&[
            Response::HoldingRegisters(vec![]),
            Response::HoldingRegisters(vec![35])
        ]),
        Verification::Settling
    );
    // Without an opening in the answer the read-back is not usable, whatever the motor says.
    assert!(matches!(
        plan.verify(&[status(stopped)]),
        Verification::NotApplied(_)
    ));
    assert!(refused(&valve(), "opening", "101").contains("0–100"));
    // Alarm openings: 0–100 %, or 255 to disable the alarm.
    let disable = self::plan(&valve(), "low_alarm_opening_1", "255");
    assert_eq!(
        disable.writes(&[]).unwrap(),
        vec![Request::WriteSingleRegister {
            address: 0xD2,
            value: 0xFF
        }]
    );
    assert_eq!(
        refused(&valve(), "low_alarm_opening_1", "150"),
        "low_alarm_opening_1 must be an integer 0–100 or 255, got 150"
    );
    assert!(refused(&valve(), "low_alarm_opening_1", "x").ends_with("or 255, got \"x\""));
}

#[test]
fn valve_mode_keeps_reserved_bits() {
    let plan = plan(&valve(), "mode", "auto");
    assert_eq!(
        plan.reads_before(),
        &[Request::ReadHoldingRegisters {
            start: 0x19,
            quantity: 1
        }]
    );
    assert_eq!(
        plan.writes(&[Response::HoldingRegisters(vec![0x00A4])])
            .unwrap(),
        vec![Request::WriteSingleRegister {
            address: 0x19,
            value: 0x00A5
        }]
    );
    assert!(refused(&valve(), "mode", "pid").contains("manual, auto"));
    assert_eq!(
        self::plan(&valve(), "mode", "MANUAL").target(),
        &Value::Enum("manual".into())
    );
}

fn block_index(profile: &Profile, name: &str) -> usize {
    profile
        .read_blocks()
        .iter()
        .position(|b| b.name == name)
        .unwrap()
}

#[test]
fn valve_live_fast_and_configuration_slow() {
    use rtu2mqtt_profile::PollClass;
    let profile = valve();
    let fast: Vec<u16> = profile
        .read_blocks()
        .iter()
        .filter(|b| b.class == PollClass::Fast)
        .map(|b| match b.request {
            Request::ReadHoldingRegisters { start, .. } => start,
            _ => panic!(),
        })
        .collect();
    assert_eq!(fast, vec![0x19, 0x74, 0x90]);
    let live = &profile.read_blocks()[block_index(&profile, "live")];
    assert_eq!(live.used_runs, vec![(0, 4), (18, 4)]);
    let config = &profile.read_blocks()[block_index(&profile, "configuration")];
    assert_eq!(config.class, PollClass::Slow);
    assert_eq!(config.used_runs, vec![(0, 2), (10, 12), (30, 14), (46, 9)]);
}

#[test]
fn valve_decodes_every_field() {
    let profile = valve();
    let mut decoded = std::collections::HashMap::new();
    let answers = [
        ("mode", Response::HoldingRegisters(vec![0x0001])),
        ("opening", Response::HoldingRegisters(vec![0x0040])),
        ("live", {
            let mut words = vec![0u16; 22];
            // motor opening (bit 2), not fully open (bit 4 = 1), fully closed reached (bit 5 = 0),
            // direction close (bit 6), open switch failed (bit 1).
            words[0] = 0b0101_0110;
            words[1] = 0x05;
            words[2] = 0x00;
            words[3] = 0x81;
            words[18] = 0x0012;
            words[19] = 0x0034;
            words[20] = 0x0100;
            words[21] = 0x0005;
            Response::HoldingRegisters(words)
        }),
        ("identity", {
            Response::HoldingRegisters(vec![
                0x0001, 0x0012, 0x0034, 0x0056, 0x0078, 0x009A, 0x00BC, 0x00DE, 0x0011, 0x0002,
                0x0006,
            ])
        }),
        ("configuration", {
            let mut words = vec![0u16; 55];
            words[0] = 0x0045;
            words[1] = 0x0067;
            words[10] = 0x0100;
            words[12] = 0x0200;
            words[14] = 0x0080;
            words[16] = 0x0090;
            words[18] = 0x0010;
            words[20] = 0x0020;
            words[30] = 0x0064;
            words[31] = 0x00FF;
            words[32] = 0x0000;
            words[33] = 0x0032;
            words[34] = 0x0001;
            words[35] = 0x0050;
            words[42] = 0x0002;
            words[46..55].copy_from_slice(&[0, 1, 30, 0, 5, 0, 0, 0, 10]);
            Response::HoldingRegisters(words)
        }),
    ];
    for (block, answer) in &answers {
        for r in profile.decode_block(block_index(&profile, block), answer) {
            decoded.insert(r.field.clone(), r.value.unwrap().to_text());
        }
    }
    assert_eq!(decoded.len(), profile.fields().len(), "every field decoded");
    let expect = [
        ("mode", "auto"),
        ("opening", "64"),
        ("closed_switch_failed", "OFF"),
        ("open_switch_failed", "ON"),
        ("motor", "opening"),
        ("fully_open", "OFF"),
        ("fully_closed", "ON"),
        ("direction", "close"),
        ("jammed", "OFF"),
        ("pid_invalid_flags", "5"),
        ("alarm_invalid_flags", "129"),
        ("measured_1", "12.34"),
        ("measured_2", "100.05"),
        ("station_address", "1"),
        ("serial_number", "123456789ABCDE"),
        ("software_version", "17"),
        ("baud_code", "6"),
        ("setpoint", "45.67"),
        ("full_scale_1", "100.00"),
        ("high_alarm_opening_1", "100"),
        ("high_alarm_opening_2", "255"),
        ("high_alarm_ratio_1", "1.50"),
        ("regulation_ratio", "2.00"),
        ("sample_period", "0:1:30"),
        ("integral_time", "0:5:0"),
        ("derivative_time", "0:0:10"),
    ];
    for (field, text) in expect {
        assert_eq!(decoded[field], text, "{field}");
    }
}

#[test]
fn valve_invalid_bcd_fails_that_field_only() {
    let profile = valve();
    let mut words = vec![0u16; 22];
    words[18] = 0x001A; // nibble A: invalid
    words[19] = 0x0034;
    words[20] = 0x0012;
    words[21] = 0x0034;
    let readings = profile.decode_block(
        block_index(&profile, "live"),
        &Response::HoldingRegisters(words),
    );
    for r in readings {
        match r.field.as_str() {
            "measured_1" => assert_eq!(r.value, Err(FieldError::InvalidBcd(0x001A))),
            "measured_2" => assert_eq!(
                r.value,
                Ok(Value::Decimal {
                    scaled: 1234,
                    precision: 2
                })
            ),
            _ => assert!(r.value.is_ok(), "{}: {:?}", r.field, r.value),
        }
    }
    // An invalid fraction nibble too.
    let mut words = vec![0u16; 22];
    words[19] = 0x00F0;
    let readings = profile.decode_block(
        block_index(&profile, "live"),
        &Response::HoldingRegisters(words),
    );
    let m1 = readings.iter().find(|r| r.field == "measured_1").unwrap();
    assert_eq!(m1.value, Err(FieldError::InvalidBcd(0x00F0)));
}

#[test]
fn valve_motor_raw_3_is_an_error_not_a_guess() {
    let profile = valve();
    let mut words = vec![0u16; 22];
    words[0] = 0b1100;
    let readings = profile.decode_block(
        block_index(&profile, "live"),
        &Response::HoldingRegisters(words),
    );
    let motor = readings.iter().find(|r| r.field == "motor").unwrap();
    assert!(motor.value.is_err());
}

#[test]
fn short_or_wrong_answers_give_errors_not_panics() {
    let profile = valve();
    let live = block_index(&profile, "live");
    for answer in [
        Response::HoldingRegisters(vec![1, 2]),
        Response::Coils(vec![true; 22]),
        Response::WriteSingleRegister {
            address: 0,
            value: 0,
        },
    ] {
        let readings = profile.decode_block(live, &answer);
        assert!(!readings.is_empty());
        assert!(readings.iter().all(|r| r.value.is_err()));
    }
    assert!(profile
        .decode_block(99, &Response::HoldingRegisters(vec![]))
        .is_empty());
}

// --- air shower -----------------------------------------------------------------------------

#[test]
fn shower_read_is_the_documented_22_coils() {
    let profile = shower();
    assert_eq!(
        profile.read_blocks()[0].request,
        Request::ReadCoils {
            start: 0,
            quantity: 22
        }
    );
    assert_eq!(profile.default_address(), Some(0x81));
    // Answer example `81 01 03 00 01 00`: light on.
    let answer = coils(&[8]);
    assert_eq!(reading(&profile, 0, &answer, "light"), Value::Bool(true));
    assert_eq!(
        reading(&profile, 0, &answer, "wind"),
        Value::Enum("off".into())
    );
}

/// Every single-coil golden frame of docs/devices.md §3, from an all-clear device.
#[test]
fn shower_every_documented_single_write() {
    let profile = shower();
    let cases: [(&str, &str, u8, u8); 12] = [
        ("emergency_stop", "ON", 0x01, 0x00),
        ("front_door_lock", "ON", 0x02, 0x00),
        ("rear_door_lock", "ON", 0x04, 0x00),
        ("strong_wind", "ON", 0x08, 0x00),
        ("breeze", "ON", 0x10, 0x00),
        ("front_door_open", "ON", 0x20, 0x00),
        ("rear_door_open", "ON", 0x40, 0x00),
        ("tunnel_extension", "ON", 0x80, 0x00),
        ("light", "ON", 0x00, 0x01),
        ("buzzer", "ON", 0x00, 0x02),
        ("voice_start", "PRESS", 0x00, 0x04),
        ("voice_door", "PRESS", 0x00, 0x08),
    ];
    for (field, text, b0, b1) in cases {
        let plan = plan(&profile, field, text);
        assert_eq!(
            plan.reads_before(),
            &[Request::ReadCoils {
                start: 0,
                quantity: 22
            }],
            "{field}"
        );
        assert_eq!(
            plan.writes(&[coils(&[])]).unwrap(),
            vec![coil_frame(b0, b1)],
            "{field}"
        );
    }
    // All clear: light OFF on a device with only the light on.
    let plan = plan(&profile, "light", "OFF");
    assert_eq!(plan.writes(&[coils(&[8])]).unwrap(), vec![coil_frame(0, 0)]);
}

#[test]
fn shower_documented_combinations_by_read_modify_write() {
    let profile = shower();
    // Both locks: rear lock on while front lock is on.
    let plan = plan(&profile, "rear_door_lock", "ON");
    assert_eq!(
        plan.writes(&[coils(&[1])]).unwrap(),
        vec![coil_frame(0x06, 0)]
    );
    // Both locks + strong.
    let plan = self::plan(&profile, "strong_wind", "ON");
    assert_eq!(
        plan.writes(&[coils(&[1, 2])]).unwrap(),
        vec![coil_frame(0x0E, 0)]
    );
    // Light + both locks + strong, with the inputs (coils 16..21) set: not part of the frame.
    let plan = self::plan(&profile, "light", "ON");
    assert_eq!(
        plan.writes(&[coils(&[1, 2, 3, 16, 17, 20])]).unwrap(),
        vec![coil_frame(0x0E, 0x01)]
    );
}

#[test]
fn shower_estop_active_and_light_on_keeps_coil_0_at_0() {
    let profile = shower();
    let plan = plan(&profile, "light", "ON");
    assert_eq!(
        plan.writes(&[coils(&[0, 5, 6])]).unwrap(),
        vec![coil_frame(0x60, 0x01)]
    );
}

#[test]
fn shower_estop_is_a_toggle() {
    let profile = shower();
    // Already active: a command for ON writes nothing.
    let on = plan(&profile, "emergency_stop", "ON");
    assert_eq!(on.writes(&[coils(&[0])]).unwrap(), Vec::<Request>::new());
    assert_eq!(on.verify(&[coils(&[0])]), Verification::Applied);
    // Active, command OFF: write 1 (which clears it), keeping the other coils.
    let off = plan(&profile, "emergency_stop", "OFF");
    assert_eq!(
        off.writes(&[coils(&[0, 8])]).unwrap(),
        vec![coil_frame(0x01, 0x01)]
    );
    // Inactive, command OFF: nothing.
    assert_eq!(off.writes(&[coils(&[8])]).unwrap(), Vec::<Request>::new());
    assert_eq!(off.verify(&[coils(&[])]), Verification::Applied);
    assert!(matches!(
        off.verify(&[coils(&[0])]),
        Verification::NotApplied(_)
    ));
}

#[test]
fn shower_voice_buttons_are_momentary() {
    let profile = shower();
    // A voice coil read back as 1 is written 0 by another command.
    let plan = plan(&profile, "buzzer", "ON");
    assert_eq!(
        plan.writes(&[coils(&[10, 11])]).unwrap(),
        vec![coil_frame(0, 0x02)]
    );
    for text in ["PRESS", "press", "ON", "on"] {
        let plan = self::plan(&profile, "voice_start", text);
        assert_eq!(
            plan.writes(&[coils(&[])]).unwrap(),
            vec![coil_frame(0, 0x04)]
        );
        assert_eq!(plan.verify(&[coils(&[])]), Verification::Applied);
    }
    assert!(refused(&profile, "voice_start", "OFF").contains("PRESS"));
}

#[test]
fn shower_strong_while_breeze_is_rejected() {
    let profile = shower();
    // From the last known state, before the bus.
    let known = state(&[
        ("breeze", Value::Bool(true)),
        ("strong_wind", Value::Bool(false)),
    ]);
    let reason = profile
        .plan_command("strong_wind", "ON", &known)
        .unwrap_err()
        .0;
    assert!(reason.contains("strong wind and breeze"), "{reason}");
    assert!(reason.contains("strong_wind ON and breeze ON"), "{reason}");
    // Unknown state: planned, then refused on the fresh read, nothing written.
    let plan = plan(&profile, "strong_wind", "ON");
    let reason = plan.writes(&[coils(&[4])]).unwrap_err().0;
    assert!(reason.contains("strong wind and breeze"), "{reason}");
    // Breeze while strong: likewise.
    let plan = self::plan(&profile, "breeze", "ON");
    assert!(plan.writes(&[coils(&[3])]).is_err());
    // Turning breeze off with strong on is fine.
    let plan = self::plan(&profile, "breeze", "OFF");
    assert_eq!(
        plan.writes(&[coils(&[3])]).unwrap(),
        vec![coil_frame(0x08, 0)]
    );
}

#[test]
fn shower_wind_select_sets_both_coils() {
    let profile = shower();
    let plan = plan(&profile, "wind", "strong");
    assert_eq!(
        plan.writes(&[coils(&[4, 8])]).unwrap(),
        vec![coil_frame(0x08, 0x01)]
    );
    let plan = self::plan(&profile, "wind", "breeze");
    assert_eq!(
        plan.writes(&[coils(&[3])]).unwrap(),
        vec![coil_frame(0x10, 0)]
    );
    assert_eq!(plan.verify(&[coils(&[4])]), Verification::Applied);
    let plan = self::plan(&profile, "wind", "off");
    assert_eq!(
        plan.writes(&[coils(&[3, 1])]).unwrap(),
        vec![coil_frame(0x02, 0)]
    );
    assert!(refused(&profile, "wind", "hurricane").contains("off, strong, breeze"));
    // Both coils on is not a wind mode: an error, not a guess.
    let readings = profile.decode_block(0, &coils(&[3, 4]));
    let wind = readings.iter().find(|r| r.field == "wind").unwrap();
    assert!(wind.value.is_err());
}

#[test]
fn shower_decodes_every_field() {
    let profile = shower();
    let answer = coils(&[1, 2, 3, 8, 16, 18, 21]);
    let readings = profile.decode_block(0, &answer);
    assert_eq!(readings.len(), profile.fields().len());
    let on: Vec<String> = readings
        .into_iter()
        .filter(|r| r.value == Ok(Value::Bool(true)) || r.field == "wind")
        .map(|r| format!("{}={}", r.field, r.value.unwrap().to_text()))
        .collect();
    assert_eq!(
        on,
        [
            "front_door_lock=ON",
            "rear_door_lock=ON",
            "strong_wind=ON",
            "wind=strong",
            "light=ON",
            "front_door_closed=ON",
            "photo_sensor_1=ON",
            "prefilter_expired=ON"
        ]
    );
}

// --- the fourth profile, a file only --------------------------------------------------------

fn th_sensor() -> Profile {
    rtu2mqtt_profile::registry::load_file(
        &std::path::Path::new(PROFILE_DIR).join("generic-th-sensor.toml"),
    )
    .unwrap()
}

#[test]
fn th_sensor_decodes_floats_in_both_word_orders() {
    let profile = th_sensor();
    assert_eq!(
        profile.read_blocks()[0].request,
        Request::ReadInputRegisters {
            start: 0,
            quantity: 8
        }
    );
    // 23.45 °C = 0x41BB999A (high word first); 56.7 % = 0x4262CCCD (high word first);
    // dew point -3.5 °C = -35 tenths = 0xFFDD; 1234.5 h = 0x449A5000, low word first.
    let answer = Response::InputRegisters(vec![
        0x41BB, 0x999A, 0x4262, 0xCCCD, 0xFFDD, 0x0000, 0x5000, 0x449A,
    ]);
    let text: Vec<(String, String)> = profile
        .decode_block(0, &answer)
        .into_iter()
        .map(|r| (r.field, r.value.unwrap().to_text()))
        .collect();
    assert_eq!(
        text,
        [
            ("temperature", "23.45"),
            ("humidity", "56.7"),
            ("dew_point", "-3.5"),
            ("operating_hours", "1234.5"),
        ]
        .map(|(a, b)| (a.to_string(), b.to_string()))
    );
    // A NaN float is the device's "not available": no value, not a number and not an error;
    // so are the infinities.
    for nan_or_infinity in [0x7FC0, 0x7F80, 0xFF80] {
        let answer = Response::InputRegisters(vec![nan_or_infinity, 0, 0x4262, 0xCCCD, 0, 0, 0, 0]);
        let readings = profile.decode_block(0, &answer);
        assert_eq!(readings[0].value, Ok(Value::Unavailable));
        assert_eq!(
            readings[1].value.as_ref().map(Value::to_text),
            Ok("56.7".to_string())
        );
    }
}

#[test]
fn th_sensor_settings_are_written_without_code() {
    let profile = th_sensor();
    let plan = plan(&profile, "temperature_offset", "-1.5");
    assert_eq!(
        plan.writes(&[]).unwrap(),
        vec![Request::WriteSingleRegister {
            address: 0x0100,
            value: (-15i16) as u16
        }]
    );
    assert!(refused(&profile, "temperature_offset", "10.5").contains("-10.0–10.0"));
    assert!(refused(&profile, "temperature", "20").contains("read-only"));
    // A scaled word: one raw count is 5 s.
    let plan = self::plan(&profile, "report_interval", "60");
    assert_eq!(
        plan.writes(&[]).unwrap(),
        vec![Request::WriteSingleRegister {
            address: 0x0102,
            value: 12
        }]
    );
    assert!(refused(&profile, "report_interval", "62").contains("multiple of the step 5"));
    // The step the command checks is the step the field declares (Home Assistant's `step`).
    let step_of = |name: &str| {
        profile
            .fields()
            .iter()
            .find(|info| info.name == name)
            .and_then(|info| info.step.clone())
    };
    assert_eq!(step_of("report_interval"), Some(Value::Int(5)));
    assert_eq!(
        step_of("temperature_offset"),
        Some(Value::Decimal {
            scaled: 1,
            precision: 1
        })
    );
    assert_eq!(step_of("alarm_enabled"), None);
    assert!(refused(&profile, "report_interval", "0").contains("5–3600"));
    let settings = Response::HoldingRegisters(vec![0xFFF6, 0x8001, 12]);
    let texts: Vec<String> = profile
        .decode_block(1, &settings)
        .into_iter()
        .map(|r| r.value.unwrap().to_text())
        .collect();
    assert_eq!(texts, ["-1.0", "ON", "60"]);
    let plan = self::plan(&profile, "alarm_enabled", "ON");
    assert_eq!(
        plan.writes(&[Response::HoldingRegisters(vec![0xFFF6, 0x8000, 12])])
            .unwrap(),
        vec![Request::WriteSingleRegister {
            address: 0x0101,
            value: 0x8001
        }]
    );
}

// --- the device side, for simulators --------------------------------------------------------

/// Every profile: an image seeded from plausible values decodes to exactly those values, and
/// each plan's writes applied through the profile's write frames read back as applied.
#[test]
fn simulated_images_round_trip_through_every_profile() {
    for profile in [dust(), valve(), shower(), th_sensor()] {
        let mut images = seeded_images(&profile);
        let answer_of = |images: &[rtu2mqtt_profile::BlockImage], b: usize| match (
            &images[b],
            &profile.read_blocks()[b].request,
        ) {
            (rtu2mqtt_profile::BlockImage::Words(w), Request::ReadInputRegisters { .. }) => {
                Response::InputRegisters(w.clone())
            }
            (rtu2mqtt_profile::BlockImage::Words(w), _) => Response::HoldingRegisters(w.clone()),
            (rtu2mqtt_profile::BlockImage::Bits(bits), _) => Response::Coils(bits.clone()),
        };
        for (b, _) in profile.read_blocks().iter().enumerate() {
            for r in profile.decode_block(b, &answer_of(&images, b)) {
                let value = r.value.unwrap_or_else(|e| panic!("{}: {e}", r.field));
                if let Some(plausible) = profile.plausible_value(&r.field) {
                    if r.field != "wind" {
                        assert_eq!(value, plausible, "{} {}", profile.name(), r.field);
                    }
                }
            }
        }
        for info in profile.fields().iter().filter(|f| f.writable) {
            if profile.toggle_fields().contains(&info.name.as_str())
                || profile.momentary_fields().contains(&info.name.as_str())
            {
                continue;
            }
            // Booleans go ON and back OFF so that no forbidden combination builds up.
            let texts: Vec<String> = match &info.kind {
                rtu2mqtt_profile::FieldKind::Bool => vec!["ON".into(), "OFF".into()],
                rtu2mqtt_profile::FieldKind::Integer { max, .. } => vec![max.to_string()],
                rtu2mqtt_profile::FieldKind::Decimal { min, .. } => vec![format!("{}", min + 1.0)],
                rtu2mqtt_profile::FieldKind::Enum { options } => {
                    vec![options.last().unwrap().clone(), options[0].clone()]
                }
                _ => continue,
            };
            for text in texts {
                let plan = profile
                    .plan_command(&info.name, &text, &DeviceState::new())
                    .unwrap();
                let before = answers_from_images(&profile, &images, plan.reads_before());
                for write in plan.writes(&before).unwrap() {
                    assert!(
                        profile.apply_write(&mut images, &write),
                        "{} {write:?}",
                        info.name
                    );
                }
                let readback = answers_from_images(&profile, &images, plan.readback());
                assert_eq!(
                    plan.verify(&readback),
                    Verification::Applied,
                    "{} {}={text}",
                    profile.name(),
                    info.name
                );
            }
        }
    }
}

#[test]
fn apply_write_refuses_addresses_outside_the_write_frames() {
    let profile = dust();
    let mut images = vec![profile.initial_image(0).unwrap()];
    assert!(!profile.apply_write(
        &mut images,
        &Request::WriteSingleRegister {
            address: 0x1001,
            value: 1
        }
    ));
    assert!(!profile.apply_write(
        &mut images,
        &Request::WriteSingleRegister {
            address: 0x2000,
            value: 1
        }
    ));
    assert!(profile.apply_write(
        &mut images,
        &Request::WriteSingleRegister {
            address: 0x1006,
            value: 42
        }
    ));
    assert_eq!(
        reading(
            &profile,
            0,
            &Response::HoldingRegisters(match &images[0] {
                rtu2mqtt_profile::BlockImage::Words(w) => w.clone(),
                _ => panic!(),
            }),
            "pulse_duration"
        ),
        Value::Int(42)
    );
}

// --- byte for byte, through the RTU codec ---------------------------------------------------

mod bytes {
    use super::*;
    use rtu2mqtt_modbus::codec::{decode_answer, encode_request, hex, Answer};

    fn frames(slave: u8, requests: &[Request]) -> Vec<String> {
        requests
            .iter()
            .map(|r| hex(&encode_request(slave, r).unwrap()))
            .collect()
    }

    #[test]
    fn dust_collector_frames() {
        let profile = dust();
        assert_eq!(
            frames(1, &[profile.read_blocks()[0].request.clone()]),
            ["01 03 10 00 00 06 C1 08"]
        );
        let gear = plan(&profile, "gear", "8");
        assert_eq!(
            frames(1, &gear.writes(&[]).unwrap()),
            ["01 06 10 02 00 08 2D 0C"]
        );
        // Power on + pulse on, gear 5, PV 2, SV 10 in one FC10, from a device in standby.
        let group = profile
            .plan_group(
                "settings",
                &[
                    ("power", "ON"),
                    ("pulse_cleaning", "ON"),
                    ("gear", "5"),
                    ("pulse_interval", "2"),
                    ("pulse_duration", "10"),
                ],
                &DeviceState::new(),
            )
            .unwrap();
        assert_eq!(group.field(), "settings");
        let standby = Response::HoldingRegisters(vec![0x0000, 3, 0, 0, 0, 21]);
        assert_eq!(
            frames(1, &group.writes(&[standby]).unwrap()),
            ["01 10 10 00 00 04 08 03 00 00 05 00 02 00 0A 25 38"]
        );
        let after = Response::HoldingRegisters(vec![0x0300, 5, 2, 10, 1400, 21]);
        assert_eq!(group.verify(&[after]), Verification::Applied);
        let ignored = Response::HoldingRegisters(vec![0x0000, 3, 0, 0, 0, 21]);
        match group.verify(&[ignored]) {
            Verification::NotApplied(detail) => {
                assert!(
                    detail.contains("power reads OFF after writing ON"),
                    "{detail}"
                );
                assert!(detail.contains("gear reads 3 after writing 5"), "{detail}");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn dust_group_keeps_unnamed_status_bits_and_refuses_strays() {
        let profile = dust();
        let group = profile
            .plan_group("settings", &[("gear", "4")], &DeviceState::new())
            .unwrap();
        let fresh = Response::HoldingRegisters(vec![0x42F1, 3, 7, 9, 0, 21]);
        assert_eq!(
            group.writes(&[fresh]).unwrap(),
            vec![Request::WriteMultipleRegisters {
                start: 0x1000,
                values: vec![0x42F1, 4, 7, 9]
            }]
        );
        let refuse = |values: &[(&str, &str)]| {
            profile
                .plan_group("settings", values, &DeviceState::new())
                .unwrap_err()
                .0
        };
        assert!(refuse(&[("fan_speed", "3")]).contains("read-only"));
        assert!(refuse(&[("gear", "11")]).contains("gear must be an integer 1–10"));
        assert!(refuse(&[("gear", "4"), ("gear", "5")]).contains("twice"));
        assert!(refuse(&[]).contains("no values"));
        assert!(profile
            .plan_group("nope", &[("gear", "4")], &DeviceState::new())
            .is_err());
    }

    #[test]
    fn air_shower_frames() {
        let profile = shower();
        assert_eq!(
            frames(0x81, &[profile.read_blocks()[0].request.clone()]),
            ["81 01 00 00 00 16 A2 04"]
        );
        // The document's answer example: light on.
        let request = profile.read_blocks()[0].request.clone();
        let answer = match decode_answer(
            0x81,
            &request,
            &[0x81, 0x01, 0x03, 0x00, 0x01, 0x00, 0x22, 0x1E],
        )
        .unwrap()
        {
            Answer::Normal(response) => response,
            other => panic!("{other:?}"),
        };
        assert_eq!(reading(&profile, 0, &answer, "light"), Value::Bool(true));
        assert_eq!(
            reading(&profile, 0, &answer, "emergency_stop"),
            Value::Bool(false)
        );

        // (field, command, coils set on the device before, golden frame)
        let cases: &[(&str, &str, &[usize], &str)] = &[
            ("light", "OFF", &[8], "81 0F 00 00 00 0C 02 00 00 84 76"),
            (
                "emergency_stop",
                "ON",
                &[],
                "81 0F 00 00 00 0C 02 01 00 85 E6",
            ),
            (
                "front_door_lock",
                "ON",
                &[],
                "81 0F 00 00 00 0C 02 02 00 85 16",
            ),
            (
                "rear_door_lock",
                "ON",
                &[],
                "81 0F 00 00 00 0C 02 04 00 86 B6",
            ),
            ("strong_wind", "ON", &[], "81 0F 00 00 00 0C 02 08 00 83 B6"),
            ("breeze", "ON", &[], "81 0F 00 00 00 0C 02 10 00 89 B6"),
            (
                "front_door_open",
                "ON",
                &[],
                "81 0F 00 00 00 0C 02 20 00 9D B6",
            ),
            (
                "rear_door_open",
                "ON",
                &[],
                "81 0F 00 00 00 0C 02 40 00 B5 B6",
            ),
            (
                "tunnel_extension",
                "ON",
                &[],
                "81 0F 00 00 00 0C 02 80 00 E5 B6",
            ),
            ("light", "ON", &[], "81 0F 00 00 00 0C 02 00 01 45 B6"),
            ("buzzer", "ON", &[], "81 0F 00 00 00 0C 02 00 02 05 B7"),
            (
                "voice_start",
                "PRESS",
                &[],
                "81 0F 00 00 00 0C 02 00 04 85 B5",
            ),
            (
                "voice_door",
                "PRESS",
                &[],
                "81 0F 00 00 00 0C 02 00 08 85 B0",
            ),
            (
                "rear_door_lock",
                "ON",
                &[1],
                "81 0F 00 00 00 0C 02 06 00 87 D6",
            ),
            (
                "strong_wind",
                "ON",
                &[1, 2],
                "81 0F 00 00 00 0C 02 0E 00 80 16",
            ),
            (
                "wind",
                "strong",
                &[1, 2],
                "81 0F 00 00 00 0C 02 0E 00 80 16",
            ),
            (
                "light",
                "ON",
                &[1, 2, 3],
                "81 0F 00 00 00 0C 02 0E 01 41 D6",
            ),
            // E-stop active + light ON: coil 0 written 0, the e-stop stays active.
            ("light", "ON", &[0], "81 0F 00 00 00 0C 02 00 01 45 B6"),
            // Voice coils read back as 1 are written 0.
            ("light", "ON", &[10, 11], "81 0F 00 00 00 0C 02 00 01 45 B6"),
        ];
        for (field, text, before, golden) in cases {
            let plan = plan(&profile, field, text);
            let reads = frames(0x81, plan.reads_before());
            assert_eq!(reads, ["81 01 00 00 00 16 A2 04"], "{field}");
            let writes = plan.writes(&[coils(before)]).unwrap();
            assert_eq!(
                frames(0x81, &writes),
                [*golden],
                "{field}={text} from {before:?}"
            );
        }
    }

    #[test]
    fn valve_setpoint_frames_are_standard_fc06() {
        let profile = valve();
        let plan = plan(&profile, "setpoint", "45.67");
        let written = frames(1, &plan.writes(&[]).unwrap());
        // Standard single-register layout: address, 06, register, value, CRC (low byte first).
        assert_eq!(written.len(), 2);
        assert!(
            written[0].starts_with("01 06 00 B2 00 45 "),
            "{}",
            written[0]
        );
        assert!(
            written[1].starts_with("01 06 00 B3 00 67 "),
            "{}",
            written[1]
        );
        for frame in &written {
            let bytes = crate::support::frame(frame);
            let crc = rtu2mqtt_modbus::crc::crc16(&bytes[..6]);
            assert_eq!(&bytes[6..], &crc.to_le_bytes());
        }
    }
}

/// The fourth profile against the generic simulated device built from it: polls decode the
/// golden words set in the device, and commands go through plan → writes → read-back.
#[test]
fn th_sensor_against_the_generic_simulator() {
    use rtu2mqtt_sim::generic::GenericDevice;

    let profile = th_sensor();
    let mut device = GenericDevice::from_profile(&profile, 7);
    for (address, word) in [
        (0u16, 0x41BB),
        (1, 0x999A),
        (2, 0x4262),
        (3, 0xCCCD),
        (4, 0xFFDD),
        (6, 0x5000),
        (7, 0x449A),
    ] {
        device.set_input_register(address, word);
    }
    let mut values = std::collections::BTreeMap::new();
    for (index, block) in profile.read_blocks().iter().enumerate() {
        let answer = ask(&mut device, &block.request);
        for r in profile.decode_block(index, &answer) {
            values.insert(r.field, r.value.unwrap().to_text());
        }
    }
    assert_eq!(values["temperature"], "23.45");
    assert_eq!(values["humidity"], "56.7");
    assert_eq!(values["dew_point"], "-3.5");
    assert_eq!(values["operating_hours"], "1234.5");

    assert_all_applied(
        &mut device,
        &profile,
        &[
            ("temperature_offset", "2.5"),
            ("alarm_enabled", "ON"),
            ("report_interval", "300"),
            ("alarm_enabled", "OFF"),
        ],
    );
}

/// The device's normal answer to `request`.
fn ask(device: &mut dyn rtu2mqtt_sim::SimDevice, request: &Request) -> Response {
    use rtu2mqtt_sim::Reply;
    match device.handle(request, std::time::Instant::now()) {
        Reply::Normal(response) => response,
        other => panic!("{request:?}: {other:?}"),
    }
}

/// Runs one planned command on a simulated device as the line does, returning the verification
/// of the read-back.
fn run_on(
    device: &mut dyn rtu2mqtt_sim::SimDevice,
    plan: &CommandPlan,
) -> Result<Verification, Rejection> {
    let before: Vec<Response> = plan
        .reads_before()
        .iter()
        .map(|read| ask(device, read))
        .collect();
    for write in plan.writes(&before)? {
        ask(device, &write);
    }
    let readback: Vec<Response> = plan
        .readback()
        .iter()
        .map(|read| ask(device, read))
        .collect();
    Ok(plan.verify(&readback))
}

/// Each (field, text) in turn, planned on no known state, is applied by the device.
fn assert_all_applied(
    device: &mut dyn rtu2mqtt_sim::SimDevice,
    profile: &Profile,
    commands: &[(&str, &str)],
) {
    for &(field, text) in commands {
        assert_eq!(
            run_on(device, &plan(profile, field, text)),
            Ok(Verification::Applied),
            "{field}={text}"
        );
    }
}

/// The built-in profiles against the seed device simulators: every command the profiles plan
/// is applied by the simulated device as intended, and no device-protecting rule is broken.
#[test]
fn seed_simulators_apply_what_the_profiles_plan() {
    use rtu2mqtt_sim::{AirShower, DustCollector, SimDevice};
    let none = DeviceState::new();

    let profile = dust();
    let mut device = DustCollector::new(1);
    device.set_internal_bits(0x40F0);
    // In standby the gear is acknowledged, not applied.
    let gear = profile.plan_command("gear", "8", &none).unwrap();
    assert!(matches!(
        run_on(&mut device, &gear),
        Ok(Verification::NotApplied(_))
    ));
    assert_all_applied(
        &mut device,
        &profile,
        &[
            ("power", "ON"),
            ("gear", "8"),
            ("pulse_cleaning", "ON"),
            ("pulse_interval", "12"),
            ("pulse_duration", "30"),
            ("pulse_cleaning", "OFF"),
        ],
    );
    assert!(device.power());
    assert_eq!(device.gear(), 8);
    assert_eq!(device.status_word() & 0x40F0, 0x40F0, "internal bits kept");
    assert_eq!(device.violations(), Vec::<String>::new());

    let profile = shower();
    let mut device = AirShower::new();
    for (field, text) in [
        ("light", "ON"),
        ("emergency_stop", "ON"),
        ("front_door_lock", "ON"),
        ("emergency_stop", "ON"),
        ("wind", "breeze"),
        ("voice_start", "PRESS"),
        ("emergency_stop", "OFF"),
        ("strong_wind", "ON"),
    ] {
        let plan = profile.plan_command(field, text, &none).unwrap();
        let outcome = run_on(&mut device, &plan);
        if (field, text) == ("strong_wind", "ON") {
            // Breeze is on: refused on the fresh read, nothing written.
            assert!(outcome.is_err(), "{outcome:?}");
        } else {
            assert_eq!(outcome, Ok(Verification::Applied), "{field}={text}");
        }
    }
    assert!(!device.emergency_stop());
    assert_eq!(device.voice_presses(), [1, 0]);
    let coils = device.coils();
    assert!(coils[8] && coils[1] && coils[4] && !coils[3]);
    assert_eq!(device.violations(), Vec::<String>::new());

    let profile = valve();
    let mut device = rtu2mqtt_sim::Valve::new(1);
    assert_all_applied(
        &mut device,
        &profile,
        &[
            ("mode", "manual"),
            ("setpoint", "45.67"),
            ("high_alarm_opening_2", "255"),
            ("regulation_ratio", "1.5"),
        ],
    );
    assert_eq!(device.register(0xB2), Some(0x0045));
    assert_eq!(device.register(0xB3), Some(0x0067));
    assert!(!device.mode_auto());
    // The motor needs time: the immediate read-back is still settling.
    device.set_opening(10);
    let opening = profile.plan_command("opening", "80", &none).unwrap();
    assert_eq!(run_on(&mut device, &opening), Ok(Verification::Settling));
    assert_eq!(device.target(), 80);
    assert_eq!(device.violations(), Vec::<String>::new());
}

// --- bad input never panics ------------------------------------------------------------------

mod robustness {
    use super::*;
    use proptest::prelude::*;

    /// Parsed once: the cases only exercise decoding and planning.
    fn profiles() -> &'static [Profile] {
        static PROFILES: std::sync::OnceLock<Vec<Profile>> = std::sync::OnceLock::new();
        PROFILES.get_or_init(|| vec![dust(), valve(), shower(), th_sensor()])
    }

    fn any_answer() -> impl Strategy<Value = Response> {
        prop_oneof![
            proptest::collection::vec(any::<u16>(), 0..64).prop_map(Response::HoldingRegisters),
            proptest::collection::vec(any::<u16>(), 0..64).prop_map(Response::InputRegisters),
            proptest::collection::vec(any::<bool>(), 0..40).prop_map(Response::Coils),
            (any::<u16>(), any::<u16>())
                .prop_map(|(address, value)| Response::WriteSingleRegister { address, value }),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        #[test]
        fn decoding_any_answer_never_panics(answer in any_answer(), block in 0usize..6) {
            for profile in profiles() {
                let readings = profile.decode_block(block, &answer);
                if block < profile.read_blocks().len() {
                    prop_assert_eq!(readings.len(), profile.block_fields(block).len());
                }
                for reading in readings {
                    if let Ok(value) = reading.value {
                        let _ = value.to_text();
                        let _ = value.to_json();
                    }
                }
            }
        }

        #[test]
        fn any_command_text_is_planned_or_refused(text in ".{0,24}", pick in any::<usize>()) {
            for profile in profiles() {
                let field = &profile.fields()[pick % profile.fields().len()].name;
                match profile.plan_command(field, &text, &DeviceState::new()) {
                    Ok(plan) => prop_assert_eq!(plan.field(), field.as_str()),
                    Err(Rejection(reason)) => prop_assert!(!reason.is_empty()),
                }
            }
        }

        /// Any value inside a writable number's range goes out and reads back as itself.
        #[test]
        fn numbers_in_range_round_trip(pick in any::<usize>(), fraction in 0.0f64..=1.0) {
            for profile in profiles() {
                let numbers: Vec<_> = profile
                    .fields()
                    .iter()
                    .filter(|f| f.writable)
                    .filter(|f| matches!(
                        f.kind,
                        rtu2mqtt_profile::FieldKind::Integer { .. }
                            | rtu2mqtt_profile::FieldKind::Decimal { .. }
                    ))
                    .collect();
                let Some(info) = numbers.get(pick % numbers.len().max(1)) else { continue };
                let text = match info.kind {
                    rtu2mqtt_profile::FieldKind::Integer { min, max } => {
                        (min + ((max - min) as f64 * fraction) as i128).to_string()
                    }
                    rtu2mqtt_profile::FieldKind::Decimal { min, max, precision } => {
                        format!("{:.*}", usize::from(precision), min + (max - min) * fraction)
                    }
                    _ => unreachable!(),
                };
                let plan = match profile.plan_command(&info.name, &text, &DeviceState::new()) {
                    Ok(plan) => plan,
                    // A scaled field refuses values off its step, with a reason.
                    Err(Rejection(reason)) => {
                        prop_assert!(reason.contains("multiple of the step"), "{}", reason);
                        continue;
                    }
                };
                let mut images = seeded_images(profile);
                let before = answers_from_images(profile, &images, plan.reads_before());
                for write in plan.writes(&before).unwrap() {
                    prop_assert!(profile.apply_write(&mut images, &write));
                }
                let readback = answers_from_images(profile, &images, plan.readback());
                prop_assert_eq!(plan.verify(&readback), Verification::Applied);
            }
        }

        #[test]
        fn writes_and_verify_take_any_fresh_answer(
            answer in any_answer(),
            pick in any::<usize>(),
        ) {
            for profile in profiles() {
                let writable: Vec<_> = profile.fields().iter().filter(|f| f.writable).collect();
                let Some(info) = writable.get(pick % writable.len().max(1)) else { continue };
                let text = match &info.kind {
                    rtu2mqtt_profile::FieldKind::Bool => "ON".to_string(),
                    rtu2mqtt_profile::FieldKind::Momentary => "PRESS".to_string(),
                    rtu2mqtt_profile::FieldKind::Integer { min, .. } => min.to_string(),
                    rtu2mqtt_profile::FieldKind::Decimal { min, .. } => min.to_string(),
                    rtu2mqtt_profile::FieldKind::Enum { options } => options[0].clone(),
                    rtu2mqtt_profile::FieldKind::Text => continue,
                };
                let plan = profile
                    .plan_command(&info.name, &text, &DeviceState::new())
                    .unwrap();
                let _ = plan.writes(std::slice::from_ref(&answer));
                let _ = plan.writes(&[]);
                let _ = plan.verify(std::slice::from_ref(&answer));
                let _ = plan.verify(&[]);
            }
        }
    }
}

#[test]
fn partial_reads_decode_the_fields_inside_them() {
    let profile = valve();
    let text = |request: Request, answer: Response| -> Vec<String> {
        profile
            .decode_read(&request, &answer)
            .into_iter()
            .map(|r| format!("{}={}", r.field, r.value.unwrap().to_text()))
            .collect()
    };
    // The setpoint's read-back in a command slot.
    assert_eq!(
        text(
            Request::ReadHoldingRegisters {
                start: 0xB2,
                quantity: 2
            },
            Response::HoldingRegisters(vec![0x0045, 0x0067])
        ),
        ["setpoint=45.67"]
    );
    // A used run of the live block: the measured values only.
    assert_eq!(
        text(
            Request::ReadHoldingRegisters {
                start: 0xA2,
                quantity: 4
            },
            Response::HoldingRegisters(vec![0x0012, 0x0034, 0x0001, 0x0000])
        ),
        ["measured_1=12.34", "measured_2=1.00"]
    );
    // Half a BCD pair is not decoded; a read outside every block gives nothing.
    assert!(text(
        Request::ReadHoldingRegisters {
            start: 0xA3,
            quantity: 2
        },
        Response::HoldingRegisters(vec![0x0034, 0x0001])
    )
    .is_empty());
    assert!(profile
        .decode_read(
            &Request::ReadHoldingRegisters {
                start: 0x50,
                quantity: 1
            },
            &Response::HoldingRegisters(vec![1])
        )
        .is_empty());
    // A short answer gives nothing rather than a panic.
    assert!(profile
        .decode_read(
            &Request::ReadHoldingRegisters {
                start: 0xB2,
                quantity: 2
            },
            &Response::HoldingRegisters(vec![0x0045])
        )
        .is_empty());
}

#[test]
fn a_write_of_part_of_a_field_touches_that_field() {
    let register = |address| Request::WriteSingleRegister { address, value: 0 };
    // Either register of the setpoint's BCD pair is a setpoint write (and an EEPROM write).
    assert_eq!(valve().fields_touched(&register(0xB2)), ["setpoint"]);
    assert_eq!(valve().fields_touched(&register(0xB3)), ["setpoint"]);
    // The gear at its own FC06 address; nothing at an address no field writes.
    assert_eq!(dust().fields_touched(&register(0x1002)), ["gear"]);
    assert!(dust().fields_touched(&register(0x1003)).is_empty());
    // A coil write is not a register write.
    let coil = Request::WriteSingleCoil {
        address: 0xB2,
        value: true,
    };
    assert!(valve().fields_touched(&coil).is_empty());
}
