//! One device's runtime on its line, in one place instead of parallel per-device vectors: its
//! configuration, its statistics, the blocks it refused merged (read by parts from then on),
//! the last answer of each block, and the one path from a read answer to the values the line
//! publishes (field data that does not decode is counted and logged, never published; a field
//! turning unavailable is counted and logged once per episode). No frames are run here.

use std::collections::HashSet;

use rtu2mqtt_modbus::Response;
use rtu2mqtt_profile::{DeviceState, Value};

use super::device_spec::DeviceSpec;
use super::stats::DeviceStats;

/// Decoded values of a device, by field name, ready for a `LineEvent::Values`.
pub(crate) type Values = Vec<(String, Value)>;

/// A configured device as its line runs it.
#[derive(Debug, Clone)]
pub(crate) struct DeviceRuntime {
    pub spec: DeviceSpec,
    pub stats: DeviceStats,
    /// Per block: the device refused the merged block, read its used runs instead.
    pub read_by_parts: Vec<bool>,
    /// Per block: the last answer whose values went to the bridge while the device has been
    /// online. An equal answer decodes to the same values, so it is neither decoded nor sent
    /// again (polling a device whose values do not move allocates nothing), and of an answer
    /// that differs only the fields whose registers moved are.
    last_answers: Vec<Option<Response>>,
    /// Per block: its latest answer while the device is online, whatever it held: where the
    /// `scale_by` fields of other blocks find their exponents.
    latest_answers: Vec<Option<Response>>,
    /// Per block: the other blocks holding fields scaled by an exponent in it.
    scaled_blocks: Vec<Vec<usize>>,
    /// The fields whose latest value is unavailable: an episode is logged and counted once.
    unavailable: HashSet<String>,
}

impl DeviceRuntime {
    pub(crate) fn new(spec: DeviceSpec) -> Self {
        DeviceRuntime {
            stats: DeviceStats::new(&spec.name),
            read_by_parts: vec![false; spec.profile.read_blocks().len()],
            last_answers: vec![None; spec.profile.read_blocks().len()],
            latest_answers: vec![None; spec.profile.read_blocks().len()],
            scaled_blocks: (0..spec.profile.read_blocks().len())
                .map(|block| spec.profile.blocks_scaled_by(block))
                .collect(),
            unavailable: HashSet::new(),
            spec,
        }
    }

    /// True when `answer` to `block` equals the last one whose values were sent and the device
    /// is online: its values are already known to the bridge. A device that comes back online
    /// sends its values again (the bridge republishes them then).
    pub(crate) fn answer_unchanged(&self, block: usize, answer: &Response) -> bool {
        self.stats.online && self.last_answers.get(block).and_then(Option::as_ref) == Some(answer)
    }

    /// The values of the device's last remembered answers: the state a client's write is
    /// validated on.
    pub(crate) fn known_state(&self) -> DeviceState {
        let mut state = DeviceState::new();
        for (block, answer) in self.last_answers.iter().enumerate() {
            let Some(answer) = answer else { continue };
            let latest = |other: usize| self.latest_answers.get(other).and_then(Option::as_ref);
            for reading in self.spec.profile.decode_block_with(block, answer, latest) {
                if let Ok(value) = reading.value {
                    state.insert(reading.field, value);
                }
            }
        }
        state
    }

    /// The device went offline: its next answers are sent whatever they hold.
    pub(crate) fn forget_answers(&mut self) {
        self.last_answers.fill(None);
        self.latest_answers.fill(None);
    }

    /// Decodes `answer` to the device's read block `block` and adds its valid values to
    /// `values`: with [`Decode::Changes`], only those of the fields whose registers moved since
    /// the block's remembered answer (every field when none is remembered or the device is not
    /// online); with [`Decode::Every`], every field. An answer whose fields all decode is
    /// remembered (see [`DeviceRuntime::answer_unchanged`]); one with invalid field data is
    /// decoded, counted and logged each time.
    pub(crate) fn decode_into(
        &mut self,
        block: usize,
        answer: &Response,
        decode: Decode,
        values: &mut Values,
    ) {
        let profile = self.spec.profile.clone();
        if let Some(latest) = self.latest_answers.get_mut(block) {
            if latest.as_ref() != Some(answer) {
                // New exponents: the blocks they scale decode again in full.
                for &user in self.scaled_blocks.get(block).into_iter().flatten() {
                    if let Some(last) = self.last_answers.get_mut(user) {
                        *last = None;
                    }
                }
                remember(latest, answer);
            }
        }
        let previous = match decode {
            Decode::Changes if self.stats.online => {
                self.last_answers.get(block).and_then(Option::as_ref)
            }
            _ => None,
        };
        let latest = |other: usize| self.latest_answers.get(other).and_then(Option::as_ref);
        let readings = profile.decode_block_changes(block, answer, previous, latest);
        let mut all_valid = true;
        values.reserve(readings.len());
        for reading in readings {
            match reading.value {
                Ok(value) => {
                    self.note_availability(&reading.field, &value);
                    values.push((reading.field, value));
                }
                Err(error) => {
                    all_valid = false;
                    self.stats.field_errors += 1;
                    tracing::warn!(
                        device = %self.spec.name,
                        field = %reading.field,
                        "invalid field data, not published: {error}"
                    );
                }
            }
        }
        if let Some(last) = self.last_answers.get_mut(block) {
            if all_valid {
                remember(last, answer);
            } else {
                *last = None;
            }
        }
    }
}

