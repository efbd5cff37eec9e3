//! The edge node's one task and its own MQTT connection: makes the session for a
//! configuration ([`session_for`]; the `[sparkplug]` settings are `crate::config`'s) and runs it
//! ([`run`]). The node's connection is its own because its Last Will is the NDEATH, so it
//! cannot share the plain connection whose Will is the gateway status. The driver feeds line
//! events to the session, hands commands from hosts to the gateway's validated command path,
//! and, with `[history]`, passes the records the bridge replays from the journal on to the
//! session, which sends them as historical DDATA once their device is born. It never touches
//! the bus.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use rumqttc::{AsyncClient, Event, LastWill, Outgoing, Packet, QoS};
use tokio::sync::{broadcast, mpsc};

use crate::bridge::driver::connection::{
    client, connect_went_out, options, take_held_events, Backoff, PacketLimit, MAX_INCOMING_PACKET,
    REQUEST_QUEUE,
};
use crate::bridge::driver::oversized::{log_oversized, oversized, SubscriptionWatch};

use crate::bus::LineEvent;
use crate::config::{Config, MqttSettings};
use crate::history::document::values_of;
use crate::history::Record;
use tokio_util::sync::CancellationToken;

use super::core::session::{
    self, Action, ExternalCommand, HistoricalValues, Session, SessionSettings,
};
use super::core::{bd_seq, node_metrics, protobuf};

/// How long a device's DBIRTH waits for the fields its first poll did not bring (blocks read
/// at a slower interval, a block that failed once); then it is born with those null.
const BIRTH_WAIT: Duration = Duration::from_secs(10);
/// How long the connection may take to flush the NDEATH and close at shutdown.
const CLOSE_GRACE: Duration = Duration::from_secs(2);
/// A connection that lived this long resets the reconnect back-off.
const STABLE_CONNECTION: Duration = Duration::from_secs(10);
/// How often replayed history is looked at, and how many historical DDATA go out each time
/// (well inside the client's request queue, beside live traffic).
const HISTORY_TICK: Duration = Duration::from_millis(250);
const HISTORY_BATCH: usize = 250;
/// The largest packet the node sends. An NBIRTH carries every node metric in one message
/// (Sparkplug allows no other way): with the figures of 1,000 lines it is about 300 KB, past
/// the plain connection's limit, so the node's is larger. A larger birth still is refused
/// alone, counted with the plain connection's.
pub const MAX_OUTGOING_PACKET: usize = 4 * 1024 * 1024;

