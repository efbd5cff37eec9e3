//! Home Assistant discovery documents, their removal, the gateway's statistics document, the
//! Prometheus text and the JSON view: pure functions checked on fields shaped like the seed
//! devices' and on the built-in profiles; then the gateway's discovery end to end on a real
//! mosquitto with the simulated seed plant.

use crate::support;

use std::collections::{HashMap, HashSet};
use std::time::{Duration, Instant};

use rand::rngs::StdRng;
use rand::SeedableRng;
use serde_json::{json, Value as Json};

use rtu2mqtt::app::{run_gateway, Hooks};
use rtu2mqtt::bridge::core::discovery::{
    all_configs, device_config, device_config_from_fields, device_config_with_state,
    gateway_config, identity_update, is_stale_config, line_config, platform_for, reannounce_delay,
    removal, unique_id_collisions, Platform, CLOCK_TO_SECONDS, REANNOUNCE_DELAY, RESULT_EVENT,
    RESULT_EVENT_TEMPLATE,
};
use rtu2mqtt::bridge::core::json_view::{json_view, json_view_payload};
use rtu2mqtt::bridge::core::payload::{CommandResult, Outcome};
use rtu2mqtt::bridge::core::state::StateUpdate;
use rtu2mqtt::bridge::observers::statistics::{
    line_stats_json, prometheus_text, stats_json, BridgeStats,
};
use rtu2mqtt::bus::LineStats;
use rtu2mqtt::topics::{is_ha_online, json_view_topic, Topics};
use rtu2mqtt_profile::{
    registry, DeviceState, FieldInfo, FieldKind, HaHints, Identity, Profile, Value,
};
use rtu2mqtt_sim::SeedPlant;
use support::{Mosquitto, PlantConfig, TestClient};
use tokio_util::sync::CancellationToken;

fn field(name: &str, kind: FieldKind, writable: bool) -> FieldInfo {
    FieldInfo {
        name: name.to_string(),
        description: String::new(),
        kind,
        writable,
        unit: None,
        step: None,
        also: Vec::new(),
        ha: HaHints::default(),
        label: None,
        identity: None,
        min_write_interval: None,
        publish: Default::default(),
        scaled_by: None,
        may_be_unavailable: false,
        unnamed_codes_as_numbers: false,
    }
}

fn with_unit(mut field: FieldInfo, unit: &str) -> FieldInfo {
    field.unit = Some(unit.to_string());
    field
}

fn int(min: i128, max: i128) -> FieldKind {
    FieldKind::Integer { min, max }
}

fn decimal(min: f64, max: f64, precision: u8) -> FieldKind {
    FieldKind::Decimal {
        min,
        max,
        precision,
    }
}

fn options(words: &[&str]) -> FieldKind {
    FieldKind::Enum {
        options: words.iter().map(|w| w.to_string()).collect(),
    }
}

fn dust_collector_fields() -> Vec<FieldInfo> {
    vec![
        field("power", FieldKind::Bool, true),
        field("pulse_cleaning", FieldKind::Bool, true),
        field("fan_alarm", FieldKind::Bool, false),
        field("filter_alarm", FieldKind::Bool, false),
        field("temperature_alarm", FieldKind::Bool, false),
        field("gear", int(1, 10), true),
        with_unit(field("pulse_interval", int(0, 99), true), "min"),
        with_unit(field("pulse_duration", int(0, 99), true), "s"),
        field("fan_speed", int(0, 65535), false),
        with_unit(field("temperature", int(0, 65535), false), "°C"),
    ]
}

fn valve_fields() -> Vec<FieldInfo> {
    vec![
        field("serial_number", FieldKind::Text, false),
        field("software_version", int(0, 255), false),
        field("mode", options(&["manual", "auto"]), true),
        with_unit(field("opening", int(0, 100), true), "%"),
        field("motor", options(&["stopped", "opening", "closing"]), false),
        field("jammed", FieldKind::Bool, false),
        field("pid_invalid_flags", int(0, 127), false),
        field("measured_1", decimal(0.0, 9999.99, 2), false),
        field("setpoint", decimal(0.0, 9999.99, 2), true),
        field("high_alarm_1", decimal(0.0, 9999.99, 2), true),
    ]
}

fn air_shower_fields() -> Vec<FieldInfo> {
    vec![
        field("emergency_stop", FieldKind::Bool, true),
        field("front_door_lock", FieldKind::Bool, true),
        field("voice_start", FieldKind::Momentary, true),
        field("voice_door", FieldKind::Momentary, true),
        field("front_door_closed", FieldKind::Bool, false),
        field("hepa_filter_expired", FieldKind::Bool, false),
    ]
}

fn context() -> Topics {
    Topics::new("rtu2mqtt-edge1", "plant")
}

/// The three seed devices' documents: (device, fields, topic, document).
fn seed_documents() -> Vec<(&'static str, Vec<FieldInfo>, String, Json)> {
    let ctx = context();
    [
        ("dust_collector", dust_collector_fields(), "Ruiwan", "dust"),
        ("valve", valve_fields(), "Wuzhou", "valve"),
        ("air_shower", air_shower_fields(), "Lixian", "shower"),
    ]
    .into_iter()
    .map(|(device, fields, manufacturer, model)| {
        let (topic, document) =
            device_config_from_fields(&ctx, device, manufacturer, model, "profile", &fields);
        (device, fields, topic, document)
    })
    .collect()
}

fn component<'d>(document: &'d Json, field: &str) -> &'d Json {
    &document["cmps"][field]
}

fn platform_of<'d>(document: &'d Json, field: &str) -> &'d str {
    component(document, field)["p"].as_str().unwrap_or("<none>")
}

fn document_of(device: &str) -> Json {
    seed_documents()
        .into_iter()
        .find(|(name, ..)| *name == device)
        .map(|(.., document)| document)
        .unwrap()
}

#[test]
fn each_seed_field_becomes_the_component_its_kind_and_access_call_for() {
    let shower = document_of("air_shower");
    assert_eq!(platform_of(&shower, "emergency_stop"), "switch");
    assert_eq!(platform_of(&shower, "voice_start"), "button");
    assert_eq!(platform_of(&shower, "front_door_closed"), "binary_sensor");

    let dust = document_of("dust_collector");
    assert_eq!(platform_of(&dust, "temperature"), "sensor");
    assert_eq!(platform_of(&dust, "fan_alarm"), "binary_sensor");
    assert_eq!(platform_of(&dust, "gear"), "number");

    let valve = document_of("valve");
    assert_eq!(platform_of(&valve, "mode"), "select");
    assert_eq!(platform_of(&valve, "jammed"), "binary_sensor");
    assert_eq!(platform_of(&valve, "motor"), "sensor");
    assert_eq!(platform_of(&valve, "opening"), "number");
    assert_eq!(platform_of(&valve, "serial_number"), "sensor");
}

