//! What the demo leaves behind on a broker it did not start: nothing. While it runs, it notes
//! every topic of its own devices and gateway it sees (`<prefix>/<device>/…`,
//! `<prefix>/gateway/<client_id>/…`) and every discovery document of its client id
//! (`<discovery_prefix>/device/<client_id>_…/config`, and the gateway's line documents
//! `<discovery_prefix>/device/<client_id>_gateway/<line>/config`); after the gateway stopped it publishes an
//! empty retained message on each, which removes whatever the broker kept there, so Home
//! Assistant on that broker shows no ghost devices and `plant/…` holds no stale values.
//! Topics of other gateways and devices are never touched.

use std::collections::BTreeSet;
use std::time::Duration;

use anyhow::{bail, Context as _};
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};

use super::endpoint::BrokerEndpoint;
use crate::broker;

/// How long the clearing may take before the demo gives up (and says so).
pub(super) const CLEAR_TIMEOUT: Duration = Duration::from_secs(5);

/// The topics the demo is answerable for, and those of them it has seen.
#[derive(Debug, Clone, Default)]
pub(super) struct Leftovers {
    /// `<prefix>/<device>/` for each configured device, and `<prefix>/gateway/<client_id>/`.
    own_levels: Vec<String>,
    /// `<discovery_prefix>/device/` and `<client_id>_`.
    discovery: Option<(String, String)>,
    seen: BTreeSet<String>,
}

impl Leftovers {
    pub(super) fn new(
        prefix: &str,
        client_id: &str,
        devices: &[String],
        discovery_prefix: Option<&str>,
    ) -> Self {
        let mut own_levels: Vec<String> = devices
            .iter()
            .map(|device| format!("{prefix}/{device}/"))
            .collect();
        own_levels.push(format!("{prefix}/gateway/{client_id}/"));
        Leftovers {
            own_levels,
            discovery: discovery_prefix
                .map(|discovery| (format!("{discovery}/device/"), format!("{client_id}_"))),
            seen: BTreeSet::new(),
        }
    }

    /// The subscriptions that show every topic [`Leftovers::note`] keeps.
    pub(super) fn discovery_filter(&self) -> Option<String> {
        self.discovery
            .as_ref()
            .map(|(levels, _)| format!("{levels}#"))
    }

    /// Remembers `topic` when it is one of the demo's own.
    pub(super) fn note(&mut self, topic: &str) {
        let own = self.own_levels.iter().any(|level| topic.starts_with(level));
        let discovered = self.discovery.as_ref().is_some_and(|(levels, id)| {
            topic
                .strip_prefix(levels.as_str())
                .and_then(|rest| rest.strip_suffix("/config"))
                .and_then(|object| object.strip_prefix(id.as_str()))
                .is_some_and(|object| match object.split_once('/') {
                    None => true,
                    // The gateway's line documents.
                    Some((node, line)) => node == "gateway" && !line.contains('/'),
                })
        });
        if own || discovered {
            self.seen.insert(topic.to_string());
        }
    }

    pub(super) fn topics(&self) -> Vec<String> {
        self.seen.iter().cloned().collect()
    }
}

/// Publishes an empty retained message on each topic (QoS 1) and waits until the broker has
/// acknowledged them all; the number cleared.
pub(super) async fn clear_retained(
    endpoint: &BrokerEndpoint,
    topics: &[String],
) -> anyhow::Result<usize> {
    if topics.is_empty() {
        return Ok(0);
    }
    let client_id = format!("rtu2mqtt-demo-cleanup-{}", std::process::id());
    let mut options = MqttOptions::new(client_id, endpoint.host.clone(), endpoint.port);
    options.set_keep_alive(Duration::from_secs(30));
    options.set_clean_session(true);
    options.set_max_packet_size(broker::MAX_PAYLOAD_SIZE, broker::MAX_PAYLOAD_SIZE);
    let (client, mut event_loop) = AsyncClient::new(options, topics.len() + 8);
    let deadline = tokio::time::Instant::now() + CLEAR_TIMEOUT;
    let mut acknowledged = 0;
    while acknowledged < topics.len() {
        let event = match tokio::time::timeout_at(deadline, event_loop.poll()).await {
            Ok(event) => event,
            Err(_) => bail!(
                "{}: {acknowledged} of {} retained topics cleared within {CLEAR_TIMEOUT:?}",
                endpoint.url(),
                topics.len()
            ),
        };
        match event.with_context(|| format!("cannot reach the broker at {}", endpoint.url()))? {
            Event::Incoming(Packet::ConnAck(_)) => {
                for topic in topics {
                    client
                        .try_publish(topic.as_str(), QoS::AtLeastOnce, true, Vec::new())
                        .context("queueing a clearing")?;
                }
            }
            Event::Incoming(Packet::PubAck(_)) => acknowledged += 1,
            _ => {}
        }
    }
    let _ = client.try_disconnect();
    // Let the DISCONNECT go out so the broker does not log a dropped connection.
    let _ = tokio::time::timeout(Duration::from_millis(200), event_loop.poll()).await;
    Ok(acknowledged)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_demos_own_topics_are_noted() {
        let devices = vec!["valve".to_string(), "air_shower".to_string()];
        let mut leftovers =
            Leftovers::new("plant", "rtu2mqtt-demo", &devices, Some("homeassistant"));
        for topic in [
            "plant/valve/opening",
            "plant/valve/availability",
            "plant/air_shower/wind/result",
            "plant/gateway/rtu2mqtt-demo/status",
            "plant/gateway/rtu2mqtt-demo/stats/commands",
            "homeassistant/device/rtu2mqtt-demo_valve/config",
            "homeassistant/device/rtu2mqtt-demo_gateway/config",
            "homeassistant/device/rtu2mqtt-demo_gateway/line-a/config",
            // Another gateway's, another device's, someone else's discovery: not ours.
            "plant/gateway/edge-1/status",
            "plant/boiler/temperature",
            "plant/valves/opening",
            "homeassistant/device/edge-1_valve/config",
            "homeassistant/device/edge-1_gateway/line-a/config",
            "homeassistant/device/rtu2mqtt-demo_valve/x/config",
            "homeassistant/sensor/rtu2mqtt-demo_valve/config",
            "homeassistant/status",
        ] {
            leftovers.note(topic);
        }
        assert_eq!(
            leftovers.topics(),
            vec![
                "homeassistant/device/rtu2mqtt-demo_gateway/config",
                "homeassistant/device/rtu2mqtt-demo_gateway/line-a/config",
                "homeassistant/device/rtu2mqtt-demo_valve/config",
                "plant/air_shower/wind/result",
                "plant/gateway/rtu2mqtt-demo/stats/commands",
                "plant/gateway/rtu2mqtt-demo/status",
                "plant/valve/availability",
                "plant/valve/opening",
            ]
        );
        assert_eq!(
            leftovers.discovery_filter().as_deref(),
            Some("homeassistant/device/#")
        );
        assert_eq!(
            Leftovers::new("demo", "x", &devices, None).discovery_filter(),
            None
        );
    }
}
