//! Home Assistant MQTT device-based discovery (HA 2024.11 and later): the retained config
//! documents that make the gateway and every configured device appear in Home Assistant by
//! themselves, their removal, and the reaction to Home Assistant's birth message.
//!
//! Everything here is pure: profile and configuration in, `(topic, JSON)` out. The bridge
//! publishes what these functions return (retained, QoS 1) and owns every MQTT decision.
//!
//! One document per device on `homeassistant/device/<client_id>_<device>/config`:
//! - `dev`: the device registry entry (identifiers, name, manufacturer and model from the
//!   profile, `via_device` pointing at the gateway's own entry, and the serial number and
//!   versions once the profile's identity fields have been read);
//! - `o`: the origin (`rtu2mqtt` and its version);
//! - shared `availability` (gateway status and device availability, `availability_mode: all`)
//!   and `qos`;
//! - `cmps`: one component per profile field, keyed by the field name. The component follows
//!   the field's kind and access (see [`platform_for`]); profile [`HaHints`] override the
//!   defaults. Command topics appear only on writable fields and are exactly the topics the
//!   gateway subscribes to, with `retain: false` so Home Assistant never leaves a command
//!   behind in the broker. Identity fields are not components (they fill `dev`); an action is
//!   one ([`action_entities`](super::action_entities)); a device that takes commands has the
//!   command-result event ([`result_event`]). Names are labels: Home Assistant adds the device's.
//!
//! The gateway itself gets a document too ([`gateway_config`]), so `via_device` names a real
//! device with a connectivity sensor and line statistics.

use super::ha_templates::also_as_unknown;
pub use super::ha_templates::{CLOCK_TO_SECONDS, RESULT_EVENT_TEMPLATE, UNAVAILABLE_AS_UNKNOWN};
use std::ops::RangeInclusive;
use std::time::Duration;

use rand::Rng;
use serde_json::{json, Map, Value as Json};

use super::action_entities::add_action_components;
use super::entity_naming::{
    default_entity_category, is_numeric, name_has_word, DIAGNOSTIC_WORDS, PROBLEM_WORDS,
};
pub use super::entity_naming::{display_name, entity_name};
use super::payload::Outcome;
use super::state::StateUpdate;
use crate::topics::{TopicKind, Topics, OFFLINE, ONLINE};
use rtu2mqtt_profile::topic_levels::GATEWAY_DEVICE;
use rtu2mqtt_profile::{ActionInfo, DeviceState, FieldInfo, FieldKind, HaHints, Profile, Value};

/// How long to wait after Home Assistant's `online` before re-announcing. A random pick in this
/// range spreads the load when several gateways restart discovery at once (HA's own advice).
pub const REANNOUNCE_DELAY: RangeInclusive<Duration> =
    Duration::from_millis(500)..=Duration::from_millis(5000);

/// Payload of a state, as published by the gateway for booleans.
const PAYLOAD_ON: &str = "ON";
const PAYLOAD_OFF: &str = "OFF";
/// What a button sends; the gateway accepts it for momentary fields.
const PAYLOAD_PRESS: &str = "PRESS";
/// A Home Assistant MQTT platform a field can be exposed as.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Platform {
    BinarySensor,
    Switch,
    Button,
    Sensor,
    Number,
    Select,
    Text,
}

impl Platform {
    /// The platform's name in a discovery document (`binary_sensor`).
    pub fn as_str(self) -> &'static str {
        match self {
            Platform::BinarySensor => "binary_sensor",
            Platform::Switch => "switch",
            Platform::Button => "button",
            Platform::Sensor => "sensor",
            Platform::Number => "number",
            Platform::Select => "select",
            Platform::Text => "text",
        }
    }

    /// Parses a profile's `component` hint; None for a platform this gateway does not build.
    pub fn from_name(name: &str) -> Option<Platform> {
        Some(match name {
            "binary_sensor" => Platform::BinarySensor,
            "switch" => Platform::Switch,
            "button" => Platform::Button,
            "sensor" => Platform::Sensor,
            "number" => Platform::Number,
            "select" => Platform::Select,
            "text" => Platform::Text,
            _ => return None,
        })
    }

    /// Whether Home Assistant sends commands through this platform.
    pub fn commands(self) -> bool {
        matches!(
            self,
            Platform::Switch
                | Platform::Button
                | Platform::Number
                | Platform::Select
                | Platform::Text
        )
    }

    /// Whether the platform shows a state.
    fn has_state(self) -> bool {
        self != Platform::Button
    }
}

