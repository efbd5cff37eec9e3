//! An MQTT subscriber that hands each message, as it arrives, to a function of its owner: for
//! the benches, whose runs are too long or too large to keep every message as [`TestClient`]
//! does, and which note only what they measure (an arrival's instant, a count, the last
//! document).
//!
//! [`TestClient`]: crate::TestClient

use std::time::Duration;

use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio::task::JoinHandle;

/// A subscriber whose messages go to its `note` function; it disconnects when dropped.
pub struct Recorder {
    task: JoinHandle<()>,
}

impl Recorder {
    /// Connects with `options` (the caller's client id, keep-alive, session and in-flight
    /// window), subscribes to each of `subscriptions` and returns once the broker has
    /// acknowledged them all. From then on every message received goes to `note` (topic,
    /// payload) in the client's own task; across a broker's restart the client connects again
    /// (with a persistent session, what was queued for it follows). `nodelay` sends its
    /// acknowledgements at once (`TCP_NODELAY`), for a bench that times arrivals.
    pub async fn start(
        options: MqttOptions,
        nodelay: bool,
        subscriptions: &[(&str, QoS)],
        mut note: impl FnMut(&str, &[u8]) + Send + 'static,
    ) -> anyhow::Result<Recorder> {
        let (client, mut eventloop) = AsyncClient::new(options, 64);
        if nodelay {
            let mut network = eventloop.network_options();
            network.set_tcp_nodelay(true);
            eventloop.set_network_options(network);
        }
        for (filter, qos) in subscriptions {
            client.subscribe(*filter, *qos).await?;
        }
        let expected = subscriptions.len();
        let (subscribed_tx, subscribed_rx) = tokio::sync::oneshot::channel();
        let task = tokio::spawn(async move {
            // The client's requests end when it is dropped: it lives as long as its loop.
            let _client = client;
            let mut subscribed_tx = Some(subscribed_tx);
            let mut acknowledged = 0;
            loop {
                match eventloop.poll().await {
                    Ok(Event::Incoming(Packet::Publish(publish))) => {
                        note(&publish.topic, &publish.payload);
                    }
                    Ok(Event::Incoming(Packet::SubAck(_))) => {
                        acknowledged += 1;
                        if acknowledged >= expected {
                            if let Some(subscribed) = subscribed_tx.take() {
                                let _ = subscribed.send(());
                            }
                        }
                    }
                    Ok(_) => {}
                    // The broker is away: tried again soon.
                    Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
                }
            }
        });
        tokio::time::timeout(Duration::from_secs(10), subscribed_rx).await??;
        Ok(Recorder { task })
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.task.abort();
    }
}
