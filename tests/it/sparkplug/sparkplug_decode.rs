//! The edge node's messages for the seed plant (every profile in `config/profiles/`) as an
//! independent Sparkplug decoder sees them: Python's `pysparkplug` decodes the NDEATH Will,
//! the NBIRTH, one DBIRTH per device and a DDATA, and every field must come back with its
//! datatype, value, unit and description, with `seq` counting and `bdSeq` matching.
//!
//! Needs `python3` with `pysparkplug` (`pip install pysparkplug==0.6.1`).

use std::path::Path;
use std::sync::Arc;

use crate::support::pysparkplug;

use pysparkplug::decode_with_pysparkplug;
use rtu2mqtt::bus::{LineEvent, Origin};
use rtu2mqtt::sparkplug::core::metrics::datatype_for;
use rtu2mqtt::sparkplug::core::protobuf::DataType;
use rtu2mqtt::sparkplug::{Action, Session, SessionSettings};
use rtu2mqtt_profile::{registry, FieldInfo, FieldKind, Profile, Value};
use serde_json::{json, Value as Json};

const NOW: u64 = 1_764_000_000_000;

/// Every seed profile, by its file name.
fn seed_plant() -> Vec<(String, Arc<Profile>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/profiles");
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|error| panic!("{}: {error}", dir.display()))
        .filter_map(|entry| entry.ok().map(|entry| entry.path()))
        .filter(|path| path.extension().is_some_and(|ext| ext == "toml"))
        .collect();
    paths.sort();
    paths
        .iter()
        .map(|path| {
            let profile = registry::load_file(path).unwrap_or_else(|error| panic!("{error}"));
            let device = path
                .file_stem()
                .map(|stem| stem.to_string_lossy().into_owned())
                .unwrap_or_default();
            (device, Arc::new(profile))
        })
        .collect()
}

/// A value at the top of each field's range (the widest a metric type must hold); numbers
/// without a device range (float registers) get a plausible reading instead.
fn sample(info: &FieldInfo) -> Value {
    match &info.kind {
        FieldKind::Bool | FieldKind::Momentary => Value::Bool(true),
        FieldKind::Integer { max, .. } => Value::Int(*max),
        FieldKind::Decimal { max, precision, .. } => Value::Decimal {
            scaled: (max.min(1234.5) * 10f64.powi(i32::from(*precision))).round() as i128,
            precision: *precision,
        },
        FieldKind::Enum { options } => Value::Enum(options.last().cloned().unwrap_or_default()),
        FieldKind::Text => Value::Text("0A".into()),
    }
}

/// The value pysparkplug must decode for `value` sent as `datatype`.
fn expected_json(datatype: DataType, value: &Value) -> Json {
    match (datatype, value) {
        (DataType::Float, _) => {
            let number: f64 = value.to_text().parse().unwrap_or(f64::NAN);
            json!(f64::from(number as f32))
        }
        _ => value.to_json(),
    }
}

fn publishes(actions: Vec<Action>) -> Vec<(String, Vec<u8>)> {
    actions
        .into_iter()
        .filter_map(|action| match action {
            Action::Publish { topic, payload, .. } => Some((topic, payload)),
            _ => None,
        })
        .collect()
}

fn metric<'a>(message: &'a Json, name: &str) -> &'a Json {
    message["metrics"]
        .as_array()
        .and_then(|metrics| metrics.iter().find(|m| m["name"] == name))
        .unwrap_or_else(|| panic!("no metric {name} in {message}"))
}