/// The default platform of a field from its kind and access.
fn default_platform(field: &FieldInfo) -> Platform {
    match (&field.kind, field.writable) {
        (FieldKind::Bool, false) => Platform::BinarySensor,
        (FieldKind::Bool, true) => Platform::Switch,
        (FieldKind::Momentary, true) => Platform::Button,
        // A button nobody can press is at best a state: show it as one.
        (FieldKind::Momentary, false) => Platform::BinarySensor,
        (FieldKind::Integer { .. } | FieldKind::Decimal { .. }, false) => Platform::Sensor,
        (FieldKind::Integer { .. }, true) if integer_choices(field).is_some() => Platform::Select,
        (FieldKind::Integer { .. } | FieldKind::Decimal { .. }, true) => Platform::Number,
        (FieldKind::Enum { .. }, false) => Platform::Sensor,
        (FieldKind::Enum { .. }, true) => Platform::Select,
        (FieldKind::Text, false) => Platform::Sensor,
        (FieldKind::Text, true) => Platform::Text,
    }
}

/// Whether `platform` can show `field` faithfully: a command platform only for a writable
/// field (the gateway rejects commands on read-only ones), and a platform whose payloads fit
/// the field's kind.
fn platform_fits(platform: Platform, field: &FieldInfo) -> bool {
    if platform.commands() && !field.writable {
        return false;
    }
    let numeric = matches!(
        field.kind,
        FieldKind::Integer { .. } | FieldKind::Decimal { .. }
    );
    match platform {
        Platform::BinarySensor | Platform::Switch => {
            matches!(field.kind, FieldKind::Bool | FieldKind::Momentary)
        }
        Platform::Button => matches!(field.kind, FieldKind::Momentary | FieldKind::Bool),
        // A number would offer the gap between the range and `also` (the valve's 101–254),
        // which the gateway always refuses: such a field is a select of its valid values.
        Platform::Number => numeric && integer_choices(field).is_none(),
        Platform::Select => {
            matches!(field.kind, FieldKind::Enum { .. }) || integer_choices(field).is_some()
        }
        Platform::Sensor | Platform::Text => true,
    }
}

/// Most options a select of integers may have: beyond this, a list is no way to pick a value.
const MAX_CHOICES: i128 = 256;

/// Every value a writable integer field with `also` values accepts, as select options
/// (`0`…`100`, `255`), when they are few and one count apart; None for any other field.
fn integer_choices(field: &FieldInfo) -> Option<Vec<String>> {
    let FieldKind::Integer { min, max } = field.kind else {
        return None;
    };
    let unit_step = matches!(field.step, None | Some(Value::Int(1)));
    let count = max.checked_sub(min)?.checked_add(1)?;
    if field.also.is_empty() || !field.writable || !unit_step || count > MAX_CHOICES {
        return None;
    }
    let mut values: Vec<i128> = (min..=max)
        .chain(field.also.iter().map(|value| i128::from(*value)))
        .collect();
    values.sort_unstable();
    values.dedup();
    Some(values.iter().map(i128::to_string).collect())
}

/// The platform a field is exposed as: the profile's `component` hint when it names a platform
/// that fits the field, otherwise the default for its kind and access (read-only boolean
/// `binary_sensor`, writable boolean `switch`, momentary `button`, read-only number or
/// enumeration `sensor`, writable number `number`, writable enumeration `select`, text `sensor`
/// or `text`).
pub fn platform_for(field: &FieldInfo) -> Platform {
    field
        .ha
        .component
        .as_deref()
        .and_then(Platform::from_name)
        .filter(|platform| platform_fits(*platform, field))
        .unwrap_or_else(|| default_platform(field))
}

/// `device_class` from a unit when the profile gives none. Only classes valid for both
/// `sensor` and `number` are produced.
fn device_class_for_unit(unit: &str) -> Option<&'static str> {
    Some(match unit {
        "°C" | "°F" | "K" => "temperature",
        "Pa" | "kPa" | "hPa" | "mbar" | "bar" | "psi" | "mmHg" | "inHg" => "pressure",
        "s" | "min" | "h" | "d" | "ms" => "duration",
        "V" | "mV" => "voltage",
        "A" | "mA" => "current",
        "W" | "kW" => "power",
        "Hz" => "frequency",
        _ => return None,
    })
}

