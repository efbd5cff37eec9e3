//! Loading the configuration: the TOML file, then `RTU2MQTT__SECTION__KEY` environment
//! overrides, layered into one tree by the `config` crate, then read into [`RawConfig`] by
//! `read`. Every unknown key, missing required key and wrongly typed value is reported with
//! its place, in our words; a problem in a value from the environment names its variable. No
//! validation beyond types here.

use std::collections::HashMap;
use std::path::Path;

use config::{Environment, File, FileFormat};

use super::deserialize::{read_leniently, Loaded};
use super::problem::{Problem, Problems};
use super::schema::RawConfig;
use super::tree::Tree;

/// Environment variables that override file keys start with this (`RTU2MQTT__MQTT__PASSWORD`).
pub const ENV_PREFIX: &str = "RTU2MQTT";
/// Separates the prefix and the key levels in an environment variable name.
pub const ENV_SEPARATOR: &str = "__";

/// One environment variable that sets a configuration key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EnvOverride {
    /// As written in the environment (`RTU2MQTT__MQTT__KEEP_ALIVE`).
    pub variable: String,
    /// The key it sets (`mqtt.keep_alive`).
    pub place: String,
}

/// Reads `path`, then applies the process environment's overrides.
pub fn load_file(path: &Path) -> Result<RawConfig, Problems> {
    load_file_with_env(path, None)
}

/// Like [`load_file`] with an explicit environment (tests); `None` reads the process's.
/// A problem in a value set from the environment names its variable.
pub fn load_file_with_env(
    path: &Path,
    env: Option<HashMap<String, String>>,
) -> Result<RawConfig, Problems> {
    load_file_lenient(path, env)?.strict()
}

/// Like [`load_file_with_env`], but a problem of the reading stage does not end the reading
/// ([`Loaded`]). Err only when the file cannot be read or parsed at all.
pub fn load_file_lenient(
    path: &Path,
    env: Option<HashMap<String, String>>,
) -> Result<Loaded, Problems> {
    let vars = env.map_or_else(process_environment, Ok)?;
    let overrides = env_overrides(&vars);
    let text = read_file(path)?;
    let file = File::from_str(&text, FileFormat::Toml);
    let mut loaded = layer_and_read(config::Config::builder().add_source(file), vars)
        .map_err(|problems| blame_overrides(problems, &overrides, true))?;
    loaded.problems = blame_overrides(Problems(loaded.problems), &overrides, true).0;
    Ok(loaded)
}

/// Like [`load_str`], lenient like [`load_file_lenient`].
pub fn load_str_lenient(text: &str) -> Result<Loaded, Problems> {
    let file = File::from_str(text, FileFormat::Toml);
    layer_and_read(config::Config::builder().add_source(file), HashMap::new())
}

/// Parses configuration text (no environment overrides): for tests and `check` of snippets.
pub fn load_str(text: &str) -> Result<RawConfig, Problems> {
    load_str_lenient(text)?.strict()
}

/// The process's environment variables. A variable of ours whose name or value is not text is a
/// problem of its own; other variables are none of our business.
pub fn process_environment() -> Result<HashMap<String, String>, Problems> {
    let ours = format!("{ENV_PREFIX}{ENV_SEPARATOR}").to_lowercase();
    let mut vars = HashMap::new();
    let mut problems = Vec::new();
    for (name, value) in std::env::vars_os() {
        match (name.into_string(), value.into_string()) {
            (Ok(name), Ok(value)) => {
                vars.insert(name, value);
            }
            (Ok(name), Err(_)) if name.to_lowercase().starts_with(&ours) => {
                problems.push(Problem::new(name, "the value is not valid UTF-8 text"));
            }
            _ => {}
        }
    }
    if problems.is_empty() {
        Ok(vars)
    } else {
        Err(Problems(problems))
    }
}

