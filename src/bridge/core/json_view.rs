//! The per-device JSON view for SCADA and Node-RED: one retained document on
//! `<prefix>/<device>` holding every current value of the device, typed (numbers as numbers,
//! booleans as booleans, enumerations and text as strings).
//!
//! Pure: the bridge passes the device's last known values and publishes the result. Keys are
//! the field names in ascending order whatever map the values came from, so two documents with
//! the same values are byte-identical (the bridge can skip publishing an unchanged view).
//! [`JsonView`] keeps the document and changes it in place, so that a reading that changed
//! one value of a hundred renders that one value again, not the hundred.

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

/// A device's JSON view kept as its document, changed in place: a reading that moved one
/// value of a hundred renders that value and splices it in, and the view costs no more memory
/// than its text. Field names are plain (lower-case letters, digits, `-`, `_`: the profile
/// checks them), so each key is its name in quotes and the members are in the order of their
/// names, as in [`json_view_payload`].
#[derive(Debug, Default, Clone)]
pub struct JsonView {
    /// The document (empty while no value is known).
    text: String,
    /// The document has not been published as it is (or its publication failed).
    stale: bool,
}

impl JsonView {
    /// Takes `value` as `field`'s; true when the view changed.
    pub fn set(&mut self, field: &str, value: &Value) -> bool {
        let json = value.to_json().to_string();
        let key = Json::String(field.to_string()).to_string();
        let changed = match self.place_of(field) {
            Place::Value(range) if self.text[range.clone()] == json => false,
            Place::Value(range) => {
                self.text.replace_range(range, &json);
                true
            }
            Place::Before(at) => {
                self.text.insert_str(at, &format!("{key}:{json},"));
                true
            }
            Place::Last => {
                let at = self.text.len() - 1;
                self.text.insert_str(at, &format!(",{key}:{json}"));
                true
            }
            Place::Empty => {
                self.text = format!("{{{key}:{json}}}");
                true
            }
        };
        self.stale |= changed;
        changed
    }

    /// Where `field` is in the document, or where it goes. A member ends where the next one
    /// starts (`,"` outside a string: inside one a quote is escaped) or at the closing brace.
    fn place_of(&self, field: &str) -> Place {
        if self.text.is_empty() {
            return Place::Empty;
        }
        let bytes = self.text.as_bytes();
        let last = self.text.len() - 1;
        let mut start = 1;
        loop {
            let end = self.text[start..last]
                .find(",\"")
                .map_or(last, |at| start + at);
            // The key: from its opening quote to the next quote not escaped.
            let mut key_end = start + 1;
            while key_end < end && bytes[key_end] != b'"' {
                key_end += if bytes[key_end] == b'\\' { 2 } else { 1 };
            }
            let name = &self.text[start + 1..key_end.min(end)];
            match name.cmp(field) {
                std::cmp::Ordering::Equal => return Place::Value(key_end + 2..end),
                std::cmp::Ordering::Greater => return Place::Before(start),
                std::cmp::Ordering::Less if end == last => return Place::Last,
                std::cmp::Ordering::Less => start = end + 1,
            }
        }
    }

    /// The view must be published again even though its values did not change.
    pub fn mark_stale(&mut self) {
        self.stale = true;
    }

    /// The payload to publish when the view changed since it was last taken (or was marked
    /// stale); None when it holds nothing or was published as it is.
    pub fn take_payload(&mut self) -> Option<String> {
        if !self.stale || self.text.is_empty() {
            return None;
        }
        self.stale = false;
        Some(self.text.clone())
    }
}

/// Where a field is in a view's document.
#[derive(Debug)]
enum Place {
    /// Its value's text.
    Value(std::ops::Range<usize>),
    /// Not there: its member goes at this offset, before the first one named after it.
    Before(usize),
    /// Not there, named after every member.
    Last,
    /// The document is empty.
    Empty,
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
            ("mode", Value::Enum("auto".into())),
            ("a", Value::Text("x,\"y\":1".into())),
            ("zz", Value::Int(-3)),
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
    fn values_set_first_last_between_and_again_keep_the_document_of_the_state() {
        let mut state = DeviceState::new();
        let mut view = JsonView::default();
        let steps = [
            ("m", Value::Int(1)),
            ("m", Value::Int(22)),
            ("c", Value::Text("a,\"b\":{".into())),
            ("x", Value::Bool(false)),
            ("f", Value::Unavailable),
            ("c", Value::Text(String::new())),
            ("a-1", Value::Int(7)),
            (
                "x",
                Value::Decimal {
                    scaled: 5,
                    precision: 1,
                },
            ),
            ("z_9", Value::Enum("open".into())),
            ("f", Value::Int(0)),
            ("a-1", Value::Int(-70)),
        ];
        for (field, value) in steps {
            view.set(field, &value);
            state.insert(field.to_string(), value);
            assert_eq!(
                view.take_payload()
                    .unwrap_or_else(|| view.text.clone())
                    .as_bytes(),
                json_view_payload(&state).as_slice()
            );
        }
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
