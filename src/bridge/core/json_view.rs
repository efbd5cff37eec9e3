//! The per-device JSON view for SCADA and Node-RED: one retained document on
//! `<prefix>/<device>` holding every current value of the device, typed (numbers as numbers,
//! booleans as booleans, enumerations and text as strings).
//!
//! Pure: the bridge passes the device's last known values and publishes the result. Keys are
//! the field names in ascending order whatever map the values came from, so two documents with
//! the same values are byte-identical (the bridge can skip publishing an unchanged view).

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

#[cfg(test)]
mod tests {
    use super::*;

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
