//! [`Topics`]: every topic, subscription filter and Home Assistant identifier one gateway
//! builds, from its client id, its prefix and the discovery prefix. Reading a topic back is
//! [`Topics::classify`]'s ([`super::kind`]).

use std::collections::HashSet;

use rtu2mqtt_profile::topic_levels::{
    AVAILABILITY, GATEWAY_DEVICE, HISTORY, REFRESH, RESULT, SET, STATS, STATUS,
};

use super::words::DEFAULT_DISCOVERY_PREFIX;

/// `<prefix>/<device>`: the topic of a device's JSON view.
pub fn json_view_topic(prefix: &str, device: &str) -> String {
    format!("{prefix}/{device}")
}

/// Every topic and identifier of one gateway; [`Topics::classify`] reads a topic back.
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
        format!("{}/{device}/{field}/{SET}", self.prefix)
    }

    /// `<prefix>/<device>/<field>/result`: the outcome of each command.
    pub fn result_topic(&self, device: &str, field: &str) -> String {
        format!("{}/{device}/{field}/{RESULT}", self.prefix)
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
        format!(
            "{}/{GATEWAY_DEVICE}/{}/{STATUS}",
            self.prefix, self.client_id
        )
    }

    /// `<prefix>/gateway/<client_id>/stats`: the gateway's statistics summary.
    pub fn gateway_stats_topic(&self) -> String {
        format!(
            "{}/{GATEWAY_DEVICE}/{}/{STATS}",
            self.prefix, self.client_id
        )
    }

    /// `<prefix>/gateway/<client_id>/stats/<line>`: one line's statistics, its devices'
    /// included (one document per line keeps each one bounded, whatever the number of lines).
    pub fn line_stats_topic(&self, line: &str) -> String {
        format!("{}/{line}", self.gateway_stats_topic())
    }

    /// The subscription that carries every command: `<prefix>/+/+/set`.
    pub fn command_filter(&self) -> String {
        format!("{}/+/+/{SET}", self.prefix)
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

    /// What to subscribe to for finding the configs this gateway published earlier. MQTT
    /// wildcards take whole levels, so `<client_id>_+` is not a valid filter: subscribe to
    /// every device config and keep the ones [`Topics::classify`] finds to be
    /// [`TopicKind::DeviceConfig`](super::TopicKind::DeviceConfig).
    pub fn config_filter(&self) -> String {
        format!("{}/device/+/config", self.discovery_prefix)
    }

    /// `homeassistant/status`: Home Assistant's birth and last-will topic.
    pub fn ha_status_topic(&self) -> String {
        format!("{}/{STATUS}", self.discovery_prefix)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::topics::TopicKind;
    use rtu2mqtt_profile::topic_levels::reserved_name_problem;

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
            topics.classify("plant/valve/refresh"),
            TopicKind::Refresh { device: "valve" }
        );
        for other in [
            "plant/valve/availability",
            "plant/valve/refresh/set",
            "plant//refresh",
            "other/valve/refresh",
        ] {
            assert!(
                !matches!(topics.classify(other), TopicKind::Refresh { .. }),
                "{other}"
            );
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
            topics.classify("ha/device/edge1_valve/config"),
            TopicKind::DeviceConfig { device: "valve" }
        );
        assert_eq!(
            topics.classify("ha/device/other_valve/config"),
            TopicKind::Other
        );
        assert_eq!(
            topics.unique_id_collisions([("a", "b_c"), ("a_b", "c"), ("v", "x")]),
            vec!["edge1_a_b_c".to_string()]
        );
    }
}
