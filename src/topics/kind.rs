//! [`Topics::classify`]: what a topic is to the gateway, read once, with the levels it names
//! ([`TopicKind`]): the inverse of the names [`Topics`] builds. The bridge routes every
//! incoming message by it, the console checks a command's topic with it, and the demo folds
//! what it watches with it.

use rtu2mqtt_profile::topic_levels::{
    AVAILABILITY, GATEWAY_DEVICE, HISTORY, REFRESH, RESULT, SET, STATS, STATUS,
};

use super::names::Topics;
use super::words::MAX_TOPIC_LEN;

/// What a topic is, with the levels it names (borrowed from the topic).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TopicKind<'t> {
    /// `<prefix>/gateway/<gateway>/status`: a gateway's birth and Will (this gateway's when
    /// `gateway` is its client id).
    GatewayStatus { gateway: &'t str },
    /// `<prefix>/gateway/<gateway>/stats`, or one line's `…/stats/<line>`.
    GatewayStats {
        gateway: &'t str,
        line: Option<&'t str>,
    },
    /// `<prefix>/<device>/availability`.
    Availability { device: &'t str },
    /// `<prefix>/<device>/refresh`: a request to read every block of the device.
    Refresh { device: &'t str },
    /// `<prefix>/<device>/history`: the device's change sets.
    History { device: &'t str },
    /// `<prefix>/<device>/<field>`: a field's state.
    State { device: &'t str, field: &'t str },
    /// `<prefix>/<device>/<field>/set`: a command.
    Command { device: &'t str, field: &'t str },
    /// `<prefix>/<device>/<field>/result`: a command's outcome.
    Result { device: &'t str, field: &'t str },
    /// `<discovery_prefix>/status`: Home Assistant's birth and Will.
    HaStatus,
    /// `<discovery_prefix>/device/<client_id>_<device>/config`: a discovery document this
    /// gateway may have published (`device` is `gateway` for its own).
    DeviceConfig { device: &'t str },
    /// `<discovery_prefix>/device/<client_id>_gateway/<line>/config`: one line's document.
    LineConfig { line: &'t str },
    /// No topic of this gateway's contract (or one too long to look at).
    Other,
}

impl Topics {
    /// What `topic` is. Every level it names is non-empty. The gateway's own space (under
    /// the prefix) is read before Home Assistant's, which the configuration keeps apart from
    /// it whenever discovery is on.
    pub fn classify<'t>(&self, topic: &'t str) -> TopicKind<'t> {
        if topic.len() > MAX_TOPIC_LEN {
            return TopicKind::Other;
        }
        let own = self
            .under_prefix(topic)
            .map_or(TopicKind::Other, classify_under_prefix);
        own.or_else(|| self.classify_discovery(topic))
    }

    /// What follows `<prefix>/` in `topic`.
    fn under_prefix<'t>(&self, topic: &'t str) -> Option<&'t str> {
        topic.strip_prefix(self.prefix.as_str())?.strip_prefix('/')
    }

    /// A topic in Home Assistant's space, as far as this gateway is concerned.
    fn classify_discovery<'t>(&self, topic: &'t str) -> TopicKind<'t> {
        let Some(rest) = topic
            .strip_prefix(self.discovery_prefix.as_str())
            .and_then(|rest| rest.strip_prefix('/'))
        else {
            return TopicKind::Other;
        };
        if rest == STATUS {
            return TopicKind::HaStatus;
        }
        let Some(object) = rest
            .strip_prefix("device/")
            .and_then(|object| object.strip_suffix("/config"))
            .and_then(|object| object.strip_prefix(self.client_id.as_str()))
            .and_then(|object| object.strip_prefix('_'))
        else {
            return TopicKind::Other;
        };
        match object.split_once('/') {
            None if !object.is_empty() => TopicKind::DeviceConfig { device: object },
            Some((GATEWAY_DEVICE, line)) if !line.is_empty() && !line.contains('/') => {
                TopicKind::LineConfig { line }
            }
            _ => TopicKind::Other,
        }
    }
}

impl<'t> TopicKind<'t> {
    /// The device the topic names, if it names one.
    pub fn device(&self) -> Option<&'t str> {
        match *self {
            TopicKind::Availability { device }
            | TopicKind::Refresh { device }
            | TopicKind::History { device }
            | TopicKind::State { device, .. }
            | TopicKind::Command { device, .. }
            | TopicKind::Result { device, .. }
            | TopicKind::DeviceConfig { device } => Some(device),
            _ => None,
        }
    }

    /// This kind, or what `other` finds when this is [`TopicKind::Other`].
    fn or_else(self, other: impl FnOnce() -> TopicKind<'t>) -> TopicKind<'t> {
        match self {
            TopicKind::Other => other(),
            kind => kind,
        }
    }
}

