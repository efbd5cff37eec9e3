//! Complete validation of a [`RawConfig`]: every phase runs, each section checked by its own
//! module ([`super::mqtt`], [`super::gateway`], [`super::health`], [`super::lines`] with
//! [`super::devices`], [`super::sparkplug`], [`super::history`], [`super::web`]), and every problem is collected
//! with its place; what no single section can see (Home Assistant ids across lines) is checked
//! here. Nothing is opened (profile files and the password file are read, ports and the broker
//! are not). The result is the bus's [`LineSpec`]s and the bridge's settings. [`load`] and
//! [`from_str`] are the way in: what the reading stage found comes first, validation of the
//! rest follows.

use std::path::Path;

use super::deserialize::Loaded;
use super::gateway::validate_gateway;
use super::gateway::GatewayOptions;
use super::health::validate_health;
use super::health::HealthSettings;
use super::history::HistoryConfig;
use super::lines::validate_lines;
use super::load as reading;
use super::mqtt::validate_mqtt;
use super::mqtt::MqttSettings;
use super::problem::{Problem, Problems};
use super::schema::RawConfig;
use super::sparkplug::validate_sparkplug;
use super::sparkplug::SparkplugConfig;
use super::web::{validate_web, WebSettings};
use crate::bus::LineSpec;

/// A validated gateway configuration.
#[derive(Debug, Clone)]
pub struct Config {
    pub mqtt: MqttSettings,
    pub gateway: GatewayOptions,
    pub health: HealthSettings,
    pub lines: Vec<LineSpec>,
    /// The Sparkplug B edge node, when `[sparkplug]` is present.
    pub sparkplug: Option<SparkplugConfig>,
    /// The journal and the history stream, when `[history]` is present.
    pub history: Option<HistoryConfig>,
    /// The browser console, when `[web]` has a `listen` address.
    pub web: Option<WebSettings>,
    /// Things that work but deserve attention (a `/dev/ttyUSB0` path, a pty ignoring parity).
    pub warnings: Vec<Problem>,
}

/// Validates `raw`; profile paths are relative to `base`.
pub(crate) fn validate(raw: &RawConfig, base: &Path) -> Result<Config, Problems> {
    let mut problems = Vec::new();
    let mut warnings = Vec::new();
    let mqtt = validate_mqtt(&raw.mqtt, base, &mut problems);
    let gateway = validate_gateway(&raw.gateway, &mut problems);
    validate_health(&raw.health, &mut problems);
    let lines = validate_lines(&raw.lines, base, &mut problems, &mut warnings);
    if let Some(mqtt) = mqtt.as_ref().filter(|mqtt| mqtt.discovery) {
        check_unique_ids(mqtt, &lines, &mut problems);
    }
    let sparkplug = raw.sparkplug.as_ref().map(|section| {
        validate_sparkplug(
            section,
            &raw.mqtt.client_id,
            mqtt.as_ref(),
            base,
            &mut problems,
        )
    });
    let history = raw
        .history
        .as_ref()
        .and_then(|table| match super::history::check(table) {
            Ok(history) => Some(history),
            Err(found) => {
                problems.extend(found);
                None
            }
        });
    let web = raw
        .web
        .as_ref()
        .and_then(|table| validate_web(table, base, &mut problems));
    if problems.is_empty() {
        if let (Some(mqtt), Some(gateway)) = (mqtt, gateway) {
            return Ok(Config {
                mqtt,
                gateway,
                sparkplug: sparkplug.flatten(),
                history,
                web,
                health: raw.health.clone(),
                lines,
                warnings,
            });
        }
    }
    Err(Problems(problems))
}

/// Home Assistant would drop one of two entities sharing a `unique_id`
/// (device `a` + field `b_c` and device `a_b` + field `c`; an action is an entity too).
fn check_unique_ids(mqtt: &MqttSettings, lines: &[LineSpec], problems: &mut Vec<Problem>) {
    let fields = lines
        .iter()
        .flat_map(|line| line.devices.iter())
        .flat_map(|device| {
            let fields = device.profile.fields().iter().map(|field| &field.name);
            let actions = device.profile.actions().map(|action| &action.name);
            fields
                .chain(actions)
                .map(|name| (device.name.as_str(), name.as_str()))
        });
    for id in mqtt.topics().unique_id_collisions(fields) {
        problems.push(Problem::new(
            "lines",
            format!(
                "two fields or actions would share the Home Assistant unique_id {id:?}: rename \
                 a device"
            ),
        ));
    }
}

/// Reads, overrides from the environment and validates the configuration at `path`.
/// A problem in a value set from the environment names its variable, not the file.
pub fn load(path: &Path) -> Result<Config, Problems> {
    load_with_env(path, reading::process_environment()?)
}

