//! The README, docs/ and ARCHITECTURE.md stay true to the code: the quick start's two
//! commands, the configuration reference's keys, the module map, and every relative link
//! between the documents.

use std::path::{Path, PathBuf};

const README: &str = include_str!("../../../README.md");
const ARCHITECTURE: &str = include_str!("../../../ARCHITECTURE.md");
const CI: &str = include_str!("../../../.ci/run");
const CONFIGURATION: &str = include_str!("../../../docs/configuration.md");
/// The README stays a first read; everything else lives in docs/.
const README_MAX_LINES: usize = 400;

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
    assert_eq!(
        commands,
        vec!["cargo run --release -p rtu2mqtt-demo", "cargo test"]
    );
    assert!(
        CI.lines()
            .any(|line| line.trim().starts_with("cargo test") && !line.contains("--test ")),
        ".ci/run must run the README's test command"
    );
}

#[test]
fn configuration_reference_lists_every_key_and_no_other() {
    use rtu2mqtt::config::history::RawHistory;
    use rtu2mqtt::config::keys_of;
    use rtu2mqtt::config::schema::{RawDevice, RawGateway, RawLine, RawMqtt, RawRs485, RawServe};
    use rtu2mqtt::config::HealthSettings;
    let history_keys = keys_of::<RawHistory>();
    let (mqtt_keys, gateway_keys, health_keys) = (
        keys_of::<RawMqtt>(),
        keys_of::<RawGateway>(),
        keys_of::<HealthSettings>(),
    );
    let (line_keys, device_keys, rs485_keys) = (
        keys_of::<RawLine>(),
        keys_of::<RawDevice>(),
        keys_of::<RawRs485>(),
    );
    assert!(
        !rs485_keys.is_empty(),
        "the key names of [lines.rs485] are not derived"
    );
    let reference = section(CONFIGURATION, "Configuration reference");
    for (table, keys) in [
        ("### `[mqtt]`", mqtt_keys),
        ("### `[gateway]`", gateway_keys),
        ("### `[health]`", health_keys),
        ("### `[history]`", history_keys),
        ("### `[web]`", keys_of::<rtu2mqtt::config::web::RawWeb>()),
        ("### `[[lines]]`", line_keys),
        ("### `[[lines.devices]]`", device_keys),
        ("### `[lines.serve]`", keys_of::<RawServe>()),
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
            for key in rs485_keys {
                assert!(
                    body.contains(&format!("`{key}`")),
                    "rs485.{key} undocumented"
                );
            }
        }
    }
}

#[test]
fn the_readme_is_short_and_links_every_document() {
    let lines = README.lines().count();
    assert!(
        lines <= README_MAX_LINES,
        "README.md has {lines} lines; move detail into docs/"
    );
    for doc in markdown_files()
        .iter()
        .filter(|path| path.starts_with("docs"))
    {
        let link = format!("]({})", doc.display());
        assert!(README.contains(&link), "README.md does not link {link}");
    }
}

/// The repository's Markdown documents outside target/ and hidden folders, relative to the
/// repository's root.
fn markdown_files() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![PathBuf::from("README.md"), PathBuf::from("ARCHITECTURE.md")];
    let docs = std::fs::read_dir(root.join("docs")).expect("docs/ is readable");
    let mut in_docs: Vec<PathBuf> = docs
        .map(|entry| entry.expect("a docs/ entry").path())
        .filter(|path| path.extension().is_some_and(|ext| ext == "md"))
        .map(|path| Path::new("docs").join(path.file_name().expect("a file name")))
        .collect();
    in_docs.sort();
    files.extend(in_docs);
    files
}

/// The link targets of `text` (`[text](target)`), outside fenced code blocks.
fn link_targets(text: &str) -> Vec<&str> {
    text.split("```")
        .step_by(2)
        .flat_map(|prose| prose.split("](").skip(1))
        .filter_map(|rest| rest.split_once(')').map(|(target, _)| target))
        .collect()
}

/// The anchors GitHub gives the headings of `text`: lower case, spaces as `-`, punctuation
/// other than `-` and `_` dropped.
fn heading_anchors(text: &str) -> Vec<String> {
    let mut in_code = false;
    text.lines()
        .filter(|line| {
            if line.starts_with("```") {
                in_code = !in_code;
            }
            !in_code && line.starts_with('#')
        })
        .map(|line| {
            line.trim_start_matches('#')
                .trim()
                .chars()
                .filter_map(|c| match c {
                    ' ' => Some('-'),
                    '-' | '_' => Some(c),
                    c if c.is_alphanumeric() => Some(c.to_lowercase().next().unwrap_or(c)),
                    _ => None,
                })
                .collect()
        })
        .collect()
}

#[test]
fn every_relative_link_between_the_documents_resolves() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut broken = Vec::new();
    for file in markdown_files() {
        let text = std::fs::read_to_string(root.join(&file)).expect("a readable document");
        let dir = file.parent().unwrap_or(Path::new(""));
        for target in link_targets(&text) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            let (path, anchor) = target.split_once('#').unwrap_or((target, ""));
            let linked = if path.is_empty() {
                file.clone()
            } else {
                dir.join(path)
            };
            let Ok(resolved) = root.join(&linked).canonicalize() else {
                broken.push(format!("{}: {target} (no such file)", file.display()));
                continue;
            };
            if !resolved.starts_with(root.canonicalize().expect("the root")) {
                broken.push(format!(
                    "{}: {target} (outside the repository)",
                    file.display()
                ));
                continue;
            }
            if !anchor.is_empty() {
                let linked_text = std::fs::read_to_string(&resolved).unwrap_or_default();
                if !heading_anchors(&linked_text).iter().any(|a| a == anchor) {
                    broken.push(format!("{}: {target} (no such heading)", file.display()));
                }
            }
        }
    }
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn architecture_links_each_crates_module_map_and_each_map_names_every_module() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut maps = vec!["src/lib.rs".to_string()];
    for entry in std::fs::read_dir(root.join("crates")).unwrap().flatten() {
        maps.push(format!(
            "crates/{}/src/lib.rs",
            entry.file_name().to_string_lossy()
        ));
    }
    maps.extend([
        "demo/src/lib.rs".to_string(),
        "testkit/src/lib.rs".to_string(),
    ]);
    assert!(maps.len() >= 6, "{maps:?}");
    for map in maps {
        assert!(
            ARCHITECTURE.contains(&format!("]({map})")),
            "ARCHITECTURE.md does not link {map}"
        );
        let text = std::fs::read_to_string(root.join(&map)).unwrap();
        let doc: String = text
            .lines()
            .filter_map(|line| line.strip_prefix("//!"))
            .collect::<Vec<_>>()
            .join("\n");
        for line in text.lines() {
            let Some(module) = line.strip_prefix("pub mod ") else {
                continue;
            };
            let module = module.trim_end_matches(';');
            assert!(
                doc.contains(&format!("[`{module}`]")) || doc.contains(&format!("`{module}`")),
                "{map}'s module map does not name `{module}`"
            );
        }
    }
}

#[test]
fn quick_start_pokes_the_plant_with_the_demos_own_example_commands() {
    let config = rtu2mqtt::config::from_str(
        include_str!("../../../config/rtu2mqtt.toml"),
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
