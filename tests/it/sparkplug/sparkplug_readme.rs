//! docs/sparkplug.md stays true to the code: its metric table is the one the profiles of the
//! seed plant give (name, Sparkplug datatype, unit, writable), and the configuration
//! reference's `[sparkplug]` table (docs/configuration.md) names exactly the section's keys.

use rtu2mqtt::config::{keys_of, SparkplugSettings};
use rtu2mqtt::sparkplug::core::metrics::datatype_for;
use rtu2mqtt_profile::registry;

const SPARKPLUG: &str = include_str!("../../../docs/sparkplug.md");
const CONFIGURATION: &str = include_str!("../../../docs/configuration.md");
const BEGIN: &str = "<!-- BEGIN sparkplug metrics (tests/it/sparkplug/sparkplug_readme.rs) -->\n";
const END: &str = "<!-- END sparkplug metrics -->";
/// The seed plant's devices as `config/rtu2mqtt.toml` names them.
const SEED: [(&str, &str); 3] = [
    ("dust_collector", "ruiwan-dust-collector"),
    ("air_shower", "lixian-air-shower"),
    ("valve", "wuzhou-valve"),
];

/// The metric table of the seed plant, one row per field.
fn metric_table() -> String {
    let mut table =
        String::from("| device | metric | type | unit | writable |\n|---|---|---|---|---|\n");
    for (device, profile) in SEED {
        let profile = registry::built_in(profile).unwrap_or_else(|error| panic!("{error}"));
        for info in profile.fields() {
            table.push_str(&format!(
                "| `{device}` | `{}` | {:?} | {} | {} |\n",
                info.name,
                datatype_for(info),
                info.unit.as_deref().unwrap_or(""),
                if info.writable { "yes" } else { "" },
            ));
        }
    }
    table
}

/// The text between the heading `{heading}` and the next heading of the same or a higher level
/// (lines in fenced code blocks are no headings).
fn section<'a>(text: &'a str, heading: &str) -> &'a str {
    let marker = format!("\n{heading}\n");
    let start = text
        .find(&marker)
        .unwrap_or_else(|| panic!("no section {heading:?}"))
        + marker.len();
    let level = heading.split(' ').next().unwrap_or("##").len();
    let mut in_code = false;
    let mut at = start;
    for line in text[start..].split_inclusive('\n') {
        if line.starts_with("```") {
            in_code = !in_code;
        }
        let hashes = line.chars().take_while(|c| *c == '#').count();
        if !in_code && hashes > 0 && hashes <= level && line[hashes..].starts_with(' ') {
            return &text[start..at];
        }
        at += line.len();
    }
    &text[start..]
}

#[test]
fn the_seed_plant_metric_table_is_the_profiles() {
    let scada = SPARKPLUG;
    let start = scada.find(BEGIN).expect("begin marker") + BEGIN.len();
    let stop = scada.find(END).expect("end marker");
    let expected = metric_table();
    assert!(
        scada[start..stop] == expected,
        "docs/sparkplug.md's metric table differs from the profiles; it should read:\n{expected}"
    );
}

#[test]
fn the_sparkplug_configuration_reference_lists_every_key_and_no_other() {
    let reference = section(CONFIGURATION, "## Configuration reference");
    let table = section(reference, "### `[sparkplug]` (optional)");
    let documented: Vec<&str> = table
        .lines()
        .filter(|line| line.starts_with("| `"))
        .filter_map(|line| line.split('|').nth(1))
        .map(|cell| cell.trim().trim_matches('`'))
        .collect();
    assert_eq!(documented, keys_of::<SparkplugSettings>());
}
