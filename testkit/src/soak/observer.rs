//! The soak run's MQTT client: it sends the commands and reads, across every broker restart
//! (it subscribes again on each connection), the seed dust collector's history stream and the
//! outcome of every command.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};

const DUST_HISTORY: &str = "plant/dust_collector/history";
const RESULTS: &str = "plant/+/+/result";

/// What the observer read.
#[derive(Debug, Default)]
pub struct Seen {
    /// The dust collector's history documents, in the order they came.
    pub dust_history: Vec<serde_json::Value>,
    /// `…/result` documents by outcome.
    pub outcomes: BTreeMap<String, u64>,
    pub connections: u64,
}

/// The client and what it read.
pub struct Observer {
    pub client: AsyncClient,
    pub seen: Arc<Mutex<Seen>>,
}

fn lock(seen: &Mutex<Seen>) -> std::sync::MutexGuard<'_, Seen> {
    seen.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Observer {
    /// Connects to the broker on `port` (and again whenever it is back).
    pub fn start(port: u16) -> Observer {
        let mut options = MqttOptions::new("soak-observer", "127.0.0.1", port);
        options.set_keep_alive(Duration::from_secs(5));
        options.set_max_packet_size(1 << 20, 1 << 20);
        let (client, mut eventloop) = AsyncClient::new(options, 1000);
        let seen = Arc::new(Mutex::new(Seen::default()));
        let shared = Arc::clone(&seen);
        let subscriber = client.clone();
        tokio::spawn(async move {
            loop {
                match eventloop.poll().await {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => {
                        lock(&shared).connections += 1;
                        for filter in [DUST_HISTORY, RESULTS] {
                            let _ = subscriber.try_subscribe(filter, QoS::AtLeastOnce);
                        }
                    }
                    Ok(Event::Incoming(Packet::Publish(publish))) => {
                        let Ok(document) =
                            serde_json::from_slice::<serde_json::Value>(&publish.payload)
                        else {
                            continue;
                        };
                        let mut seen = lock(&shared);
                        if publish.topic == DUST_HISTORY {
                            seen.dust_history.push(document);
                        } else if let Some(outcome) = document["outcome"].as_str() {
                            *seen.outcomes.entry(outcome.to_string()).or_default() += 1;
                        }
                    }
                    Ok(_) => {}
                    // The broker is away: tried again soon, before the gateway's back-off ends.
                    Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
                }
            }
        });
        Observer { client, seen }
    }

    pub fn lock(&self) -> std::sync::MutexGuard<'_, Seen> {
        lock(&self.seen)
    }

    /// Sends `payload` to `topic` (QoS 1); false when the client could not take it.
    pub fn command(&self, topic: &str, payload: &str) -> bool {
        self.client
            .try_publish(topic, QoS::AtLeastOnce, false, payload.as_bytes().to_vec())
            .is_ok()
    }
}

/// The dust collector's alarm bits after each history document (folding the change sets, as
/// a historian would), repeats collapsed.
pub fn alarm_states(documents: &[serde_json::Value]) -> Vec<u16> {
    let mut bits = [false; 3];
    let mut states: Vec<u16> = Vec::new();
    for document in documents {
        let values = &document["values"];
        for (at, name) in ["temperature_alarm", "filter_alarm", "fan_alarm"]
            .into_iter()
            .enumerate()
        {
            if let Some(on) = values[name].as_bool() {
                bits[at] = on;
            }
        }
        let state = bits
            .iter()
            .enumerate()
            .fold(0u16, |acc, (at, &on)| acc | (u16::from(on) << at));
        if states.last() != Some(&state) {
            states.push(state);
        }
    }
    states
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn change_sets_fold_into_the_states_the_device_took() {
        let documents: Vec<serde_json::Value> = [
            r#"{"values":{"fan_alarm":false,"filter_alarm":false,"temperature_alarm":false,"gear":3}}"#,
            r#"{"values":{"temperature_alarm":true}}"#,
            r#"{"values":{"gear":4}}"#,
            r#"{"values":{"fan_alarm":true,"temperature_alarm":false}}"#,
        ]
        .iter()
        .map(|text| serde_json::from_str(text).expect("json"))
        .collect();
        assert_eq!(alarm_states(&documents), [0, 1, 4]);
    }
}