/// What the levels under the prefix name.
fn classify_under_prefix(rest: &str) -> TopicKind<'_> {
    let levels: Vec<&str> = rest.split('/').collect();
    if levels.iter().any(|level| level.is_empty()) {
        return TopicKind::Other;
    }
    match levels[..] {
        [GATEWAY_DEVICE, gateway, STATUS] => TopicKind::GatewayStatus { gateway },
        [GATEWAY_DEVICE, gateway, STATS] => TopicKind::GatewayStats {
            gateway,
            line: None,
        },
        [GATEWAY_DEVICE, gateway, STATS, line] => TopicKind::GatewayStats {
            gateway,
            line: Some(line),
        },
        [device, AVAILABILITY] => TopicKind::Availability { device },
        [device, REFRESH] => TopicKind::Refresh { device },
        [device, HISTORY] => TopicKind::History { device },
        [device, field] => TopicKind::State { device, field },
        [device, field, SET] => TopicKind::Command { device, field },
        [device, field, RESULT] => TopicKind::Result { device, field },
        _ => TopicKind::Other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_topics_are_parsed_strictly() {
        let topics = Topics::new("gw", "site/plant");
        assert_eq!(
            topics.classify("site/plant/valve/opening/set"),
            TopicKind::Command {
                device: "valve",
                field: "opening"
            }
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
            assert!(
                !matches!(topics.classify(bad), TopicKind::Command { .. }),
                "{bad}"
            );
        }
        let long = format!("site/plant/{}/f/set", "d".repeat(MAX_TOPIC_LEN));
        assert_eq!(topics.classify(&long), TopicKind::Other);
    }

    #[test]
    fn every_topic_built_is_read_back_as_what_it_is() {
        let topics = Topics::new("edge1", "site/plant").with_discovery_prefix("ha");
        let (device, field) = ("valve", "opening");
        for (topic, kind) in [
            (
                topics.gateway_status_topic(),
                TopicKind::GatewayStatus { gateway: "edge1" },
            ),
            (
                topics.gateway_stats_topic(),
                TopicKind::GatewayStats {
                    gateway: "edge1",
                    line: None,
                },
            ),
            (
                topics.line_stats_topic("north"),
                TopicKind::GatewayStats {
                    gateway: "edge1",
                    line: Some("north"),
                },
            ),
            (
                topics.availability_topic(device),
                TopicKind::Availability { device },
            ),
            (topics.refresh_topic(device), TopicKind::Refresh { device }),
            (topics.history_topic(device), TopicKind::History { device }),
            (
                topics.state_topic(device, field),
                TopicKind::State { device, field },
            ),
            (
                topics.command_topic(device, field),
                TopicKind::Command { device, field },
            ),
            (
                topics.result_topic(device, field),
                TopicKind::Result { device, field },
            ),
            (topics.ha_status_topic(), TopicKind::HaStatus),
            (
                topics.config_topic(device),
                TopicKind::DeviceConfig { device },
            ),
            (
                topics.gateway_config_topic(),
                TopicKind::DeviceConfig { device: "gateway" },
            ),
            (
                topics.line_config_topic("north"),
                TopicKind::LineConfig { line: "north" },
            ),
            (topics.json_view_topic(device), TopicKind::Other),
        ] {
            assert_eq!(topics.classify(&topic), kind, "{topic}");
        }
    }

    #[test]
    fn topics_of_others_and_malformed_topics_are_no_kind_of_ours() {
        let topics = Topics::new("edge1", "plant").with_discovery_prefix("ha");
        assert_eq!(
            topics.classify("plant/gateway/edge2/status"),
            TopicKind::GatewayStatus { gateway: "edge2" }
        );
        for other in [
            "plant",
            "plant/valve",
            "plant//availability",
            "plant/valve/opening/set/extra",
            "plant/gateway//status",
            "plantx/valve/availability",
            "ha/device/edge2_valve/config",
            "ha/device/edge1_/config",
            "ha/device/edge1_valve/x/config",
            "ha/device/edge1_gateway//config",
            "ha/device/edge1_valve/config/x",
            "ha/statusx",
        ] {
            assert_eq!(topics.classify(other), TopicKind::Other, "{other}");
        }
    }

    #[test]
    fn the_gateways_own_space_is_read_before_home_assistants() {
        // Discovery off, the prefixes may nest: a topic of both spaces is the gateway's.
        let topics = Topics::new("edge1", "plant").with_discovery_prefix("plant/gateway/edge1");
        assert_eq!(
            topics.classify("plant/gateway/edge1/status"),
            TopicKind::GatewayStatus { gateway: "edge1" }
        );
    }
}
