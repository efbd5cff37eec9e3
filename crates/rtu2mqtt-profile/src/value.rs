//! A decoded field value and its text and JSON forms (the MQTT payload contract).

/// The text payload of a field that has no value ([`Value::Unavailable`]).
pub const UNAVAILABLE: &str = "unavailable";

/// A field's value as decoded from the device or parsed from a command; its text form is the
/// MQTT payload.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// A bit, coil or momentary field: `ON` (true) or `OFF` as text.
    Bool(bool),
    /// An integer; wide enough for every 64-bit register value, signed or not, with an offset.
    Int(i128),
    /// A fixed-point number: `scaled / 10^precision`, kept exact (BCD 12.34 is 1234, 2).
    Decimal {
        /// The value times `10^precision`.
        scaled: i128,
        /// Digits after the decimal point, kept when shown (`12.30` stays `12.30`).
        precision: u8,
    },
    /// An enumeration word (`opening`).
    Enum(String),
    /// The text of a `string` or `bytes` field, as shown (`SN1234`, `0A1B2C`, `1:02:03`).
    Text(String),
    /// The device reports that it has no value here: the raw value is one of the field's
    /// `invalid` marks (SunSpec's "not implemented"), or its exponent is, a float is NaN, an
    /// enum code is not named. Published as [`UNAVAILABLE`] on the field's topic, `null` in the
    /// JSON view and Sparkplug, never as a number.
    Unavailable,
}

impl Value {
    /// The MQTT text payload: `ON`/`OFF`, decimal integers, decimals with their precision,
    /// [`UNAVAILABLE`] for no value.
    pub fn to_text(&self) -> String {
        match self {
            Self::Bool(true) => "ON".to_string(),
            Self::Bool(false) => "OFF".to_string(),
            Self::Int(value) => value.to_string(),
            Self::Decimal { scaled, precision } => {
                if *precision == 0 {
                    return scaled.to_string();
                }
                let divisor = 10u128.pow(u32::from(*precision));
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
            Self::Unavailable => UNAVAILABLE.to_string(),
        }
    }

    /// The same value, numbers compared by magnitude whatever their precision (`1.50` is
    /// `1.5`, a `scale_by` read-back at its exponent's places is the commanded value).
    pub(crate) fn same_number(&self, other: &Value) -> bool {
        let as_fraction = |value: &Value| match value {
            Self::Int(integer) => Some((*integer, 0u8)),
            Self::Decimal { scaled, precision } => Some((*scaled, *precision)),
            _ => None,
        };
        match (as_fraction(self), as_fraction(other)) {
            (Some((a, pa)), Some((b, pb))) => {
                let widen = |value: i128, from: u8, to: u8| {
                    value.checked_mul(10i128.checked_pow(u32::from(to - from))?)
                };
                let places = pa.max(pb);
                widen(a, pa, places).is_some() && widen(a, pa, places) == widen(b, pb, places)
            }
            _ => self == other,
        }
    }

    /// True when the value is one to publish (not [`Value::Unavailable`]).
    pub fn is_available(&self) -> bool {
        !matches!(self, Self::Unavailable)
    }

    /// Typed JSON for the per-device JSON view: booleans, numbers (exact at every magnitude),
    /// strings, and `null` for a value the device marks unavailable.
    pub fn to_json(&self) -> serde_json::Value {
        match self {
            Self::Bool(on) => serde_json::Value::Bool(*on),
            Self::Int(_) | Self::Decimal { .. } => exact_number(&self.to_text()),
            Self::Enum(word) | Self::Text(word) => serde_json::Value::String(word.clone()),
            Self::Unavailable => serde_json::Value::Null,
        }
    }
}

/// A JSON number with exactly the value of `text` (a decimal in the payload grammar). Where a
/// 64-bit integer or a binary float carries it exactly, that is the number (so 12.30 is written
/// `12.3` and 5.00 `5.0`, as a float would be); otherwise the digits themselves are the number
/// (an energy counter above 2^63, or 17 significant digits), never a rounded neighbour.
fn exact_number(text: &str) -> serde_json::Value {
    if let Ok(integer) = text.parse::<i64>() {
        return serde_json::Value::from(integer);
    }
    if let Ok(integer) = text.parse::<u64>() {
        return serde_json::Value::from(integer);
    }
    let float = text.parse::<f64>().ok().filter(|float| {
        super::number::DecimalText::parse(&float.to_string())
            .zip(super::number::DecimalText::parse(text))
            .is_some_and(|(shown, exact)| {
                // Equal at the text's own precision: the float is the decimal, not a neighbour.
                let places = exact.places();
                shown.scaled(places).ok() == exact.scaled(places).ok()
            })
    });
    if let Some(number) = float.and_then(serde_json::Number::from_f64) {
        return serde_json::Value::Number(number);
    }
    text.parse::<serde_json::Number>()
        .map_or(serde_json::Value::Null, serde_json::Value::Number)
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

    #[test]
    fn json_numbers_are_exact_at_every_magnitude() {
        let json = |value: Value| value.to_json().to_string();
        let decimal = |scaled, precision| Value::Decimal { scaled, precision };
        // A u64 counter above i64::MAX, and beyond u64 after an offset.
        assert_eq!(
            json(Value::Int(18_446_744_073_709_551_614)),
            "18446744073709551614"
        );
        assert_eq!(json(Value::Int(1 << 70)), "1180591620717411303424");
        assert_eq!(
            json(Value::Int(i128::from(i64::MIN))),
            "-9223372036854775808"
        );
        // More digits than a double holds: the digits themselves.
        assert_eq!(
            json(decimal(18_446_744_073_709_551_614, 3)),
            "18446744073709551.614"
        );
        assert_eq!(
            json(decimal(12_345_678_901_234_567, 2)),
            "123456789012345.67"
        );
        // A double that is the decimal: written as before.
        assert_eq!(json(decimal(1230, 2)), "12.3");
        assert_eq!(json(decimal(500, 2)), "5.0");
        assert_eq!(json(decimal(-5, 2)), "-0.05");
        assert_eq!(json(Value::Unavailable), "null");
        assert_eq!(Value::Unavailable.to_text(), "unavailable");
    }

    #[test]
    fn numbers_compare_by_magnitude() {
        let decimal = |scaled, precision| Value::Decimal { scaled, precision };
        assert!(decimal(150, 2).same_number(&decimal(15, 1)));
        assert!(decimal(1_234_500, 0).same_number(&Value::Int(1_234_500)));
        assert!(!decimal(151, 2).same_number(&decimal(15, 1)));
        assert!(Value::Bool(true).same_number(&Value::Bool(true)));
        assert!(!Value::Unavailable.same_number(&Value::Int(0)));
    }
}