fn unit_of(field: &FieldInfo) -> Option<&str> {
    field.ha.unit.as_deref().or(field.unit.as_deref())
}

/// A JSON number from a profile bound: integral bounds stay integers so Home Assistant shows
/// `1`, not `1.0`.
fn json_number(value: f64) -> Json {
    if value.fract() == 0.0 && value.abs() < 9.0e15 {
        json!(value as i64)
    } else {
        json!(value)
    }
}

/// The step of a number field: the profile's step (one raw count), else one unit of the last
/// shown place (`2` decimals → `0.01`).
fn number_step(field: &FieldInfo) -> Json {
    let step = match (&field.step, &field.kind) {
        (Some(step), _) => step.clone(),
        (None, FieldKind::Decimal { precision, .. }) if *precision > 0 => Value::Decimal {
            scaled: 1,
            precision: *precision,
        },
        (None, _) => Value::Int(1),
    };
    match step {
        Value::Int(counts) => json!(counts),
        // Through the decimal text: the nearest f64 (0.1, not 0.1000000000000000055…).
        other => other.to_text().parse::<f64>().map_or(json!(1), json_number),
    }
}

/// The component key of a device's command-result event. The `-` keeps it apart from every
/// field (field names have none), so its unique id can equal no field's.
pub const RESULT_EVENT: &str = "command-result";

/// The event entity that makes every command outcome of a device visible in Home Assistant
/// (a refused command included): fed by every `…/result` of the device, one event type per
/// outcome word.
pub fn result_event(ctx: &Topics, device: &str) -> Json {
    let outcomes: Vec<&str> = Outcome::ALL.iter().map(|outcome| outcome.word()).collect();
    json!({
        "p": "event",
        "name": "Command result",
        "unique_id": ctx.unique_id(device, RESULT_EVENT),
        "state_topic": ctx.result_topic(device, "+"),
        "event_types": outcomes,
        "value_template": RESULT_EVENT_TEMPLATE,
        "icon": "mdi:console-line",
        "entity_category": "diagnostic",
    })
}

