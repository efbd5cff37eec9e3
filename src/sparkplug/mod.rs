//! The gateway as a Sparkplug B 3.0 edge node, beside the plain topics. [`payload`] is the
//! protobuf payload, [`metrics`] turns profile fields into typed metrics and command metrics
//! back into command text, [`session`] is the pure edge node state machine. This module holds
//! the `[sparkplug]` settings with their validation and the thin driver ([`run`]) that owns
//! the node's own MQTT connection (its Last Will is the NDEATH, so it cannot share the plain
//! connection whose Will is the gateway status), feeds line events to the session, and hands
//! commands from hosts to the gateway's validated command path. It never touches the bus.

pub mod metrics;
pub mod payload;
pub mod session;

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use rumqttc::{AsyncClient, Event, LastWill, Outgoing, Packet, QoS};
use serde::Deserialize;
use tokio::sync::{broadcast, mpsc};

use crate::bridge::mqtt::{options, Backoff, REQUEST_QUEUE};

use crate::bus::LineEvent;
use crate::config::{MqttSettings, Problem};
use crate::shutdown::Shutdown;

pub use session::{Action, NodeMetricSpec, Session, SessionSettings, SparkplugCommand};

/// Appended to the plain connection's client id when the node shares its broker: two
/// connections with one client id would take each other over.
pub const CLIENT_ID_SUFFIX: &str = "-sparkplug";

/// How long the connection may take to flush the NDEATH and close at shutdown.
const CLOSE_GRACE: Duration = Duration::from_secs(2);
/// A connection that lived this long resets the reconnect back-off.
const STABLE_CONNECTION: Duration = Duration::from_secs(10);

/// The `[sparkplug]` section as written.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SparkplugSettings {
    /// The Sparkplug group (required).
    #[serde(default)]
    pub group_id: String,
    /// Default: the MQTT client id.
    #[serde(default)]
    pub edge_node_id: Option<String>,
    /// With a primary host, births wait for its STATE `online`.
    #[serde(default)]
    pub primary_host_id: Option<String>,
    /// A broker of its own, in the form of `[mqtt]` (validated by the same rules); default:
    /// the `[mqtt]` broker with the client id suffixed [`CLIENT_ID_SUFFIX`].
    #[serde(default)]
    pub mqtt: Option<toml::Table>,
}

/// The checked Sparkplug identity of the node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SparkplugIdentity {
    pub group_id: String,
    pub edge_node_id: String,
    pub primary_host_id: Option<String>,
}

impl SparkplugSettings {
    /// Checks the ids by Sparkplug's rules (non-empty, no `+`, `#` or `/`; they are topic
    /// levels) and fills the edge node id from the MQTT client id. Every problem is named
    /// with its place (`sparkplug.group_id`).
    pub fn validate(&self, mqtt_client_id: &str) -> Result<SparkplugIdentity, Vec<Problem>> {
        let mut problems = Vec::new();
        let edge_node_id = self
            .edge_node_id
            .clone()
            .unwrap_or_else(|| mqtt_client_id.to_string());
        check_id("sparkplug.group_id", &self.group_id, &mut problems);
        let place = if self.edge_node_id.is_some() {
            "sparkplug.edge_node_id"
        } else {
            "sparkplug.edge_node_id (from mqtt.client_id)"
        };
        check_id(place, &edge_node_id, &mut problems);
        if let Some(host) = &self.primary_host_id {
            check_id("sparkplug.primary_host_id", host, &mut problems);
        }
        if !problems.is_empty() {
            return Err(problems);
        }
        Ok(SparkplugIdentity {
            group_id: self.group_id.clone(),
            edge_node_id,
            primary_host_id: self.primary_host_id.clone(),
        })
    }
}

/// The plain broker settings made fit for the node's own connection: same broker, own client
/// id, clean session (Sparkplug 3.0 requires a clean session on MQTT 3.1.1).
pub fn shared_broker(plain: &MqttSettings) -> MqttSettings {
    MqttSettings {
        client_id: format!("{}{CLIENT_ID_SUFFIX}", plain.client_id),
        clean_session: true,
        ..plain.clone()
    }
}

fn check_id(place: &str, id: &str, problems: &mut Vec<Problem>) {
    if id.is_empty() {
        problems.push(Problem::new(
            place,
            "is required (a non-empty Sparkplug id)",
        ));
    } else if let Some(bad) = id.chars().find(|c| matches!(c, '+' | '#' | '/')) {
        problems.push(Problem::new(
            place,
            format!("`{id}` contains `{bad}`; Sparkplug ids must not contain +, # or /"),
        ));
    }
}

/// Milliseconds since the Unix epoch (Sparkplug timestamps).
pub fn now_millis() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |since| {
            u64::try_from(since.as_millis()).unwrap_or(u64::MAX)
        })
}

