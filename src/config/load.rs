//! Reading the configuration: the TOML file, then `RTU2MQTT__SECTION__KEY` environment
//! overrides (the `config` crate), into [`RawConfig`]. Every unknown key is reported with its
//! place before serde gets to stop at the first one. No validation beyond types here.

use std::collections::HashMap;
use std::path::Path;

use config::{Environment, File, FileFormat};
use serde_json::Value as Json;

use super::schema::{
    RawConfig, DEVICE_KEYS, GATEWAY_KEYS, LINE_KEYS, MQTT_KEYS, RS485_KEYS, TOP_KEYS,
};
use super::{Problem, Problems};

/// Environment variables that override file keys start with this (`RTU2MQTT__MQTT__PASSWORD`).
pub const ENV_PREFIX: &str = "RTU2MQTT";
/// Separates the prefix and the key levels in an environment variable name.
pub const ENV_SEPARATOR: &str = "__";

/// Reads `path`, then applies the process environment's overrides.
pub fn load_file(path: &Path) -> Result<RawConfig, Problems> {
    load_file_with_env(path, None)
}

/// Like [`load_file`] with an explicit environment (tests); `None` reads the process's.
pub fn load_file_with_env(
    path: &Path,
    env: Option<HashMap<String, String>>,
) -> Result<RawConfig, Problems> {
    // `config` would report a missing file as a key lookup failure; say what it is.
    if let Err(error) = std::fs::metadata(path) {
        return Err(Problems::one(
            path.display().to_string(),
            format!("cannot read the configuration file: {error}"),
        ));
    }
    let file = File::from(path).format(FileFormat::Toml).required(true);
    build(config::Config::builder().add_source(file), env)
}

/// Parses configuration text (no environment overrides): for tests and `check` of snippets.
pub fn load_str(text: &str) -> Result<RawConfig, Problems> {
    let file = File::from_str(text, FileFormat::Toml);
    build(
        config::Config::builder().add_source(file),
        Some(HashMap::new()),
    )
}

fn build(
    builder: config::ConfigBuilder<config::builder::DefaultState>,
    env: Option<HashMap<String, String>>,
) -> Result<RawConfig, Problems> {
    // No `try_parsing`: a password such as `1e5` must stay text; typed fields parse strings.
    let environment = Environment::with_prefix(ENV_PREFIX)
        .separator(ENV_SEPARATOR)
        .source(env.map(|vars| vars.into_iter().collect()));
    let merged = builder
        .add_source(environment)
        .build()
        .map_err(|error| Problems::one("", error.to_string()))?;

    let tree: Json = merged
        .clone()
        .try_deserialize()
        .map_err(|error| Problems::one("", error.to_string()))?;
    let unknown = unknown_keys(&tree);
    if !unknown.is_empty() {
        return Err(Problems(unknown));
    }
    merged
        .try_deserialize::<RawConfig>()
        .map_err(|error| Problems::one("", error.to_string()))
}

/// Every key the schema does not know, with its place (`lines[0].devices[1].adress`).
fn unknown_keys(tree: &Json) -> Vec<Problem> {
    let mut problems = Vec::new();
    check_table(tree, "", TOP_KEYS, &mut problems);
    if let Some(mqtt) = tree.get("mqtt") {
        check_table(mqtt, "mqtt", MQTT_KEYS, &mut problems);
    }
    if let Some(gateway) = tree.get("gateway") {
        check_table(gateway, "gateway", GATEWAY_KEYS, &mut problems);
    }
    if let Some(Json::Array(lines)) = tree.get("lines") {
        for (line_index, line) in lines.iter().enumerate() {
            let place = format!("lines[{line_index}]");
            check_table(line, &place, LINE_KEYS, &mut problems);
            if let Some(rs485) = line.get("rs485") {
                check_table(rs485, &format!("{place}.rs485"), RS485_KEYS, &mut problems);
            }
            if let Some(Json::Array(devices)) = line.get("devices") {
                for (device_index, device) in devices.iter().enumerate() {
                    let place = format!("{place}.devices[{device_index}]");
                    check_table(device, &place, DEVICE_KEYS, &mut problems);
                }
            }
        }
    }
    problems
}

fn check_table(table: &Json, place: &str, known: &[&str], problems: &mut Vec<Problem>) {
    let Json::Object(map) = table else {
        return;
    };
    let mut keys: Vec<&String> = map.keys().collect();
    keys.sort();
    for key in keys {
        if !known.contains(&key.as_str()) {
            let at = if place.is_empty() {
                key.clone()
            } else {
                format!("{place}.{key}")
            };
            problems.push(Problem::new(
                at,
                format!("unknown key (known here: {})", known.join(", ")),
            ));
        }
    }
}
