//! A device profile's fields as Sparkplug metrics: the datatype each field is born with
//! (Boolean for bits and buttons, the narrowest Int/UInt holding the field's range, Float or
//! Double for scaled fields, String for enumerations and identifiers), units, descriptions and
//! ranges as metric properties, stable aliases, field values as metric values, and a command
//! metric back to the command text the profile's `plan_command` judges. The profile's actions
//! follow the fields as metrics that carry no value and are only written: Boolean `true` runs
//! an action without parameters, one parameter is its integer type, several are a String of
//! their JSON object. Pure: no topics, no sequence numbers, no I/O.

use std::sync::Arc;

use serde_json::Value as Json;

use super::protobuf::{DataType, Metric, MetricValue, PropertyScalar, PropertySet, PropertyValue};
use rtu2mqtt_profile::{ActionInfo, FieldInfo, FieldKind, Profile, Value};

/// Range bounds this large come from the number format (float registers), not the device.
const NO_RANGE: f64 = 1e15;
/// Largest scaled magnitude a Float holds to the last digit (2^24).
const FLOAT_EXACT: f64 = 16_777_216.0;

/// One field of a device as a metric.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricDef {
    /// The profile's field name, which is also the metric name.
    pub name: String,
    pub alias: u64,
    pub datatype: DataType,
    pub writable: bool,
    /// One of the profile's actions: never a value of its own (null in the birth), a command
    /// when written.
    pub action: bool,
    properties: PropertySet,
}

/// The metrics of one configured device.
#[derive(Debug, Clone)]
pub struct DeviceMetrics {
    pub device: String,
    pub profile: Arc<Profile>,
    defs: Vec<MetricDef>,
}

