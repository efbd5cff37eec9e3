//! A decoded field value and its text and JSON forms (the MQTT payload contract).

/// A field value.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    Bool(bool),
    Int(i64),
    /// A fixed-point number: `scaled / 10^precision`, kept exact (BCD 12.34 is 1234, 2).
    Decimal {
        scaled: i64,
        precision: u8,
    },
    /// An enumeration word (`opening`).
    Enum(String),
    Text(String),
}

impl Value {
    /// The MQTT text payload: `ON`/`OFF`, decimal integers, decimals with their precision.
    pub fn to_text(&self) -> String {
        todo!("profile helper")
    }

    /// Typed JSON for the per-device JSON view.
    pub fn to_json(&self) -> serde_json::Value {
        todo!("profile helper")
    }
}
