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
        match self {
            Self::Bool(true) => "ON".to_string(),
            Self::Bool(false) => "OFF".to_string(),
            Self::Int(value) => value.to_string(),
            Self::Decimal { scaled, precision } => {
                if *precision == 0 {
                    return scaled.to_string();
                }
                let divisor = 10u64.pow(u32::from(*precision));
                let magnitude = scaled.unsigned_abs();
                let sign = if *scaled < 0 { "-" } else { "" };
                format!(
                    "{sign}{}.{:0width$}",
                    magnitude / divisor,
                    magnitude % divisor,
                    width = usize::from(*precision)
                )
            }
            Self::Enum(word) | Self::Text(word) => word.clone(),
        }
    }

    /// Typed JSON for the per-device JSON view: booleans, numbers, strings.
    pub fn to_json(&self) -> serde_json::Value {
        match self {
            Self::Bool(on) => serde_json::Value::Bool(*on),
            Self::Int(value) => serde_json::Value::from(*value),
            Self::Decimal { scaled, precision } => {
                // Through the text form so 12.34 stays 12.34 rather than 12.339999….
                let number: f64 = self
                    .to_text()
                    .parse()
                    .unwrap_or(*scaled as f64 / 10f64.powi(i32::from(*precision)));
                serde_json::Number::from_f64(number)
                    .map_or(serde_json::Value::Null, serde_json::Value::Number)
            }
            Self::Enum(word) | Self::Text(word) => serde_json::Value::String(word.clone()),
        }
    }
}

impl std::fmt::Display for Value {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.to_text())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_forms() {
        assert_eq!(Value::Bool(true).to_text(), "ON");
        assert_eq!(Value::Bool(false).to_text(), "OFF");
        assert_eq!(Value::Int(-7).to_text(), "-7");
        let decimal = |scaled, precision| Value::Decimal { scaled, precision };
        assert_eq!(decimal(1234, 2).to_text(), "12.34");
        assert_eq!(decimal(5, 2).to_text(), "0.05");
        assert_eq!(decimal(-5, 2).to_text(), "-0.05");
        assert_eq!(decimal(-1234, 1).to_text(), "-123.4");
        assert_eq!(decimal(42, 0).to_text(), "42");
        assert_eq!(Value::Enum("opening".into()).to_text(), "opening");
    }

    #[test]
    fn json_forms() {
        let decimal = Value::Decimal {
            scaled: 1234,
            precision: 2,
        };
        assert_eq!(decimal.to_json().to_string(), "12.34");
        assert_eq!(Value::Bool(true).to_json(), serde_json::Value::Bool(true));
        assert_eq!(Value::Int(8).to_json().to_string(), "8");
        assert_eq!(Value::Text("0A".into()).to_json().to_string(), "\"0A\"");
    }
}