/// Why a command metric cannot become a command (nothing reaches the bus).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal(pub String);

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl DeviceMetrics {
    /// The device's metrics, aliased `alias_base + field index`, then its actions' after them
    /// (stable while the profile's field and action order is).
    pub fn new(device: &str, profile: Arc<Profile>, alias_base: u64) -> Self {
        let fields = profile.fields().iter().map(|info| MetricDef {
            name: info.name.clone(),
            alias: 0,
            datatype: datatype_for(info),
            writable: info.writable,
            action: false,
            properties: properties_for(info),
        });
        let actions = profile.actions().map(|action| MetricDef {
            name: action.name.clone(),
            alias: 0,
            datatype: action_datatype(action),
            writable: true,
            action: true,
            properties: action_properties(action),
        });
        let defs = fields
            .chain(actions)
            .enumerate()
            .map(|(index, def)| MetricDef {
                alias: alias_base + index as u64,
                ..def
            })
            .collect();
        DeviceMetrics {
            device: device.to_string(),
            profile,
            defs,
        }
    }

    pub fn defs(&self) -> &[MetricDef] {
        &self.defs
    }

    pub fn by_name(&self, name: &str) -> Option<&MetricDef> {
        self.defs.iter().find(|def| def.name == name)
    }

    pub fn by_alias(&self, alias: u64) -> Option<&MetricDef> {
        self.defs.iter().find(|def| def.alias == alias)
    }

    /// The metric a host's metric names: by name, or by alias when the name is absent.
    pub fn named_by(&self, metric: &Metric) -> Option<&MetricDef> {
        match (&metric.name, metric.alias) {
            (Some(name), _) => self.by_name(name),
            (None, Some(alias)) => self.by_alias(alias),
            (None, None) => None,
        }
    }

    /// The DBIRTH form: name, alias, datatype, properties and the value (null when unknown).
    pub fn birth_metric(def: &MetricDef, value: Option<&Value>, timestamp: u64) -> Metric {
        Metric {
            name: Some(def.name.clone()),
            properties: (!def.properties.keys.is_empty()).then(|| def.properties.clone()),
            ..value_metric(def, value, timestamp)
        }
    }

    /// The DDATA form: alias only (the name is known from the birth), datatype and value.
    pub fn data_metric(def: &MetricDef, value: Option<&Value>, timestamp: u64) -> Metric {
        value_metric(def, value, timestamp)
    }

    /// The historical DDATA form of a value from a history document (typed as the JSON view
    /// types it): alias, datatype, the instant it was read and `is_historical`.
    pub fn historical_metric(def: &MetricDef, value: &Json, read_at: u64) -> Metric {
        Metric {
            is_historical: Some(true),
            ..metric_of(def, json_metric_value(def.datatype, value), read_at)
        }
    }

    /// The metric a DCMD names ([`Self::named_by`]) and the command
    /// text its value stands for. Unknown metrics, read-only fields, a datatype other than the
    /// birth's and values of the wrong kind are refused.
    pub fn command_text(&self, metric: &Metric) -> Result<(&MetricDef, String), Refusal> {
        let def = self.named_by(metric).ok_or_else(|| {
            Refusal(format!(
                "{}: unknown metric {}",
                self.device,
                metric
                    .name
                    .clone()
                    .or(metric.alias.map(|alias| format!("alias {alias}")))
                    .unwrap_or_else(|| "without name or alias".to_string())
            ))
        })?;
        let field = &def.name;
        if !def.writable {
            return Err(Refusal(format!("{field} is read-only")));
        }
        if let Some(number) = metric.datatype {
            if number != def.datatype.number() {
                return Err(Refusal(format!(
                    "{field} is {:?}, the command says datatype {number}",
                    def.datatype
                )));
            }
        }
        if metric.is_null == Some(true) {
            return Err(Refusal(format!("{field}: a null value is no command")));
        }
        let wrong_kind = || Refusal(format!("{field}: the value is not a {:?}", def.datatype));
        let value = metric.value.as_ref().ok_or_else(wrong_kind)?;
        let text = match (def.datatype, value) {
            (DataType::Boolean, MetricValue::Boolean(false)) if def.action => {
                return Err(Refusal(format!(
                    "{field}: an action runs when written true"
                )));
            }
            (DataType::Boolean, MetricValue::Boolean(on)) => {
                if *on { "ON" } else { "OFF" }.to_string()
            }
            (DataType::Float, MetricValue::Float(number)) => number.to_string(),
            (DataType::Float | DataType::Double, MetricValue::Double(number)) => number.to_string(),
            (DataType::Double, MetricValue::Float(number)) => number.to_string(),
            (DataType::String | DataType::Text, MetricValue::String(text)) => text.clone(),
            (datatype, MetricValue::Int(word)) => {
                integer_from_wire(datatype, u64::from(*word)).ok_or_else(wrong_kind)?
            }
            (datatype, MetricValue::Long(word)) => {
                integer_from_wire(datatype, *word).ok_or_else(wrong_kind)?
            }
            _ => return Err(wrong_kind()),
        };
        Ok((def, text))
    }
}

/// The datatype a field is born with.
pub fn datatype_for(info: &FieldInfo) -> DataType {
    match &info.kind {
        FieldKind::Bool | FieldKind::Momentary => DataType::Boolean,
        FieldKind::Integer { min, max } => {
            let low = info
                .also
                .iter()
                .map(|v| i128::from(*v))
                .fold(*min, i128::min);
            let high = info
                .also
                .iter()
                .map(|v| i128::from(*v))
                .fold(*max, i128::max);
            integer_type(low, high)
        }
        FieldKind::Decimal {
            min,
            max,
            precision,
        } => {
            let scaled = min.abs().max(max.abs()) * 10f64.powi(i32::from(*precision));
            if scaled <= FLOAT_EXACT {
                DataType::Float
            } else {
                DataType::Double
            }
        }
        FieldKind::Enum { .. } | FieldKind::Text => DataType::String,
    }
}

/// The datatype of an action's metric: Boolean without parameters, the narrowest integer
/// holding a single parameter's range, String (the JSON object) for several.
pub fn action_datatype(action: &ActionInfo) -> DataType {
    match action.params.as_slice() {
        [] => DataType::Boolean,
        [param] => integer_type(param.min, param.max),
        _ => DataType::String,
    }
}

