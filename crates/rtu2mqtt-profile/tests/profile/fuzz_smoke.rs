//! Fuzz smoke without cargo-fuzz: many proptest cases of hostile input against the places where
//! bytes and text from outside enter. Checked only for not panicking and for refusals that say
//! something. Complements the wire crate's `codec_props.rs` (random bytes, which almost never
//! pass the CRC) and the profile robustness properties (decoding any answer, planning any short
//! command text):
//!   - frames with a valid CRC over random contents, so the decoders get past the CRC check;
//!   - the profile TOML loader on arbitrary text and on mutated real profiles;
//!   - a planned command's writes and read-back judged on arbitrary device answers;
//!   - commands and write groups from arbitrary bytes.

use std::sync::OnceLock;

use proptest::prelude::*;

use rtu2mqtt_modbus::codec::{decode_answer, decode_request, request_frame_len};
use rtu2mqtt_modbus::crc::append_crc;
use rtu2mqtt_modbus::{Request, Response};
use rtu2mqtt_profile::{DeviceState, Profile, Rejection, Verification};

use crate::support::PROFILE_DIR;

const PROFILE_FILES: [&str; 4] = [
    "ruiwan-dust-collector",
    "wuzhou-valve",
    "lixian-air-shower",
    "generic-th-sensor",
];

fn profile_text(name: &str) -> String {
    let path = format!("{PROFILE_DIR}/{name}.toml");
    std::fs::read_to_string(path).unwrap()
}

/// The profile files as text and compiled, read once.
fn profiles() -> &'static [(String, Profile)] {
    static PROFILES: OnceLock<Vec<(String, Profile)>> = OnceLock::new();
    PROFILES.get_or_init(|| {
        PROFILE_FILES
            .iter()
            .map(|name| {
                let text = profile_text(name);
                let profile = Profile::from_toml(&text, name).unwrap();
                (text, profile)
            })
            .collect()
    })
}

fn with_crc(mut bytes: Vec<u8>) -> Vec<u8> {
    append_crc(&mut bytes);
    bytes
}

fn any_read_request() -> impl Strategy<Value = Request> {
    (0u8..4, any::<u16>(), 1u16..=125).prop_map(|(kind, start, quantity)| match kind {
        0 => Request::ReadCoils { start, quantity },
        1 => Request::ReadDiscreteInputs { start, quantity },
        2 => Request::ReadHoldingRegisters { start, quantity },
        _ => Request::ReadInputRegisters { start, quantity },
    })
}

/// Any answer a device could put in a well-formed frame, of any shape and length.
fn any_answer() -> impl Strategy<Value = Response> {
    prop_oneof![
        proptest::collection::vec(any::<u16>(), 0..130).prop_map(Response::HoldingRegisters),
        proptest::collection::vec(any::<u16>(), 0..130).prop_map(Response::InputRegisters),
        proptest::collection::vec(any::<bool>(), 0..80).prop_map(Response::Coils),
        proptest::collection::vec(any::<bool>(), 0..80).prop_map(Response::DiscreteInputs),
        (any::<u16>(), any::<u16>())
            .prop_map(|(address, value)| Response::WriteSingleRegister { address, value }),
        (any::<u16>(), any::<u16>())
            .prop_map(|(start, quantity)| Response::WriteMultipleRegisters { start, quantity }),
    ]
}

/// Small edits of a real profile: a value replaced by arbitrary text, a line dropped or
/// repeated, the text cut short. Most results are still TOML, so the validation runs.
#[derive(Debug, Clone)]
enum Mutation {
    ReplaceValue {
        line: usize,
        with: String,
    },
    /// One of the numbers of the profile (an offset, count, address, digit count …) changed.
    ReplaceNumber {
        pick: usize,
        with: i64,
    },
    DropLine(usize),
    RepeatLine(usize),
    Truncate(usize),
}

