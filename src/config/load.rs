//! Reading the configuration: the TOML file, then `RTU2MQTT__SECTION__KEY` environment
//! overrides (the `config` crate), into [`RawConfig`]. Every unknown key is reported with its
//! place before serde gets to stop at the first one. No validation beyond types here.

use std::collections::HashMap;
use std::path::Path;

use config::{Environment, File, FileFormat};
use serde_json::Value as Json;

use super::schema::{
    RawConfig, DEVICE_KEYS, GATEWAY_KEYS, HEALTH_KEYS, LINE_KEYS, MQTT_KEYS, RS485_KEYS, TOP_KEYS,
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
    if let Some(health) = tree.get("health") {
        check_table(health, "health", HEALTH_KEYS, &mut problems);
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

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
[mqtt]
url = "mqtt://127.0.0.1:1883"
client_id = "edge1"

[[lines]]
name = "line-a"
port = "/dev/ttyUSB0"

[[lines.devices]]
name = "valve"
profile = "wuzhou-valve"
address = 0x81
poll_interval = "300ms"
"#;

    #[test]
    fn reads_hex_addresses_durations_and_defaults() {
        let raw = load_str(MINIMAL).unwrap();
        assert_eq!(raw.mqtt.prefix, "plant");
        assert!(raw.mqtt.discovery);
        let device = &raw.lines[0].devices[0];
        assert_eq!(device.address, 0x81);
        assert_eq!(
            device.poll_interval,
            Some(std::time::Duration::from_millis(300))
        );
        assert_eq!(raw.lines[0].retries, 1);
        assert_eq!(raw.gateway.command_ttl, std::time::Duration::from_secs(300));
    }

    #[test]
    fn lists_every_unknown_key_with_its_place() {
        let text = MINIMAL
            .replace("client_id", "colour = 1\nclient_id")
            .replace("poll_interval", "adress = 3\npoll_interval")
            .replace("[[lines]]", "typo = true\n[[lines]]");
        let problems = load_str(&text).unwrap_err();
        let places: Vec<&str> = problems.0.iter().map(|p| p.place.as_str()).collect();
        assert_eq!(
            places,
            ["mqtt.colour", "mqtt.typo", "lines[0].devices[0].adress"],
            "{problems}"
        );
    }

    #[test]
    fn environment_overrides_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("config.toml");
        std::fs::write(&path, MINIMAL).unwrap();
        let env = HashMap::from([
            ("RTU2MQTT__MQTT__PASSWORD".to_string(), "1e5".to_string()),
            ("RTU2MQTT__MQTT__USERNAME".to_string(), "gw".to_string()),
            ("RTU2MQTT__MQTT__KEEP_ALIVE".to_string(), "45s".to_string()),
            (
                "RTU2MQTT__GATEWAY__JSON_VIEW".to_string(),
                "true".to_string(),
            ),
            ("RTU2MQTT_CONFIG".to_string(), "/elsewhere".to_string()),
        ]);
        let raw = load_file_with_env(&path, Some(env)).unwrap();
        // Text stays text: a password that looks like a number is not reformatted.
        assert_eq!(raw.mqtt.password.as_deref(), Some("1e5"));
        assert_eq!(raw.mqtt.username.as_deref(), Some("gw"));
        assert_eq!(raw.mqtt.keep_alive, std::time::Duration::from_secs(45));
        assert!(raw.gateway.json_view);
    }

    #[test]
    fn a_missing_file_and_bad_toml_are_reported() {
        let missing = load_file_with_env(Path::new("/nonexistent/rtu2mqtt.toml"), None);
        assert!(missing.unwrap_err().to_string().contains("cannot read"));
        assert!(load_str("[mqtt\nurl=").is_err());
        let wrong_type = load_str(&MINIMAL.replace("address = 0x81", "address = \"one\""));
        assert!(wrong_type.unwrap_err().to_string().contains("address"));
    }
}