/// The narrowest Sparkplug integer type holding `low..=high`.
fn integer_type(low: i128, high: i128) -> DataType {
    if low >= 0 {
        match high {
            ..=0xff => DataType::UInt8,
            0x100..=0xffff => DataType::UInt16,
            0x1_0000..=0xffff_ffff => DataType::UInt32,
            _ => DataType::UInt64,
        }
    } else if low >= i128::from(i8::MIN) && high <= i128::from(i8::MAX) {
        DataType::Int8
    } else if low >= i128::from(i16::MIN) && high <= i128::from(i16::MAX) {
        DataType::Int16
    } else if low >= i128::from(i32::MIN) && high <= i128::from(i32::MAX) {
        DataType::Int32
    } else {
        DataType::Int64
    }
}

/// Unit, description and range of a field as metric properties (only those the profile has).
fn properties_for(info: &FieldInfo) -> PropertySet {
    let mut set = PropertySet::default();
    let mut push = |key: &str, datatype: DataType, value: PropertyScalar| {
        push_property(&mut set, key, datatype, value);
    };
    if let Some(unit) = &info.unit {
        push(
            "engUnit",
            DataType::String,
            PropertyScalar::String(unit.clone()),
        );
    }
    let (low, high) = match &info.kind {
        FieldKind::Integer { min, max } => (Some(*min as f64), Some(*max as f64)),
        FieldKind::Decimal { min, max, .. } => (Some(*min), Some(*max)),
        _ => (None, None),
    };
    // Float registers span the whole float range: no device range worth showing.
    let range = low
        .zip(high)
        .filter(|(low, high)| low.abs() < NO_RANGE && high.abs() < NO_RANGE);
    if let Some((low, high)) = range {
        push("engLow", DataType::Double, PropertyScalar::Double(low));
        push("engHigh", DataType::Double, PropertyScalar::Double(high));
    }
    if !info.description.trim().is_empty() {
        push(
            "description",
            DataType::String,
            PropertyScalar::String(info.description.clone()),
        );
    }
    if let FieldKind::Enum { options } = &info.kind {
        push(
            "options",
            DataType::String,
            PropertyScalar::String(options.join(",")),
        );
    }
    push(
        "readOnly",
        DataType::Boolean,
        PropertyScalar::Boolean(!info.writable),
    );
    set
}

/// Adds one property to `set`.
fn push_property(set: &mut PropertySet, key: &str, datatype: DataType, value: PropertyScalar) {
    set.keys.push(key.to_string());
    set.values.push(PropertyValue {
        r#type: Some(datatype.number()),
        is_null: None,
        value: Some(value),
    });
}

/// An action's description and, for a single parameter, its range and unit as metric
/// properties; never read-only.
fn action_properties(action: &ActionInfo) -> PropertySet {
    let mut set = PropertySet::default();
    let mut push = |key: &str, datatype: DataType, value: PropertyScalar| {
        push_property(&mut set, key, datatype, value);
    };
    if let [param] = action.params.as_slice() {
        if let Some(unit) = &param.unit {
            push(
                "engUnit",
                DataType::String,
                PropertyScalar::String(unit.clone()),
            );
        }
        push(
            "engLow",
            DataType::Double,
            PropertyScalar::Double(param.min as f64),
        );
        push(
            "engHigh",
            DataType::Double,
            PropertyScalar::Double(param.max as f64),
        );
    }
    if !action.description.trim().is_empty() {
        push(
            "description",
            DataType::String,
            PropertyScalar::String(action.description.clone()),
        );
    }
    push(
        "readOnly",
        DataType::Boolean,
        PropertyScalar::Boolean(false),
    );
    set
}

/// Alias, datatype, timestamp and value (or the null flag).
fn value_metric(def: &MetricDef, value: Option<&Value>, timestamp: u64) -> Metric {
    let value = value.and_then(|value| metric_value(def.datatype, value));
    metric_of(def, value, timestamp)
}

