//! The MQTT contract in one place: every topic name the gateway publishes or subscribes to
//! (state, `…/set`, `…/result`, availability, a device's refresh request, the gateway's status
//! and statistics, the JSON view, Home Assistant discovery), the strict parse of an incoming command topic, Home
//! Assistant identifiers, the payload words `online`/`offline`, and the names reserved for the
//! gateway itself.
//!
//! Pure string work with no dependency on the rest of the crate: configuration validation,
//! discovery and the bridge all build their names here, so they cannot drift apart.

use std::collections::HashSet;

/// Availability and status payload of something that is there.
pub const ONLINE: &str = "online";
/// Availability and status payload of something that is gone (also the gateway's Will).
pub const OFFLINE: &str = "offline";

/// The device name reserved for the gateway's own topics (`<prefix>/gateway/<client_id>/…`)
/// and its own discovery document.
pub const GATEWAY_DEVICE: &str = "gateway";
/// The last level of a device's availability topic.
pub const AVAILABILITY: &str = "availability";
/// The last level of a device's history stream (`<prefix>/<device>/history`).
pub const HISTORY: &str = "history";
/// The last level of a device's refresh request (`<prefix>/<device>/refresh`).
const REFRESH: &str = "refresh";

/// Names a device or a field must not have: every word the contract itself uses as a topic
/// level next to device and field names. A field `availability` would publish its values on
/// the device's availability topic; `set` and `result` are the command and outcome levels;
/// `gateway` holds the gateway's own `status` and `stats`; `history` is the history stream;
/// `refresh` asks for a device's every block to be read.
const RESERVED_NAMES: &[&str] = &[
    "availability",
    GATEWAY_DEVICE,
    HISTORY,
    REFRESH,
    "result",
    "set",
    "stats",
    "status",
];

/// Longest device, line or field name (a topic level). Keeps every topic the gateway builds
/// (prefix of at most 128 bytes, device, field, `/result`) far below [`MAX_TOPIC_LEN`] and
/// MQTT's 65,535-byte limit, and below the broker's and Home Assistant's practical limits
/// on ids (`<client_id>_<device>_<field>`).
pub const MAX_NAME_LEN: usize = 64;

/// Why `name` cannot be a device or field name of the contract, if it cannot, with a name
/// to use instead.
pub fn reserved_name_problem(name: &str) -> Option<String> {
    RESERVED_NAMES.contains(&name).then(|| {
        format!(
            "{name:?} is reserved: the gateway uses it as a topic level of its own (reserved: \
             {}); call it e.g. \"device_{name}\"",
            RESERVED_NAMES.join(", ")
        )
    })
}

/// The names no device or field may have ([`reserved_name_problem`]).
pub fn reserved_names() -> &'static [&'static str] {
    RESERVED_NAMES
}

/// The default Home Assistant discovery prefix.
pub const DEFAULT_DISCOVERY_PREFIX: &str = "homeassistant";

/// Home Assistant announces itself with `online` on this topic (under the discovery prefix).
const HA_STATUS_SUFFIX: &str = "status";

/// Longest command topic looked at; anything longer is dropped unparsed.
pub const MAX_TOPIC_LEN: usize = 512;

/// `<prefix>/<device>`: the topic of a device's JSON view.
pub fn json_view_topic(prefix: &str, device: &str) -> String {
    format!("{prefix}/{device}")
}

/// Whether a payload on Home Assistant's status topic is its birth message.
pub fn is_ha_online(payload: &[u8]) -> bool {
    std::str::from_utf8(payload)
        .map(|text| text.trim().eq_ignore_ascii_case(ONLINE))
        .unwrap_or(false)
}

/// The availability word of `online`.
pub fn availability_word(online: bool) -> &'static str {
    if online {
        ONLINE
    } else {
        OFFLINE
    }
}