/// How a command handed out by the node ended, reported back so a refused or failed one is
/// re-published with the device's true value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandReport {
    pub device: String,
    pub field: String,
    pub applied: bool,
}

/// The channels the node is wired with.
#[derive(Debug)]
pub struct NodeLinks {
    pub line_events: broadcast::Receiver<LineEvent>,
    pub commands: mpsc::Sender<SparkplugCommand>,
    pub reports: mpsc::Receiver<CommandReport>,
    /// Values of the declared gateway figures ([`session::NodeMetricSpec`]).
    pub node_values: mpsc::Receiver<Vec<(String, payload::MetricValue)>>,
    pub shutdown: Shutdown,
}

/// Runs the edge node until shutdown: connects (a fresh bdSeq and NDEATH Will per connection),
/// lets the session answer every event, reconnects with the plain connection's back-off, and
/// at shutdown publishes the NDEATH itself before disconnecting.
pub async fn run(mut session: Session, mqtt: MqttSettings, mut links: NodeLinks) {
    let topics = mqtt.topics();
    let mut backoff = Backoff::default();
    loop {
        let will = session.prepare_connect(now_millis());
        let mut mqtt_options = match options(&mqtt, &topics) {
            Ok(mqtt_options) => mqtt_options,
            Err(error) => {
                tracing::error!(%error, "Sparkplug: cannot build the MQTT connection");
                return;
            }
        };
        mqtt_options
            .set_clean_session(true)
            .set_last_will(LastWill::new(
                will.topic,
                will.payload,
                QoS::AtLeastOnce,
                false,
            ));
        let (client, mut eventloop) = AsyncClient::new(mqtt_options, REQUEST_QUEUE);
        let mut closing = false;
        let mut connected_since = None;
        // Set when the node ends for good; bounds the wait for the Disconnect to go out.
        let mut stop_by: Option<tokio::time::Instant> = None;
        loop {
            let stop_wait = async {
                match stop_by {
                    Some(deadline) => tokio::time::sleep_until(deadline).await,
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                () = stop_wait => break,
                polled = eventloop.poll() => match polled {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => {
                        connected_since = Some(tokio::time::Instant::now());
                        tracing::info!(bd_seq = session.bd_seq(), "Sparkplug edge node connected");
                        let actions = session.on_connected(now_millis());
                        closing |= carry_out(&client, &links.commands, actions).await;
                    }
                    Ok(Event::Incoming(Packet::Publish(publish))) => {
                        let actions = session.on_message(now_millis(), &publish.topic, &publish.payload);
                        closing |= carry_out(&client, &links.commands, actions).await;
                    }
                    Ok(Event::Outgoing(Outgoing::Disconnect)) => {
                        let drain = async { while eventloop.poll().await.is_ok() {} };
                        let _ = tokio::time::timeout(CLOSE_GRACE, drain).await;
                        break;
                    }
                    Ok(_) => {}
                    Err(error) => {
                        // A connection that dies young (a client-id takeover, an auth refusal)
                        // keeps the back-off growing.
                        if connected_since.is_some_and(|since| since.elapsed() >= STABLE_CONNECTION) {
                            backoff.reset();
                        }
                        tracing::warn!(%error, "Sparkplug connection lost");
                        session.on_disconnected();
                        break;
                    }
                },
                event = links.line_events.recv(), if !closing => match event {
                    Ok(event) => {
                        let actions = session.on_line_event(now_millis(), &event);
                        closing |= carry_out(&client, &links.commands, actions).await;
                    }
                    Err(broadcast::error::RecvError::Lagged(missed)) => {
                        tracing::warn!(missed, "Sparkplug: line events missed; the next values catch up");
                    }
                    Err(broadcast::error::RecvError::Closed) => {
                        closing = true;
                        stop_by = Some(tokio::time::Instant::now() + CLOSE_GRACE);
                        end_session(&client, &mut session);
                    }
                },
                Some(report) = links.reports.recv(), if !closing => {
                    let actions = session.on_command_outcome(now_millis(), &report.device, &report.field, report.applied);
                    closing |= carry_out(&client, &links.commands, actions).await;
                }
                Some(values) = links.node_values.recv(), if !closing => {
                    let actions = session.on_node_values(now_millis(), &values);
                    closing |= carry_out(&client, &links.commands, actions).await;
                }
                () = links.shutdown.fired(), if !closing => {
                    closing = true;
                    stop_by = Some(tokio::time::Instant::now() + CLOSE_GRACE);
                    end_session(&client, &mut session);
                }
            }
        }
        if stop_by.is_some() {
            return;
        }
        // Keep the session's view of devices and figures current while waiting to reconnect
        // (nothing is published before the next births).
        let wait = tokio::time::sleep(backoff.next_wait());
        tokio::pin!(wait);
        loop {
            tokio::select! {
                () = &mut wait => break,
                event = links.line_events.recv() => match event {
                    Ok(event) => { session.on_line_event(now_millis(), &event); }
                    Err(broadcast::error::RecvError::Lagged(_)) => {}
                    Err(broadcast::error::RecvError::Closed) => return,
                },
                Some(values) = links.node_values.recv() => {
                    session.on_node_values(now_millis(), &values);
                }
                // Outcomes of commands from before the connection was lost: the births
                // carry the true values.
                Some(_) = links.reports.recv() => {}
                () = links.shutdown.fired() => return,
            }
        }
    }
}

/// The node's orderly end: the NDEATH published by the node itself, then Disconnect (after a
/// clean disconnect the broker drops the Will).
fn end_session(client: &AsyncClient, session: &mut Session) {
    let death = session.death(now_millis());
    let _ = client.try_publish(death.topic, QoS::AtLeastOnce, false, death.payload);
    let _ = client.try_disconnect();
    session.on_disconnected();
}

/// Carries out the session's actions on the connection; true when the session ended the
/// connection (the host went offline).
async fn carry_out(
    client: &AsyncClient,
    commands: &mpsc::Sender<SparkplugCommand>,
    actions: Vec<Action>,
) -> bool {
    let mut closing = false;
    for action in actions {
        match action {
            Action::Publish {
                topic,
                payload,
                delivery,
            } => {
                let qos = match delivery {
                    session::Delivery::AtMostOnce => QoS::AtMostOnce,
                    session::Delivery::AtLeastOnce => QoS::AtLeastOnce,
                };
                if let Err(error) = client.try_publish(&topic, qos, false, payload) {
                    tracing::warn!(%error, %topic, "Sparkplug: publish dropped");
                }
            }
            Action::Subscribe { topic } => {
                if let Err(error) = client.try_subscribe(&topic, QoS::AtLeastOnce) {
                    tracing::warn!(%error, %topic, "Sparkplug: subscribe dropped");
                }
            }
            Action::Disconnect => {
                closing = true;
                let _ = client.try_disconnect();
            }
            Action::Command(command) => {
                if commands.send(command).await.is_err() {
                    tracing::warn!("Sparkplug: the command path is gone");
                }
            }
            Action::Refused {
                device,
                field,
                reason,
            } => {
                tracing::warn!(%device, field = field.as_deref().unwrap_or("-"), %reason, "Sparkplug command refused");
            }
        }
    }
    closing
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(group: &str, node: Option<&str>, host: Option<&str>) -> SparkplugSettings {
        SparkplugSettings {
            group_id: group.to_string(),
            edge_node_id: node.map(str::to_string),
            primary_host_id: host.map(str::to_string),
            mqtt: None,
        }
    }

    #[test]
    fn the_edge_node_id_defaults_to_the_client_id() {
        let identity = settings("plant", None, Some("scada")).validate("rtu2mqtt-1");
        assert_eq!(
            identity,
            Ok(SparkplugIdentity {
                group_id: "plant".into(),
                edge_node_id: "rtu2mqtt-1".into(),
                primary_host_id: Some("scada".into()),
            })
        );
    }

    #[test]
    fn ids_follow_the_sparkplug_rules() {
        let Err(problems) = settings("", Some("a/b"), Some("h+")).validate("gw") else {
            panic!("invalid ids accepted");
        };
        let shown: Vec<String> = problems.iter().map(ToString::to_string).collect();
        assert_eq!(
            shown,
            [
                "sparkplug.group_id: is required (a non-empty Sparkplug id)",
                "sparkplug.edge_node_id: `a/b` contains `/`; Sparkplug ids must not contain +, # or /",
                "sparkplug.primary_host_id: `h+` contains `+`; Sparkplug ids must not contain +, # or /",
            ]
        );
        let Err(problems) = settings("g", None, None).validate("gw#1") else {
            panic!("invalid client id accepted as edge node id");
        };
        assert_eq!(
            problems[0].place,
            "sparkplug.edge_node_id (from mqtt.client_id)"
        );
    }

    #[test]
    fn the_section_parses_from_toml() {
        let parsed: Result<SparkplugSettings, _> = toml::from_str(
            "group_id = \"plant\"\nprimary_host_id = \"scada\"\n[mqtt]\nurl = \"mqtt://broker:1883\"\n",
        );
        let Ok(parsed) = parsed else {
            panic!("{parsed:?}");
        };
        assert_eq!(parsed.group_id, "plant");
        assert!(parsed.mqtt.is_some_and(|table| table.contains_key("url")));
        assert!(toml::from_str::<SparkplugSettings>("group = \"x\"").is_err());
    }
}
