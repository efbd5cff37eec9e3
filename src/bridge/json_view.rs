//! The per-device JSON view for SCADA and Node-RED: one retained document on
//! `<prefix>/<device>` holding every current value of the device, typed (numbers as numbers,
//! booleans as booleans, enumerations and text as strings).
//!
//! Pure: the bridge passes the device's last known values and publishes the result. Keys are
//! the field names in ascending order whatever map the values came from, so two documents with
//! the same values are byte-identical (the bridge can skip publishing an unchanged view).
//! [`JsonView`] keeps each field's JSON text, so that a reading that changed one value of a
//! hundred renders that one value again, not the hundred.

use std::collections::BTreeMap;

use serde_json::{Map, Value as Json};

use rtu2mqtt_profile::{DeviceState, Value};

/// The JSON view of `(field, value)` pairs: an object keyed by field name in ascending order.
/// A field given twice keeps its last value (the newest reading).
pub fn json_view_from_pairs<'v, I>(values: I) -> Json
where
    I: IntoIterator<Item = (&'v str, &'v Value)>,
{
    let mut sorted: Vec<(&str, &Value)> = values.into_iter().collect();
    // A stable sort keeps the given order among equal names, so the last one wins below.
    sorted.sort_by(|a, b| a.0.cmp(b.0));
    let mut document = Map::new();
    for (field, value) in sorted {
        document.insert(field.to_string(), value.to_json());
    }
    Json::Object(document)
}

/// The JSON view of a device's current state.
pub fn json_view(state: &DeviceState) -> Json {
    json_view_from_pairs(state.iter().map(|(field, value)| (field.as_str(), value)))
}

/// The JSON view as the payload bytes to publish.
pub fn json_view_payload(state: &DeviceState) -> Vec<u8> {
    json_view(state).to_string().into_bytes()
}

/// A device's JSON view as its fields' JSON texts, in ascending order of field names.
#[derive(Debug, Default, Clone)]
pub struct JsonView {
    /// Field name → (the name as a JSON string, the value as JSON).
    fields: BTreeMap<String, (String, String)>,
    /// The payload of these values has not been published (or its publication failed).
    stale: bool,
}

impl JsonView {
    /// Takes `value` as `field`'s; true when the view changed.
    pub fn set(&mut self, field: &str, value: &Value) -> bool {
        let json = value.to_json().to_string();
        let changed = match self.fields.get_mut(field) {
            Some((_, known)) if *known == json => false,
            Some((_, known)) => {
                *known = json;
                true
            }
            None => {
                let key = Json::String(field.to_string()).to_string();
                self.fields.insert(field.to_string(), (key, json));
                true
            }
        };
        self.stale |= changed;
        changed
    }

    /// The view must be published again even though its values did not change.
    pub fn mark_stale(&mut self) {
        self.stale = true;
    }

    /// The payload to publish when the view changed since it was last taken (or was marked
    /// stale); None when it holds nothing or was published as it is.
    pub fn take_payload(&mut self) -> Option<String> {
        if !self.stale || self.fields.is_empty() {
            return None;
        }
        self.stale = false;
        Some(self.payload())
    }

    /// The document: byte for byte [`json_view_payload`] of the same values.
    pub fn payload(&self) -> String {
        let length: usize = self
            .fields
            .values()
            .map(|(key, json)| key.len() + json.len() + 2)
            .sum();
        let mut text = String::with_capacity(length + 2);
        text.push('{');
        for (index, (key, json)) in self.fields.values().enumerate() {
            if index > 0 {
                text.push(',');
            }
            text.push_str(key);
            text.push(':');
            text.push_str(json);
        }
        text.push('}');
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kept_view_is_the_document_of_its_values_and_knows_what_changed() {
        let mut state = DeviceState::new();
        let mut view = JsonView::default();
        let readings = [
            (
                "temperature",
                Value::Decimal {
                    scaled: 2150,
                    precision: 2,
                },
            ),
            ("power", Value::Bool(true)),
            ("mode \"eco\"", Value::Enum("auto".into())),
            ("energy", Value::Int(18_446_744_073_709_551_614)),
            ("humidity", Value::Unavailable),
        ];
        for (field, value) in &readings {
            assert!(view.set(field, value));
            state.insert(field.to_string(), value.clone());
        }
        let first = view.take_payload().expect("a new view is published");
        assert_eq!(first.as_bytes(), json_view_payload(&state).as_slice());
        assert_eq!(view.take_payload(), None, "published as it is");
        assert!(!view.set("power", &Value::Bool(true)), "an equal value");
        assert_eq!(view.take_payload(), None);
        assert!(view.set(
            "temperature",
            &Value::Decimal {
                scaled: 2200,
                precision: 2
            }
        ));
        state.insert(
            "temperature".into(),
            Value::Decimal {
                scaled: 2200,
                precision: 2,
            },
        );
        let second = view.take_payload().expect("a changed view is published");
        assert_eq!(second.as_bytes(), json_view_payload(&state).as_slice());
        assert!(second.contains("\"temperature\":22.0"), "{second}");
        view.mark_stale();
        assert_eq!(view.take_payload(), Some(second));
    }

    #[test]
    fn an_unavailable_value_is_null_and_a_64_bit_counter_exact() {
        let mut state = DeviceState::new();
        state.insert("current".to_string(), Value::Unavailable);
        state.insert("energy".to_string(), Value::Int(18_446_744_073_709_551_614));
        state.insert("model".to_string(), Value::Text("SDM630".to_string()));
        assert_eq!(
            String::from_utf8_lossy(&json_view_payload(&state)),
            r#"{"current":null,"energy":18446744073709551614,"model":"SDM630"}"#
        );
    }
}