#[test]
fn components_carry_the_keys_of_their_platform() {
    let shower = document_of("air_shower");
    let estop = component(&shower, "emergency_stop");
    assert_eq!(estop["payload_on"], "ON");
    assert_eq!(estop["payload_off"], "OFF");
    assert_eq!(estop["state_topic"], "plant/air_shower/emergency_stop");
    let voice = component(&shower, "voice_start");
    assert_eq!(voice["payload_press"], "PRESS");
    assert!(voice.get("state_topic").is_none(), "a button has no state");

    let dust = document_of("dust_collector");
    let gear = component(&dust, "gear");
    assert_eq!(gear["min"], 1);
    assert_eq!(gear["max"], 10);
    assert_eq!(gear["step"], 1);
    assert_eq!(gear["mode"], "box");
    let temperature = component(&dust, "temperature");
    assert_eq!(temperature["unit_of_measurement"], "°C");
    assert_eq!(temperature["device_class"], "temperature");
    assert_eq!(temperature["state_class"], "measurement");
    assert_eq!(
        component(&dust, "pulse_duration")["device_class"],
        "duration"
    );

    let valve = document_of("valve");
    let opening = component(&valve, "opening");
    assert_eq!(opening["min"], 0);
    assert_eq!(opening["max"], 100);
    assert_eq!(opening["step"], 1);
    assert_eq!(opening["unit_of_measurement"], "%");
    let setpoint = component(&valve, "setpoint");
    assert_eq!(setpoint["step"], 0.01);
    assert_eq!(setpoint["max"], 9999.99);
    assert_eq!(
        component(&valve, "measured_1")["suggested_display_precision"],
        2
    );
    let mode = component(&valve, "mode");
    assert_eq!(mode["options"], serde_json::json!(["manual", "auto"]));
    let motor = component(&valve, "motor");
    assert_eq!(motor["device_class"], "enum");
    assert_eq!(
        motor["options"],
        serde_json::json!(["stopped", "opening", "closing"])
    );
    // Home Assistant refuses an enumeration sensor with a state class or a unit.
    assert!(motor.get("state_class").is_none());
    assert!(motor.get("unit_of_measurement").is_none());
    assert_eq!(component(&valve, "jammed")["device_class"], "problem");
}

#[test]
fn number_steps_follow_the_raw_count_of_scaled_fields() {
    let document = |name: &str| {
        let profile = registry::built_in(name).unwrap();
        device_config(&context(), "device", &profile).1
    };
    let sensor_profile = registry::load_file(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/profiles/generic-th-sensor.toml"
    )))
    .unwrap();
    let sensor = device_config(&context(), "device", &sensor_profile).1;
    // One raw count of `report_interval` is 5 s: Home Assistant must offer 5, 10, 15 …
    let interval = component(&sensor, "report_interval");
    assert_eq!(interval["p"], "number");
    assert_eq!(interval["step"], 5);
    assert_eq!(interval["min"], 5);
    // An i16 with one decimal steps by 0.1, the nearest f64 of it exactly.
    assert_eq!(component(&sensor, "temperature_offset")["step"], json!(0.1));

    let valve = document("wuzhou-valve");
    assert_eq!(component(&valve, "setpoint")["step"], json!(0.01));
    assert_eq!(component(&valve, "opening")["step"], 1);
    // 0–100 or 255 (alarm disabled): a select of exactly these values, so Home Assistant
    // never offers 101–254, which the gateway always refuses.
    let accepted: Vec<String> = (0..=100).chain([255]).map(|v: i64| v.to_string()).collect();
    for field in [
        "high_alarm_opening_1",
        "high_alarm_opening_2",
        "low_alarm_opening_1",
        "low_alarm_opening_2",
    ] {
        let alarm = component(&valve, field);
        assert_eq!(alarm["p"], "select", "{field}");
        assert_eq!(alarm["options"], json!(accepted), "{field}");
        assert_eq!(alarm["entity_category"], "config", "{field}");
        for key in ["min", "max", "unit_of_measurement", "device_class"] {
            assert!(alarm.get(key).is_none(), "{field} has {key}");
        }
    }
    let dust = document("ruiwan-dust-collector");
    assert_eq!(component(&dust, "gear")["step"], 1);

    // A hand-made scaled decimal: one raw count is 0.5 units.
    let mut half = field("half_steps", decimal(0.0, 50.0, 1), true);
    half.step = Some(Value::Decimal {
        scaled: 5,
        precision: 1,
    });
    let (_, doc) =
        device_config_from_fields(&context(), "device", "m", "x", "profile", &[half.clone()]);
    assert_eq!(component(&doc, "half_steps")["step"], json!(0.5));
    // Without a step from the profile the last shown place decides.
    half.step = None;
    let (_, doc) = device_config_from_fields(&context(), "device", "m", "x", "profile", &[half]);
    assert_eq!(component(&doc, "half_steps")["step"], json!(0.1));
}

#[test]
fn door_contacts_that_are_on_when_closed_carry_no_door_class() {
    // Home Assistant shows a `door` binary sensor ON as "Open"; these contacts are ON when the
    // door is closed, so a door class would show every state the wrong way round.
    let profile = registry::built_in("lixian-air-shower").unwrap();
    let (_, shower) = device_config(&context(), "air_shower", &profile);
    for name in ["front_door_closed", "rear_door_closed"] {
        let contact = component(&shower, name);
        assert_eq!(contact["p"], "binary_sensor", "{name}");
        assert_eq!(contact["payload_on"], "ON", "{name}");
        assert!(
            contact.get("device_class").is_none(),
            "{name} has device_class {}",
            contact["device_class"]
        );
        assert_eq!(contact["icon"], "mdi:door-closed", "{name}");
        assert_eq!(contact["state_topic"], format!("plant/air_shower/{name}"));
    }
    // Contacts whose ON does mean what their class says keep the class.
    assert_eq!(
        component(&shower, "photo_sensor_1")["device_class"],
        "occupancy"
    );
}

#[test]
fn command_topics_are_the_set_topics_of_writable_fields_only_and_never_retained() {
    let ctx = context();
    for (device, fields, _, document) in seed_documents() {
        for field in &fields {
            let config = component(&document, &field.name);
            assert!(config.is_object(), "{device}/{} missing", field.name);
            if field.writable {
                assert_eq!(
                    config["command_topic"].as_str(),
                    Some(format!("plant/{device}/{}/set", field.name).as_str())
                );
                assert_eq!(
                    config["command_topic"].as_str(),
                    Some(ctx.command_topic(device, &field.name).as_str())
                );
                assert_eq!(config["retain"], false, "{device}/{}", field.name);
            } else {
                assert!(
                    config.get("command_topic").is_none(),
                    "{device}/{} is read-only",
                    field.name
                );
            }
            if let Some(state) = config.get("state_topic") {
                assert_eq!(
                    state.as_str(),
                    Some(format!("plant/{device}/{}", field.name).as_str())
                );
            }
        }
        // One component per field, and the device's command-result event.
        assert_eq!(
            document["cmps"].as_object().map(|c| c.len()),
            Some(fields.len() + 1),
            "one component per field of {device}"
        );
        assert_eq!(document["cmps"]["command-result"]["p"], "event", "{device}");
    }
}