/// One component of a device document (without the shared keys).
pub fn component(ctx: &Topics, device: &str, field: &FieldInfo) -> Json {
    let platform = platform_for(field);
    let hints: &HaHints = &field.ha;
    let mut config = Map::new();
    let mut put = |key: &str, value: Json| {
        config.insert(key.to_string(), value);
    };

    put("p", json!(platform.as_str()));
    put("name", json!(entity_name(field)));
    put("unique_id", json!(ctx.unique_id(device, &field.name)));
    if platform.has_state() {
        put("state_topic", json!(ctx.state_topic(device, &field.name)));
    }
    if platform.commands() {
        put(
            "command_topic",
            json!(ctx.command_topic(device, &field.name)),
        );
        // Never leave a command retained in the broker on Home Assistant's behalf.
        put("retain", json!(false));
    }
    if let Some(icon) = &hints.icon {
        put("icon", json!(icon));
    }

    // A clock text (`0:0:2`, h:min:s) the profile calls a duration: seconds for Home
    // Assistant, which then shows it as a duration rather than as text.
    let clock = field.kind == FieldKind::Text
        && platform == Platform::Sensor
        && hints.device_class.as_deref() == Some("duration");
    if clock {
        put("value_template", json!(CLOCK_TO_SECONDS));
    }
    // A field the device can leave without a value is published as `unavailable`: Home
    // Assistant shows it as unknown (`None`), never as a stale number or a parse error.
    if field.may_be_unavailable && platform.has_state() && !clock {
        put("value_template", json!(UNAVAILABLE_AS_UNKNOWN));
    }
    let unit = unit_of(field).or(clock.then_some("s"));
    // An enum that publishes unnamed codes as numbers is no closed list to Home Assistant.
    let enumeration =
        matches!(field.kind, FieldKind::Enum { .. }) && !field.unnamed_codes_as_numbers;
    match platform {
        Platform::BinarySensor | Platform::Switch => {
            put("payload_on", json!(PAYLOAD_ON));
            put("payload_off", json!(PAYLOAD_OFF));
        }
        Platform::Button => {
            // A boolean shown as a button (by a hint) takes `ON`; `PRESS` is for momentary
            // fields only.
            let press = if field.kind == FieldKind::Bool {
                PAYLOAD_ON
            } else {
                PAYLOAD_PRESS
            };
            put("payload_press", json!(press));
        }
        Platform::Number => {
            let (min, max) = match &field.kind {
                // The range only: Home Assistant must not offer what the gateway refuses.
                // `also` values of a field too wide for a select show as unknown (the
                // template gives `None`, Home Assistant's reset payload) instead of an
                // out-of-range error.
                FieldKind::Integer { min, max } => {
                    if !field.also.is_empty() {
                        put(
                            "value_template",
                            json!(also_as_unknown(&field.also, field.may_be_unavailable)),
                        );
                    }
                    (json!(min), json!(max))
                }
                FieldKind::Decimal { min, max, .. } => (json_number(*min), json_number(*max)),
                // `platform_fits` admits only numeric kinds here.
                _ => (json!(0), json!(100)),
            };
            put("min", min);
            put("max", max);
            put("step", number_step(field));
            put("mode", json!("box"));
        }
        Platform::Select => match &field.kind {
            FieldKind::Enum { options } => put("options", json!(options)),
            _ => put("options", json!(integer_choices(field).unwrap_or_default())),
        },
        Platform::Sensor => {
            if let (FieldKind::Enum { options }, true) = (&field.kind, enumeration) {
                put("options", json!(options));
            }
            // A `scale_by` number has as many places as its device's exponent gives it.
            if let (FieldKind::Decimal { precision, .. }, None) = (&field.kind, &field.scaled_by) {
                put("suggested_display_precision", json!(precision));
            }
        }
        Platform::Text => {}
    }

    // Home Assistant refuses a unit or a state class on an enumeration sensor, and a select
    // has neither.
    if !enumeration && platform != Platform::Select {
        if let Some(unit) = unit {
            put("unit_of_measurement", json!(unit));
        }
    }

    let device_class = match &hints.device_class {
        Some(class) => Some(class.clone()),
        None if enumeration && platform == Platform::Sensor => Some("enum".to_string()),
        None if is_numeric(&field.kind)
            && matches!(platform, Platform::Sensor | Platform::Number) =>
        {
            unit.and_then(device_class_for_unit).map(str::to_string)
        }
        None if platform == Platform::BinarySensor && name_has_word(&field.name, PROBLEM_WORDS) => {
            Some("problem".to_string())
        }
        None => None,
    };
    if let Some(class) = &device_class {
        put("device_class", json!(class));
    }

    if platform == Platform::Sensor && !enumeration {
        let diagnostic_counter = name_has_word(&field.name, DIAGNOSTIC_WORDS);
        let state_class = match &hints.state_class {
            Some(class) => Some(class.as_str()),
            // A number worth a graph: a live measurement. Flag words and versions are not.
            None if is_numeric(&field.kind) && !diagnostic_counter => Some("measurement"),
            None => None,
        };
        if let Some(class) = state_class {
            put("state_class", json!(class));
        }
    }

    let category = hints
        .entity_category
        .as_deref()
        .or_else(|| default_entity_category(field))
        .map(|category| {
            // Home Assistant refuses `config` on a sensor or binary sensor (only controls can
            // be configuration): a read-only view of a setting is diagnostic.
            let read_only = matches!(platform, Platform::Sensor | Platform::BinarySensor);
            if read_only && category == "config" {
                "diagnostic"
            } else {
                category
            }
        });
    if let Some(category) = category {
        put("entity_category", json!(category));
    }

    Json::Object(config)
}

/// The `o` (origin) block: who published the document.
pub fn origin() -> Json {
    // No `support_url`: the package names no repository, and Home Assistant refuses an
    // empty URL.
    json!({
        "name": "rtu2mqtt",
        "sw_version": env!("CARGO_PKG_VERSION"),
    })
}

/// The availability both a device's entities depend on: the gateway is up and the device
/// answers. `availability_mode: all` makes an entity unavailable when either is `offline`.
fn device_availability(ctx: &Topics, device: &str) -> Json {
    json!([
        {
            "topic": ctx.gateway_status_topic(),
            "payload_available": ONLINE,
            "payload_not_available": OFFLINE,
        },
        {
            "topic": ctx.availability_topic(device),
            "payload_available": ONLINE,
            "payload_not_available": OFFLINE,
        },
    ])
}

