//! The writer task: it hands each request the driver takes from the outbox to the MQTT client,
//! waiting for room in the client's short queue. A history publish is handed only while the
//! link is up; otherwise it goes back to the driver to be journaled.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use rumqttc::AsyncClient;
use tokio::sync::mpsc;

use super::connection::{LinkEvent, LinkFlag};
use super::history_stream::is_history;
use super::outbox::ClientOrder;
use super::oversized::SubscriptionWatch;
use crate::bridge::core::Publish;

/// How long the writer waits before offering a history publish to a full client queue again.
const HANDOVER_RETRY: Duration = Duration::from_millis(10);

/// The writer task: hands each request to the client, waiting for room in its queue. A history
/// publish is handed only while the link is up; otherwise it goes back to the bridge
/// ([`LinkEvent::Unsent`]) to be journaled.
pub(super) fn spawn_writer(
    client: AsyncClient,
    mut requests: mpsc::Receiver<ClientOrder>,
    (link, link_tx, in_writer, subscriptions): (
        LinkFlag,
        mpsc::Sender<LinkEvent>,
        Arc<AtomicUsize>,
        SubscriptionWatch,
    ),
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut client_gone = false;
        while let Some(request) = requests.recv().await {
            let result = match request {
                // The client has ended (a stop): history publishes still go back for the
                // journal, the rest has nowhere to go.
                ClientOrder::Publish(publish)
                    if client_gone && is_history(&publish.topic, publish.retain) =>
                {
                    let _ = link_tx.send(LinkEvent::Unsent(publish)).await;
                    Ok(())
                }
                _ if client_gone => Ok(()),
                ClientOrder::Publish(publish) if is_history(&publish.topic, publish.retain) => {
                    hand_history(&client, publish, &link, &link_tx).await
                }
                ClientOrder::Publish(publish) => {
                    client
                        .publish(publish.topic, publish.qos, publish.retain, publish.payload)
                        .await
                }
                // One left out (it keeps bringing an oversized retained message) is not sent.
                ClientOrder::Subscribe { filter, qos } => {
                    if subscriptions.handing(&filter, Instant::now()) {
                        client.subscribe(filter, qos).await
                    } else {
                        Ok(())
                    }
                }
                ClientOrder::Unsubscribe { filter } => client.unsubscribe(filter).await,
                ClientOrder::Disconnect => client.disconnect().await,
            };
            in_writer.fetch_sub(1, Ordering::SeqCst);
            if let Err(error) = result {
                // Only when the event loop has ended (shutdown).
                tracing::debug!(%error, "MQTT client gone");
                client_gone = true;
            }
        }
    })
}

/// One history publish to the client: offered while the link is up (never waiting inside the
/// client's queue, where a lost connection would leave it to be sent ahead of older journaled
/// records), given back once it is down.
async fn hand_history(
    client: &AsyncClient,
    publish: Publish,
    link: &LinkFlag,
    link_tx: &mpsc::Sender<LinkEvent>,
) -> Result<(), rumqttc::ClientError> {
    loop {
        if !link.load(Ordering::SeqCst) {
            // Refused only when the bridge is gone (shutdown).
            let _ = link_tx.send(LinkEvent::Unsent(publish)).await;
            return Ok(());
        }
        let offered = client.try_publish(
            publish.topic.clone(),
            publish.qos,
            publish.retain,
            publish.payload.clone(),
        );
        match offered {
            Ok(()) => return Ok(()),
            Err(_) if !link_tx.is_closed() => tokio::time::sleep(HANDOVER_RETRY).await,
            Err(error) => return Err(error),
        }
    }
}