#[test]
fn device_documents_carry_dev_origin_and_both_availabilities() {
    for (device, _, topic, document) in seed_documents() {
        assert_eq!(
            topic,
            format!("homeassistant/device/rtu2mqtt-edge1_{device}/config")
        );
        // Valid JSON on the wire: it survives a round trip through text.
        let text = document.to_string();
        let parsed: Json = serde_json::from_str(&text).unwrap();
        assert_eq!(parsed, document);

        let dev = &document["dev"];
        assert_eq!(
            dev["identifiers"],
            serde_json::json!([format!("rtu2mqtt-edge1_{device}")])
        );
        assert_eq!(dev["name"], device);
        assert!(dev["manufacturer"].is_string());
        assert!(dev["model"].is_string());
        assert_eq!(dev["via_device"], "rtu2mqtt-edge1");

        let origin = &document["o"];
        assert_eq!(origin["name"], "rtu2mqtt");
        assert_eq!(origin["sw_version"], env!("CARGO_PKG_VERSION"));
        // No project URL to give: Home Assistant refuses an empty `support_url`.
        assert!(origin.get("support_url").is_none());
        assert_eq!(origin.as_object().map(|o| o.len()), Some(2));

        let topics: Vec<&str> = document["availability"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(|a| a["topic"].as_str())
            .collect();
        assert_eq!(
            topics,
            vec![
                "plant/gateway/rtu2mqtt-edge1/status".to_string(),
                format!("plant/{device}/availability"),
            ]
        );
        assert_eq!(document["availability_mode"], "all");
    }
}

#[test]
fn unique_ids_are_unique_across_devices_and_the_gateway_and_follow_the_pattern() {
    let ctx = context();
    let mut seen = HashSet::new();
    for (device, fields, _, document) in seed_documents() {
        for field in &fields {
            let id = component(&document, &field.name)["unique_id"]
                .as_str()
                .unwrap()
                .to_string();
            assert_eq!(id, format!("rtu2mqtt-edge1_{device}_{}", field.name));
            assert!(seen.insert(id.clone()), "duplicate {id}");
        }
    }
    let gateway = std::iter::once(gateway_config(&ctx).1)
        .chain(["line-a", "line-b"].map(|line| line_config(&ctx, line).1));
    for document in gateway {
        for (_, config) in document["cmps"].as_object().unwrap() {
            let id = config["unique_id"].as_str().unwrap().to_string();
            assert!(seen.insert(id.clone()), "duplicate {id}");
        }
    }
    // Stable: the same input gives the same document.
    assert_eq!(seed_documents()[0].3, seed_documents()[0].3);
}

#[test]
fn entity_categories_mark_identity_data_as_diagnostic_and_leave_live_values_primary() {
    let valve = document_of("valve");
    for name in ["serial_number", "software_version", "pid_invalid_flags"] {
        assert_eq!(
            component(&valve, name)["entity_category"],
            "diagnostic",
            "{name}"
        );
    }
    // A flag word is not a measurement to graph.
    assert!(component(&valve, "pid_invalid_flags")
        .get("state_class")
        .is_none());
    assert_eq!(
        component(&valve, "high_alarm_1")["entity_category"],
        "config"
    );
    let dust = document_of("dust_collector");
    assert_eq!(
        component(&dust, "pulse_interval")["entity_category"],
        "config"
    );
    assert!(component(&dust, "gear").get("entity_category").is_none());
    assert!(component(&dust, "temperature_alarm")
        .get("entity_category")
        .is_none());
    for name in ["opening", "measured_1", "jammed", "mode", "setpoint"] {
        assert!(
            component(&valve, name).get("entity_category").is_none(),
            "{name}"
        );
    }
}

#[test]
fn profile_hints_override_the_defaults_but_never_add_a_command_to_a_read_only_field() {
    let mut gear = field("gear", int(1, 10), true);
    gear.ha = HaHints {
        component: Some("sensor".to_string()),
        device_class: Some("power_factor".to_string()),
        state_class: Some("total".to_string()),
        unit: Some("steps".to_string()),
        icon: Some("mdi:fan".to_string()),
        entity_category: Some("config".to_string()),
    };
    let mut alarm = field("alarm", FieldKind::Bool, false);
    alarm.ha.component = Some("switch".to_string());
    let mut limit = field("limit", int(0, 9), true);
    limit.ha.entity_category = Some("config".to_string());
    let mut unknown = field("level", int(0, 9), true);
    unknown.ha.component = Some("light".to_string());

    assert_eq!(platform_for(&gear), Platform::Sensor);
    assert_eq!(platform_for(&alarm), Platform::BinarySensor);
    assert_eq!(platform_for(&unknown), Platform::Number);

    let ctx = context();
    let (_, document) =
        device_config_from_fields(&ctx, "dev1", "m", "n", "p", &[gear, alarm, limit, unknown]);
    let gear = component(&document, "gear");
    assert_eq!(gear["p"], "sensor");
    assert_eq!(gear["device_class"], "power_factor");
    assert_eq!(gear["state_class"], "total");
    assert_eq!(gear["unit_of_measurement"], "steps");
    assert_eq!(gear["icon"], "mdi:fan");
    // Home Assistant accepts no `config` sensor: shown as a sensor, a setting is diagnostic.
    assert_eq!(gear["entity_category"], "diagnostic");
    assert!(component(&document, "alarm").get("command_topic").is_none());
    assert_eq!(component(&document, "level")["p"], "number");
    assert_eq!(component(&document, "limit")["entity_category"], "config");

    // A boolean shown as a button must send what the gateway accepts for a boolean.
    let mut reset = field("reset", FieldKind::Bool, true);
    reset.ha.component = Some("button".to_string());
    let (_, document) = device_config_from_fields(&ctx, "dev1", "m", "n", "p", &[reset]);
    assert_eq!(component(&document, "reset")["p"], "button");
    assert_eq!(component(&document, "reset")["payload_press"], "ON");
}

#[test]
fn gateway_document_is_a_real_device_whose_sensors_read_existing_stats_keys() {
    let ctx = context();
    let (topic, document) = gateway_config(&ctx);
    assert_eq!(topic, "homeassistant/device/rtu2mqtt-edge1_gateway/config");
    assert_eq!(
        document["dev"]["identifiers"],
        serde_json::json!(["rtu2mqtt-edge1"])
    );
    assert_eq!(document["o"]["name"], "rtu2mqtt");
    let status = &document["cmps"]["status"];
    assert_eq!(status["p"], "binary_sensor");
    assert_eq!(status["device_class"], "connectivity");
    assert_eq!(status["state_topic"], "plant/gateway/rtu2mqtt-edge1/status");
    assert_eq!(status["payload_on"], "online");

    // The statistics document the bridge publishes on the stats topic.
    let mut line_a = LineStats::new(
        "line-a",
        &["dust_collector".to_string(), "air_shower".to_string()],
        Instant::now(),
    );
    line_a.bus_load = 0.4237;
    line_a.transactions = 17;
    line_a.devices[1].online = true;
    let mut line_b = LineStats::new("line-b", &["valve".to_string()], Instant::now());
    line_b.crc_errors = 3;
    line_b.devices[0].online = true;
    // Given in the other order than configured: sensors select lines by name.
    let bridge = BridgeStats {
        uptime: Duration::from_secs(77),
        waiting_commands: 2,
        ..BridgeStats::default()
    };
    // The summary, and each line's own document on its own topic.
    let mut documents = HashMap::new();
    documents.insert(
        "plant/gateway/rtu2mqtt-edge1/stats".to_string(),
        stats_json(&[line_b.clone(), line_a.clone()], &bridge),
    );
    for line in [&line_b, &line_a] {
        documents.insert(
            format!("plant/gateway/rtu2mqtt-edge1/stats/{}", line.line),
            line_stats_json(line),
        );
    }

    let expected: &[(&str, f64)] = &[
        ("devices_online", 2.0),
        ("waiting_commands", 2.0),
        ("uptime", 77.0),
        ("line_a_bus_load_percent", 42.4),
        ("line_a_transactions", 17.0),
        ("line_a_crc_errors", 0.0),
        ("line_b_crc_errors", 3.0),
        ("line_b_transactions", 0.0),
        ("line_b_timeouts", 0.0),
        ("line_b_exceptions", 0.0),
    ];
    // Each line's sensors are in a document of their own, on the same gateway device.
    let mut components = document["cmps"].as_object().unwrap().clone();
    for line in ["line-a", "line-b"] {
        let (topic, line_document) = line_config(&ctx, line);
        assert_eq!(
            topic,
            format!("homeassistant/device/rtu2mqtt-edge1_gateway/{line}/config")
        );
        assert_eq!(line_document["dev"], document["dev"]);
        assert_eq!(line_document["o"], document["o"]);
        components.extend(line_document["cmps"].as_object().unwrap().clone());
    }
    let mut templates = 0;
    for (id, config) in &components {
        let Some(template) = config["value_template"].as_str() else {
            continue;
        };
        let topic = config["state_topic"].as_str().unwrap_or_default();
        let line_topic = id
            .strip_prefix("line_a_")
            .map(|_| "plant/gateway/rtu2mqtt-edge1/stats/line-a")
            .or_else(|| {
                id.strip_prefix("line_b_")
                    .map(|_| "plant/gateway/rtu2mqtt-edge1/stats/line-b")
            });
        assert_eq!(
            topic,
            line_topic.unwrap_or("plant/gateway/rtu2mqtt-edge1/stats"),
            "{id}"
        );
        let stats = &documents[topic];
        let value = render_stats_template(stats, template)
            .unwrap_or_else(|| panic!("{id}: {template} reads nothing in {stats}"));
        if let Some((_, want)) = expected.iter().find(|(key, _)| key == id) {
            assert!((value - want).abs() < 1e-9, "{id}: {value} != {want}");
        }
        templates += 1;
    }
    assert_eq!(templates, 3 + 2 * 5, "stats sensors");
    for (id, _) in expected {
        assert!(components.get(*id).is_some(), "no sensor {id}");
    }
}

/// Follows a `{{ value_json.a['b'].c }}` template through a statistics document, as Home
/// Assistant would, to the number it shows.
fn render_stats_template(document: &Json, template: &str) -> Option<f64> {
    let path = template
        .trim()
        .strip_prefix("{{")?
        .strip_suffix("}}")?
        .trim()
        .strip_prefix("value_json")?;
    let mut current = document;
    let mut rest = path;
    while !rest.is_empty() {
        if let Some(after) = rest.strip_prefix("['") {
            let end = after.find("']")?;
            current = current.get(&after[..end])?;
            rest = &after[end + 2..];
        } else if let Some(after) = rest.strip_prefix('.') {
            let end = after.find(['.', '[']).unwrap_or(after.len());
            current = current.get(&after[..end])?;
            rest = &after[end..];
        } else {
            return None;
        }
    }
    current.as_f64()
}

#[test]
fn only_configs_this_gateway_published_for_removed_devices_are_stale() {
    let ctx = context();
    let configured = vec!["valve".to_string(), "air_shower".to_string()];
    let ours = |device: &str| {
        device_config_from_fields(&ctx, device, "m", "n", "p", &valve_fields())
            .1
            .to_string()
            .into_bytes()
    };
    let removed_topic = "homeassistant/device/rtu2mqtt-edge1_old_pump/config";
    assert!(is_stale_config(
        &ctx,
        removed_topic,
        &ours("old_pump"),
        &configured
    ));
    assert!(!is_stale_config(
        &ctx,
        "homeassistant/device/rtu2mqtt-edge1_valve/config",
        &ours("valve"),
        &configured
    ));
    // Another gateway whose client id extends ours: same topic shape, not our document.
    let other = Topics::new("rtu2mqtt-edge1_b", "plant");
    let theirs = device_config_from_fields(&other, "pump", "m", "n", "p", &valve_fields())
        .1
        .to_string();
    assert!(!is_stale_config(
        &ctx,
        "homeassistant/device/rtu2mqtt-edge1_b_pump/config",
        theirs.as_bytes(),
        &configured
    ));
    assert!(!is_stale_config(&ctx, removed_topic, b"", &configured));
    assert!(!is_stale_config(
        &ctx,
        removed_topic,
        b"{not json",
        &configured
    ));
    let gateway = gateway_config(&ctx).1.to_string();
    assert!(!is_stale_config(
        &ctx,
        &ctx.gateway_config_topic(),
        gateway.as_bytes(),
        &configured
    ));
    assert!(!is_stale_config(
        &ctx,
        "homeassistant/sensor/rtu2mqtt-edge1_x/config",
        &ours("x"),
        &configured
    ));

    let (topic, payload) = removal(&ctx, "old_pump");
    assert_eq!(topic, removed_topic);
    assert!(payload.is_empty());
    assert_eq!(ctx.config_filter(), "homeassistant/device/+/config");
}

#[test]
fn home_assistant_birth_message_is_recognised_and_nothing_else() {
    assert!(is_ha_online(b"online"));
    assert!(is_ha_online(b" online\n"));
    assert!(is_ha_online(b"ONLINE"));
    assert!(!is_ha_online(b"offline"));
    assert!(!is_ha_online(b""));
    assert!(!is_ha_online(b"onlinex"));
    assert!(!is_ha_online(&[0xff, 0xfe, 0x00]));
    assert_eq!(context().ha_status_topic(), "homeassistant/status");
}

#[test]
fn reannounce_delays_stay_in_range_and_vary() {
    let mut rng = StdRng::seed_from_u64(7);
    let delays: Vec<Duration> = (0..200).map(|_| reannounce_delay(&mut rng)).collect();
    assert!(delays.iter().all(|d| REANNOUNCE_DELAY.contains(d)));
    let distinct: HashSet<Duration> = delays.iter().copied().collect();
    assert!(distinct.len() > 100, "delays do not spread: {distinct:?}");
}

#[test]
fn colliding_unique_ids_are_reported() {
    let ctx = context();
    let a = vec![field("b_c", FieldKind::Bool, false)];
    let ab = vec![field("c", FieldKind::Bool, false)];
    let sound = valve_fields();
    assert_eq!(
        unique_id_collisions(&ctx, &[("a", &a), ("a_b", &ab)]),
        vec!["rtu2mqtt-edge1_a_b_c".to_string()]
    );
    assert!(unique_id_collisions(&ctx, &[("valve", &sound), ("valve2", &sound)]).is_empty());
}

fn sample_lines() -> Vec<LineStats> {
    let now = Instant::now();
    let mut line = LineStats::new(
        "line-a",
        &["dust_collector".to_string(), "odd \"name\\\n".to_string()],
        now,
    );
    line.port_open = true;
    line.transactions = 1234;
    line.timeouts = 5;
    line.crc_errors = 2;
    line.bus_load = 0.25;
    line.last_command_latency = Some(Duration::from_millis(180));
    line.devices[0].online = true;
    line.devices[0].transactions = 1000;
    line.devices[0].timeouts = 3;
    line.devices[0].crc_errors = 1;
    line.devices[0].last_latency = Some(Duration::from_micros(41_500));
    let idle = LineStats::new("line-b", &["valve".to_string()], now);
    vec![line, idle]
}

#[test]
fn prometheus_text_is_well_formed_with_contiguous_families_and_escaped_labels() {
    let bridge = BridgeStats {
        uptime: Duration::from_secs(3600),
        mqtt_connected: true,
        mqtt_connects: 2,
        published: 99,
        waiting_commands: 1,
        commands_received: 4,
        commands_applied: 3,
        commands_rejected: 1,
        ..BridgeStats::default()
    };
    let text = prometheus_text(&sample_lines(), &bridge);
    assert!(text.ends_with('\n'));

    let mut declared: Vec<String> = Vec::new();
    let mut typed: HashSet<String> = HashSet::new();
    let mut current: Option<String> = None;
    for line in text.lines() {
        if let Some(rest) = line.strip_prefix("# HELP ") {
            let name = rest.split(' ').next().unwrap().to_string();
            assert!(!declared.contains(&name), "{name} declared twice");
            declared.push(name.clone());
            current = Some(name);
        } else if let Some(rest) = line.strip_prefix("# TYPE ") {
            let mut parts = rest.split(' ');
            let name = parts.next().unwrap();
            assert_eq!(Some(name), current.as_deref());
            assert!(matches!(parts.next(), Some("counter" | "gauge")));
            typed.insert(name.to_string());
        } else {
            let name_end = line.find(['{', ' ']).unwrap();
            let name = &line[..name_end];
            assert_eq!(
                Some(name),
                current.as_deref(),
                "sample out of its family: {line}"
            );
            assert!(typed.contains(name));
            let value = line.rsplit(' ').next().unwrap();
            assert!(value.parse::<f64>().is_ok(), "bad value in {line}");
        }
    }

    assert!(text.contains("rtu2mqtt_line_transactions_total{line=\"line-a\"} 1234\n"));
    assert!(text.contains("rtu2mqtt_line_transactions_total{line=\"line-b\"} 0\n"));
    assert!(text.contains("rtu2mqtt_line_bus_load_ratio{line=\"line-a\"} 0.25\n"));
    assert!(text.contains("rtu2mqtt_line_command_latency_seconds{line=\"line-a\"} 0.18\n"));
    assert!(!text.contains("rtu2mqtt_line_command_latency_seconds{line=\"line-b\"}"));
    assert!(text.contains("rtu2mqtt_device_online{line=\"line-a\",device=\"dust_collector\"} 1\n"));
    assert!(text
        .contains("rtu2mqtt_device_failures_total{line=\"line-a\",device=\"dust_collector\"} 4\n"));
    assert!(text.contains(
        "rtu2mqtt_device_latency_seconds{line=\"line-a\",device=\"dust_collector\"} 0.0415\n"
    ));
    assert!(text.contains("device=\"odd \\\"name\\\\\\n\"} 0\n"));
    assert!(text.contains("rtu2mqtt_command_outcomes_total{outcome=\"applied\"} 3\n"));
    assert!(text.contains("rtu2mqtt_mqtt_connected 1\n"));
    assert!(text.contains("rtu2mqtt_uptime_seconds 3600\n"));
    assert!(text.contains("rtu2mqtt_commands_waiting 1\n"));
    assert!(text.contains("rtu2mqtt_mqtt_connects_total 2\n"));
}

/// The built-in profiles of the seed plant, as configured in `config/rtu2mqtt.toml`.
fn built_in_documents() -> Vec<(&'static str, Profile, Json)> {
    let ctx = context();
    [
        ("dust_collector", "ruiwan-dust-collector"),
        ("valve", "wuzhou-valve"),
        ("air_shower", "lixian-air-shower"),
    ]
    .into_iter()
    .map(|(device, name)| {
        let profile = registry::built_in(name).unwrap();
        let (topic, document) = device_config(&ctx, device, &profile);
        assert_eq!(
            topic,
            format!("homeassistant/device/rtu2mqtt-edge1_{device}/config")
        );
        (device, profile, document)
    })
    .collect()
}

#[test]
fn built_in_profiles_give_the_expected_component_for_every_seed_field() {
    let documents = built_in_documents();
    let document = |device: &str| {
        documents
            .iter()
            .find(|(name, ..)| *name == device)
            .map(|(.., document)| document)
            .unwrap()
    };
    let shower = document("air_shower");
    let dust = document("dust_collector");
    let valve = document("valve");
    assert_eq!(platform_of(shower, "emergency_stop"), "switch");
    assert_eq!(platform_of(shower, "voice_start"), "button");
    assert_eq!(component(shower, "voice_start")["payload_press"], "PRESS");
    assert_eq!(platform_of(dust, "temperature"), "sensor");
    assert_eq!(platform_of(valve, "mode"), "select");
    assert_eq!(
        component(valve, "mode")["options"],
        serde_json::json!(["manual", "auto"])
    );
    assert_eq!(platform_of(valve, "jammed"), "binary_sensor");
    let gear = component(dust, "gear");
    assert_eq!(
        (&gear["p"], &gear["min"], &gear["max"], &gear["step"]),
        (&json!("number"), &json!(1), &json!(10), &json!(1))
    );
    assert_eq!(gear["mode"], "box");
    let opening = component(valve, "opening");
    assert_eq!(
        (&opening["p"], &opening["min"], &opening["max"]),
        (&json!("number"), &json!(0), &json!(100))
    );
}

#[test]
fn built_in_profiles_expose_every_field_with_commands_exactly_on_writable_ones() {
    let ctx = context();
    let mut unique_ids = HashSet::new();
    for (device, profile, document) in built_in_documents() {
        // Valid JSON with the keys Home Assistant requires of a device document.
        let reparsed: Json = serde_json::from_str(&document.to_string()).unwrap();
        assert_eq!(reparsed, document);
        assert_eq!(document["dev"]["manufacturer"], profile.manufacturer());
        assert_eq!(document["dev"]["model"], profile.model());
        assert_eq!(document["dev"]["via_device"], "rtu2mqtt-edge1");
        assert_eq!(document["o"]["name"], "rtu2mqtt");
        assert_eq!(document["availability_mode"], "all");
        assert_eq!(document["availability"].as_array().map(Vec::len), Some(2));

        // Identity fields fill the device entry instead of being entities; every other field
        // is one, and the command-result event is one more.
        let components = document["cmps"].as_object().unwrap();
        let identities = profile
            .fields()
            .iter()
            .filter(|f| f.identity.is_some())
            .count();
        assert_eq!(
            components.len(),
            profile.fields().len() - identities + 1,
            "{device}"
        );
        assert_eq!(components["command-result"]["p"], "event", "{device}");
        for field in profile.fields() {
            if field.identity.is_some() {
                assert!(!components.contains_key(&field.name), "{}", field.name);
                continue;
            }
            let config = &components[&field.name];
            let platform = config["p"].as_str().unwrap();
            assert!(
                Platform::from_name(platform).is_some(),
                "{device}/{}: {platform}",
                field.name
            );
            assert!(unique_ids.insert(config["unique_id"].as_str().unwrap().to_string()));
            match config.get("command_topic") {
                Some(topic) => {
                    assert!(field.writable, "{device}/{} is read-only", field.name);
                    assert_eq!(
                        topic.as_str(),
                        Some(ctx.command_topic(device, &field.name).as_str())
                    );
                    assert_eq!(config["retain"], false);
                }
                None => assert!(!field.writable, "{device}/{} has no command", field.name),
            }
            if platform != "button" {
                assert_eq!(
                    config["state_topic"].as_str(),
                    Some(format!("plant/{device}/{}", field.name).as_str())
                );
            }
            if let Some(category) = config.get("entity_category") {
                assert!(category == "config" || category == "diagnostic");
                if platform == "sensor" || platform == "binary_sensor" {
                    assert_eq!(category, "diagnostic", "{device}/{}", field.name);
                }
            }
            // Home Assistant refuses these combinations outright.
            if config["device_class"] == "enum" {
                assert!(config.get("state_class").is_none());
                assert!(config.get("unit_of_measurement").is_none());
            }
        }
        let fields: Vec<FieldInfo> = profile.fields().to_vec();
        assert!(unique_id_collisions(&ctx, &[(device, &fields)]).is_empty());
    }
}

/// The built-in document of one seed device.
fn built_in_document(device: &str) -> (Profile, Json) {
    built_in_documents()
        .into_iter()
        .find(|(name, ..)| *name == device)
        .map(|(_, profile, document)| (profile, document))
        .unwrap()
}

#[test]
fn every_device_home_assistant_can_command_has_an_event_entity_fed_by_its_results() {
    let words: Vec<&str> = Outcome::ALL.iter().map(|o| o.word()).collect();
    assert_eq!(
        words,
        [
            "applied",
            "not_applied",
            "rejected",
            "failed",
            "expired",
            "superseded"
        ]
    );
    for (device, _, document) in built_in_documents() {
        let event = &document["cmps"][RESULT_EVENT];
        assert_eq!(event["p"], "event", "{device}");
        assert_eq!(event["name"], "Command result");
        assert_eq!(
            event["unique_id"],
            format!("rtu2mqtt-edge1_{device}_{RESULT_EVENT}")
        );
        // Every `…/result` of the device, whichever field: one level wildcard.
        assert_eq!(event["state_topic"], format!("plant/{device}/+/result"));
        assert_eq!(event["event_types"], json!(words));
        assert_eq!(event["value_template"], RESULT_EVENT_TEMPLATE);
        assert!(event.get("command_topic").is_none());
    }
    // The template reads exactly the keys a result carries, and makes the outcome the type.
    let result: Json = serde_json::from_str(
        &CommandResult::new("150", Outcome::Rejected, "must be 0–100 or 255").to_json(),
    )
    .unwrap();
    for key in ["outcome", "value", "detail"] {
        assert!(result.get(key).is_some(), "{key}");
        assert!(
            RESULT_EVENT_TEMPLATE.contains(&format!("value_json.{key}")),
            "{key}"
        );
    }
    assert!(RESULT_EVENT_TEMPLATE.contains("'event_type': value_json.outcome"));
    assert!(RESULT_EVENT_TEMPLATE.ends_with("| to_json }}"));

    // A device Home Assistant cannot command has no results to show.
    let (_, sensor_only) = device_config_from_fields(
        &context(),
        "probe",
        "m",
        "n",
        "p",
        &[field("temperature", int(0, 99), false)],
    );
    assert!(sensor_only["cmps"].get(RESULT_EVENT).is_none());
}

#[test]
fn identity_fields_fill_the_device_entry_once_their_values_are_known() {
    let ctx = context();
    let (profile, before) = built_in_document("valve");
    let identities: Vec<(&str, Identity)> = profile
        .fields()
        .iter()
        .filter_map(|f| f.identity.map(|identity| (f.name.as_str(), identity)))
        .collect();
    assert_eq!(
        identities,
        [
            ("serial_number", Identity::SerialNumber),
            ("software_version", Identity::SoftwareVersion),
            ("hardware_version", Identity::HardwareVersion),
        ]
    );
    // Not entities, and nothing in the entry before the device answered.
    for (name, identity) in &identities {
        assert!(before["cmps"].get(*name).is_none(), "{name}");
        assert!(before["dev"].get(identity.key()).is_none(), "{name}");
    }

    let mut state = DeviceState::new();
    state.insert(
        "serial_number".to_string(),
        Value::Text("0a1b2c3d4e5f60".to_string()),
    );
    state.insert("software_version".to_string(), Value::Int(12));
    state.insert("hardware_version".to_string(), Value::Int(3));
    state.insert("opening".to_string(), Value::Int(40));
    let (topic, after) = device_config_with_state(&ctx, "valve", &profile, Some(&state));
    assert_eq!(topic, ctx.config_topic("valve"));
    assert_eq!(after["dev"]["serial_number"], "0a1b2c3d4e5f60");
    assert_eq!(after["dev"]["sw_version"], "12");
    assert_eq!(after["dev"]["hw_version"], "3");
    // Everything else is the document as before.
    let mut stripped = after.clone();
    for key in ["serial_number", "sw_version", "hw_version"] {
        stripped["dev"].as_object_mut().unwrap().remove(key);
    }
    assert_eq!(stripped, before);

    // An empty text fills nothing (Home Assistant would show a blank entry).
    state.insert("serial_number".to_string(), Value::Text(String::new()));
    let (_, blank) = device_config_with_state(&ctx, "valve", &profile, Some(&state));
    assert!(blank["dev"].get("serial_number").is_none());

    // The document goes out again when an identity value arrives or changes, not otherwise.
    let update = |field: &str| StateUpdate {
        device: "valve".to_string(),
        field: field.to_string(),
        text: "x".to_string(),
    };
    assert_eq!(
        identity_update(
            &ctx,
            "valve",
            &profile,
            Some(&state),
            &[update("opening"), update("software_version")]
        ),
        Some(device_config_with_state(
            &ctx,
            "valve",
            &profile,
            Some(&state)
        ))
    );
    assert_eq!(
        identity_update(&ctx, "valve", &profile, Some(&state), &[update("opening")]),
        None
    );
    assert_eq!(
        identity_update(&ctx, "valve", &profile, Some(&state), &[]),
        None
    );
}

#[test]
fn entity_names_are_labels_without_the_device_name() {
    for (device, profile, document) in built_in_documents() {
        for (key, config) in document["cmps"].as_object().unwrap() {
            let name = config["name"].as_str().unwrap();
            // Home Assistant puts the device name in front by itself.
            for word in [device, profile.name()] {
                assert!(
                    !name.to_lowercase().contains(&word.replace('_', " ")) && !name.contains(word),
                    "{device}/{key}: {name}"
                );
            }
            assert!(!name.contains('_'), "{device}/{key}: {name}");
        }
    }
    let (_, valve) = built_in_document("valve");
    let (_, shower) = built_in_document("air_shower");
    let (_, dust) = built_in_document("dust_collector");
    // Acronyms as the manual writes them, and the profile's `label` where it gives one.
    assert_eq!(
        valve["cmps"]["pid_invalid_flags"]["name"],
        "PID invalid flags"
    );
    assert_eq!(valve["cmps"]["sample_period"]["name"], "PID sample period");
    assert_eq!(
        shower["cmps"]["hepa_filter_expired"]["name"],
        "HEPA filter expired"
    );
    assert_eq!(dust["cmps"]["gear"]["name"], "Gear");
    assert_eq!(dust["cmps"]["pulse_interval"]["name"], "Pulse interval");

    let mut labelled = field("pv_1", int(0, 9), false);
    labelled.label = Some("Process value (channel 1)".to_string());
    let (_, document) = device_config_from_fields(&context(), "d", "m", "n", "p", &[labelled]);
    assert_eq!(
        document["cmps"]["pv_1"]["name"],
        "Process value (channel 1)"
    );
}

#[test]
fn clock_texts_called_durations_are_seconds_for_home_assistant() {
    let (_, valve) = built_in_document("valve");
    for name in ["sample_period", "integral_time", "derivative_time"] {
        let config = &valve["cmps"][name];
        assert_eq!(config["p"], "sensor", "{name}");
        assert_eq!(config["device_class"], "duration", "{name}");
        assert_eq!(config["unit_of_measurement"], "s", "{name}");
        assert_eq!(config["value_template"], CLOCK_TO_SECONDS, "{name}");
        assert_eq!(config["entity_category"], "diagnostic", "{name}");
        assert!(config.get("state_class").is_none(), "{name}");
    }
    // Invalid clocks (`27:81:62`, `00:00`) must come out as `None`, Home Assistant's unknown.
    assert!(CLOCK_TO_SECONDS.contains("p | length == 3"));
    assert!(CLOCK_TO_SECONDS.contains("p[1] < 60 and p[2] < 60"));
    assert!(CLOCK_TO_SECONDS.contains("{% else %}None{% endif %}"));
    // Numeric durations keep their unit and need no template.
    let (_, dust) = built_in_document("dust_collector");
    let interval = &dust["cmps"]["pulse_interval"];
    assert_eq!(
        (&interval["device_class"], &interval["unit_of_measurement"]),
        (&json!("duration"), &json!("min"))
    );
    assert!(interval.get("value_template").is_none());
    // A text without the hint stays text.
    let (_, plain) = device_config_from_fields(
        &context(),
        "d",
        "m",
        "n",
        "p",
        &[field("clock", FieldKind::Text, false)],
    );
    assert!(plain["cmps"]["clock"].get("value_template").is_none());
    assert!(plain["cmps"]["clock"].get("unit_of_measurement").is_none());
}

#[test]
fn integers_with_also_values_offer_only_accepted_values() {
    let ctx = context();
    // Too many values for a select: a number over the range only, the `also` values unknown.
    let mut wide = field("limit", int(0, 1000), true);
    wide.also = vec![65535];
    // A hint cannot bring back the number box over a small range with `also` values.
    let mut small = field("opening_alarm", int(0, 100), true);
    small.also = vec![255];
    small.ha.component = Some("number".to_string());
    let (_, document) = device_config_from_fields(&ctx, "d", "m", "n", "p", &[wide, small]);
    let limit = &document["cmps"]["limit"];
    assert_eq!(limit["p"], "number");
    assert_eq!((&limit["min"], &limit["max"]), (&json!(0), &json!(1000)));
    assert_eq!(
        limit["value_template"],
        "{% if value in ['65535'] %}None{% else %}{{ value }}{% endif %}"
    );
    let alarm = &document["cmps"]["opening_alarm"];
    assert_eq!(alarm["p"], "select");
    assert_eq!(alarm["options"].as_array().map(Vec::len), Some(102));
    assert_eq!(alarm["options"][101], "255");
    assert_eq!(alarm["command_topic"], "plant/d/opening_alarm/set");
    // Without `also` the number stays a number.
    let (_, plain) =
        device_config_from_fields(&ctx, "d", "m", "n", "p", &[field("x", int(0, 100), true)]);
    assert_eq!(plain["cmps"]["x"]["p"], "number");
    assert!(plain["cmps"]["x"].get("value_template").is_none());
}

/// A small profile with two read-only numbers (`serial`, `firmware`) and a writable one
/// (`level`), each followed by the extra lines given for it.
fn identity_profile(serial_extra: &str, version_extra: &str, level_extra: &str) -> String {
    let mut text = String::from(
        "device = { name = \"ident\", manufacturer = \"Test\", model = \"T1\" }\n\
         line = { max_read_registers = 10 }\n\
         blocks = [{ name = \"main\", function = 3, start = 0, count = 4 }]\n",
    );
    let fields = [
        ("serial", "", serial_extra),
        ("firmware", "", version_extra),
        (
            "level",
            "range = [0, 100]\nwrite = { function = 6, address = 2 }\n",
            level_extra,
        ),
    ];
    for (offset, (name, write, extra)) in fields.into_iter().enumerate() {
        text.push_str(&format!(
            "\n[[fields]]\nname = \"{name}\"\nblock = \"main\"\noffset = {offset}\n\
             codec = {{ type = \"u16\" }}\n{write}{extra}\n"
        ));
    }
    text
}

#[test]
fn identity_and_label_keys_are_checked_when_a_profile_loads() {
    let load = |text: String| Profile::from_toml(&text, "test.toml");
    let profile = load(identity_profile(
        "identity = \"serial_number\"",
        "identity = \"sw_version\"\nlabel = \"Firmware (PLC)\"",
        "",
    ))
    .unwrap();
    assert_eq!(
        profile.field("serial").unwrap().identity,
        Some(Identity::SerialNumber)
    );
    assert_eq!(
        profile.field("firmware").unwrap().label.as_deref(),
        Some("Firmware (PLC)")
    );
    assert_eq!(profile.field("level").unwrap().identity, None);

    let refused = |text: String, fragments: &[&str]| {
        let errors = load(text).expect_err("accepted").to_string();
        for fragment in fragments {
            assert!(errors.contains(fragment), "{fragment:?} not in {errors}");
        }
    };
    refused(
        identity_profile(
            "identity = \"serial_number\"",
            "identity = \"serial_number\"",
            "",
        ),
        &[
            "fields[1] (firmware).identity",
            "`serial_number` is already the identity of field `serial`",
        ],
    );
    refused(
        identity_profile("identity = \"firmware\"", "", ""),
        &["firmware", "serial_number"],
    );
    refused(
        identity_profile("", "", "identity = \"hw_version\""),
        &["fields[2] (level).identity", "never written"],
    );
    refused(
        identity_profile("label = \" \"", "", ""),
        &["fields[0] (serial).label"],
    );
}

#[test]
fn json_view_is_typed_and_in_field_order_whatever_the_map() {
    let mut state = DeviceState::new();
    state.insert("temperature".to_string(), Value::Int(41));
    state.insert("power".to_string(), Value::Bool(true));
    state.insert(
        "measured_1".to_string(),
        Value::Decimal {
            scaled: 1234,
            precision: 2,
        },
    );
    state.insert("motor".to_string(), Value::Enum("opening".to_string()));
    state.insert("serial_number".to_string(), Value::Text("0a1b".to_string()));
    let view = json_view(&state);
    assert_eq!(view["temperature"], 41);
    assert_eq!(view["power"], true);
    assert_eq!(view["measured_1"], 12.34);
    assert_eq!(view["motor"], "opening");
    assert_eq!(view["serial_number"], "0a1b");
    let text = String::from_utf8(json_view_payload(&state)).unwrap();
    assert_eq!(
        text,
        r#"{"measured_1":12.34,"motor":"opening","power":true,"serial_number":"0a1b","temperature":41}"#
    );
    // The same values inserted in another order give the same bytes.
    let mut reversed = DeviceState::new();
    for (key, value) in state.iter().collect::<Vec<_>>().into_iter().rev() {
        reversed.insert(key.clone(), value.clone());
    }
    assert_eq!(json_view_payload(&reversed), text.into_bytes());
    assert_eq!(json_view_topic("plant", "valve"), "plant/valve");
    assert_eq!(json_view(&DeviceState::new()), json!({}));
}

#[test]
fn all_configs_lead_with_the_gateway_and_follow_the_configured_devices() {
    let ctx = context();
    let documents = built_in_documents();
    let devices: Vec<(&str, &Profile)> = documents
        .iter()
        .map(|(device, profile, _)| (*device, profile))
        .collect();
    let lines = vec!["line-a".to_string(), "line-b".to_string()];
    let messages = all_configs(&ctx, &lines, &devices);
    let topics: Vec<&str> = messages.iter().map(|(topic, _)| topic.as_str()).collect();
    assert_eq!(
        topics,
        vec![
            "homeassistant/device/rtu2mqtt-edge1_gateway/config",
            "homeassistant/device/rtu2mqtt-edge1_gateway/line-a/config",
            "homeassistant/device/rtu2mqtt-edge1_gateway/line-b/config",
            "homeassistant/device/rtu2mqtt-edge1_dust_collector/config",
            "homeassistant/device/rtu2mqtt-edge1_valve/config",
            "homeassistant/device/rtu2mqtt-edge1_air_shower/config",
        ]
    );
    for ((_, payload), (_, _, document)) in messages[3..].iter().zip(&documents) {
        assert_eq!(&serde_json::from_str::<Json>(payload).unwrap(), document);
    }
    let gateway: Json = serde_json::from_str(&messages[0].1).unwrap();
    assert_eq!(
        gateway["dev"]["identifiers"][0],
        documents[0].2["dev"]["via_device"]
    );
}

#[test]
fn stats_json_carries_lines_devices_and_bridge_counters() {
    let bridge = BridgeStats {
        commands_failed: 2,
        waiting_commands: 1,
        ..BridgeStats::default()
    };
    let lines = sample_lines();
    let stats = stats_json(&lines, &bridge);
    assert!(
        stats.get("lines").is_none(),
        "lines have their own documents"
    );
    assert_eq!(stats["lines_total"], lines.len());
    let line = &line_stats_json(&lines[0]);
    assert_eq!(line["line"], "line-a");
    assert_eq!(line["transactions"], 1234);
    assert_eq!(line["bus_load_percent"], 25.0);
    assert_eq!(line["command_latency_ms"], 180.0);
    assert_eq!(line["worst_command_latency_ms"], Json::Null);
    let device = &line["devices"]["dust_collector"];
    assert_eq!(device["online"], true);
    assert_eq!(device["failures"], 4);
    assert_eq!(device["latency_ms"], 41.5);
    assert_eq!(stats["devices_online"], 1);
    assert_eq!(stats["devices_total"], 3);
    assert_eq!(stats["commands"]["failed"], 2);
    assert_eq!(stats["commands"]["waiting"], 1);
    let text = stats.to_string();
    assert_eq!(serde_json::from_str::<Json>(&text).unwrap(), stats);
}

// ----- End to end: the gateway's discovery on a real broker -----

/// Generous bound for a busy 2-core machine: it only fails when something is broken.
const ANSWER: Duration = Duration::from_secs(20);

fn plant_config(broker: &Mosquitto, plant: &SeedPlant, client_id: &str) -> String {
    PlantConfig {
        discovery: true,
        gateway: "json_view = true",
        explicit_serial: true,
        ..PlantConfig::default()
    }
    .text(broker, plant, client_id)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gateway_announces_discovery_that_home_assistant_can_use_on_a_real_broker() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap();
    let client_id = "disc-e2e-gw";
    let ctx = Topics::new(client_id, "plant");

    // What an earlier run left behind: a device since removed from the configuration, and a
    // device of another gateway whose client id extends ours.
    let setup = TestClient::connect(broker.port, "disc-e2e-setup").await;
    let (_, old_pump) = device_config_from_fields(&ctx, "old_pump", "m", "n", "p", &valve_fields());
    let old_pump_topic = ctx.config_topic("old_pump");
    setup
        .publish(&old_pump_topic, old_pump.to_string(), true)
        .await;
    let other = Topics::new(&format!("{client_id}_x"), "plant");
    let (other_topic, other_document) =
        device_config_from_fields(&other, "pump", "m", "n", "p", &valve_fields());
    setup
        .publish(&other_topic, other_document.to_string(), true)
        .await;

    let mut observer = TestClient::connect(broker.port, "disc-e2e-observer").await;
    observer.subscribe("homeassistant/#").await;
    observer.subscribe("plant/#").await;
    // Both retained leftovers are there before the gateway starts.
    observer.next_on(&old_pump_topic, ANSWER).await;
    observer.next_on(&other_topic, ANSWER).await;

    let config = rtu2mqtt::config::from_str(
        &plant_config(&broker, &plant, client_id),
        std::path::Path::new("."),
    )
    .unwrap();
    let shutdown = CancellationToken::new();
    let trigger = shutdown.clone();
    let gateway = tokio::spawn(run_gateway(config, shutdown, Hooks::default()));

    // A client that follows the command-result events exactly as announced.
    let mut events = TestClient::connect(broker.port, "disc-e2e-events").await;

    // One config per device, equal to what the profile gives, and the gateway's own. (Should
    // the valve's identity block already have been read, its entry carries those values.)
    let devices = built_in_documents();
    for (device, profile, _) in &devices {
        let message = observer
            .wait_for(&ctx.config_topic(device), ANSWER, |m| !m.payload.is_empty())
            .await;
        let (_, expected) = device_config(&ctx, device, profile);
        let mut announced = message.json();
        if let Some(dev) = announced["dev"].as_object_mut() {
            for identity in ["serial_number", "sw_version", "hw_version"] {
                dev.remove(identity);
            }
        }
        assert_eq!(announced, expected, "{device}");
        let event_topic = expected["cmps"][RESULT_EVENT]["state_topic"]
            .as_str()
            .unwrap()
            .to_string();
        events.subscribe(&event_topic).await;
    }

    // Once the valve's identity block is read, its device entry carries the serial number and
    // versions the gateway publishes as state, in a document otherwise unchanged.
    let mut identity = Vec::new();
    for (field, key) in [
        ("serial_number", "serial_number"),
        ("software_version", "sw_version"),
        ("hardware_version", "hw_version"),
    ] {
        let state = observer
            .wait_for(&format!("plant/valve/{field}"), ANSWER, |m| {
                !m.payload.is_empty()
            })
            .await
            .text();
        identity.push((key, state));
    }
    let identified = observer
        .wait_for(&ctx.config_topic("valve"), ANSWER, |m| {
            m.json()["dev"].get("serial_number").is_some()
        })
        .await
        .json();
    for (key, state) in &identity {
        assert_eq!(identified["dev"][*key], json!(state), "{key}");
    }
    let serial = identity[0].1.clone();
    assert!(identified["cmps"].get("serial_number").is_none());
    assert!(
        identified["cmps"] == device_config(&ctx, "valve", &devices[1].1).1["cmps"],
        "the identity changed the valve's entities"
    );

    // The alarm openings' states (the simulated valve has one disabled: 255) are options of
    // their selects, so Home Assistant can show every value the gateway publishes.
    let mut disabled_seen = false;
    for field in [
        "high_alarm_opening_1",
        "high_alarm_opening_2",
        "low_alarm_opening_1",
        "low_alarm_opening_2",
    ] {
        let state = observer
            .wait_for(&format!("plant/valve/{field}"), ANSWER, |m| {
                !m.payload.is_empty()
            })
            .await
            .text();
        let options = identified["cmps"][field]["options"].as_array().unwrap();
        assert!(options.contains(&json!(state)), "{field} = {state}");
        disabled_seen |= state == "255";
    }
    assert!(
        disabled_seen,
        "no alarm opening is disabled in the simulated valve"
    );
    let gateway_document = observer
        .wait_for(&ctx.gateway_config_topic(), ANSWER, |m| {
            !m.payload.is_empty()
        })
        .await
        .json();
    assert_eq!(gateway_document, gateway_config(&ctx).1);
    let line_document = observer
        .wait_for(&ctx.line_config_topic("line-b"), ANSWER, |m| {
            !m.payload.is_empty()
        })
        .await
        .json();
    assert_eq!(line_document, line_config(&ctx, "line-b").1);

    // The removed device's config is cleared; the other gateway's is left alone.
    observer
        .wait_for(&old_pump_topic, ANSWER, |m| m.payload.is_empty())
        .await;

    // Retained in the broker: a client arriving now gets every document.
    let mut late = TestClient::connect(broker.port, "disc-e2e-late").await;
    late.subscribe("homeassistant/device/+/config").await;
    for (device, ..) in &devices {
        let message = late.next_on(&ctx.config_topic(device), ANSWER).await;
        assert!(message.retain, "{device} config not retained");
    }
    let kept = late.next_on(&other_topic, ANSWER).await;
    assert_eq!(kept.json(), other_document);
    late.settle(Duration::from_millis(500)).await;
    assert!(
        late.on(&old_pump_topic).is_empty(),
        "the removed device's config is still retained"
    );

    // The JSON view: one retained, typed document per device, keyed by the profile's fields.
    let view = observer
        // Blocks arrive one by one: wait for the one holding the status word too.
        .wait_for("plant/valve", ANSWER, |m| {
            let view = m.json();
            view.get("opening").is_some_and(Json::is_number) && view.get("jammed").is_some()
        })
        .await
        .json();
    assert!(view["mode"].is_string(), "{view}");
    assert!(view["jammed"].is_boolean(), "{view}");
    let valve_profile = &devices[1].1;
    for key in view.as_object().unwrap().keys() {
        assert!(
            valve_profile.field(key).is_some(),
            "{key} is not a valve field"
        );
    }
    // A client arriving now gets the view at once, from the broker.
    late.subscribe("plant/valve").await;
    let retained_view = late.next_on("plant/valve", ANSWER).await;
    assert!(retained_view.retain);
    assert!(
        retained_view.json()["opening"].is_number(),
        "{}",
        retained_view.text()
    );

    // Every command topic announced is one the gateway listens to and maps to its field: a
    // malformed value comes back `rejected` for that field's own reason, before any bus work.
    for (device, _, document) in &devices {
        for (field, config) in document["cmps"].as_object().unwrap() {
            let Some(topic) = config["command_topic"].as_str() else {
                continue;
            };
            observer.publish(topic, "not-a-value%", false).await;
            let result = observer
                .next_on(&format!("plant/{device}/{field}/result"), ANSWER)
                .await
                .json();
            let detail = result["detail"].as_str().unwrap_or_default().to_string();
            assert_eq!(result["outcome"], "rejected", "{device}/{field}: {result}");
            // The same result reaches Home Assistant's event entity through its wildcard.
            let event = events
                .next_on(&format!("plant/{device}/{field}/result"), ANSWER)
                .await
                .json();
            assert_eq!(event, result, "{device}/{field}");
            let types = document["cmps"][RESULT_EVENT]["event_types"].clone();
            assert!(
                types.as_array().unwrap().contains(&result["outcome"]),
                "{device}/{field}"
            );
            assert!(
                !detail.contains("unknown field") && !detail.contains("read-only"),
                "{device}/{field}: {detail}"
            );
        }
    }

    // Home Assistant's birth message brings every document again, the valve's with its
    // identity.
    observer.settle(Duration::from_millis(200)).await;
    observer.forget();
    observer
        .publish("homeassistant/status", "online", false)
        .await;
    for (device, ..) in &devices {
        let message = observer
            .wait_for(&ctx.config_topic(device), ANSWER, |m| !m.payload.is_empty())
            .await;
        assert_eq!(message.json()["dev"]["via_device"], client_id);
        if *device == "valve" {
            assert_eq!(message.json()["dev"]["serial_number"], json!(serial));
        }
    }

    trigger.cancel();
    tokio::time::timeout(ANSWER, gateway)
        .await
        .unwrap()
        .unwrap()
        .unwrap();
}