/// The metric `def` names carrying `value` (null when there is none) read at `timestamp`.
fn metric_of(def: &MetricDef, value: Option<MetricValue>, timestamp: u64) -> Metric {
    Metric {
        alias: Some(def.alias),
        timestamp: Some(timestamp),
        datatype: Some(def.datatype.number()),
        is_null: value.is_none().then_some(true),
        value,
        ..Default::default()
    }
}

/// A field value in the metric's datatype; None when the value does not fit it (sent as null
/// rather than as something else).
pub fn metric_value(datatype: DataType, value: &Value) -> Option<MetricValue> {
    match (datatype, value) {
        (DataType::Boolean, Value::Bool(on)) => Some(MetricValue::Boolean(*on)),
        (DataType::String | DataType::Text, Value::Enum(text) | Value::Text(text)) => {
            Some(MetricValue::String(text.clone()))
        }
        // An enum's unnamed code (`unknown = "publish_number"`) is sent as its number's text.
        (DataType::String | DataType::Text, Value::Int(code)) => {
            Some(MetricValue::String(code.to_string()))
        }
        (DataType::Float | DataType::Double, Value::Int(_) | Value::Decimal { .. }) => {
            // Through the text form so 12.34 becomes the float nearest 12.34.
            let number: f64 = value.to_text().parse().ok()?;
            Some(if datatype == DataType::Float {
                MetricValue::Float(number as f32)
            } else {
                MetricValue::Double(number)
            })
        }
        (datatype, Value::Int(number)) => integer_to_wire(datatype, *number),
        (
            datatype,
            Value::Decimal {
                scaled,
                precision: 0,
            },
        ) => integer_to_wire(datatype, *scaled),
        _ => None,
    }
}

/// A value of a history document in the metric's datatype, as [`metric_value`] makes it from
/// the field value the document was written from; None when it does not fit.
pub fn json_metric_value(datatype: DataType, value: &Json) -> Option<MetricValue> {
    match (datatype, value) {
        (DataType::Boolean, Json::Bool(on)) => Some(MetricValue::Boolean(*on)),
        (DataType::String | DataType::Text, Json::String(text)) => {
            Some(MetricValue::String(text.clone()))
        }
        (DataType::Float, Json::Number(number)) => number
            .as_f64()
            .map(|number| MetricValue::Float(number as f32)),
        (DataType::Double, Json::Number(number)) => number.as_f64().map(MetricValue::Double),
        (datatype, Json::Number(number)) => {
            let integer = match number.as_i64() {
                Some(signed) => i128::from(signed),
                None => i128::from(number.as_u64()?),
            };
            integer_to_wire(datatype, integer)
        }
        _ => None,
    }
}

/// An integer in its Sparkplug wire form: 8-, 16- and 32-bit types in `int_value`, 64-bit ones
/// in `long_value`, negatives as two's complement in the type's width.
fn integer_to_wire(datatype: DataType, number: i128) -> Option<MetricValue> {
    let (bits, signed) = datatype.integer_bits()?;
    let fits = if signed {
        (-(1i128 << (bits - 1))..(1i128 << (bits - 1))).contains(&number)
    } else {
        (0..(1i128 << bits)).contains(&number)
    };
    if !fits {
        return None;
    }
    let word = (number as u64) & (u64::MAX >> (64 - bits));
    Some(if bits == 64 {
        MetricValue::Long(word)
    } else {
        MetricValue::Int(u32::try_from(word).ok()?)
    })
}

