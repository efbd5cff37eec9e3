//! The history stream's document, pure: `{"ts":"2026-12-02T15:00:01.123Z","values":{…}}`,
//! `ts` the instant the answer was read (RFC 3339, UTC, milliseconds), the values typed as in
//! the JSON view (numbers as numbers, booleans as booleans, words as strings), keys in
//! ascending order.

use std::time::{SystemTime, UNIX_EPOCH};

use serde_json::{Map, Value as Json};

use rtu2mqtt_profile::Value;

/// The document of one change set read at `at`. A field given twice keeps its last value.
pub fn document<'v, I>(at: SystemTime, values: I) -> String
where
    I: IntoIterator<Item = (&'v str, &'v Value)>,
{
    let mut sorted: Vec<(&str, &Value)> = values.into_iter().collect();
    sorted.sort_by(|a, b| a.0.cmp(b.0));
    let mut fields = Map::new();
    for (field, value) in sorted {
        fields.insert(field.to_string(), value.to_json());
    }
    let mut document = Map::new();
    document.insert("ts".into(), Json::String(timestamp(at)));
    document.insert("values".into(), Json::Object(fields));
    Json::Object(document).to_string()
}

/// The values of a history document, in its order; None when it is not one.
pub fn values_of(document: &str) -> Option<Vec<(String, Json)>> {
    match serde_json::from_str::<Json>(document).ok()? {
        Json::Object(mut fields) => match fields.remove("values")? {
            Json::Object(values) => Some(values.into_iter().collect()),
            _ => None,
        },
        _ => None,
    }
}

/// The read instant (`ts`) of a history document, in milliseconds since the epoch.
pub fn read_at_of(document: &str) -> Option<u64> {
    let parsed: Json = serde_json::from_str(document).ok()?;
    let at = humantime::parse_rfc3339(parsed.get("ts")?.as_str()?).ok()?;
    Some(epoch_ms(at))
}

/// RFC 3339 in UTC with milliseconds (`2026-12-02T15:00:01.123Z`).
pub fn timestamp(at: SystemTime) -> String {
    humantime::format_rfc3339_millis(at).to_string()
}

/// Milliseconds since the Unix epoch (0 before it).
pub fn epoch_ms(at: SystemTime) -> u64 {
    at.duration_since(UNIX_EPOCH).map_or(0, |since| {
        u64::try_from(since.as_millis()).unwrap_or(u64::MAX)
    })
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    #[test]
    fn the_document_is_the_contract() {
        let at = UNIX_EPOCH + Duration::from_millis(1_796_223_601_123);
        let values = [
            ("fan_speed".to_string(), Value::Int(1234)),
            ("alarm".to_string(), Value::Bool(false)),
            (
                "pressure".to_string(),
                Value::Decimal {
                    scaled: 1234,
                    precision: 2,
                },
            ),
            ("mode".to_string(), Value::Enum("auto".into())),
        ];
        assert_eq!(
            document(at, values.iter().map(|(f, v)| (f.as_str(), v))),
            r#"{"ts":"2026-12-02T15:00:01.123Z","values":{"alarm":false,"fan_speed":1234,"mode":"auto","pressure":12.34}}"#
        );
        assert_eq!(epoch_ms(at), 1_796_223_601_123);
        let text = document(at, values.iter().map(|(f, v)| (f.as_str(), v)));
        assert_eq!(read_at_of(&text), Some(1_796_223_601_123));
        assert_eq!(read_at_of("{}"), None);
    }

    #[test]
    fn the_values_come_back_out_of_a_document() {
        let at = UNIX_EPOCH + Duration::from_millis(1_796_223_601_123);
        let values = [
            ("gear".to_string(), Value::Int(8)),
            ("alarm".to_string(), Value::Bool(true)),
        ];
        let text = document(at, values.iter().map(|(f, v)| (f.as_str(), v)));
        assert_eq!(
            values_of(&text),
            Some(vec![
                ("alarm".to_string(), Json::Bool(true)),
                ("gear".to_string(), Json::from(8)),
            ])
        );
        assert_eq!(values_of("{\"ts\":\"x\"}"), None);
        assert_eq!(values_of("not json"), None);
    }
}