/// Builds and parses every topic and identifier of one gateway.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topics {
    /// The MQTT client id, also the gateway's id (`rtu2mqtt-edge1`).
    pub client_id: String,
    /// The state topic prefix (`plant`).
    pub prefix: String,
    /// Home Assistant's discovery prefix (`homeassistant`).
    pub discovery_prefix: String,
}

impl Topics {
    /// The topics of gateway `client_id` under `prefix`, with the default discovery prefix.
    pub fn new(client_id: &str, prefix: &str) -> Self {
        Topics {
            client_id: client_id.to_string(),
            prefix: prefix.to_string(),
            discovery_prefix: DEFAULT_DISCOVERY_PREFIX.to_string(),
        }
    }

    /// The same topics with another Home Assistant discovery prefix.
    pub fn with_discovery_prefix(mut self, discovery_prefix: &str) -> Self {
        self.discovery_prefix = discovery_prefix.to_string();
        self
    }

    // ----- the gateway's own topics -----

    /// `<prefix>/<device>/<field>`: the retained state.
    pub fn state_topic(&self, device: &str, field: &str) -> String {
        format!("{}/{device}/{field}", self.prefix)
    }

    /// `<prefix>/<device>/<field>/set`: where commands arrive.
    pub fn command_topic(&self, device: &str, field: &str) -> String {
        format!("{}/{device}/{field}/set", self.prefix)
    }

    /// `<prefix>/<device>/<field>/result`: the outcome of each command.
    pub fn result_topic(&self, device: &str, field: &str) -> String {
        format!("{}/{device}/{field}/result", self.prefix)
    }

    /// `<prefix>/<device>/availability`.
    pub fn availability_topic(&self, device: &str) -> String {
        format!("{}/{device}/{AVAILABILITY}", self.prefix)
    }

    /// `<prefix>/<device>/history`: the device's timestamped change sets (not retained).
    pub fn history_topic(&self, device: &str) -> String {
        format!("{}/{device}/{HISTORY}", self.prefix)
    }

    /// `<prefix>/<device>/refresh`: a message there (not retained) has every block of the
    /// device read at once. It arrives on [`Topics::refresh_filter`].
    pub fn refresh_topic(&self, device: &str) -> String {
        format!("{}/{device}/{REFRESH}", self.prefix)
    }

