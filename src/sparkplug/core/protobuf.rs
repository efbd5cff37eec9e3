//! The Sparkplug B payload as protobuf messages: the subset of the Sparkplug B schema an edge
//! node of scalar metrics uses (payload timestamp, seq, metrics with name, alias, timestamp,
//! datatype, null flag and a scalar value; property sets for units and descriptions), with
//! the field numbers of the Sparkplug B definition so any Sparkplug host decodes them. Pure
//! byte work: encode and decode, nothing about topics or sessions.

use prost::Message as _;

/// Sparkplug B datatype numbers (Sparkplug specification, "Datatypes").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum DataType {
    Int8 = 1,
    Int16 = 2,
    Int32 = 3,
    Int64 = 4,
    UInt8 = 5,
    UInt16 = 6,
    UInt32 = 7,
    UInt64 = 8,
    Float = 9,
    Double = 10,
    Boolean = 11,
    String = 12,
    DateTime = 13,
    Text = 14,
}

impl DataType {
    /// The datatype for a wire number; None for unknown and non-scalar types.
    pub fn from_number(number: u32) -> Option<Self> {
        use DataType::*;
        Some(match number {
            1 => Int8,
            2 => Int16,
            3 => Int32,
            4 => Int64,
            5 => UInt8,
            6 => UInt16,
            7 => UInt32,
            8 => UInt64,
            9 => Float,
            10 => Double,
            11 => Boolean,
            12 => String,
            13 => DateTime,
            14 => Text,
            _ => return None,
        })
    }

    pub fn number(self) -> u32 {
        self as u32
    }

    /// The width in bits of an integer type; None for the others.
    pub fn integer_bits(self) -> Option<(u32, bool)> {
        use DataType::*;
        match self {
            Int8 => Some((8, true)),
            Int16 => Some((16, true)),
            Int32 => Some((32, true)),
            Int64 => Some((64, true)),
            UInt8 => Some((8, false)),
            UInt16 => Some((16, false)),
            UInt32 => Some((32, false)),
            UInt64 | DateTime => Some((64, false)),
            _ => None,
        }
    }
}

/// `Payload` (field numbers of the Sparkplug B schema).
#[derive(Clone, PartialEq, prost::Message)]
pub struct Payload {
    /// Milliseconds since the Unix epoch (UTC).
    #[prost(uint64, optional, tag = "1")]
    pub timestamp: Option<u64>,
    #[prost(message, repeated, tag = "2")]
    pub metrics: Vec<Metric>,
    #[prost(uint64, optional, tag = "3")]
    pub seq: Option<u64>,
    #[prost(string, optional, tag = "4")]
    pub uuid: Option<String>,
    #[prost(bytes = "vec", optional, tag = "5")]
    pub body: Option<Vec<u8>>,
}

/// `Payload.Metric`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Metric {
    #[prost(string, optional, tag = "1")]
    pub name: Option<String>,
    #[prost(uint64, optional, tag = "2")]
    pub alias: Option<u64>,
    #[prost(uint64, optional, tag = "3")]
    pub timestamp: Option<u64>,
    #[prost(uint32, optional, tag = "4")]
    pub datatype: Option<u32>,
    #[prost(bool, optional, tag = "5")]
    pub is_historical: Option<bool>,
    #[prost(bool, optional, tag = "6")]
    pub is_transient: Option<bool>,
    #[prost(bool, optional, tag = "7")]
    pub is_null: Option<bool>,
    #[prost(message, optional, tag = "9")]
    pub properties: Option<PropertySet>,
    #[prost(oneof = "MetricValue", tags = "10, 11, 12, 13, 14, 15, 16")]
    pub value: Option<MetricValue>,
}

/// The scalar members of `Payload.Metric.value`. Integers travel as unsigned words: signed
/// types as their two's complement in the type's width (Int8 −1 is 255).
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum MetricValue {
    #[prost(uint32, tag = "10")]
    Int(u32),
    #[prost(uint64, tag = "11")]
    Long(u64),
    #[prost(float, tag = "12")]
    Float(f32),
    #[prost(double, tag = "13")]
    Double(f64),
    #[prost(bool, tag = "14")]
    Boolean(bool),
    #[prost(string, tag = "15")]
    String(String),
    #[prost(bytes, tag = "16")]
    Bytes(Vec<u8>),
}