/// The session for `config`'s devices, identity and lines (None without `[sparkplug]`),
/// with the broker settings of its own connection.
pub fn session_for(config: &Config) -> Option<(Session, MqttSettings)> {
    let sparkplug = config.sparkplug.as_ref()?;
    let devices = config
        .lines
        .iter()
        .flat_map(|line| &line.devices)
        .map(|device| (device.name.clone(), device.profile.clone()))
        .collect();
    let lines: Vec<String> = config.lines.iter().map(|line| line.name.clone()).collect();
    let settings = SessionSettings {
        group_id: sparkplug.identity.group_id.clone(),
        edge_node_id: sparkplug.identity.edge_node_id.clone(),
        primary_host_id: sparkplug.identity.primary_host_id.clone(),
        devices,
        version: env!("CARGO_PKG_VERSION").to_string(),
        node_metrics: node_metrics::node_metric_specs(&lines),
    };
    let first_bd_seq = bd_seq::BdSeqStore::for_config(config).map_or(0, |store| store.load());
    let session = Session::new(settings, first_bd_seq).with_birth_wait(BIRTH_WAIT);
    Some((session, sparkplug.mqtt.clone()))
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
pub use crate::bridge::core::CommandReport;

/// The channels the node is wired with.
#[derive(Debug)]
pub struct NodeLinks {
    pub line_events: broadcast::Receiver<LineEvent>,
    pub commands: mpsc::Sender<ExternalCommand>,
    pub reports: mpsc::Receiver<CommandReport>,
    /// Values of the declared gateway figures ([`session::NodeMetricSpec`]).
    pub node_values: mpsc::Receiver<Vec<(String, protobuf::MetricValue)>>,
    pub shutdown: CancellationToken,
    /// Where the next bdSeq is kept across restarts (none: it starts at 0 each run).
    pub bd_seq_store: Option<bd_seq::BdSeqStore>,
    /// The records the bridge replays from the history journal (with `[history]`).
    pub replayed: Option<mpsc::Receiver<Record>>,
    /// Refuses a payload rumqttc would end the connection on (shared with the bridge's
    /// statistics: [`crate::bridge::Bridge::packet_limit`]).
    pub packet_limit: PacketLimit,
}

/// Runs the edge node until shutdown: connects (a fresh bdSeq and NDEATH Will per connection),
/// lets the session answer every event, reconnects with the plain connection's back-off, and
/// at shutdown publishes the NDEATH itself before disconnecting.
pub async fn run(mut session: Session, mqtt: MqttSettings, mut links: NodeLinks) {
    let topics = mqtt.topics();
    let mut backoff = Backoff::default();
    let mut history_tick = tokio::time::interval(HISTORY_TICK);
    history_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut kept_bd_seq = bd_seq::Keeper::new(links.bd_seq_store.take());
    // Which subscriptions go out and are acknowledged, across the node's connections.
    let subscriptions = SubscriptionWatch::default();
    loop {
        let will = session.prepare_connect(now_millis());
        // Kept before the CONNECT that uses this one goes out, so a restart never repeats it.
        kept_bd_seq.keep(session.next_bd_seq());
        let mut mqtt_options = match options(&mqtt, &topics) {
            Ok(mqtt_options) => mqtt_options,
            Err(error) => {
                tracing::error!(%error, "Sparkplug: cannot build the MQTT connection");
                return;
            }
        };
        mqtt_options
            .set_max_packet_size(MAX_INCOMING_PACKET, links.packet_limit.max())
            .set_clean_session(true)
            .set_last_will(LastWill::new(
                will.topic,
                will.payload,
                QoS::AtLeastOnce,
                false,
            ));
        let (client, mut eventloop) = client(mqtt_options, REQUEST_QUEUE);
        subscriptions.new_client();
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
                polled = eventloop.poll() => match polled.inspect(|event| subscriptions.seen(event)) {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => {
                        connected_since = Some(tokio::time::Instant::now());
                        tracing::info!(bd_seq = session.bd_seq(), "Sparkplug edge node connected");
                        let actions = session.on_connected(now_millis());
                        closing |= carry_out(&client, &links.commands, &mut links.packet_limit, &subscriptions, actions).await;
                    }
                    Ok(Event::Incoming(Packet::Publish(publish))) => {
                        let actions = session.on_message(now_millis(), &publish.topic, &publish.payload);
                        closing |= carry_out(&client, &links.commands, &mut links.packet_limit, &subscriptions, actions).await;
                    }
                    Ok(Event::Outgoing(Outgoing::Disconnect)) => {
                        let drain = async { while eventloop.poll().await.is_ok() {} };
                        let _ = tokio::time::timeout(CLOSE_GRACE, drain).await;
                        break;
                    }
                    Ok(_) => {}
                    Err(error) => {
                        for event in take_held_events(&mut eventloop) {
                            subscriptions.seen(&event);
                        }
                        // The node's session is always clean: a message too large to read
                        // comes back only as a retained one, with a subscription.
                        let oversized = oversized(&error);
                        let blame = subscriptions.connection_ended(&[], oversized.is_some(), std::time::Instant::now());
                        if let Some(size) = oversized {
                            log_oversized("sparkplug", size, MAX_INCOMING_PACKET, &blame, false);
                        }
                        // A connection that dies young (a client-id takeover, an auth refusal)
                        // keeps the back-off growing.
                        if connected_since.is_some_and(|since| since.elapsed() >= STABLE_CONNECTION) {
                            backoff.reset();
                        }
                        // Sparkplug counts CONNECT packets: an attempt that sent none (the
                        // broker refused the TCP connection) gives its bdSeq back.
                        if connected_since.is_none() && !connect_went_out(&error) {
                            session.connect_not_sent();
                            kept_bd_seq.keep(session.next_bd_seq());
                        }
                        tracing::warn!(%error, "Sparkplug connection lost");
                        session.on_disconnected();
                        break;
                    }
                },
                event = links.line_events.recv(), if !closing => match event {
                    Ok(event) => {
                        let actions = session.on_line_event(now_millis(), &event);
                        closing |= carry_out(&client, &links.commands, &mut links.packet_limit, &subscriptions, actions).await;
                    }
                    Err(broadcast::error::RecvError::Lagged(missed)) => {
                        // A device may have come or gone unseen: births tell the host the
                        // node's whole view again, the next polls bring the values.
                        tracing::warn!(missed, "Sparkplug: line events missed; rebirth");
                        let actions = session.rebirth(now_millis());
                        closing |= carry_out(&client, &links.commands, &mut links.packet_limit, &subscriptions, actions).await;
                    }
                    Err(broadcast::error::RecvError::Closed) => {
                        closing = true;
                        stop_by = Some(tokio::time::Instant::now() + CLOSE_GRACE);
                        end_session(&client, &mut session);
                    }
                },
                Some(report) = links.reports.recv(), if !closing => {
                    let actions = session.on_command_outcome(now_millis(), &report.device, &report.field, report.applied);
                    closing |= carry_out(&client, &links.commands, &mut links.packet_limit, &subscriptions, actions).await;
                }
                Some(values) = links.node_values.recv(), if !closing => {
                    let actions = session.on_node_values(now_millis(), &values);
                    closing |= carry_out(&client, &links.commands, &mut links.packet_limit, &subscriptions, actions).await;
                }
                record = next_replayed(&mut links.replayed), if !closing => {
                    queue_replayed(&mut session, record);
                }
                _ = history_tick.tick(), if !closing && session.history_waiting() > 0 => {
                    let actions = session.history_batch(HISTORY_BATCH);
                    closing |= carry_out(&client, &links.commands, &mut links.packet_limit, &subscriptions, actions).await;
                }
                () = links.shutdown.cancelled(), if !closing => {
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
                record = next_replayed(&mut links.replayed) => queue_replayed(&mut session, record),
                // Outcomes of commands from before the connection was lost: the births
                // carry the true values.
                Some(_) = links.reports.recv() => {}
                () = links.shutdown.cancelled() => return,
            }
        }
    }
}