/// The decimal text of an integer metric's wire word; None for a word outside the type.
fn integer_from_wire(datatype: DataType, word: u64) -> Option<String> {
    let (bits, signed) = datatype.integer_bits()?;
    if bits < 64 && word >> bits != 0 {
        return None;
    }
    Some(match (signed, bits) {
        (false, _) => word.to_string(),
        (true, 64) => (word as i64).to_string(),
        (true, _) => {
            let sign_bit = 1u64 << (bits - 1);
            let number = if word & sign_bit != 0 {
                word as i64 - (1i64 << bits)
            } else {
                word as i64
            };
            number.to_string()
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_types_are_the_narrowest_holding_the_range() {
        assert_eq!(integer_type(0, 1), DataType::UInt8);
        assert_eq!(integer_type(0, 255), DataType::UInt8);
        assert_eq!(integer_type(0, 256), DataType::UInt16);
        assert_eq!(integer_type(0, 70_000), DataType::UInt32);
        assert_eq!(integer_type(0, 1 << 40), DataType::UInt64);
        assert_eq!(integer_type(-1, 127), DataType::Int8);
        assert_eq!(integer_type(-1, 128), DataType::Int16);
        assert_eq!(integer_type(-40_000, 0), DataType::Int32);
        assert_eq!(integer_type(i128::from(i64::MIN), 0), DataType::Int64);
        assert_eq!(integer_type(0, i128::from(u64::MAX)), DataType::UInt64);
    }

    #[test]
    fn a_history_document_value_becomes_the_metric_value_of_the_live_path() {
        let cases = [
            (
                DataType::Float,
                Value::Decimal {
                    scaled: 1234,
                    precision: 2,
                },
            ),
            (
                DataType::Double,
                Value::Decimal {
                    scaled: -5,
                    precision: 1,
                },
            ),
            (DataType::Int8, Value::Int(-1)),
            (DataType::UInt16, Value::Int(1500)),
            (DataType::Boolean, Value::Bool(true)),
            (DataType::String, Value::Enum("opening".into())),
        ];
        for (datatype, value) in cases {
            assert_eq!(
                json_metric_value(datatype, &value.to_json()),
                metric_value(datatype, &value),
                "{datatype:?} {value:?}"
            );
        }
        assert_eq!(json_metric_value(DataType::UInt8, &Json::from(300)), None);
        assert_eq!(json_metric_value(DataType::Boolean, &Json::from(1)), None);
    }

    #[test]
    fn signed_integers_travel_as_twos_complement_of_their_width() {
        assert_eq!(
            integer_to_wire(DataType::Int8, -1),
            Some(MetricValue::Int(255))
        );
        assert_eq!(
            integer_to_wire(DataType::Int16, -2),
            Some(MetricValue::Int(0xfffe))
        );
        assert_eq!(
            integer_to_wire(DataType::Int64, -1),
            Some(MetricValue::Long(u64::MAX))
        );
        assert_eq!(integer_to_wire(DataType::UInt8, 256), None);
        assert_eq!(integer_to_wire(DataType::UInt8, -1), None);
        assert_eq!(
            integer_from_wire(DataType::Int8, 255).as_deref(),
            Some("-1")
        );
        assert_eq!(
            integer_from_wire(DataType::Int16, 0x7fff).as_deref(),
            Some("32767")
        );
        assert_eq!(integer_from_wire(DataType::UInt8, 256), None);
        assert_eq!(
            integer_from_wire(DataType::Int64, u64::MAX).as_deref(),
            Some("-1")
        );
    }

    #[test]
    fn decimals_become_floats_near_their_text() {
        let value = Value::Decimal {
            scaled: 1234,
            precision: 2,
        };
        assert_eq!(
            metric_value(DataType::Float, &value),
            Some(MetricValue::Float(12.34))
        );
        assert_eq!(
            metric_value(DataType::Double, &value),
            Some(MetricValue::Double(12.34))
        );
        assert_eq!(metric_value(DataType::Boolean, &value), None);
    }

    /// A value of the field's kind near the top of its range.
    fn sample(info: &FieldInfo) -> Value {
        match &info.kind {
            FieldKind::Bool | FieldKind::Momentary => Value::Bool(true),
            FieldKind::Integer { max, .. } => Value::Int(*max),
            FieldKind::Decimal { max, precision, .. } => Value::Decimal {
                scaled: (max.min(9999.99) * 10f64.powi(i32::from(*precision))).round() as i128,
                precision: *precision,
            },
            FieldKind::Enum { options } => Value::Enum(options.last().cloned().unwrap_or_default()),
            FieldKind::Text => Value::Text("0A".into()),
        }
    }

    #[test]
    fn actions_follow_the_fields_as_metrics_only_written() {
        let text = "[device]\nname = \"meter\"\nmanufacturer = \"m\"\nmodel = \"x\"\n[line]\n\
            [[blocks]]\nname = \"hold\"\nfunction = 3\nstart = 0\ncount = 1\n\
            [[fields]]\nname = \"energy\"\nblock = \"hold\"\noffset = 0\n\
            codec = { type = \"u16\" }\n\
            [[actions]]\nname = \"reset\"\naddress = 10\nregisters = [1]\n\
            [[actions]]\nname = \"set_tariff\"\naddress = 10\nregisters = [2, \"tariff\"]\n\
            params = { tariff = { range = [1, 4] } }\n\
            [[actions]]\nname = \"set_clock\"\naddress = 10\nregisters = [3, \"h\", \"m\"]\n";
        let profile = match Profile::from_toml(text, "meter") {
            Ok(profile) => Arc::new(profile),
            Err(errors) => panic!("{errors}"),
        };
        let metrics = DeviceMetrics::new("meter", profile, 1000);
        let shape: Vec<(&str, u64, DataType, bool)> = metrics
            .defs()
            .iter()
            .map(|def| (def.name.as_str(), def.alias, def.datatype, def.action))
            .collect();
        assert_eq!(
            shape,
            [
                ("energy", 1000, DataType::UInt16, false),
                ("reset", 1001, DataType::Boolean, true),
                ("set_tariff", 1002, DataType::UInt8, true),
                ("set_clock", 1003, DataType::String, true),
            ]
        );
        let written = |name: &str, value: MetricValue| {
            let metric = Metric {
                name: Some(name.to_string()),
                value: Some(value),
                ..Default::default()
            };
            metrics
                .command_text(&metric)
                .map(|(def, text)| (def.name.clone(), text))
        };
        assert_eq!(
            written("reset", MetricValue::Boolean(true)),
            Ok(("reset".to_string(), "ON".to_string()))
        );
        assert_eq!(
            written("reset", MetricValue::Boolean(false)),
            Err(Refusal("reset: an action runs when written true".into()))
        );
        assert_eq!(
            written("set_tariff", MetricValue::Int(3)),
            Ok(("set_tariff".to_string(), "3".to_string()))
        );
        let clock = r#"{"h": 7, "m": 30}"#;
        assert_eq!(
            written("set_clock", MetricValue::String(clock.into())),
            Ok(("set_clock".to_string(), clock.to_string()))
        );
        let tariff = metrics.by_name("set_tariff").map(|def| {
            let birth = DeviceMetrics::birth_metric(def, None, 5);
            (birth.is_null, birth.properties.map(|set| set.keys))
        });
        let keys = ["engLow", "engHigh", "readOnly"].map(String::from).to_vec();
        assert_eq!(tariff, Some((Some(true), Some(keys))));
    }

    #[test]
    fn every_writable_field_round_trips_through_a_command_metric() {
        for name in rtu2mqtt_profile::registry::built_in_names() {
            let profile = match rtu2mqtt_profile::registry::built_in(name) {
                Ok(profile) => Arc::new(profile),
                Err(error) => panic!("{error}"),
            };
            let metrics = DeviceMetrics::new("d", Arc::clone(&profile), 1000);
            for info in profile.fields().iter().filter(|info| info.writable) {
                let Some(def) = metrics.by_name(&info.name) else {
                    panic!("{name}.{} has no metric", info.name);
                };
                let value = sample(info);
                let metric = Metric {
                    alias: Some(def.alias),
                    value: metric_value(def.datatype, &value),
                    ..Default::default()
                };
                let text = match metrics.command_text(&metric) {
                    Ok((_, text)) => text,
                    Err(refusal) => panic!("{name}.{}: {refusal}", info.name),
                };
                assert_eq!(
                    profile.parse_value(&info.name, &text),
                    Ok(value),
                    "{name}.{} as {text}",
                    info.name
                );
            }
        }
    }
}
