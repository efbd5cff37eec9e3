//! Which broker the demo talks to and under which prefix: the one named by `--broker`, the
//! embedded one, or an MQTT broker already on the port; and, on a broker others use, a look for
//! gateways already online so that the demo never takes over their topics.

use std::time::Duration;

use anyhow::{bail, Context as _};
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};

use crate::broker::{self, BrokerError};
use rtu2mqtt::config::mqtt;

/// How long the look for running gateways waits for the broker's answer.
pub(super) const PROBE_CONNECT: Duration = Duration::from_secs(5);

/// After the subscription is acknowledged, how long retained statuses may keep arriving.
pub(super) const PROBE_SETTLE: Duration = Duration::from_millis(500);

/// [`BrokerEndpoint::origin`] of the broker the demo started itself: nobody else is on it.
pub(super) const EMBEDDED_ORIGIN: &str = "embedded broker";

/// The prefix the demo falls back to on a broker where a gateway already serves the example's.
pub(super) const SHARED_BROKER_PREFIX: &str = "demo";

/// Where the demo's MQTT traffic goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct BrokerEndpoint {
    pub(super) host: String,
    pub(super) port: u16,
    /// Shown in the header: "embedded broker", "existing broker", "--broker".
    pub(super) origin: &'static str,
}

impl BrokerEndpoint {
    pub(super) fn url(&self) -> String {
        if self.host.contains(':') {
            format!("mqtt://[{}]:{}", self.host, self.port)
        } else {
            format!("mqtt://{}:{}", self.host, self.port)
        }
    }

    /// `mosquitto_pub`/`mosquitto_sub` options reaching it (none for the default 127.0.0.1:1883
    /// and localhost, to keep the hints short).
    pub(super) fn client_options(&self) -> String {
        let host = match self.host.as_str() {
            "127.0.0.1" | "localhost" => String::new(),
            host => format!("-h {host} "),
        };
        let port = if self.port == 1883 {
            String::new()
        } else {
            format!("-p {} ", self.port)
        };
        format!("{host}{port}")
    }
}

/// `mqtt://host[:port]` (or a bare `host[:port]`) as host and port, read as the configuration's
/// `mqtt.url` is; the demo talks plain MQTT only.
pub(super) fn parse_broker_url(url: &str) -> anyhow::Result<(String, u16)> {
    let url = if url.contains("://") {
        url.to_string()
    } else {
        format!("mqtt://{url}")
    };
    let endpoint = mqtt::parse_broker_url(&url).map_err(|problem| anyhow::anyhow!(problem))?;
    if endpoint.tls {
        bail!("`{url}`: the demo talks plain MQTT only (mqtt://host:port)");
    }
    Ok((endpoint.host, endpoint.port))
}

/// The given broker, the embedded one on `port`, or (when `port` is taken by something that
/// answers MQTT, as the `mosquitto` service Debian starts after installing it) that one.
pub(super) fn choose_broker(broker: Option<String>, port: u16) -> anyhow::Result<BrokerEndpoint> {
    if let Some(url) = broker {
        let (host, port) = parse_broker_url(&url)?;
        return Ok(BrokerEndpoint {
            host,
            port,
            origin: "--broker",
        });
    }
    if port == 0 {
        bail!("--port 0: give the embedded broker a port (1883 by default)");
    }
    match broker::start(port) {
        Ok(embedded) => Ok(BrokerEndpoint {
            host: embedded.addr().ip().to_string(),
            port: embedded.addr().port(),
            origin: EMBEDDED_ORIGIN,
        }),
        Err(error @ BrokerError::PortInUse { .. }) => {
            let address = std::net::SocketAddr::from(([127, 0, 0, 1], port));
            if broker::mqtt_handshake(address).is_ok() {
                tracing::warn!(
                    "127.0.0.1:{port} is already served by an MQTT broker: the demo uses it \
                     (--port N starts the embedded broker on another port)"
                );
                Ok(BrokerEndpoint {
                    host: "127.0.0.1".to_string(),
                    port,
                    origin: "existing broker",
                })
            } else {
                Err(error.into())
            }
        }
        Err(error) => Err(error.into()),
    }
}

/// Where on the broker the demo publishes: the example's prefix, or another one when a gateway
/// already serves the example's prefix there.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Placement {
    pub(super) prefix: Option<String>,
    /// Said loudly in the introduction and under the table when the prefix had to change.
    pub(super) notice: Option<String>,
}