/// The configuration keys `vars` set, named the way the `config` crate's [`Environment`] reads
/// them: prefix and separator case-insensitive, key levels lower-cased.
pub fn env_overrides(vars: &HashMap<String, String>) -> Vec<EnvOverride> {
    let ours = format!("{ENV_PREFIX}{ENV_SEPARATOR}").to_lowercase();
    let mut overrides: Vec<EnvOverride> = vars
        .keys()
        .filter_map(|variable| {
            let lower = variable.to_lowercase();
            let key = lower.strip_prefix(&ours)?;
            Some(EnvOverride {
                variable: variable.clone(),
                place: key.replace(ENV_SEPARATOR, "."),
            })
        })
        .collect();
    overrides.sort_by(|a, b| a.variable.cmp(&b.variable));
    overrides
}

/// Names the environment variable behind each problem whose value it set. With `structure`,
/// also a problem with a table or list that a variable reached into (`lines` made a table by
/// `RTU2MQTT__LINES__0__PORT`): only the reading stage has such problems.
pub fn blame_overrides(
    mut problems: Problems,
    overrides: &[EnvOverride],
    structure: bool,
) -> Problems {
    for problem in &mut problems.0 {
        if problem.variable.is_some() || problem.place.is_empty() {
            continue;
        }
        if let Some(culprit) = overrides
            .iter()
            .find(|o| is_within(&problem.place, &o.place))
        {
            problem.variable = Some(culprit.variable.clone());
        } else if let Some(culprit) = overrides
            .iter()
            .find(|o| structure && is_within(&o.place, &problem.place))
        {
            problem.variable = Some(culprit.variable.clone());
            if problem.place.starts_with("lines") {
                problem
                    .reason
                    .push_str("; the environment cannot set a key of one line or device");
            }
        }
    }
    problems
}

/// `place` is `ancestor` or lies inside it (`lines[0].baud` inside `lines`).
pub fn is_within(place: &str, ancestor: &str) -> bool {
    place
        .strip_prefix(ancestor)
        .is_some_and(|rest| rest.is_empty() || rest.starts_with('.') || rest.starts_with('['))
}

fn read_file(path: &Path) -> Result<String, Problems> {
    let problem = |reason: String| Problems::one(path.display().to_string(), reason);
    match std::fs::metadata(path) {
        Ok(metadata) if metadata.is_dir() => {
            return Err(problem(
                "is a directory; --config takes the configuration file itself \
                 (such as /etc/rtu2mqtt/config.toml)"
                    .to_string(),
            ))
        }
        Ok(_) => {}
        Err(error) => {
            return Err(problem(format!(
                "cannot read the configuration file: {error}"
            )))
        }
    }
    std::fs::read_to_string(path)
        .map_err(|error| problem(format!("cannot read the configuration file: {error}")))
}