fn any_mutation() -> impl Strategy<Value = Mutation> {
    let value = prop_oneof![
        1 => any::<i64>().prop_map(|n| n.to_string()),
        // Values that fit the keys' types, so validation rather than parsing decides.
        4 => any::<u16>().prop_map(|n| n.to_string()),
        4 => (0u16..300).prop_map(|n| n.to_string()),
        4 => (0u8..20).prop_map(|n| n.to_string()),
        1 => any::<f64>().prop_map(|f| format!("{f:?}")),
        1 => "\"[a-z_]{0,12}\"",
        1 => Just("[]".to_string()),
        1 => Just("{}".to_string()),
        1 => Just("[0, 65535]".to_string()),
        1 => Just("{ type = \"bcd\", int_digits = 200, frac_digits = 200 }".to_string()),
        1 => Just("{ type = \"bits\", bit = 15, width = 16 }".to_string()),
        1 => Just("{ type = \"u16\", decimals = 30, scale = 0.0000001 }".to_string()),
        1 => ".{0,16}",
    ];
    prop_oneof![
        1 => (any::<usize>(), value).prop_map(|(line, with)| Mutation::ReplaceValue { line, with }),
        3 => (any::<usize>(), prop_oneof![-2i64..40, 0i64..70000])
            .prop_map(|(pick, with)| Mutation::ReplaceNumber { pick, with }),
        1 => any::<usize>().prop_map(Mutation::DropLine),
        1 => any::<usize>().prop_map(Mutation::RepeatLine),
        1 => any::<usize>().prop_map(Mutation::Truncate),
    ]
}

