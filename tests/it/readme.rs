//! The README and ARCHITECTURE.md stay true to the code: the quick start's two commands, the
//! configuration reference's keys, the Home Assistant section copied from its source, the
//! module map.

const README: &str = include_str!("../../README.md");
const ARCHITECTURE: &str = include_str!("../../ARCHITECTURE.md");
const LIB: &str = include_str!("../../src/lib.rs");
const CI: &str = include_str!("../../.ci/run");
const HOME_ASSISTANT: &str = include_str!("../../docs/home-assistant.md");

/// The text between the heading `## {title}` and the next `## ` heading.
fn section<'a>(text: &'a str, title: &str) -> &'a str {
    let heading = format!("\n## {title}\n");
    let start = text
        .find(&heading)
        .unwrap_or_else(|| panic!("no section {title:?}"))
        + heading.len();
    let end = text[start..]
        .find("\n## ")
        .map_or(text.len(), |end| start + end);
    &text[start..end]
}

/// The contents of the fenced code blocks of `text`.
fn code_blocks(text: &str) -> Vec<String> {
    text.split("```")
        .skip(1)
        .step_by(2)
        .map(|block| {
            block
                .split_once('\n')
                .map_or("", |(_, body)| body)
                .to_string()
        })
        .collect()
}

#[test]
fn quick_start_is_two_commands_and_ci_runs_the_second() {
    let quick_start = section(README, "Quick start");
    let blocks = code_blocks(quick_start);
    let commands: Vec<&str> = blocks[1]
        .lines()
        .map(|line| line.split('#').next().unwrap_or_default().trim())
        .filter(|line| !line.is_empty())
        .collect();
    assert_eq!(commands, vec!["cargo run --release -- demo", "cargo test"]);
    assert!(
        CI.lines()
            .any(|line| line.trim().starts_with("cargo test") && !line.contains("--test ")),
        ".ci/run must run the README's test command"
    );
}

#[test]
fn configuration_reference_lists_every_key_and_no_other() {
    use rtu2mqtt::config::schema::{
        DEVICE_KEYS, GATEWAY_KEYS, HEALTH_KEYS, LINE_KEYS, MQTT_KEYS, RS485_KEYS,
    };
    let reference = section(README, "Configuration reference");
    for (table, keys) in [
        ("### `[mqtt]`", MQTT_KEYS),
        ("### `[gateway]`", GATEWAY_KEYS),
        ("### `[health]`", HEALTH_KEYS),
        ("### `[[lines]]`", LINE_KEYS),
        ("### `[[lines.devices]]`", DEVICE_KEYS),
    ] {
        let start = reference
            .find(table)
            .unwrap_or_else(|| panic!("no table {table}"));
        let rest = &reference[start + table.len()..];
        let body = &rest[..rest.find("\n### ").unwrap_or(rest.len())];
        let documented: Vec<&str> = body
            .lines()
            .filter(|line| line.starts_with("| `"))
            .flat_map(|line| {
                let first_cell = line.split('|').nth(1).unwrap_or_default();
                first_cell
                    .split(',')
                    .map(|key| key.trim().trim_matches('`'))
                    .collect::<Vec<_>>()
            })
            .collect();
        for key in keys {
            if *key == "devices" {
                continue; // the [[lines.devices]] table itself
            }
            assert!(documented.contains(key), "{table}: `{key}` undocumented");
        }
        for key in &documented {
            assert!(keys.contains(key), "{table}: `{key}` is not a key");
        }
        if *table == *"### `[[lines]]`" {
            for key in RS485_KEYS {
                assert!(
                    body.contains(&format!("`{key}`")),
                    "rs485.{key} undocumented"
                );
            }
        }
    }
}

#[test]
fn home_assistant_section_is_the_discovery_documentation() {
    let begin = "<!-- BEGIN docs/home-assistant.md -->\n";
    let end = "<!-- END docs/home-assistant.md -->";
    let start = README.find(begin).expect("begin marker") + begin.len();
    let stop = README.find(end).expect("end marker");
    assert!(
        README[start..stop] == *HOME_ASSISTANT,
        "README.md's Home Assistant section differs from docs/home-assistant.md: run \
         .ci/sync-readme"
    );
}

#[test]
fn architecture_maps_every_module_of_the_crate() {
    let modules: Vec<&str> = LIB
        .lines()
        .filter_map(|line| line.strip_prefix("pub mod "))
        .map(|name| name.trim_end_matches(';'))
        .collect();
    assert!(modules.len() >= 10, "{modules:?}");
    let map = section(ARCHITECTURE, "Module map");
    for module in modules {
        assert!(
            map.contains(&format!("| `{module}` |")),
            "ARCHITECTURE.md's module map lacks `{module}`"
        );
    }
}

#[test]
fn quick_start_pokes_the_plant_with_the_demos_own_example_commands() {
    let config = rtu2mqtt::config::from_str(
        include_str!("../../config/rtu2mqtt.toml"),
        std::path::Path::new("config"),
    )
    .unwrap_or_else(|problems| panic!("the example configuration: {problems:?}"));
    let prefix = &config.mqtt.prefix;
    let from_profiles: Vec<String> = config
        .lines
        .iter()
        .flat_map(|line| &line.devices)
        .flat_map(|device| {
            device
                .profile
                .example_commands()
                .into_iter()
                .map(|(field, value)| {
                    format!(
                        "mosquitto_pub -t {prefix}/{}/{field}/set -m {value}",
                        device.name
                    )
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let quick_start = section(README, "Quick start");
    let in_readme: Vec<String> = code_blocks(quick_start)
        .iter()
        .flat_map(|block| block.lines().map(str::to_string).collect::<Vec<_>>())
        .filter(|line| line.starts_with("mosquitto_pub "))
        .map(|line| {
            line.split('#')
                .next()
                .unwrap_or_default()
                .trim()
                .to_string()
        })
        .collect();
    assert!(!from_profiles.is_empty());
    assert_eq!(
        in_readme, from_profiles,
        "the README's commands are the ones the demo prints (the profiles' examples)"
    );
}