/// `Payload.PropertySet`: parallel lists of keys and values.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PropertySet {
    #[prost(string, repeated, tag = "1")]
    pub keys: Vec<String>,
    #[prost(message, repeated, tag = "2")]
    pub values: Vec<PropertyValue>,
}

/// `Payload.PropertyValue` (scalar members only).
#[derive(Clone, PartialEq, prost::Message)]
pub struct PropertyValue {
    #[prost(uint32, optional, tag = "1")]
    pub r#type: Option<u32>,
    #[prost(bool, optional, tag = "2")]
    pub is_null: Option<bool>,
    #[prost(oneof = "PropertyScalar", tags = "3, 4, 5, 6, 7, 8")]
    pub value: Option<PropertyScalar>,
}

/// The scalar members of `Payload.PropertyValue.value`.
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum PropertyScalar {
    #[prost(uint32, tag = "3")]
    Int(u32),
    #[prost(uint64, tag = "4")]
    Long(u64),
    #[prost(float, tag = "5")]
    Float(f32),
    #[prost(double, tag = "6")]
    Double(f64),
    #[prost(bool, tag = "7")]
    Boolean(bool),
    #[prost(string, tag = "8")]
    String(String),
}

impl PropertySet {
    /// A set of String properties (`engUnit`, `description`), in the given order.
    pub fn strings<'a>(pairs: impl IntoIterator<Item = (&'a str, &'a str)>) -> Self {
        let mut set = PropertySet::default();
        for (key, value) in pairs {
            set.keys.push(key.to_string());
            set.values.push(PropertyValue {
                r#type: Some(DataType::String.number()),
                is_null: None,
                value: Some(PropertyScalar::String(value.to_string())),
            });
        }
        set
    }

    /// The String property `key`, if present.
    pub fn string(&self, key: &str) -> Option<&str> {
        let index = self.keys.iter().position(|k| k == key)?;
        match self.values.get(index)?.value.as_ref()? {
            PropertyScalar::String(text) => Some(text),
            _ => None,
        }
    }
}

impl Payload {
    pub fn encode_to_bytes(&self) -> Vec<u8> {
        self.encode_to_vec()
    }

    /// Decodes a payload received from the broker; malformed bytes give an error, never a panic.
    pub fn decode_bytes(bytes: &[u8]) -> Result<Self, prost::DecodeError> {
        Self::decode(bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_metric_round_trips_with_the_schema_field_numbers() {
        let payload = Payload {
            timestamp: Some(1),
            seq: Some(7),
            metrics: vec![Metric {
                name: Some("gear".into()),
                alias: Some(3),
                datatype: Some(DataType::UInt8.number()),
                value: Some(MetricValue::Int(8)),
                ..Default::default()
            }],
            ..Default::default()
        };
        let bytes = payload.encode_to_bytes();
        // timestamp (field 1), metrics (2: name 1, alias 2, datatype 4, int_value 10), seq (3).
        let expected = [
            0x08, 1, 0x12, 12, 0x0a, 4, b'g', b'e', b'a', b'r', 0x10, 3, 0x20, 5, 0x50, 8, 0x18, 7,
        ];
        assert_eq!(bytes, expected);
        assert_eq!(Payload::decode_bytes(&bytes), Ok(payload));
    }

    #[test]
    fn garbage_is_an_error() {
        assert!(Payload::decode_bytes(&[0x12, 0xff, 0xff]).is_err());
    }

    #[test]
    fn properties_hold_strings_by_key() {
        let set = PropertySet::strings([("engUnit", "Pa"), ("description", "pressure")]);
        assert_eq!(set.string("engUnit"), Some("Pa"));
        assert_eq!(set.string("description"), Some("pressure"));
        assert_eq!(set.string("missing"), None);
    }
}