fn layer_and_read(
    builder: config::ConfigBuilder<config::builder::DefaultState>,
    vars: HashMap<String, String>,
) -> Result<Loaded, Problems> {
    let env_text: HashMap<String, String> = env_overrides(&vars)
        .into_iter()
        .filter_map(|o| Some((o.place, vars.get(&o.variable)?.clone())))
        .collect();
    // Environment text typed by its look (`10` an integer, `true` a boolean); the reading
    // types it again by the key it sets where the look was wrong (a password `1e5` is text).
    let environment = Environment::with_prefix(ENV_PREFIX)
        .separator(ENV_SEPARATOR)
        .try_parsing(true)
        .source(Some(vars.into_iter().collect()));
    let merged = builder
        .add_source(environment)
        .build()
        .map_err(|error| Problems::one("", error.to_string().trim_end()))?;
    Ok(read_leniently(Tree::new(merged.cache, env_text)))
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

    fn reasons(problems: &Problems) -> Vec<String> {
        problems.0.iter().map(ToString::to_string).collect()
    }

    #[test]
    fn lists_unknown_keys_missing_keys_and_wrong_types_together_in_one_wording() {
        let text = MINIMAL
            .replace("client_id = \"edge1\"", "colour = 1\ninflight = 70000")
            .replace(
                "port = \"/dev/ttyUSB0\"",
                "port = \"/dev/ttyUSB0\"\nbaud = \"fast\"\nparity = \"mark\"\necho = 2",
            )
            .replace("address = 0x81", "address = 1.5")
            .replace("\"300ms\"", "\"soon\"");
        let problems = load_str(&text).unwrap_err();
        assert_eq!(
            reasons(&problems)
                .iter()
                .map(|line| line.split(" (known here").next().unwrap())
                .collect::<Vec<_>>(),
            [
                "mqtt.colour: unknown key",
                "mqtt.client_id: required, but not set",
                "mqtt.inflight: 70000 is out of range (0 to 65535)",
                "lines[0].baud: \"fast\" is not an integer",
                "lines[0].parity: \"mark\" is not one of none, even, odd",
                "lines[0].echo: 2 is not true or false",
                "lines[0].devices[0].address: 1.5 is not an integer",
                "lines[0].devices[0].poll_interval: \"soon\" is not a duration (such as \"300ms\", \"2s\" or \"5m\")",
            ],
            "{problems}"
        );
    }

    #[test]
    fn a_table_or_list_of_the_wrong_shape_is_named() {
        let problems = load_str("mqtt = 5\nlines = \"a\"").unwrap_err();
        assert_eq!(
            reasons(&problems),
            [
                "mqtt: 5 is not a table",
                "lines: \"a\" is not a list of tables"
            ]
        );
    }

    fn write_minimal() -> (tempfile::TempDir, std::path::PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("config.toml");
        std::fs::write(&path, MINIMAL).unwrap();
        (dir, path)
    }

    #[test]
    fn a_problem_in_an_environment_value_names_the_variable() {
        let (_dir, path) = write_minimal();
        let env = HashMap::from([
            ("RTU2MQTT__MQTT__COLOUR".to_string(), "x".to_string()),
            ("RTU2MQTT__MQTT__INFLIGHT".to_string(), "lots".to_string()),
            ("RTU2MQTT__MQTT__PREFIX".to_string(), "site".to_string()),
        ]);
        let problems = load_file_with_env(&path, Some(env)).unwrap_err();
        let lines = reasons(&problems);
        assert_eq!(lines.len(), 2, "{problems}");
        assert!(
            lines[0].starts_with("RTU2MQTT__MQTT__COLOUR (environment, mqtt.colour): unknown key"),
            "{problems}"
        );
        assert_eq!(
            lines[1],
            "RTU2MQTT__MQTT__INFLIGHT (environment, mqtt.inflight): \"lots\" is not an integer"
        );
    }

    #[test]
    fn a_validation_problem_in_an_environment_value_names_the_variable() {
        let (_dir, path) = write_minimal();
        let env = HashMap::from([(
            "RTU2MQTT__MQTT__KEEP_ALIVE".to_string(),
            "500ms".to_string(),
        )]);
        let problems = crate::config::load_with_env(&path, env).unwrap_err();
        let keep_alive = problems
            .0
            .iter()
            .find(|problem| problem.place == "mqtt.keep_alive")
            .unwrap();
        assert_eq!(
            keep_alive.variable.as_deref(),
            Some("RTU2MQTT__MQTT__KEEP_ALIVE"),
            "{problems}"
        );
        // A problem the file alone causes stays the file's.
        let problems = crate::config::load_with_env(&path, HashMap::new()).unwrap_err();
        assert!(
            problems.0.iter().all(|p| p.variable.is_none()),
            "{problems}"
        );
    }

    #[test]
    fn an_override_reaching_into_the_lines_is_blamed_for_breaking_them() {
        let (_dir, path) = write_minimal();
        let env = HashMap::from([("RTU2MQTT__LINES__0__BAUD".to_string(), "4800".to_string())]);
        let problems = load_file_with_env(&path, Some(env)).unwrap_err();
        assert_eq!(problems.0.len(), 1, "{problems}");
        assert_eq!(problems.0[0].place, "lines");
        assert_eq!(
            problems.0[0].variable.as_deref(),
            Some("RTU2MQTT__LINES__0__BAUD")
        );
    }

    #[test]
    fn a_directory_given_as_the_file_is_called_a_directory() {
        let dir = tempfile::tempdir().unwrap();
        let problems = load_file_with_env(dir.path(), Some(HashMap::new())).unwrap_err();
        assert!(
            problems.to_string().contains("is a directory"),
            "{problems}"
        );
        assert!(!problems.to_string().contains("not found"), "{problems}");
    }

    #[test]
    fn every_key_the_structs_take_is_read() {
        let text = r#"
[mqtt]
url = "mqtt://127.0.0.1:1883"
client_id = "edge1"
prefix = "site"
username = "gw"
password = "secret"
password_file = "/run/secrets/mqtt"
ca_file = "ca.pem"
cert_file = "cert.pem"
key_file = "key.pem"
keep_alive = "45s"
clean_session = true
inflight = 10
discovery = false
discovery_prefix = "ha"

[gateway]
command_ttl = "1m"
json_view = true
stats_interval = "30s"
metrics_listen = "127.0.0.1:9184"
frame_log = "frames.log"
allow_raw_writes = true
max_payload = 2048

[health]
status_file = ""
interval = "5s"
stale_after = "30s"
stall_limit = "2m"

[[lines]]
name = "line-a"
port = "/dev/ttyUSB0"
baud = 19200
parity = "odd"
data_bits = 8
stop_bits = 2
response_timeout = "300ms"
retries = 2
offline_after = 4
echo = true
broadcast_turnaround = "250ms"
rs485 = { rts_on_send = false, delay_before_send = "1ms", delay_after_send = "2ms" }

[[lines.devices]]
name = "valve"
profile = "wuzhou-valve"
address = 3
poll_interval = "2s"
"#;
        let raw = load_str(text).unwrap();
        assert_eq!(raw.lines[0].stop_bits, 2);
        assert_eq!(raw.gateway.max_payload, 2048);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(300))]

        /// Whatever keys and values a file holds, reading ends with the configuration or
        /// with problems, each placed.
        #[test]
        fn reading_any_file_ends_with_placed_problems(
            entries in proptest::collection::vec(
                (
                    proptest::sample::select(vec![
                        "mqtt", "mqtt.url", "mqtt.client_id", "mqtt.inflight", "mqtt.password",
                        "gateway", "gateway.json_view", "lines", "sparkplug", "sparkplug.mqtt",
                        "sparkplug.group_id", "health.interval", "colour",
                    ]),
                    proptest::sample::select(vec![
                        "1", "70000", "1.5", "true", "\"x\"", "\"5s\"", "{}", "[]", "[{}]",
                        "[1]", "{ name = 2 }", "[{ name = \"a\", devices = [{}] }]",
                    ]),
                ),
                0..8,
            )
        ) {
            let text: String = entries
                .iter()
                .map(|(key, value)| format!("{key} = {value}\n"))
                .collect();
            // A key given twice ends at the TOML parser; everything else is read.
            let Ok(loaded) = load_str_lenient(&text) else {
                return Ok(());
            };
            for problem in &loaded.problems {
                proptest::prop_assert!(!problem.reason.is_empty(), "{problem}");
            }
            proptest::prop_assert!(loaded.raw.is_some() || !loaded.problems.is_empty());
        }

        #[test]
        fn reading_nested_tables_of_any_shape_ends(
            mqtt in proptest::sample::select(vec!["", "url = 1", "client_id = []", "x = 1"]),
            line in proptest::sample::select(vec![
                "", "name = 1", "devices = 5", "devices = [1, {}]", "rs485 = 3",
                "rs485 = { rts_on_send = \"x\" }", "parity = 1", "baud = -1",
            ]),
            device in proptest::sample::select(vec![
                "", "address = \"a\"", "name = []", "poll_interval = 1", "x = 2",
            ]),
        ) {
            let text = format!(
                "[mqtt]\n{mqtt}\n[[lines]]\n{line}\n[[lines.devices]]\n{device}\n"
            );
            let Ok(loaded) = load_str_lenient(&text) else {
                return Ok(());
            };
            proptest::prop_assert!(loaded.raw.is_some() || !loaded.problems.is_empty());
        }
    }
}