    /// `device` of `<prefix>/<device>/refresh`.
    pub fn device_of_refresh_topic<'t>(&self, topic: &'t str) -> Option<&'t str> {
        match self.parse_device_topic(topic)? {
            (device, REFRESH) => Some(device),
            _ => None,
        }
    }

    /// `<prefix>/+/history`: every device's history stream, what a historian subscribes to.
    pub fn history_filter(&self) -> String {
        self.history_topic("+")
    }

    /// `<prefix>/<device>`: the device's JSON view.
    pub fn json_view_topic(&self, device: &str) -> String {
        json_view_topic(&self.prefix, device)
    }

    /// `<prefix>/gateway/<client_id>/status`: birth `online`, Will `offline`.
    pub fn gateway_status_topic(&self) -> String {
        format!("{}/{GATEWAY_DEVICE}/{}/status", self.prefix, self.client_id)
    }

    /// `<prefix>/gateway/<client_id>/stats`: the gateway's statistics summary.
    pub fn gateway_stats_topic(&self) -> String {
        format!("{}/{GATEWAY_DEVICE}/{}/stats", self.prefix, self.client_id)
    }

    /// `<prefix>/gateway/<client_id>/stats/<line>`: one line's statistics, its devices'
    /// included (one document per line keeps each one bounded, whatever the number of lines).
    pub fn line_stats_topic(&self, line: &str) -> String {
        format!("{}/{line}", self.gateway_stats_topic())
    }

    /// Whether `topic` is the statistics summary or one line's statistics.
    pub fn is_stats_topic(&self, topic: &str) -> bool {
        let summary = self.gateway_stats_topic();
        topic.strip_prefix(summary.as_str()).is_some_and(|rest| {
            rest.is_empty()
                || rest
                    .strip_prefix('/')
                    .is_some_and(|line| !line.is_empty() && !line.contains('/'))
        })
    }

    /// The subscription that carries every command: `<prefix>/+/+/set`.
    pub fn command_filter(&self) -> String {
        format!("{}/+/+/set", self.prefix)
    }

    /// `(device, field)` of a command topic, or None when the topic is not exactly
    /// `<prefix>/<device>/<field>/set` with non-empty levels (or is too long to look at).
    pub fn parse_command<'t>(&self, topic: &'t str) -> Option<(&'t str, &'t str)> {
        let rest = self.under_prefix(topic)?;
        let mut levels = rest.splitn(4, '/');
        let device = levels.next()?;
        let field = levels.next()?;
        let set = levels.next()?;
        if levels.next().is_some() || set != "set" || device.is_empty() || field.is_empty() {
            return None;
        }
        Some((device, field))
    }

    /// `<prefix>/+/+`: every device's state, availability and refresh topic. The gateway
    /// no longer subscribes to it (it would bring all of its own state back); it is removed
    /// from a persistent session that still holds it.
    pub fn device_topics_filter(&self) -> String {
        format!("{}/+/+", self.prefix)
    }

    /// `<prefix>/+/availability`: every device's availability, ours and other gateways'.
    pub fn availability_filter(&self) -> String {
        self.availability_topic("+")
    }

    /// `<prefix>/+/refresh`: the refresh requests.
    pub fn refresh_filter(&self) -> String {
        self.refresh_topic("+")
    }

    /// `<prefix>/<device>/+`: one device's state topics (and its availability and refresh
    /// topics), watched while the device is audited.
    pub fn device_filter(&self, device: &str) -> String {
        format!("{}/{device}/+", self.prefix)
    }

    /// `(device, level)` of a topic exactly two levels under the prefix: a state topic
    /// `<prefix>/<device>/<field>` or an availability topic.
    pub fn parse_device_topic<'t>(&self, topic: &'t str) -> Option<(&'t str, &'t str)> {
        let rest = self.under_prefix(topic)?;
        let (device, level) = rest.split_once('/')?;
        if device.is_empty() || level.is_empty() || level.contains('/') {
            return None;
        }
        Some((device, level))
    }

    /// What follows `<prefix>/` in `topic` (None for other topics and for topics too long to
    /// look at).
    fn under_prefix<'t>(&self, topic: &'t str) -> Option<&'t str> {
        if topic.len() > MAX_TOPIC_LEN {
            return None;
        }
        topic.strip_prefix(self.prefix.as_str())?.strip_prefix('/')
    }

    /// `device` of `<prefix>/<device>/availability`.
    pub fn device_of_availability_topic<'t>(&self, topic: &'t str) -> Option<&'t str> {
        match self.parse_device_topic(topic)? {
            (device, AVAILABILITY) => Some(device),
            _ => None,
        }
    }

    // ----- Home Assistant -----

    /// The gateway's identifier in Home Assistant's device registry (the `via_device` target).
    pub fn gateway_id(&self) -> String {
        self.client_id.clone()
    }

    /// A configured device's identifier in the device registry: `<client_id>_<device>`.
    pub fn device_id(&self, device: &str) -> String {
        format!("{}_{}", self.client_id, device)
    }

    /// `<client_id>_<device>_<field>`: stable across restarts and renames of nothing but the
    /// field itself, so Home Assistant keeps the entity's history and customisation.
    pub fn unique_id(&self, device: &str, field: &str) -> String {
        format!("{}_{}_{}", self.client_id, device, field)
    }

    /// `unique_id`s that two `(device, field)` pairs would share (device `a` with field `b_c`
    /// and device `a_b` with field `c` both give `<client_id>_a_b_c`), each named once.
    pub fn unique_id_collisions<'n>(
        &self,
        fields: impl IntoIterator<Item = (&'n str, &'n str)>,
    ) -> Vec<String> {
        let mut seen = HashSet::new();
        let mut collisions = Vec::new();
        for (device, field) in fields {
            let id = self.unique_id(device, field);
            if !seen.insert(id.clone()) && !collisions.contains(&id) {
                collisions.push(id);
            }
        }
        collisions
    }

    /// `homeassistant/device/<client_id>_<device>/config`.
    pub fn config_topic(&self, device: &str) -> String {
        format!(
            "{}/device/{}/config",
            self.discovery_prefix,
            self.device_id(device)
        )
    }

    /// `homeassistant/device/<client_id>_gateway/config`.
    pub fn gateway_config_topic(&self) -> String {
        self.config_topic(GATEWAY_DEVICE)
    }

    /// `homeassistant/device/<client_id>_gateway/<line>/config`: the document of one line's
    /// sensors on the gateway device (the discovery topic's optional node id level keeps it
    /// apart from every device's config topic).
    pub fn line_config_topic(&self, line: &str) -> String {
        format!(
            "{}/device/{}/{line}/config",
            self.discovery_prefix,
            self.device_id(GATEWAY_DEVICE)
        )
    }

    /// Where this gateway's line documents are found: `homeassistant/device/<client_id>_gateway/+/config`.
    pub fn line_config_filter(&self) -> String {
        self.line_config_topic("+")
    }

    /// The line of a [`Topics::line_config_topic`], or None.
    pub fn line_of_config_topic<'t>(&self, topic: &'t str) -> Option<&'t str> {
        let gateway = format!(
            "{}/device/{}/",
            self.discovery_prefix,
            self.device_id(GATEWAY_DEVICE)
        );
        let line = topic.strip_prefix(&gateway)?.strip_suffix("/config")?;
        (!line.is_empty() && !line.contains('/')).then_some(line)
    }

    /// What to subscribe to for finding the configs this gateway published earlier. MQTT
    /// wildcards take whole levels, so `<client_id>_+` is not a valid filter: subscribe to
    /// every device config and keep the ones [`Topics::device_of_config_topic`] names.
    pub fn config_filter(&self) -> String {
        format!("{}/device/+/config", self.discovery_prefix)
    }

    /// The device name of a config topic this gateway may have published
    /// (`homeassistant/device/<client_id>_<device>/config` → `<device>`), or None.
    pub fn device_of_config_topic<'t>(&self, topic: &'t str) -> Option<&'t str> {
        let object_id = topic
            .strip_prefix(&self.discovery_prefix)?
            .strip_prefix("/device/")?
            .strip_suffix("/config")?;
        let device = object_id.strip_prefix(&self.client_id)?.strip_prefix('_')?;
        (!device.is_empty() && !device.contains('/')).then_some(device)
    }

    /// `homeassistant/status`: Home Assistant's birth and last-will topic.
    pub fn ha_status_topic(&self) -> String {
        format!("{}/{}", self.discovery_prefix, HA_STATUS_SUFFIX)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_field_with_a_reserved_name_is_refused_where_any_profile_is_read() {
        for name in reserved_names() {
            let text = format!(
                "[device]\nname = \"x\"\nmanufacturer = \"m\"\nmodel = \"m\"\n\
                 [line]\naddress_range = [1, 247]\n\
                 [[blocks]]\nname = \"b\"\nfunction = 3\nstart = 0\ncount = 1\n\
                 [[fields]]\nname = \"{name}\"\nblock = \"b\"\noffset = 0\ncodec = {{ type = \"u16\" }}\n"
            );
            let errors = crate::Profile::from_toml(&text, "p.toml")
                .unwrap_err()
                .to_string();
            assert!(
                errors.contains(&format!("fields[0] ({name}).name: \"{name}\" is reserved"))
                    && errors.contains(&format!("call it e.g. \"device_{name}\"")),
                "{errors}"
            );
        }
    }

    #[test]
    fn the_profile_format_lists_every_reserved_name() {
        let doc = include_str!("../../../docs/profiles.md");
        let section = doc
            .split("### Reserved names")
            .nth(1)
            .and_then(|rest| rest.split("\n### ").next())
            .unwrap_or_default();
        let listed: Vec<&str> = section
            .split('`')
            .skip(1)
            .step_by(2)
            .take(RESERVED_NAMES.len())
            .collect();
        assert_eq!(listed, RESERVED_NAMES);
    }

    #[test]
    fn contract_topics() {
        let topics = Topics::new("rtu2mqtt-edge1", "plant");
        assert_eq!(
            topics.state_topic("valve", "opening"),
            "plant/valve/opening"
        );
        assert_eq!(
            topics.command_topic("valve", "opening"),
            "plant/valve/opening/set"
        );
        assert_eq!(
            topics.result_topic("valve", "opening"),
            "plant/valve/opening/result"
        );
        assert_eq!(
            topics.availability_topic("valve"),
            "plant/valve/availability"
        );
        assert_eq!(
            topics.gateway_status_topic(),
            "plant/gateway/rtu2mqtt-edge1/status"
        );
        assert_eq!(
            topics.gateway_stats_topic(),
            "plant/gateway/rtu2mqtt-edge1/stats"
        );
        assert_eq!(topics.command_filter(), "plant/+/+/set");
        assert_eq!(topics.refresh_topic("valve"), "plant/valve/refresh");
        assert_eq!(
            topics.device_of_refresh_topic("plant/valve/refresh"),
            Some("valve")
        );
        for other in [
            "plant/valve/availability",
            "plant/valve/refresh/set",
            "plant//refresh",
            "other/valve/refresh",
        ] {
            assert_eq!(topics.device_of_refresh_topic(other), None, "{other}");
        }
        assert!(reserved_name_problem(REFRESH).is_some());
        assert_eq!(topics.json_view_topic("valve"), "plant/valve");
    }

    #[test]
    fn home_assistant_names() {
        let topics = Topics::new("edge1", "plant").with_discovery_prefix("ha");
        assert_eq!(topics.unique_id("valve", "opening"), "edge1_valve_opening");
        assert_eq!(topics.config_topic("valve"), "ha/device/edge1_valve/config");
        assert_eq!(
            topics.gateway_config_topic(),
            "ha/device/edge1_gateway/config"
        );
        assert_eq!(topics.config_filter(), "ha/device/+/config");
        assert_eq!(topics.ha_status_topic(), "ha/status");
        assert_eq!(
            topics.device_of_config_topic("ha/device/edge1_valve/config"),
            Some("valve")
        );
        assert_eq!(
            topics.device_of_config_topic("ha/device/other_valve/config"),
            None
        );
        assert_eq!(
            topics.unique_id_collisions([("a", "b_c"), ("a_b", "c"), ("v", "x")]),
            vec!["edge1_a_b_c".to_string()]
        );
    }

    #[test]
    fn command_topics_are_parsed_strictly() {
        let topics = Topics::new("gw", "site/plant");
        assert_eq!(
            topics.parse_command("site/plant/valve/opening/set"),
            Some(("valve", "opening"))
        );
        for bad in [
            "site/plant/valve/opening",
            "site/plant/valve/opening/set/extra",
            "site/plant//opening/set",
            "site/plant/valve//set",
            "site/plantx/valve/opening/set",
            "other/valve/opening/set",
            "site/plant/valve/opening/result",
        ] {
            assert_eq!(topics.parse_command(bad), None, "{bad}");
        }
        let long = format!("site/plant/{}/f/set", "d".repeat(MAX_TOPIC_LEN));
        assert_eq!(topics.parse_command(&long), None);
    }

    #[test]
    fn words() {
        assert!(is_ha_online(b" Online\n"));
        assert!(!is_ha_online(b"offline"));
        assert!(!is_ha_online(&[0xff]));
        assert_eq!(availability_word(true), ONLINE);
        assert_eq!(availability_word(false), OFFLINE);
    }
}