/// The discovery document of one device from its profile's identity and fields, before any
/// value is known. The profile only supplies data here, so this is what tests can feed with
/// hand-made fields.
pub fn device_config_from_fields(
    ctx: &Topics,
    device: &str,
    manufacturer: &str,
    model: &str,
    profile_name: &str,
    fields: &[FieldInfo],
) -> (String, Json) {
    let model = DeviceModel {
        manufacturer,
        model,
        profile_name,
    };
    device_document(ctx, device, &model, fields, std::iter::empty(), None)
}

/// Who made a device and which profile describes it: the fixed part of its registry entry.
struct DeviceModel<'a> {
    manufacturer: &'a str,
    model: &'a str,
    profile_name: &'a str,
}

/// A device's document: `dev` (with the identity values known in `state`), the shared keys,
/// one component per field that is not an identity field and per action, and the
/// command-result event when Home Assistant can send the device commands.
fn device_document<'a>(
    ctx: &Topics,
    device: &str,
    model: &DeviceModel<'_>,
    fields: &[FieldInfo],
    actions: impl Iterator<Item = &'a ActionInfo>,
    state: Option<&DeviceState>,
) -> (String, Json) {
    let mut components: Map<String, Json> = fields
        .iter()
        .filter(|field| field.identity.is_none())
        .map(|field| (field.name.clone(), component(ctx, device, field)))
        .collect();
    let has_actions = add_action_components(ctx, device, actions, &mut components);
    if has_actions || fields.iter().any(|field| platform_for(field).commands()) {
        components.insert(RESULT_EVENT.to_string(), result_event(ctx, device));
    }
    let mut dev = json!({
        "identifiers": [ctx.device_id(device)],
        "name": device,
        "manufacturer": model.manufacturer,
        "model": model.model,
        "model_id": model.profile_name,
        "via_device": ctx.gateway_id(),
    });
    if let (Some(entry), Some(state)) = (dev.as_object_mut(), state) {
        for field in fields {
            let Some(identity) = field.identity else {
                continue;
            };
            let text = state
                .get(&field.name)
                .filter(|value| value.is_available())
                .map(Value::to_text);
            if let Some(text) = text.filter(|text| !text.trim().is_empty()) {
                entry.insert(identity.key().to_string(), json!(text));
            }
        }
    }
    let document = json!({
        "dev": dev,
        "o": origin(),
        "availability": device_availability(ctx, device),
        "availability_mode": "all",
        "qos": 1,
        "cmps": components,
    });
    (ctx.config_topic(device), document)
}

/// The retained discovery document of one configured device before any value is known:
/// `(topic, payload)`.
pub fn device_config(ctx: &Topics, device: &str, profile: &Profile) -> (String, Json) {
    device_config_with_state(ctx, device, profile, None)
}

/// The retained discovery document of one configured device, its `dev` entry carrying the
/// serial number and versions from the last known values of the profile's identity fields.
pub fn device_config_with_state(
    ctx: &Topics,
    device: &str,
    profile: &Profile,
    state: Option<&DeviceState>,
) -> (String, Json) {
    let model = DeviceModel {
        manufacturer: profile.manufacturer(),
        model: profile.model(),
        profile_name: profile.name(),
    };
    let actions = profile.actions();
    device_document(ctx, device, &model, profile.fields(), actions, state)
}

/// The device's document again when `updates` (the state about to be published: changed
/// values, or all of them when the device came back) carry an identity field, so the device
/// registry learns the serial number and versions when they first arrive or change. None
/// when no identity field is among them.
pub fn identity_update(
    ctx: &Topics,
    device: &str,
    profile: &Profile,
    state: Option<&DeviceState>,
    updates: &[StateUpdate],
) -> Option<(String, Json)> {
    identity_changed(device, profile, updates)
        .then(|| device_config_with_state(ctx, device, profile, state))
}

/// Whether `updates` change one of `device`'s identity fields (its discovery document then
/// changes).
pub fn identity_changed(device: &str, profile: &Profile, updates: &[StateUpdate]) -> bool {
    updates.iter().any(|update| {
        update.device == device
            && profile
                .field(&update.field)
                .is_some_and(|field| field.identity.is_some())
    })
}

