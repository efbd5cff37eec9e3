//! A small rumqttc client that records what it receives, for tests to subscribe, publish and
//! wait for messages.

use std::time::Duration;

use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio::sync::mpsc;

/// One message as a subscriber saw it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Message {
    pub topic: String,
    pub payload: Vec<u8>,
    pub retain: bool,
}

impl Message {
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.payload).into_owned()
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.payload).unwrap_or(serde_json::Value::Null)
    }
}

enum ClientEvent {
    Message(Message),
    SubAck,
}

/// A test's MQTT client: subscribe, publish, wait for messages.
pub struct TestClient {
    pub client: AsyncClient,
    rx: mpsc::UnboundedReceiver<ClientEvent>,
    /// Everything received so far, in order.
    pub received: Vec<Message>,
    task: tokio::task::JoinHandle<()>,
}

impl TestClient {
    /// Connects (clean session) and waits for the ConnAck.
    pub async fn connect(port: u16, id: &str) -> TestClient {
        let mut options = MqttOptions::new(id, "127.0.0.1", port);
        options.set_keep_alive(Duration::from_secs(5));
        options.set_max_packet_size(1024 * 1024, 1024 * 1024);
        let (client, mut eventloop) = AsyncClient::new(options, 100);
        let (tx, rx) = mpsc::unbounded_channel();
        let (connected_tx, connected_rx) = tokio::sync::oneshot::channel();
        let task = tokio::spawn(async move {
            let mut connected_tx = Some(connected_tx);
            loop {
                match eventloop.poll().await {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => {
                        if let Some(tx) = connected_tx.take() {
                            let _ = tx.send(());
                        }
                    }
                    Ok(Event::Incoming(Packet::Publish(publish))) => {
                        let message = Message {
                            topic: publish.topic.clone(),
                            payload: publish.payload.to_vec(),
                            retain: publish.retain,
                        };
                        if tx.send(ClientEvent::Message(message)).is_err() {
                            return;
                        }
                    }
                    Ok(Event::Incoming(Packet::SubAck(_))) => {
                        if tx.send(ClientEvent::SubAck).is_err() {
                            return;
                        }
                    }
                    Ok(_) => {}
                    Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
                }
            }
        });
        tokio::time::timeout(Duration::from_secs(10), connected_rx)
            .await
            .expect("test client connect timed out")
            .expect("test client event loop ended");
        TestClient {
            client,
            rx,
            received: Vec::new(),
            task,
        }
    }

    /// Subscribes and waits for the SubAck.
    pub async fn subscribe(&mut self, filter: &str) {
        self.client
            .subscribe(filter, QoS::AtLeastOnce)
            .await
            .expect("subscribe");
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        loop {
            match tokio::time::timeout_at(deadline, self.rx.recv()).await {
                Ok(Some(ClientEvent::SubAck)) => return,
                Ok(Some(ClientEvent::Message(message))) => self.received.push(message),
                _ => panic!("no SubAck for {filter}"),
            }
        }
    }

    pub async fn publish(&self, topic: &str, payload: impl Into<Vec<u8>>, retain: bool) {
        self.client
            .publish(topic, QoS::AtLeastOnce, retain, payload.into())
            .await
            .expect("publish");
    }

    /// Waits for the next message on `topic` that satisfies `accept` (messages received
    /// earlier are looked at first, from the oldest not yet taken).
    pub async fn wait_for(
        &mut self,
        topic: &str,
        timeout: Duration,
        accept: impl Fn(&Message) -> bool,
    ) -> Message {
        self.try_wait_for(topic, timeout, accept)
            .await
            .unwrap_or_else(|| {
                let seen: Vec<String> = self
                    .received
                    .iter()
                    .filter(|m| m.topic == topic)
                    .map(|m| m.text())
                    .collect();
                panic!("no matching message on {topic} within {timeout:?}; seen there: {seen:?}")
            })
    }

    /// Like [`TestClient::wait_for`] but None on timeout.
    pub async fn try_wait_for(
        &mut self,
        topic: &str,
        timeout: Duration,
        accept: impl Fn(&Message) -> bool,
    ) -> Option<Message> {
        if let Some(index) = self
            .received
            .iter()
            .position(|m| m.topic == topic && accept(m))
        {
            return Some(self.received.remove(index));
        }
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            match tokio::time::timeout_at(deadline, self.rx.recv()).await {
                Ok(Some(ClientEvent::Message(message))) => {
                    if message.topic == topic && accept(&message) {
                        return Some(message);
                    }
                    self.received.push(message);
                }
                Ok(Some(ClientEvent::SubAck)) => {}
                _ => return None,
            }
        }
    }

    /// Like [`TestClient::wait_for`], ignoring what arrived on `topic` before this call (a state change
    /// that has to happen from now on, not one seen at start-up).
    pub async fn wait_for_new(
        &mut self,
        topic: &str,
        timeout: Duration,
        accept: impl Fn(&Message) -> bool,
    ) -> Message {
        self.drain();
        self.received.retain(|m| m.topic != topic);
        self.wait_for(topic, timeout, accept).await
    }

    /// Moves whatever has arrived into `received` without waiting.
    pub fn drain(&mut self) {
        while let Ok(event) = self.rx.try_recv() {
            if let ClientEvent::Message(message) = event {
                self.received.push(message);
            }
        }
    }

    /// Waits for the next message on `topic`, whatever it says.
    pub async fn next_on(&mut self, topic: &str, timeout: Duration) -> Message {
        self.wait_for(topic, timeout, |_| true).await
    }

    /// Collects everything arriving for `duration` into `received`.
    pub async fn settle(&mut self, duration: Duration) {
        let deadline = tokio::time::Instant::now() + duration;
        while let Ok(Some(event)) = tokio::time::timeout_at(deadline, self.rx.recv()).await {
            if let ClientEvent::Message(message) = event {
                self.received.push(message);
            }
        }
    }

    /// Forgets what was received so far (after settling).
    pub fn forget(&mut self) {
        self.received.clear();
    }

    /// Messages received on `topic` (not yet taken by a wait).
    pub fn on(&self, topic: &str) -> Vec<&Message> {
        self.received.iter().filter(|m| m.topic == topic).collect()
    }
}

impl Drop for TestClient {
    fn drop(&mut self) {
        self.task.abort();
    }
}