/// Like [`load()`] with an explicit environment (tests).
pub fn load_with_env(
    path: &Path,
    env: std::collections::HashMap<String, String>,
) -> Result<Config, Problems> {
    let overrides = reading::env_overrides(&env);
    let loaded = reading::load_file_lenient(path, Some(env))?;
    let base = path.parent().unwrap_or_else(|| Path::new("."));
    validate_loaded(loaded, base)
        .map_err(|problems| reading::blame_overrides(problems, &overrides, false))
}

/// Parses and validates configuration text (profile paths relative to `base`).
pub fn from_str(text: &str, base: &Path) -> Result<Config, Problems> {
    validate_loaded(reading::load_str_lenient(text)?, base)
}

/// Validates what reading found. Problems of the reading stage come first; validation of the
/// rest follows, leaving out problems at a place the reading stage already reported.
fn validate_loaded(loaded: Loaded, base: &Path) -> Result<Config, Problems> {
    let Some(raw) = &loaded.raw else {
        return Err(Problems(loaded.problems));
    };
    let validated = validate(raw, base);
    if loaded.problems.is_empty() {
        return validated;
    }
    let mut problems = loaded.problems;
    if let Err(Problems(found)) = validated {
        let reported: Vec<String> = problems.iter().map(|p| p.place.clone()).collect();
        problems.extend(found.into_iter().filter(|problem| {
            !reported
                .iter()
                .any(|place| !place.is_empty() && reading::is_within(&problem.place, place))
        }));
    }
    Err(Problems(problems))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_action_and_a_field_of_two_devices_may_not_share_a_unique_id() {
        let dir = tempfile::tempdir().unwrap();
        let device = "[device]\nname = \"m\"\nmanufacturer = \"m\"\nmodel = \"x\"\n[line]\n\
            [[blocks]]\nname = \"hold\"\nfunction = 3\nstart = 0\ncount = 1\n";
        let with_action = format!(
            "{device}[[fields]]\nname = \"energy\"\nblock = \"hold\"\noffset = 0\n\
             codec = {{ type = \"u16\" }}\n\
             [[actions]]\nname = \"set_tariff\"\naddress = 9\nregisters = [1, \"tariff\"]\n"
        );
        let with_field = format!(
            "{device}[[fields]]\nname = \"tariff\"\nblock = \"hold\"\noffset = 0\n\
             codec = {{ type = \"u16\" }}\n"
        );
        std::fs::write(dir.path().join("a.toml"), with_action).unwrap();
        std::fs::write(dir.path().join("f.toml"), with_field).unwrap();
        let text = "[mqtt]\nurl = \"mqtt://broker\"\nclient_id = \"edge1\"\n\
                    [[lines]]\nname = \"a\"\nport = \"/dev/ttyS1\"\n\
                    [[lines.devices]]\nname = \"meter\"\nprofile = \"a.toml\"\naddress = 1\n\
                    [[lines.devices]]\nname = \"meter_set\"\nprofile = \"f.toml\"\naddress = 2\n";
        let raw = crate::config::load::load_str(text).unwrap();
        let Err(Problems(problems)) = validate(&raw, dir.path()) else {
            panic!("two entities of one unique id accepted");
        };
        let found: Vec<(&str, &str)> = problems
            .iter()
            .map(|problem| (problem.place.as_str(), problem.reason.as_str()))
            .collect();
        assert_eq!(
            found,
            [(
                "lines",
                "two fields or actions would share the Home Assistant unique_id \
                 \"edge1_meter_set_tariff\": rename a device"
            )]
        );
    }

    #[test]
    fn every_section_s_problems_are_collected_in_one_list_with_their_places() {
        let text = "[mqtt]\nurl = \"http://broker\"\nclient_id = \"edge1\"\n\
                    [gateway]\nmax_payload = 0\n[health]\ninterval = \"10ms\"\n\
                    [[lines]]\nname = \"a\"\nport = \"/dev/ttyS1\"\ndata_bits = 7\n\
                    [[lines.devices]]\nname = \"valve\"\nprofile = \"wuzhou-valve\"\naddress = 300\n\
                    [sparkplug]\ngroup_id = \"a/b\"\n[history]\npath = \"\"\n";
        let raw = crate::config::load::load_str(text).unwrap();
        let Err(Problems(problems)) = validate(&raw, Path::new(".")) else {
            panic!("a broken configuration accepted");
        };
        let places: Vec<&str> = problems
            .iter()
            .map(|problem| problem.place.as_str())
            .collect();
        assert_eq!(
            places,
            [
                "mqtt.url",
                "gateway.max_payload",
                "health.interval",
                "lines[0].data_bits",
                "lines[0].devices[0].address",
                "sparkplug.group_id",
                "history.path",
            ]
        );
    }
}