/// Every discovery message of a gateway, ready to publish retained: the gateway's own document
/// first (so `via_device` resolves), its lines' documents, then one per configured device in
/// the order given. `lines` are the configured line names, `devices` the configured devices
/// with their profiles.
pub fn all_configs(
    ctx: &Topics,
    lines: &[String],
    devices: &[(&str, &Profile)],
) -> Vec<(String, String)> {
    let gateway = gateway_config(ctx);
    let lines = lines.iter().map(|line| line_config(ctx, line));
    let devices = devices
        .iter()
        .map(|(device, profile)| device_config(ctx, device, profile));
    std::iter::once(gateway)
        .chain(lines)
        .chain(devices)
        .map(|(topic, document)| (topic, document.to_string()))
        .collect()
}

/// A line's statistics exposed on the gateway device: (key in the line's statistics
/// document, name suffix, unit, state class).
const LINE_SENSORS: &[(&str, &str, Option<&str>, &str)] = &[
    ("bus_load_percent", "bus load", Some("%"), "measurement"),
    ("transactions", "transactions", None, "total_increasing"),
    ("timeouts", "timeouts", None, "total_increasing"),
    ("crc_errors", "CRC errors", None, "total_increasing"),
    ("exceptions", "exceptions", None, "total_increasing"),
];

/// The gateway's own discovery document: a `status` connectivity sensor on the gateway status
/// topic, and from the statistics summary on `<prefix>/gateway/<client_id>/stats`
/// ([`crate::bridge::observers::statistics::stats_json`]) the number of devices online, waiting commands and
/// uptime. It is what every device's `via_device` points at. Each line's sensors are in a
/// document of their own ([`line_config`]), so this one is the same size whatever the number
/// of lines.
pub fn gateway_config(ctx: &Topics) -> (String, Json) {
    let status_topic = ctx.gateway_status_topic();
    let stats_topic = ctx.gateway_stats_topic();
    let mut components = Map::new();
    // No availability on the status itself: it must show `offline`, not `unavailable`.
    components.insert(
        "status".to_string(),
        json!({
            "p": "binary_sensor",
            "name": "Status",
            "unique_id": ctx.unique_id(GATEWAY_DEVICE, "status"),
            "state_topic": status_topic,
            "payload_on": ONLINE,
            "payload_off": OFFLINE,
            "device_class": "connectivity",
            "entity_category": "diagnostic",
        }),
    );
    components.insert(
        "devices_online".to_string(),
        stats_sensor(
            ctx,
            "devices_online",
            "Devices online",
            &stats_topic,
            "{{ value_json.devices_online }}",
            "measurement",
        ),
    );
    components.insert(
        "waiting_commands".to_string(),
        stats_sensor(
            ctx,
            "waiting_commands",
            "Waiting commands",
            &stats_topic,
            "{{ value_json.commands.waiting }}",
            "measurement",
        ),
    );
    let mut uptime = stats_sensor(
        ctx,
        "uptime",
        "Uptime",
        &stats_topic,
        "{{ value_json.uptime_seconds }}",
        "measurement",
    );
    if let Some(map) = uptime.as_object_mut() {
        map.insert("unit_of_measurement".to_string(), json!("s"));
        map.insert("device_class".to_string(), json!("duration"));
    }
    components.insert("uptime".to_string(), uptime);
    (
        ctx.gateway_config_topic(),
        gateway_document(ctx, components),
    )
}

/// One line's sensors on the gateway device, on [`Topics::line_config_topic`]: its bus load
/// and counters from the line's statistics document on `<prefix>/gateway/<client_id>/stats/<line>`
/// ([`crate::bridge::observers::statistics::line_stats_json`]). Home Assistant puts them on the gateway device,
/// whose identifier they name; their unique ids are the gateway's, as when they were in its
/// own document.
pub fn line_config(ctx: &Topics, line: &str) -> (String, Json) {
    let line_key = line.replace('-', "_");
    let line_topic = ctx.line_stats_topic(line);
    let mut components = Map::new();
    for (key, label, unit, state_class) in LINE_SENSORS {
        let component_id = format!("{line_key}_{key}");
        let template = format!("{{{{ value_json.{key} }}}}");
        let mut sensor = stats_sensor(
            ctx,
            &component_id,
            &format!("{line} {label}"),
            &line_topic,
            &template,
            state_class,
        );
        if let (Some(unit), Some(map)) = (unit, sensor.as_object_mut()) {
            map.insert("unit_of_measurement".to_string(), json!(unit));
        }
        components.insert(component_id, sensor);
    }
    (
        ctx.line_config_topic(line),
        gateway_document(ctx, components),
    )
}

