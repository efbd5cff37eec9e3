//! A profile file as the gateway reads it (`Profile::from_toml`): any text. Input: the TOML
//! text (seeds: the library's profiles).
//!
//! Asserted: a refusal lists at least one problem, each placed in the file; a profile that
//! loads answers for every block (an answer of its shape decodes to readings of its own fields
//! only, an answer of another shape to an error for each of them), and plans or refuses a
//! command on every field, a planned command being for that field.

#![no_main]

use std::collections::HashSet;

use libfuzzer_sys::fuzz_target;
use rtu2mqtt_modbus::Response;
use rtu2mqtt_profile::{DeviceState, Profile, Rejection};

const SOURCE: &str = "fuzz.toml";

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let profile = match Profile::from_toml(text, SOURCE) {
        Ok(profile) => profile,
        Err(errors) => {
            assert!(!errors.0.is_empty(), "a refusal without a problem");
            for error in &errors.0 {
                assert!(error.place.starts_with(SOURCE), "unplaced: {error}");
                assert!(!error.reason.is_empty(), "no reason: {error}");
            }
            return;
        }
    };
    let names: HashSet<&str> = profile.fields().iter().map(|f| f.name.as_str()).collect();
    assert_eq!(
        names.len(),
        profile.fields().len(),
        "two fields of one name"
    );
    for (index, block) in profile.read_blocks().iter().enumerate() {
        let own: HashSet<&str> = profile.block_fields(index).into_iter().collect();
        let Some(zero) = block.request.empty_answer() else {
            panic!("block {index} is no read: {:?}", block.request);
        };
        for answer in [patterned(&zero), zero] {
            let readings = profile.decode_block(index, &answer);
            for reading in &readings {
                assert!(
                    own.contains(reading.field.as_str()),
                    "block {index} gave a reading of {}",
                    reading.field
                );
            }
        }
        let wrong_shape = Response::WriteSingleRegister {
            address: 0,
            value: 0,
        };
        for reading in profile.decode_block(index, &wrong_shape) {
            assert!(
                reading.value.is_err(),
                "{}: a value from no answer",
                reading.field
            );
        }
    }
    let examples = profile.example_commands();
    for field in profile.fields() {
        let texts = examples
            .iter()
            .filter(|(name, _)| *name == field.name)
            .map(|(_, text)| text.clone())
            .chain(["1", "ON", "-1", "65536"].map(String::from));
        for text in texts {
            match profile.plan_command(&field.name, &text, &DeviceState::new()) {
                Ok(plan) => {
                    assert!(
                        field.writable,
                        "{}: planned on a read-only field",
                        field.name
                    );
                    assert_eq!(plan.field(), field.name);
                }
                Err(Rejection(reason)) => assert!(!reason.is_empty()),
            }
        }
    }
});

/// An answer of the same shape whose words and bits are all different from zero's.
fn patterned(zero: &Response) -> Response {
    match zero {
        Response::HoldingRegisters(words) => Response::HoldingRegisters(
            (0..words.len())
                .map(|i| 0x8001 ^ (i as u16 * 0x0101))
                .collect(),
        ),
        Response::InputRegisters(words) => {
            Response::InputRegisters((0..words.len()).map(|i| 0xFFFF - i as u16).collect())
        }
        Response::Coils(bits) => Response::Coils(vec![true; bits.len()]),
        Response::DiscreteInputs(bits) => Response::DiscreteInputs(vec![true; bits.len()]),
        other => other.clone(),
    }
}