/// The next record the bridge replayed; never ready once nothing more can come.
async fn next_replayed(replayed: &mut Option<mpsc::Receiver<Record>>) -> Record {
    if let Some(receiver) = replayed {
        if let Some(record) = receiver.recv().await {
            return record;
        }
        *replayed = None;
    }
    std::future::pending().await
}

/// Keeps a replayed record for historical DDATA (a record whose document cannot be read is
/// left to the history topic alone).
fn queue_replayed(session: &mut Session, record: Record) {
    match values_of(&record.document) {
        Some(values) => session.queue_history(HistoricalValues {
            device: record.device,
            read_at: record.at_ms,
            values,
        }),
        None => {
            tracing::warn!(device = %record.device, "Sparkplug: a replayed history record is unreadable")
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
    commands: &mpsc::Sender<ExternalCommand>,
    packet_limit: &mut PacketLimit,
    subscriptions: &SubscriptionWatch,
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
                // Refused alone: handed over, it would end the node's connection.
                if !packet_limit.admits(&topic, payload.len(), qos) {
                    continue;
                }
                if let Err(error) = client.try_publish(&topic, qos, false, payload) {
                    tracing::warn!(%error, %topic, "Sparkplug: publish dropped");
                }
            }
            Action::Subscribe { topic } => {
                // One left out (it keeps bringing an oversized retained message) is not sent.
                if !subscriptions.handing(&topic, std::time::Instant::now()) {
                    continue;
                }
                if let Err(error) = client.try_subscribe(&topic, QoS::AtLeastOnce) {
                    subscriptions.not_handed(&topic);
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
