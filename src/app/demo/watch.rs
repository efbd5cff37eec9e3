//! The demo's eyes: a subscription like any MQTT user's, forwarding every message under the
//! demo's prefix to the view until shutdown.

use std::time::Duration;

use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio::sync::mpsc;

use super::endpoint::BrokerEndpoint;
use crate::broker;
use crate::shutdown::Shutdown;

/// Subscribes to `filter` like any MQTT user and forwards every message until shutdown;
/// reconnects with a pause (the broker may start after the view, or restart).
pub(super) async fn watch_broker(
    endpoint: BrokerEndpoint,
    filter: String,
    messages_tx: mpsc::Sender<(String, Vec<u8>)>,
    mut shutdown: Shutdown,
) {
    let client_id = format!("rtu2mqtt-demo-view-{}", std::process::id());
    let mut options = MqttOptions::new(client_id, endpoint.host.clone(), endpoint.port);
    options.set_keep_alive(Duration::from_secs(30));
    options.set_max_packet_size(broker::MAX_PAYLOAD_SIZE, broker::MAX_PAYLOAD_SIZE);
    let (client, mut event_loop) = AsyncClient::new(options, 64);
    loop {
        let event = tokio::select! {
            _ = shutdown.fired() => break,
            event = event_loop.poll() => event,
        };
        match event {
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                if let Err(error) = client.try_subscribe(filter.clone(), QoS::AtMostOnce) {
                    tracing::warn!(%error, "demo view: cannot subscribe");
                }
            }
            Ok(Event::Incoming(Packet::Publish(publish))) => {
                if messages_tx
                    .send((publish.topic.clone(), publish.payload.to_vec()))
                    .await
                    .is_err()
                {
                    break;
                }
            }
            Ok(_) => {}
            Err(error) => {
                tracing::debug!(%error, "demo view: broker connection lost; retrying");
                tokio::select! {
                    _ = shutdown.fired() => break,
                    _ = tokio::time::sleep(Duration::from_millis(500)) => {}
                }
            }
        }
    }
    let _ = client.try_disconnect();
}