impl DeviceRuntime {
    /// Logs and counts a field turning unavailable once per episode, and its return.
    fn note_availability(&mut self, field: &str, value: &Value) {
        let available = value.is_available();
        if !available && !self.unavailable.contains(field) {
            self.unavailable.insert(field.to_string());
            self.stats.unavailable_episodes += 1;
            tracing::info!(
                device = %self.spec.name,
                field,
                "the device reports no value: published as unavailable until it has one"
            );
        } else if available && self.unavailable.remove(field) {
            tracing::info!(device = %self.spec.name, field, "the device has a value again");
        }
    }
}

/// Which of a block's fields [`DeviceRuntime::decode_into`] decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Decode {
    /// Those whose registers moved: a poll, whose unchanged values the bridge already has.
    Changes,
    /// All of them: a command's reads, which go out whatever they hold.
    Every,
}

/// Keeps `answer` in `slot`, reusing the slot's buffer when it holds one of the same kind.
fn remember(slot: &mut Option<Response>, answer: &Response) {
    match (slot.as_mut(), answer) {
        (Some(Response::HoldingRegisters(kept)), Response::HoldingRegisters(words))
        | (Some(Response::InputRegisters(kept)), Response::InputRegisters(words)) => {
            kept.clone_from(words);
        }
        (Some(Response::Coils(kept)), Response::Coils(bits))
        | (Some(Response::DiscreteInputs(kept)), Response::DiscreteInputs(bits)) => {
            kept.clone_from(bits);
        }
        _ => *slot = Some(answer.clone()),
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::time::Duration;

    use super::*;
    use rtu2mqtt_profile::Profile;

    /// A fast block holding the exponent, a slow one holding the value it scales.
    const PROFILE: &str = r#"
[device]
name = "scaled"
manufacturer = "Test"
model = "S1"

[line]

[[blocks]]
name = "factors"
function = 3
start = 0
count = 1

[[blocks]]
name = "ratings"
function = 3
start = 10
count = 1
poll = "slow"

[[fields]]
name = "rating_sf"
block = "factors"
offset = 0
codec = { type = "i16", invalid = [0x8000] }

[[fields]]
name = "rating"
block = "ratings"
offset = 0
codec = { type = "u16", scale_by = "rating_sf" }
"#;

    /// An online device named `name` with the profile `text`.
    fn online(text: &str, name: &str) -> DeviceRuntime {
        let profile = Profile::from_toml(text, &format!("{name}.toml")).expect("valid profile");
        let mut runtime = DeviceRuntime::new(DeviceSpec {
            name: name.to_string(),
            address: 1,
            profile: Arc::new(profile),
            poll_interval: Duration::from_millis(100),
            publish: Default::default(),
        });
        runtime.stats.online = true;
        runtime
    }

    fn runtime() -> DeviceRuntime {
        online(PROFILE, "scaled")
    }

    fn words(word: u16) -> Response {
        Response::HoldingRegisters(vec![word])
    }

    fn decoded(runtime: &mut DeviceRuntime, block: usize, answer: &Response) -> Values {
        let mut values = Values::new();
        runtime.decode_into(block, answer, Decode::Changes, &mut values);
        values
    }

    /// One block: a value, a value scaled by an exponent beside it, the exponent, a u32.
    const METER: &str = r#"
[device]
name = "meter"
manufacturer = "Test"
model = "M1"

[line]

[[blocks]]
name = "readings"
function = 3
start = 0
count = 5

[[fields]]
name = "volts"
block = "readings"
offset = 0
codec = { type = "u16" }

[[fields]]
name = "amps"
block = "readings"
offset = 1
codec = { type = "u16", scale_by = "amps_sf" }

[[fields]]
name = "amps_sf"
block = "readings"
offset = 2
codec = { type = "i16" }

[[fields]]
name = "energy"
block = "readings"
offset = 3
codec = { type = "u32" }
"#;

    fn meter() -> DeviceRuntime {
        online(METER, "meter")
    }

    fn names(values: &Values) -> Vec<&str> {
        values.iter().map(|(field, _)| field.as_str()).collect()
    }

    fn readings(words: [u16; 5]) -> Response {
        Response::HoldingRegisters(words.to_vec())
    }

    #[test]
    fn a_poll_decodes_only_the_fields_whose_registers_moved() {
        let mut runtime = meter();
        let first = decoded(&mut runtime, 0, &readings([230, 15, 0xFFFF, 0, 7]));
        assert_eq!(names(&first), ["volts", "amps", "amps_sf", "energy"]);
        // The low word of the u32 alone moved.
        let energy = decoded(&mut runtime, 0, &readings([230, 15, 0xFFFF, 0, 8]));
        assert_eq!(energy, [("energy".to_string(), Value::Int(8))]);
        // The exponent moved: the value it scales is decoded with it, though its register
        // did not move.
        let scaled = decoded(&mut runtime, 0, &readings([230, 15, 0xFFFE, 0, 8]));
        assert_eq!(names(&scaled), ["amps", "amps_sf"]);
        assert_eq!(
            scaled[0].1,
            Value::Decimal {
                scaled: 15,
                precision: 2
            }
        );
        assert!(runtime.answer_unchanged(0, &readings([230, 15, 0xFFFE, 0, 8])));
        assert_eq!(runtime.known_state().len(), 4);
    }

    #[test]
    fn every_field_is_decoded_for_a_command_offline_or_after_invalid_data() {
        let mut runtime = meter();
        decoded(&mut runtime, 0, &readings([230, 15, 0xFFFF, 0, 7]));
        let mut values = Values::new();
        runtime.decode_into(
            0,
            &readings([231, 15, 0xFFFF, 0, 7]),
            Decode::Every,
            &mut values,
        );
        assert_eq!(names(&values), ["volts", "amps", "amps_sf", "energy"]);
        // A device that is not online (coming back) sends what it holds in full.
        runtime.stats.online = false;
        let back = decoded(&mut runtime, 0, &readings([232, 15, 0xFFFF, 0, 7]));
        assert_eq!(names(&back), ["volts", "amps", "amps_sf", "energy"]);
        runtime.stats.online = true;
        // An answer of another length fits no field: nothing is remembered, so the next
        // answer is decoded in full.
        let short = Response::HoldingRegisters(vec![232, 15]);
        assert!(decoded(&mut runtime, 0, &short).is_empty());
        assert_eq!(runtime.stats.field_errors, 4);
        let again = decoded(&mut runtime, 0, &readings([232, 15, 0xFFFF, 0, 7]));
        assert_eq!(names(&again), ["volts", "amps", "amps_sf", "energy"]);
    }

    #[test]
    fn an_exponent_in_another_block_is_its_latest_read() {
        let mut runtime = runtime();
        // Not read yet: the value is invalid data, not published.
        assert!(decoded(&mut runtime, 1, &words(4200)).is_empty());
        assert_eq!(runtime.stats.field_errors, 1);
        let exponent = decoded(&mut runtime, 0, &words(0xFFFE));
        assert_eq!(exponent, [("rating_sf".to_string(), Value::Int(-2))]);
        let value = Value::Decimal {
            scaled: 4200,
            precision: 2,
        };
        // The value's answer did not change, but its exponent did: it is decoded again.
        assert!(!runtime.answer_unchanged(1, &words(4200)));
        assert_eq!(
            decoded(&mut runtime, 1, &words(4200)),
            [("rating".to_string(), value.clone())]
        );
        assert!(runtime.answer_unchanged(1, &words(4200)));
        assert_eq!(runtime.known_state()["rating"], value);
        // "Not implemented": the value is unavailable, not an error.
        decoded(&mut runtime, 0, &words(0x8000));
        assert!(!runtime.answer_unchanged(1, &words(4200)));
        assert_eq!(
            decoded(&mut runtime, 1, &words(4200)),
            [("rating".to_string(), Value::Unavailable)]
        );
        assert_eq!(runtime.stats.field_errors, 1);
    }
}
