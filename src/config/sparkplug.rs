//! The checked `[sparkplug]` section: the Sparkplug B identity of the gateway's edge node
//! (group, edge node and optional primary host ids, checked by Sparkplug's rules) and the
//! broker of its own connection (its own `mqtt` table, or the plain broker under another
//! client id). Only settings: the edge node itself is `crate::sparkplug`'s; the section as
//! written is `schema`'s, and its own broker is checked like `[mqtt]` by [`super::mqtt`].

use std::path::Path;

use super::mqtt::validate_mqtt_section;
use super::mqtt::MqttSettings;
use super::problem::Problem;
use super::schema::SparkplugSettings;

/// Appended to the plain connection's client id when the node shares its broker: two
/// connections with one client id would take each other over.
pub const CLIENT_ID_SUFFIX: &str = "-sparkplug";

/// The checked Sparkplug identity of the node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SparkplugIdentity {
    pub group_id: String,
    pub edge_node_id: String,
    pub primary_host_id: Option<String>,
}

/// The checked `[sparkplug]` section.
#[derive(Debug, Clone, PartialEq)]
pub struct SparkplugConfig {
    pub identity: SparkplugIdentity,
    /// The node's own connection (always a clean session).
    pub mqtt: MqttSettings,
}

/// Checks the ids of `raw` by Sparkplug's rules (non-empty, no `+`, `#` or `/`; they are
/// topic levels) and fills the edge node id from the MQTT client id. Every problem is named
/// with its place (`sparkplug.group_id`).
pub(crate) fn check_identity(
    raw: &SparkplugSettings,
    mqtt_client_id: &str,
) -> Result<SparkplugIdentity, Vec<Problem>> {
    let mut problems = Vec::new();
    let edge_node_id = raw
        .edge_node_id
        .clone()
        .unwrap_or_else(|| mqtt_client_id.to_string());
    check_id("sparkplug.group_id", &raw.group_id, &mut problems);
    let place = if raw.edge_node_id.is_some() {
        "sparkplug.edge_node_id"
    } else {
        "sparkplug.edge_node_id (from mqtt.client_id)"
    };
    check_id(place, &edge_node_id, &mut problems);
    if let Some(host) = &raw.primary_host_id {
        check_id("sparkplug.primary_host_id", host, &mut problems);
    }
    if !problems.is_empty() {
        return Err(problems);
    }
    Ok(SparkplugIdentity {
        group_id: raw.group_id.clone(),
        edge_node_id,
        primary_host_id: raw.primary_host_id.clone(),
    })
}

/// The plain broker settings made fit for the node's own connection: same broker, own client
/// id, clean session (Sparkplug 3.0 requires a clean session on MQTT 3.1.1).
pub fn shared_broker(plain: &MqttSettings) -> MqttSettings {
    MqttSettings {
        client_id: format!("{}{CLIENT_ID_SUFFIX}", plain.client_id),
        clean_session: true,
        ..plain.clone()
    }
}

/// The whole section: identity and broker, every problem added to `problems`. `plain` is the
/// checked `[mqtt]` (None when it has problems of its own; the identity is still checked).
pub(crate) fn validate_sparkplug(
    raw: &SparkplugSettings,
    plain_client_id: &str,
    plain: Option<&MqttSettings>,
    base: &Path,
    problems: &mut Vec<Problem>,
) -> Option<SparkplugConfig> {
    let identity = check_identity(raw, plain_client_id)
        .map_err(|found| problems.extend(found))
        .ok();
    let mqtt = match &raw.mqtt {
        Some(own) => {
            let checked = validate_mqtt_section("sparkplug.mqtt", own, base, problems)?;
            if let Some(plain) = plain.filter(|plain| same_client(plain, &checked)) {
                problems.push(Problem::new(
                    "sparkplug.mqtt.client_id",
                    format!(
                        "{:?} is also mqtt.client_id on the same broker: the two connections \
                         would take each other over",
                        plain.client_id
                    ),
                ));
                return None;
            }
            MqttSettings {
                clean_session: true,
                ..checked
            }
        }
        None => shared_broker(plain?),
    };
    Some(SparkplugConfig {
        identity: identity?,
        mqtt,
    })
}

fn same_client(a: &MqttSettings, b: &MqttSettings) -> bool {
    a.host == b.host && a.port == b.port && a.client_id == b.client_id
}