#[test]
fn seed_plant_births_and_data_decode_with_pysparkplug() {
    let plant = seed_plant();
    assert!(plant.len() >= 3, "the seed plant has its profiles");
    let mut session = Session::new(
        SessionSettings {
            group_id: "plant".into(),
            edge_node_id: "gw1".into(),
            primary_host_id: None,
            devices: plant.clone(),
            version: "0.1.0".into(),
            node_metrics: Vec::new(),
        },
        7,
    );
    let will = session.prepare_connect(NOW);
    let mut messages = vec![(will.topic, will.payload)];
    messages.extend(publishes(session.on_connected(NOW)));
    let mut samples = Vec::new();
    for (device, profile) in &plant {
        let values: Vec<(String, Value)> = profile
            .fields()
            .iter()
            .map(|info| (info.name.clone(), sample(info)))
            .collect();
        samples.push(values.clone());
        let event = LineEvent::Values {
            device: device.clone(),
            values,
            read_at: std::time::SystemTime::UNIX_EPOCH,
            origin: Origin::Poll,
        };
        messages.extend(publishes(session.on_line_event(NOW + 1, &event)));
    }
    // One change on the dust collector: the gear from 10 to 8.
    let change = LineEvent::Values {
        device: "ruiwan-dust-collector".into(),
        values: vec![("gear".into(), Value::Int(8))],
        read_at: std::time::SystemTime::UNIX_EPOCH,
        origin: Origin::Poll,
    };
    messages.extend(publishes(session.on_line_event(NOW + 2, &change)));

    let decoded = decode_with_pysparkplug(
        messages
            .iter()
            .map(|(topic, payload)| (topic.as_str(), payload.as_slice())),
    );
    assert_eq!(decoded.len(), messages.len());

    // The Will and the NBIRTH carry the same bdSeq.
    let ndeath = &decoded[0];
    assert_eq!(ndeath["type"], "NDEATH");
    assert_eq!(metric(ndeath, "bdSeq")["value"], 7);
    assert_eq!(
        metric(ndeath, "bdSeq")["datatype"],
        DataType::UInt64.number()
    );
    let nbirth = &decoded[1];
    assert_eq!(
        (&nbirth["type"], &nbirth["group"], &nbirth["node"]),
        (&json!("NBIRTH"), &json!("plant"), &json!("gw1"))
    );
    assert_eq!(metric(nbirth, "bdSeq")["value"], 7);
    let rebirth = metric(nbirth, "Node Control/Rebirth");
    assert_eq!(rebirth["value"], false);
    assert_eq!(rebirth["datatype"], DataType::Boolean.number());

    // seq counts 0, 1, 2, … across every message after the Will.
    let seqs: Vec<u64> = decoded[1..]
        .iter()
        .map(|m| m["seq"].as_u64().unwrap_or(u64::MAX))
        .collect();
    let counting: Vec<u64> = (0..seqs.len() as u64).collect();
    assert_eq!(seqs, counting);

    // One DBIRTH per device with every field typed, valued and described.
    let mut types_seen = std::collections::BTreeSet::new();
    for ((device, profile), values) in plant.iter().zip(&samples) {
        let dbirth = decoded
            .iter()
            .find(|m| m["type"] == "DBIRTH" && m["device"] == device.as_str())
            .unwrap_or_else(|| panic!("no DBIRTH for {device}"));
        // Every field, then every action (born null: it has no state).
        assert_eq!(
            dbirth["metrics"].as_array().map(Vec::len),
            Some(profile.fields().len() + profile.actions().len()),
            "{device}"
        );
        for (info, (_, value)) in profile.fields().iter().zip(values) {
            let decoded_metric = metric(dbirth, &info.name);
            let datatype = datatype_for(info);
            types_seen.insert(datatype.number());
            assert_eq!(
                decoded_metric["datatype"],
                datatype.number(),
                "{device}.{}",
                info.name
            );
            assert_eq!(
                decoded_metric["value"],
                expected_json(datatype, value),
                "{device}.{}",
                info.name
            );
            let properties = &decoded_metric["properties"];
            if let Some(unit) = &info.unit {
                assert_eq!(
                    properties["engUnit"],
                    unit.as_str(),
                    "{device}.{}",
                    info.name
                );
            }
            if !info.description.trim().is_empty() {
                assert_eq!(
                    properties["description"],
                    info.description.as_str(),
                    "{device}.{}",
                    info.name
                );
            }
            assert_eq!(
                properties["readOnly"], !info.writable,
                "{device}.{}",
                info.name
            );
        }
    }
    // The seed plant exercises booleans, unsigned words, scaled numbers and enumerations.
    for datatype in [
        DataType::Boolean,
        DataType::UInt8,
        DataType::Float,
        DataType::String,
    ] {
        assert!(
            types_seen.contains(&datatype.number()),
            "{datatype:?} unused"
        );
    }
    let dust = plant
        .iter()
        .find(|(device, _)| device == "ruiwan-dust-collector")
        .map(|(_, profile)| profile)
        .unwrap_or_else(|| panic!("the dust collector is part of the seed plant"));
    assert_eq!(dust.field("gear").map(datatype_for), Some(DataType::UInt8));
    let dust_birth = decoded
        .iter()
        .find(|m| m["type"] == "DBIRTH" && m["device"] == "ruiwan-dust-collector")
        .unwrap_or_else(|| panic!("no DBIRTH for the dust collector"));
    let gear = &metric(dust_birth, "gear")["properties"];
    assert_eq!(
        (&gear["engLow"], &gear["engHigh"]),
        (&json!(1.0), &json!(10.0))
    );

    // The change arrives as DDATA with only the gear, by alias, resolved through the DBIRTH.
    let ddata = &decoded[decoded.len() - 1];
    assert_eq!(ddata["type"], "DDATA");
    assert_eq!(ddata["device"], "ruiwan-dust-collector");
    let metrics = ddata["metrics"].as_array().cloned().unwrap_or_default();
    assert_eq!(metrics.len(), 1, "{ddata}");
    assert_eq!(metrics[0]["name"], "gear");
    assert_eq!(metrics[0]["value"], 8);
}
