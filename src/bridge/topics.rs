//! The topic names of the contract (`<prefix>/<device>/<field>`, `…/set`, `…/result`,
//! `…/availability`, `<prefix>/gateway/<client_id>/status` and `/stats`) and the bounded
//! parsing of incoming command topics. Pure string work.

/// Longest command topic looked at; anything longer is dropped unparsed.
pub const MAX_TOPIC_LEN: usize = 512;

/// Builds and parses the gateway's topics.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topics {
    prefix: String,
    client_id: String,
}

impl Topics {
    pub fn new(prefix: &str, client_id: &str) -> Self {
        Topics {
            prefix: prefix.to_string(),
            client_id: client_id.to_string(),
        }
    }

    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// `plant/<device>/<field>`: the retained state.
    pub fn state(&self, device: &str, field: &str) -> String {
        format!("{}/{device}/{field}", self.prefix)
    }

    /// `plant/<device>/<field>/set`.
    pub fn set(&self, device: &str, field: &str) -> String {
        format!("{}/{device}/{field}/set", self.prefix)
    }

    /// `plant/<device>/<field>/result`.
    pub fn result(&self, device: &str, field: &str) -> String {
        format!("{}/{device}/{field}/result", self.prefix)
    }

    /// `plant/<device>/availability`.
    pub fn availability(&self, device: &str) -> String {
        format!("{}/{device}/availability", self.prefix)
    }

    /// `plant/gateway/<client_id>/status`: birth `online`, Will `offline`.
    pub fn gateway_status(&self) -> String {
        format!("{}/gateway/{}/status", self.prefix, self.client_id)
    }

    /// `plant/gateway/<client_id>/stats`.
    pub fn gateway_stats(&self) -> String {
        format!("{}/gateway/{}/stats", self.prefix, self.client_id)
    }

    /// The subscription that carries every command: `plant/+/+/set`.
    pub fn command_filter(&self) -> String {
        format!("{}/+/+/set", self.prefix)
    }

    /// `(device, field)` of a command topic, or None when the topic is not exactly
    /// `<prefix>/<device>/<field>/set` with non-empty levels (or is too long to look at).
    pub fn parse_command<'t>(&self, topic: &'t str) -> Option<(&'t str, &'t str)> {
        if topic.len() > MAX_TOPIC_LEN {
            return None;
        }
        let rest = topic
            .strip_prefix(self.prefix.as_str())?
            .strip_prefix('/')?;
        let mut levels = rest.splitn(4, '/');
        let device = levels.next()?;
        let field = levels.next()?;
        let set = levels.next()?;
        if levels.next().is_some() || set != "set" || device.is_empty() || field.is_empty() {
            return None;
        }
        Some((device, field))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contract_topics() {
        let topics = Topics::new("plant", "rtu2mqtt-edge1");
        assert_eq!(topics.state("valve", "opening"), "plant/valve/opening");
        assert_eq!(topics.set("valve", "opening"), "plant/valve/opening/set");
        assert_eq!(
            topics.result("valve", "opening"),
            "plant/valve/opening/result"
        );
        assert_eq!(topics.availability("valve"), "plant/valve/availability");
        assert_eq!(
            topics.gateway_status(),
            "plant/gateway/rtu2mqtt-edge1/status"
        );
        assert_eq!(topics.gateway_stats(), "plant/gateway/rtu2mqtt-edge1/stats");
        assert_eq!(topics.command_filter(), "plant/+/+/set");
    }

    /// Discovery documents name the same topics the bridge publishes on (built separately in
    /// `discovery.rs` for now): they must agree, or Home Assistant listens in the wrong place.
    #[test]
    fn discovery_names_the_topics_the_bridge_uses() {
        let topics = Topics::new("site/plant", "edge1");
        let discovery = crate::bridge::discovery::DiscoveryContext::new("edge1", "site/plant");
        assert_eq!(
            discovery.state_topic("valve", "opening"),
            topics.state("valve", "opening")
        );
        assert_eq!(
            discovery.command_topic("valve", "opening"),
            topics.set("valve", "opening")
        );
        assert_eq!(
            discovery.availability_topic("valve"),
            topics.availability("valve")
        );
        assert_eq!(discovery.gateway_status_topic(), topics.gateway_status());
        assert_eq!(discovery.gateway_stats_topic(), topics.gateway_stats());
    }

    #[test]
    fn command_topics_are_parsed_strictly() {
        let topics = Topics::new("site/plant", "gw");
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
}