fn check_id(place: &str, id: &str, problems: &mut Vec<Problem>) {
    if id.is_empty() {
        problems.push(Problem::new(
            place,
            "is required (a non-empty Sparkplug id)",
        ));
    } else if let Some(bad) = id.chars().find(|c| matches!(c, '+' | '#' | '/')) {
        problems.push(Problem::new(
            place,
            format!("`{id}` contains `{bad}`; Sparkplug ids must not contain +, # or /"),
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(group: &str, node: Option<&str>, host: Option<&str>) -> SparkplugSettings {
        SparkplugSettings {
            group_id: group.to_string(),
            edge_node_id: node.map(str::to_string),
            primary_host_id: host.map(str::to_string),
            mqtt: None,
        }
    }

    #[test]
    fn the_edge_node_id_defaults_to_the_client_id() {
        let identity = check_identity(&settings("plant", None, Some("scada")), "rtu2mqtt-1");
        assert_eq!(
            identity,
            Ok(SparkplugIdentity {
                group_id: "plant".into(),
                edge_node_id: "rtu2mqtt-1".into(),
                primary_host_id: Some("scada".into()),
            })
        );
    }

    #[test]
    fn ids_follow_the_sparkplug_rules() {
        let Err(problems) = check_identity(&settings("", Some("a/b"), Some("h+")), "gw") else {
            panic!("invalid ids accepted");
        };
        let shown: Vec<String> = problems.iter().map(ToString::to_string).collect();
        assert_eq!(
            shown,
            [
                "sparkplug.group_id: is required (a non-empty Sparkplug id)",
                "sparkplug.edge_node_id: `a/b` contains `/`; Sparkplug ids must not contain +, # or /",
                "sparkplug.primary_host_id: `h+` contains `+`; Sparkplug ids must not contain +, # or /",
            ]
        );
        let Err(problems) = check_identity(&settings("g", None, None), "gw#1") else {
            panic!("invalid client id accepted as edge node id");
        };
        assert_eq!(
            problems[0].place,
            "sparkplug.edge_node_id (from mqtt.client_id)"
        );
    }

    #[test]
    fn the_section_parses_from_toml() {
        let parsed: Result<SparkplugSettings, _> = toml::from_str(
            "group_id = \"plant\"\nprimary_host_id = \"scada\"\n[mqtt]\nurl = \"mqtt://broker:1883\"\nclient_id = \"gw-sp\"\n",
        );
        let Ok(parsed) = parsed else {
            panic!("{parsed:?}");
        };
        assert_eq!(parsed.group_id, "plant");
        assert!(parsed
            .mqtt
            .is_some_and(|mqtt| mqtt.url == "mqtt://broker:1883"));
        assert!(toml::from_str::<SparkplugSettings>("group = \"x\"").is_err());
    }

    const PLAIN: &str = "[mqtt]\nurl = \"mqtt://127.0.0.1:1883\"\nclient_id = \"edge1\"\n";
    const LINE: &str = "[[lines]]\nname = \"a\"\nport = \"/dev/ttyS0\"\n[[lines.devices]]\nname = \"valve\"\nprofile = \"wuzhou-valve\"\naddress = 3\n";

    fn load_with_sparkplug(extra: &str) -> Result<super::super::Config, String> {
        super::super::from_str(&format!("{PLAIN}{LINE}{extra}"), Path::new("."))
            .map_err(|problems| problems.to_string())
    }

    #[test]
    fn absent_means_no_edge_node_and_present_shares_the_broker_by_default() {
        let config = load_with_sparkplug("").unwrap_or_else(|problems| panic!("{problems}"));
        assert!(config.sparkplug.is_none());
        let Ok(config) = load_with_sparkplug("[sparkplug]\ngroup_id = \"plant\"\n") else {
            panic!("[sparkplug] refused");
        };
        let Some(sparkplug) = config.sparkplug else {
            panic!("[sparkplug] ignored");
        };
        assert_eq!(sparkplug.identity.edge_node_id, "edge1");
        assert_eq!(sparkplug.mqtt.client_id, "edge1-sparkplug");
        assert_eq!(sparkplug.mqtt.port, 1883);
        assert!(sparkplug.mqtt.clean_session);
    }

    #[test]
    fn its_own_broker_is_checked_like_mqtt_with_every_problem_placed() {
        let Ok(config) = load_with_sparkplug(
            "[sparkplug]\ngroup_id = \"plant\"\n[sparkplug.mqtt]\nurl = \"mqtt://scada:1884\"\nclient_id = \"edge1\"\n",
        ) else {
            panic!("own broker refused");
        };
        let mqtt = config.sparkplug.map(|sparkplug| sparkplug.mqtt);
        assert_eq!(
            mqtt.map(|mqtt| (mqtt.host, mqtt.port)),
            Some(("scada".into(), 1884))
        );

        let Err(problems) = load_with_sparkplug(
            "[sparkplug]\ngroup_id = \"a/b\"\n[sparkplug.mqtt]\nurl = \"http://x\"\nclient_id = \"edge1\"\ninflight = 0\n",
        ) else {
            panic!("bad section accepted");
        };
        for expected in [
            "sparkplug.group_id: `a/b` contains `/`",
            "sparkplug.mqtt.url: \"http://x\" must start with mqtt://",
            "sparkplug.mqtt.inflight: must be at least 1",
        ] {
            assert!(problems.contains(expected), "{expected}\n{problems}");
        }

        let Err(problems) = load_with_sparkplug(
            "[sparkplug]\ngroup_id = \"plant\"\n[sparkplug.mqtt]\nurl = \"mqtt://127.0.0.1:1883\"\nclient_id = \"edge1\"\n",
        ) else {
            panic!("a client id taking over the plain connection accepted");
        };
        assert!(
            problems.contains("sparkplug.mqtt.client_id: \"edge1\" is also mqtt.client_id"),
            "{problems}"
        );

        let Err(problems) = load_with_sparkplug("[sparkplug]\nedge_node_id = \"gw\"\ncolour = 1\n")
        else {
            panic!("missing group_id accepted");
        };
        assert!(
            problems.contains("sparkplug.group_id: required"),
            "{problems}"
        );
        assert!(
            problems.contains("sparkplug.colour: unknown key"),
            "{problems}"
        );
    }
}
