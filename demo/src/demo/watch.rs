//! The demo's eyes: subscriptions like any MQTT user's, forwarding every message under the
//! demo's prefix (and its discovery documents) with its retain flag until shutdown.

use std::time::Duration;

use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio::sync::mpsc;

use super::endpoint::BrokerEndpoint;
use crate::broker;
use tokio_util::sync::CancellationToken;

/// A message as the view receives it.
#[derive(Debug, Clone)]
pub(super) struct Seen {
    pub(super) topic: String,
    pub(super) payload: Vec<u8>,
    /// Delivered from the broker's store on subscribing (possibly from an earlier run).
    pub(super) retained: bool,
}

/// Subscribes to `filters` like any MQTT user and forwards every message until shutdown;
/// reconnects with a pause (the broker may start after the view, or restart).
pub(super) async fn watch_broker(
    endpoint: BrokerEndpoint,
    filters: Vec<String>,
    messages_tx: mpsc::Sender<Seen>,
    shutdown: CancellationToken,
) {
    let client_id = format!("rtu2mqtt-demo-view-{}", std::process::id());
    let mut options = MqttOptions::new(client_id, endpoint.host.clone(), endpoint.port);
    options.set_keep_alive(Duration::from_secs(30));
    options.set_max_packet_size(broker::MAX_PAYLOAD_SIZE, broker::MAX_PAYLOAD_SIZE);
    let (client, mut event_loop) = AsyncClient::new(options, 64);
    loop {
        let event = tokio::select! {
            _ = shutdown.cancelled() => break,
            event = event_loop.poll() => event,
        };
        match event {
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                for filter in &filters {
                    if let Err(error) = client.try_subscribe(filter.clone(), QoS::AtMostOnce) {
                        tracing::warn!(%error, "demo view: cannot subscribe");
                    }
                }
            }
            Ok(Event::Incoming(Packet::Publish(publish))) => {
                let seen = Seen {
                    topic: publish.topic.clone(),
                    payload: publish.payload.to_vec(),
                    retained: publish.retain,
                };
                if messages_tx.send(seen).await.is_err() {
                    break;
                }
            }
            Ok(_) => {}
            Err(error) => {
                tracing::debug!(%error, "demo view: broker connection lost; retrying");
                tokio::select! {
                    _ = shutdown.cancelled() => break,
                    _ = tokio::time::sleep(Duration::from_millis(500)) => {}
                }
            }
        }
    }
    let _ = client.try_disconnect();
}