/// A sensor of the gateway device reading `template` from the statistics on `topic`,
/// available while the gateway is online.
fn stats_sensor(
    ctx: &Topics,
    key: &str,
    name: &str,
    topic: &str,
    template: &str,
    state_class: &str,
) -> Json {
    json!({
        "p": "sensor",
        "name": name,
        "unique_id": ctx.unique_id(GATEWAY_DEVICE, key),
        "state_topic": topic,
        "value_template": template,
        "state_class": state_class,
        "availability": [{
            "topic": ctx.gateway_status_topic(),
            "payload_available": ONLINE,
            "payload_not_available": OFFLINE,
        }],
        "entity_category": "diagnostic",
    })
}

/// A discovery document of the gateway device holding `components`.
fn gateway_document(ctx: &Topics, components: Map<String, Json>) -> Json {
    json!({
        "dev": {
            "identifiers": [ctx.gateway_id()],
            "name": ctx.client_id,
            "manufacturer": "rtu2mqtt",
            "model": "Modbus RTU to MQTT gateway",
            "sw_version": env!("CARGO_PKG_VERSION"),
        },
        "o": origin(),
        "qos": 1,
        "cmps": components,
    })
}

/// The removal of a device's discovery document: its topic and the empty retained payload
/// that makes Home Assistant drop the device and the broker forget the document.
pub fn removal(ctx: &Topics, device: &str) -> (String, Vec<u8>) {
    (ctx.config_topic(device), Vec::new())
}

/// [`is_stale_device_config`] of the device a config topic seen on [`Topics::config_filter`]
/// names; false for any other topic.
pub fn is_stale_config(ctx: &Topics, topic: &str, payload: &[u8], configured: &[String]) -> bool {
    let TopicKind::DeviceConfig { device } = ctx.classify(topic) else {
        return false;
    };
    is_stale_device_config(ctx, device, payload, configured)
}

/// Whether `payload`, retained on `device`'s config topic, is a document this gateway
/// published for a device no longer configured, to be cleared with [`removal`].
///
/// The topic alone is not proof: with client ids `edge` and `edge_b`, `edge_b_valve` matches
/// both. So the document itself must name this gateway as its `via_device`. Empty payloads
/// (already removed) and the gateway's own document are never stale.
pub fn is_stale_device_config(
    ctx: &Topics,
    device: &str,
    payload: &[u8],
    configured_devices: &[String],
) -> bool {
    if device == GATEWAY_DEVICE || configured_devices.iter().any(|name| name == device) {
        return false;
    }
    let Ok(document) = serde_json::from_slice::<Json>(payload) else {
        return false;
    };
    let via = document
        .get("dev")
        .or_else(|| document.get("device"))
        .and_then(|dev| dev.get("via_device").or_else(|| dev.get("via_dev")))
        .and_then(Json::as_str);
    via == Some(ctx.gateway_id().as_str())
}

/// A random delay in [`REANNOUNCE_DELAY`] before re-publishing discovery after Home
/// Assistant's birth message.
pub fn reannounce_delay<R: Rng + ?Sized>(rng: &mut R) -> Duration {
    rng.gen_range(REANNOUNCE_DELAY)
}

/// `unique_id`s that two configured fields would share (device `a` with field `b_c` and device
/// `a_b` with field `c` both give `<client_id>_a_b_c`). Empty for a sound configuration; the
/// configuration check reports any as an error, since Home Assistant would drop one entity.
pub fn unique_id_collisions(ctx: &Topics, devices: &[(&str, &[FieldInfo])]) -> Vec<String> {
    ctx.unique_id_collisions(devices.iter().flat_map(|(device, fields)| {
        fields
            .iter()
            .map(move |field| (*device, field.name.as_str()))
    }))
}