fn mutate(text: &str, mutations: &[Mutation]) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    for mutation in mutations {
        if lines.is_empty() {
            break;
        }
        let len = lines.len();
        match mutation {
            Mutation::ReplaceValue { line, with } => {
                let line = &mut lines[line % len];
                if let Some(at) = line.find(" = ") {
                    line.truncate(at + 3);
                    line.push_str(with);
                }
            }
            Mutation::ReplaceNumber { pick, with } => {
                let numbered: Vec<usize> = lines
                    .iter()
                    .enumerate()
                    .filter(|(_, line)| {
                        line.split(" = ")
                            .nth(1)
                            .is_some_and(|value| value.starts_with(|c: char| c.is_ascii_digit()))
                    })
                    .map(|(i, _)| i)
                    .collect();
                if let Some(&index) = numbered.get(pick % numbered.len().max(1)) {
                    let line = &mut lines[index];
                    if let Some(at) = line.find(" = ") {
                        line.truncate(at + 3);
                        line.push_str(&with.to_string());
                    }
                }
            }
            Mutation::DropLine(line) => {
                lines.remove(line % len);
            }
            Mutation::RepeatLine(line) => {
                let copy = lines[line % len].clone();
                lines.insert(line % len, copy);
            }
            Mutation::Truncate(line) => lines.truncate(line % len),
        }
    }
    lines.join("\n")
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Random contents under a correct CRC: the decoder reaches the function, count and data
    /// checks, and refuses or decodes without panicking.
    #[test]
    fn answers_with_a_valid_crc_never_panic_the_decoder(
        slave in any::<u8>(),
        request in any_read_request(),
        answer_slave in prop_oneof![Just(None), any::<u8>().prop_map(Some)],
        function in prop_oneof![1u8..=6, Just(0x0F), Just(0x10), any::<u8>()],
        rest in proptest::collection::vec(any::<u8>(), 0..260),
    ) {
        let mut bytes = vec![answer_slave.unwrap_or(slave), function];
        bytes.extend(rest);
        let frame = with_crc(bytes);
        let _ = decode_answer(slave, &request, &frame);
    }

    #[test]
    fn requests_with_a_valid_crc_never_panic_the_decoder(
        slave in any::<u8>(),
        function in prop_oneof![1u8..=6, Just(0x0F), Just(0x10), any::<u8>()],
        rest in proptest::collection::vec(any::<u8>(), 0..260),
    ) {
        let mut bytes = vec![slave, function];
        bytes.extend(rest);
        let frame = with_crc(bytes);
        let _ = request_frame_len(&frame);
        let _ = decode_request(&frame);
    }

    /// Any command text, from arbitrary bytes, on any field of any profile: planned or refused
    /// with a reason that names the field.
    #[test]
    fn commands_from_arbitrary_bytes_are_planned_or_refused(
        bytes in proptest::collection::vec(any::<u8>(), 0..48),
        pick in any::<usize>(),
    ) {
        let text = String::from_utf8_lossy(&bytes);
        for (_, profile) in profiles() {
            let field = &profile.fields()[pick % profile.fields().len()].name;
            match profile.plan_command(field, &text, &DeviceState::new()) {
                Ok(plan) => prop_assert_eq!(plan.field(), field.as_str()),
                Err(Rejection(reason)) => prop_assert!(
                    reason.contains(field.as_str()),
                    "{field}: {reason}"
                ),
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]

    #[test]
    fn arbitrary_text_never_panics_the_profile_loader(text in "(?s).{0,400}") {
        let _ = Profile::from_toml(&text, "fuzz.toml");
    }

    /// Edited real profiles: loaded or refused, and a refusal lists at least one problem with
    /// its place in the file.
    #[test]
    fn mutated_profiles_are_loaded_or_refused_with_places(
        pick in any::<usize>(),
        mutations in proptest::collection::vec(any_mutation(), 1..4),
    ) {
        let (text, _) = &profiles()[pick % profiles().len()];
        let mutated = mutate(text, &mutations);
        match Profile::from_toml(&mutated, "fuzz.toml") {
            Ok(profile) => {
                // A profile that loads is usable: every field plans or refuses a command.
                for field in profile.fields() {
                    let _ = profile.plan_command(&field.name, "1", &DeviceState::new());
                }
            }
            Err(errors) => {
                prop_assert!(!errors.0.is_empty());
                for error in &errors.0 {
                    prop_assert!(error.to_string().starts_with("fuzz.toml"), "{}", error);
                }
            }
        }
    }

    /// A command's fresh read and read-back come from the device: whatever it answers, the
    /// plan computes writes or refuses, and judges the read-back without panicking. A
    /// read-back that is not a usable answer is never taken as applied.
    #[test]
    fn plans_survive_any_device_answers(
        pick_profile in any::<usize>(),
        pick_field in any::<usize>(),
        before in proptest::collection::vec(any_answer(), 0..3),
        after in proptest::collection::vec(any_answer(), 0..3),
    ) {
        let (_, profile) = &profiles()[pick_profile % profiles().len()];
        let writable: Vec<_> = profile.fields().iter().filter(|f| f.writable).collect();
        let field = writable[pick_field % writable.len()];
        let Some(value) = profile.plausible_value(&field.name) else {
            return Ok(());
        };
        let text = match value.to_text().as_str() {
            "OFF" if field.kind == rtu2mqtt_profile::FieldKind::Momentary => "PRESS".to_string(),
            other => other.to_string(),
        };
        let Ok(plan) = profile.plan_command(&field.name, &text, &DeviceState::new()) else {
            return Ok(());
        };
        match plan.writes(&before) {
            Ok(writes) => {
                for write in writes {
                    prop_assert!(
                        matches!(
                            write,
                            Request::WriteSingleCoil { .. }
                                | Request::WriteSingleRegister { .. }
                                | Request::WriteMultipleCoils { .. }
                                | Request::WriteMultipleRegisters { .. }
                        ),
                        "{write:?}"
                    );
                }
            }
            Err(Rejection(reason)) => prop_assert!(!reason.is_empty()),
        }
        let verdict = plan.verify(&after);
        let no_read_answer = after.iter().all(|answer| {
            matches!(
                answer,
                Response::WriteSingleRegister { .. } | Response::WriteMultipleRegisters { .. }
            )
        });
        if no_read_answer {
            prop_assert!(matches!(verdict, Verification::NotApplied(_)), "{verdict:?}");
        }
    }

    #[test]
    fn write_groups_from_arbitrary_text_are_planned_or_refused(
        pick in any::<usize>(),
        frame_pick in any::<usize>(),
        values in proptest::collection::vec(("[a-z_]{0,16}", ".{0,12}"), 0..5),
    ) {
        let (_, profile) = &profiles()[pick % profiles().len()];
        let frames = profile.write_frame_names();
        let frame = frames
            .get(frame_pick % frames.len().max(1))
            .map_or("no_such_frame".to_string(), |name| name.to_string());
        // Real field names too, so the value checks are reached, not only the name checks.
        let fields: Vec<&str> = profile.fields().iter().map(|f| f.name.as_str()).collect();
        let named: Vec<(String, String)> = values
            .iter()
            .enumerate()
            .map(|(i, (name, text))| {
                let name = if i % 2 == 0 {
                    fields[(pick + i) % fields.len()].to_string()
                } else {
                    name.clone()
                };
                (name, text.clone())
            })
            .collect();
        let pairs: Vec<(&str, &str)> =
            named.iter().map(|(n, t)| (n.as_str(), t.as_str())).collect();
        match profile.plan_group(&frame, &pairs, &DeviceState::new()) {
            Ok(plan) => prop_assert_eq!(plan.targets().len(), pairs.len()),
            Err(Rejection(reason)) => prop_assert!(!reason.is_empty()),
        }
    }
}
