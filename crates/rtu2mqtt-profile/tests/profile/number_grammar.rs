//! One number grammar for every numeric field, checked through the profiles' own command
//! parsing: plain decimal notation read exactly, at most the field's decimals whatever the
//! magnitude, integers without fraction (zeros excepted), no exponent, hex, sign `+`, `inf` or
//! `nan`; blanks around the text ignored.

use std::path::Path;

use rtu2mqtt_profile::registry::{built_in, load_file};
use rtu2mqtt_profile::{DeviceState, Profile, Rejection, Value};

use crate::support::{refused, PROFILE_DIR};

fn dust() -> Profile {
    built_in("ruiwan-dust-collector").expect("built-in dust collector")
}
fn valve() -> Profile {
    built_in("wuzhou-valve").expect("built-in valve")
}
/// A profile with a signed one-decimal setting (`temperature_offset`, −10.0–10.0 °C).
fn sensor() -> Profile {
    load_file(&Path::new(PROFILE_DIR).join("generic-th-sensor.toml")).expect("the sensor profile")
}

fn accepted(profile: &Profile, field: &str, text: &str) -> Value {
    match profile.plan_command(field, text, &DeviceState::new()) {
        Ok(_) => profile
            .parse_value(field, text)
            .unwrap_or_else(|Rejection(why)| panic!("{field}={text:?}: {why}")),
        Err(Rejection(why)) => panic!("{field}={text:?} refused: {why}"),
    }
}

fn decimal(scaled: i128, precision: u8) -> Value {
    Value::Decimal { scaled, precision }
}

#[test]
fn extra_decimals_are_refused_at_every_magnitude() {
    let valve = valve();
    for text in ["9999.994", "5000.004", "12.345", "0.001", "9999.991"] {
        let reason = refused(&valve, "setpoint", text);
        assert_eq!(
            reason,
            format!("setpoint takes at most 2 decimals (0.00–9999.99), got {text}")
        );
    }
    assert_eq!(accepted(&valve, "setpoint", "9999.99"), decimal(999_999, 2));
    assert_eq!(accepted(&valve, "setpoint", "5000"), decimal(500_000, 2));
    assert_eq!(accepted(&valve, "setpoint", "12.3"), decimal(1_230, 2));
    // Zeros beyond the precision change nothing.
    assert_eq!(accepted(&valve, "setpoint", "12.3400"), decimal(1_234, 2));
    assert_eq!(accepted(&valve, "setpoint", "-0"), decimal(0, 2));
}

#[test]
fn a_one_decimal_field_says_so_in_the_singular() {
    let sensor = sensor();
    assert_eq!(
        accepted(&sensor, "temperature_offset", "-2.5"),
        decimal(-25, 1)
    );
    assert_eq!(
        accepted(&sensor, "temperature_offset", "-10"),
        decimal(-100, 1)
    );
    assert_eq!(
        refused(&sensor, "temperature_offset", "1.25"),
        "temperature_offset takes at most 1 decimal (-10.0–10.0), got 1.25"
    );
    assert_eq!(
        refused(&sensor, "temperature_offset", "-10.1"),
        "temperature_offset must be a number -10.0–10.0 with at most 1 decimal, got -10.1"
    );
}

#[test]
fn integers_take_no_fraction_and_no_exponent() {
    let dust = dust();
    assert_eq!(accepted(&dust, "gear", "10"), Value::Int(10));
    assert_eq!(accepted(&dust, "gear", "8.0"), Value::Int(8));
    assert_eq!(accepted(&dust, "gear", " 8\n"), Value::Int(8));
    assert_eq!(accepted(&dust, "gear", "08"), Value::Int(8));
    assert_eq!(
        refused(&dust, "gear", "8.5"),
        "gear must be an integer 1–10, got 8.5"
    );
    for (text, shown) in [
        ("1e1", "\"1e1\""),
        ("1E1", "\"1E1\""),
        ("0xA", "\"0xA\""),
        ("+8", "\"+8\""),
        ("8.", "\"8.\""),
        (".8e1", "\".8e1\""),
        ("inf", "\"inf\""),
        ("NaN", "\"NaN\""),
        ("1_0", "\"1_0\""),
        ("8 8", "\"8 8\""),
    ] {
        assert_eq!(
            refused(&dust, "gear", text),
            format!("gear must be an integer 1–10, got {shown}"),
            "{text}"
        );
    }
    assert_eq!(
        refused(&dust, "gear", "-0"),
        "gear must be an integer 1–10, got -0"
    );
}

#[test]
fn the_same_grammar_applies_to_values_beside_the_range() {
    // The valve's alarm openings take 0–100 or 255 (alarm disabled).
    let valve = valve();
    for text in ["255", "255.0", " 255 "] {
        let plan = valve.plan_command("low_alarm_opening_1", text, &DeviceState::new());
        assert!(plan.is_ok(), "{text:?}: {plan:?}");
    }
    for text in ["+255", "2.55e2", "0xFF"] {
        let reason = refused(&valve, "low_alarm_opening_1", text);
        assert_eq!(
            reason,
            format!("low_alarm_opening_1 must be an integer 0–100 or 255, got \"{text}\"")
        );
    }
}

#[test]
fn huge_numbers_are_refused_not_wrapped() {
    let valve = valve();
    let huge = "9".repeat(50);
    let reason = refused(&valve, "setpoint", &huge);
    assert!(
        reason.starts_with("setpoint must be a number 0.00–9999.99"),
        "{reason}"
    );
    let reason = refused(&dust(), "gear", &huge);
    assert!(
        reason.starts_with("gear must be an integer 1–10"),
        "{reason}"
    );
}