/// Gateway ids whose retained `<prefix>/gateway/<id>/status` is `online` on `endpoint`.
pub(super) async fn gateways_online(
    endpoint: &BrokerEndpoint,
    prefix: &str,
) -> anyhow::Result<Vec<String>> {
    let client_id = format!("rtu2mqtt-demo-probe-{}", std::process::id());
    let mut options = MqttOptions::new(client_id, endpoint.host.clone(), endpoint.port);
    options.set_keep_alive(Duration::from_secs(30));
    options.set_clean_session(true);
    let (client, mut event_loop) = AsyncClient::new(options, 16);
    let filter = format!("{prefix}/gateway/+/status");
    let mut online = Vec::new();
    let mut settled_at: Option<tokio::time::Instant> = None;
    let connect_deadline = tokio::time::Instant::now() + PROBE_CONNECT;
    loop {
        let deadline = settled_at.unwrap_or(connect_deadline);
        let event = match tokio::time::timeout_at(deadline, event_loop.poll()).await {
            Ok(event) => event,
            Err(_) if settled_at.is_some() => break,
            Err(_) => bail!(
                "{}: no answer from the broker within {PROBE_CONNECT:?}",
                endpoint.url()
            ),
        };
        match event.with_context(|| format!("cannot reach the broker at {}", endpoint.url()))? {
            Event::Incoming(Packet::ConnAck(_)) => {
                client
                    .subscribe(filter.clone(), QoS::AtMostOnce)
                    .await
                    .context("asking the broker for gateway statuses")?;
            }
            Event::Incoming(Packet::SubAck(_)) => {
                settled_at = Some(tokio::time::Instant::now() + PROBE_SETTLE);
            }
            Event::Incoming(Packet::Publish(publish)) => {
                let id = publish
                    .topic
                    .strip_prefix(&format!("{prefix}/gateway/"))
                    .and_then(|rest| rest.strip_suffix("/status"));
                if let Some(id) = id {
                    if publish.retain && publish.payload.as_ref() == b"online" {
                        online.push(id.to_string());
                    }
                }
            }
            _ => {}
        }
    }
    let _ = client.try_disconnect();
    online.sort();
    online.dedup();
    Ok(online)
}

/// The example's prefix unless a gateway is online under it on this broker (a real one, or
/// another demo): then [`SHARED_BROKER_PREFIX`], so that the demo neither answers that gateway's
/// commands nor leaves its devices `offline` when it stops. Refuses when both are taken.
pub(super) async fn choose_placement(
    endpoint: &BrokerEndpoint,
    example_prefix: &str,
) -> anyhow::Result<Placement> {
    if endpoint.origin == EMBEDDED_ORIGIN {
        return Ok(Placement {
            prefix: None,
            notice: None,
        });
    }
    let taken = gateways_online(endpoint, example_prefix).await?;
    if taken.is_empty() {
        return Ok(Placement {
            prefix: None,
            notice: None,
        });
    }
    let also_taken = gateways_online(endpoint, SHARED_BROKER_PREFIX).await?;
    if !also_taken.is_empty() {
        bail!(
            "{}: gateways are online under both `{example_prefix}/` ({}) and \
             `{SHARED_BROKER_PREFIX}/` ({}); the demo would take over their topics. Run it on \
             its embedded broker (without --broker, --port N if 1883 is taken)",
            endpoint.url(),
            taken.join(", "),
            also_taken.join(", ")
        );
    }
    let notice = format!(
        "NOTE: gateway {} is online under {example_prefix}/ on this broker: the demo uses \
         {SHARED_BROKER_PREFIX}/ instead (no Home Assistant discovery)",
        taken.join(", ")
    );
    tracing::warn!("{notice}");
    Ok(Placement {
        prefix: Some(SHARED_BROKER_PREFIX.to_string()),
        notice: Some(notice),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broker_urls() {
        assert_eq!(
            parse_broker_url("mqtt://10.0.0.5:1884").unwrap(),
            ("10.0.0.5".to_string(), 1884)
        );
        assert_eq!(
            parse_broker_url("mqtt://broker.local").unwrap(),
            ("broker.local".to_string(), 1883)
        );
        assert_eq!(
            parse_broker_url("localhost:1883").unwrap(),
            ("localhost".to_string(), 1883)
        );
        assert!(parse_broker_url("mqtts://host:8883").is_err());
        assert!(parse_broker_url("mqtt://host:99999").is_err());
        assert!(parse_broker_url("mqtt://user@host").is_err());
        assert!(parse_broker_url("mqtt://").is_err());
        assert!(parse_broker_url("mqtt://host:0").is_err());
        assert_eq!(
            parse_broker_url("mqtt://[::1]:1884").unwrap(),
            ("::1".to_string(), 1884)
        );
    }

    #[test]
    fn hints_stay_short_for_the_default_broker() {
        let endpoint = BrokerEndpoint {
            host: "127.0.0.1".to_string(),
            port: 1883,
            origin: "test",
        };
        assert_eq!(endpoint.client_options(), "");
    }
}
