//! The Sparkplug edge node driver on a real mosquitto: births after the primary host's STATE,
//! DDATA for a change, NDATA for a gateway figure, a DCMD handed to the command path and a failed one re-published, NCMD
//! rebirth, the NDEATH Will (matching the NBIRTH's bdSeq) when the node dies, and the node's
//! own NDEATH at an orderly shutdown.

use crate::support;

use std::sync::Arc;
use std::time::Duration;

use rtu2mqtt::bridge::driver::connection::{publish_packet_size, PacketLimit};
use rtu2mqtt::bus::{LineEvent, Origin};
use rtu2mqtt::config::MqttSettings;
use rtu2mqtt::sparkplug::core::bd_seq::BdSeqStore;
use rtu2mqtt::sparkplug::core::protobuf::{DataType, Metric, MetricValue, Payload};
use rtu2mqtt::sparkplug::{
    run, CommandReport, ExternalCommand, NodeLinks, NodeMetricSpec, Session, SessionSettings,
};
use rtu2mqtt_profile::{registry, Value};
use rumqttc::QoS;
use support::{Message, Mosquitto, TestClient};
use tokio::sync::{broadcast, mpsc};
use tokio_util::sync::CancellationToken;

const WAIT: Duration = Duration::from_secs(10);
const NBIRTH: &str = "spBv1.0/plant/NBIRTH/gw1";
const NDEATH: &str = "spBv1.0/plant/NDEATH/gw1";
const DBIRTH: &str = "spBv1.0/plant/DBIRTH/gw1/dust";
const DDATA: &str = "spBv1.0/plant/DDATA/gw1/dust";
const NDATA: &str = "spBv1.0/plant/NDATA/gw1";
const BUS_LOAD: &str = "Lines/line-a/Bus Load";

fn settings(port: u16) -> MqttSettings {
    MqttSettings {
        host: "127.0.0.1".into(),
        port,
        tls: None,
        client_id: "gw1-sparkplug".into(),
        prefix: "plant".into(),
        username: None,
        password: None,
        keep_alive: Duration::from_secs(5),
        clean_session: true,
        inflight: 100,
        discovery: false,
        discovery_prefix: "homeassistant".into(),
    }
}

fn session(primary_host_id: Option<&str>) -> Session {
    session_from(primary_host_id, 0)
}

/// The session of a node whose first connection takes `bd_seq`.
fn session_from(primary_host_id: Option<&str>, bd_seq: u8) -> Session {
    let dust = registry::built_in("ruiwan-dust-collector").unwrap_or_else(|e| panic!("{e}"));
    Session::new(
        SessionSettings {
            group_id: "plant".into(),
            edge_node_id: "gw1".into(),
            primary_host_id: primary_host_id.map(str::to_string),
            devices: vec![("dust".into(), Arc::new(dust))],
            version: "test".into(),
            node_metrics: vec![NodeMetricSpec {
                name: BUS_LOAD.into(),
                datatype: DataType::Float,
            }],
        },
        bd_seq,
    )
}

fn decode(message: &Message) -> Payload {
    Payload::decode_bytes(&message.payload)
        .unwrap_or_else(|error| panic!("{}: {error}", message.topic))
}

fn value_of(payload: &Payload, name: &str) -> Option<MetricValue> {
    payload
        .metrics
        .iter()
        .find(|m| m.name.as_deref() == Some(name))
        .and_then(|m| m.value.clone())
}

fn dust(gear: i64) -> LineEvent {
    LineEvent::Values {
        device: "dust".into(),
        values: vec![
            ("power".into(), Value::Bool(true)),
            ("gear".into(), Value::Int(i128::from(gear))),
        ],
        read_at: std::time::SystemTime::UNIX_EPOCH,
        origin: Origin::Poll,
    }
}

/// A DCMD payload writing `value` to the metric `name`.
pub(crate) fn command(name: &str, datatype: DataType, value: MetricValue) -> Vec<u8> {
    Payload {
        timestamp: Some(1),
        metrics: vec![Metric {
            name: Some(name.into()),
            datatype: Some(datatype.number()),
            value: Some(value),
            ..Default::default()
        }],
        ..Default::default()
    }
    .encode_to_bytes()
}

struct Node {
    events: broadcast::Sender<LineEvent>,
    commands: mpsc::Receiver<ExternalCommand>,
    reports: mpsc::Sender<CommandReport>,
    node_values: mpsc::Sender<Vec<(String, MetricValue)>>,
    trigger: CancellationToken,
    task: tokio::task::JoinHandle<()>,
}

fn start(session: Session, port: u16) -> Node {
    start_with(session, port, None)
}

/// Like [`start`], keeping bdSeq in `bd_seq_store`.
fn start_with(session: Session, port: u16, bd_seq_store: Option<BdSeqStore>) -> Node {
    let limit = PacketLimit::new(rtu2mqtt::sparkplug::MAX_OUTGOING_PACKET, "sparkplug");
    start_limited(session, port, bd_seq_store, limit)
}

/// Like [`start_with`], sending nothing larger than `packet_limit` allows.
fn start_limited(
    session: Session,
    port: u16,
    bd_seq_store: Option<BdSeqStore>,
    packet_limit: PacketLimit,
) -> Node {
    let (events, line_events) = broadcast::channel(64);
    let (commands_tx, commands) = mpsc::channel(16);
    let (reports, reports_rx) = mpsc::channel(16);
    let (node_values, node_values_rx) = mpsc::channel(16);
    let shutdown = CancellationToken::new();
    let trigger = shutdown.clone();
    let links = NodeLinks {
        line_events,
        commands: commands_tx,
        reports: reports_rx,
        node_values: node_values_rx,
        shutdown,
        bd_seq_store,
        replayed: None,
        packet_limit,
    };
    let task = tokio::spawn(run(session, settings(port), links));
    Node {
        events,
        commands,
        reports,
        node_values,
        trigger,
        task,
    }
}

/// The sizes of the NBIRTH and of the dust collector's DBIRTH the node sends, as MQTT packets.
fn birth_sizes() -> (usize, usize) {
    let mut probe = session(None);
    probe.prepare_connect(0);
    let mut actions = probe.on_connected(rtu2mqtt::sparkplug::now_millis());
    actions.extend(probe.on_line_event(rtu2mqtt::sparkplug::now_millis(), &dust(3)));
    let size_of = |wanted: &str| {
        actions.iter().find_map(|action| match action {
            rtu2mqtt::sparkplug::Action::Publish { topic, payload, .. } if topic == wanted => {
                Some(publish_packet_size(topic, payload.len(), QoS::AtLeastOnce))
            }
            _ => None,
        })
    };
    let nbirth = size_of(NBIRTH).expect("an NBIRTH");
    let dbirth = size_of(DBIRTH).expect("a DBIRTH");
    (nbirth, dbirth)
}

/// A birth larger than the node's packet limit is refused alone: the connection stays (the
/// broker never publishes the NDEATH Will), what fits keeps flowing, the refusal is counted.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_birth_over_the_packet_limit_is_refused_and_the_connection_stays() {
    let (nbirth, dbirth) = birth_sizes();
    // Room for the NBIRTH (its timestamps may take a few more bytes), not for the DBIRTH.
    let max = nbirth + 32;
    assert!(dbirth > max, "NBIRTH {nbirth} bytes, DBIRTH {dbirth} bytes");
    let limit = PacketLimit::new(max, "sparkplug");
    let counted = limit.for_connection("count", max);
    let broker = Mosquitto::start();
    let mut host = TestClient::connect(broker.port, "limit-host").await;
    host.subscribe("spBv1.0/plant/#").await;
    let node = start_limited(session(None), broker.port, None, limit);
    host.next_on(NBIRTH, WAIT).await;
    let _ = node.events.send(dust(3));
    let _ = node
        .node_values
        .send(vec![(BUS_LOAD.to_string(), MetricValue::Float(0.5))])
        .await;
    host.next_on(NDATA, WAIT).await;
    host.settle(Duration::from_millis(500)).await;
    assert!(host.on(DBIRTH).is_empty(), "the DBIRTH went out");
    assert!(host.on(NDEATH).is_empty(), "the connection was lost");
    assert_eq!(counted.refused(), 1);
    node.trigger.cancel();
    let _ = tokio::time::timeout(WAIT, node.task).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_edge_node_lives_and_dies_by_the_sparkplug_rules() {
    let broker = Mosquitto::start();
    let mut host = TestClient::connect(broker.port, "scada-host").await;
    host.subscribe("spBv1.0/plant/#").await;
    let mut node = start(session(Some("scada")), broker.port);

    // Births wait for the primary host.
    host.settle(Duration::from_millis(700)).await;
    assert!(host.on(NBIRTH).is_empty(), "NBIRTH before the host's STATE");
    let _ = node.events.send(dust(3));
    host.publish(
        "spBv1.0/STATE/scada",
        r#"{"online":true,"timestamp":1764000000000}"#,
        true,
    )
    .await;
    let nbirth = decode(&host.next_on(NBIRTH, WAIT).await);
    assert_eq!(nbirth.seq, Some(0));
    let bd_seq = value_of(&nbirth, "bdSeq");
    assert_eq!(bd_seq, Some(MetricValue::Long(0)));
    let dbirth = decode(&host.next_on(DBIRTH, WAIT).await);
    assert_eq!(value_of(&dbirth, "gear"), Some(MetricValue::Int(3)));
    assert_eq!(dbirth.seq, Some(1));

    // A change arrives as DDATA with the next seq.
    let _ = node.events.send(dust(5));
    let ddata = decode(&host.next_on(DDATA, WAIT).await);
    assert_eq!(ddata.metrics.len(), 1);
    assert_eq!(ddata.metrics[0].value, Some(MetricValue::Int(5)));
    let after_birth = ddata.seq.unwrap_or(0);
    assert!(after_birth >= 2, "seq {after_birth} after the births");

    // A gateway figure arrives as NDATA.
    let _ = node
        .node_values
        .send(vec![(BUS_LOAD.to_string(), MetricValue::Float(0.5))])
        .await;
    let ndata = host
        .wait_for(NDATA, WAIT, |m| {
            decode(m)
                .metrics
                .iter()
                .any(|metric| metric.value == Some(MetricValue::Float(0.5)))
        })
        .await;
    assert!(decode(&ndata).seq > Some(after_birth));

    // A DCMD on the gear reaches the command path; one on a read-only field does not.
    host.publish(
        "spBv1.0/plant/DCMD/gw1/dust",
        command("fan_speed", DataType::UInt16, MetricValue::Int(1)),
        false,
    )
    .await;
    host.publish(
        "spBv1.0/plant/DCMD/gw1/dust",
        command("gear", DataType::UInt8, MetricValue::Int(8)),
        false,
    )
    .await;
    let handed = tokio::time::timeout(WAIT, node.commands.recv()).await;
    assert_eq!(
        handed.ok().flatten(),
        Some(ExternalCommand {
            device: "dust".into(),
            field: "gear".into(),
            text: "8".into()
        })
    );
    assert!(
        node.commands.try_recv().is_err(),
        "the read-only write was handed on"
    );
    // It failed on the bus: the true gear is published again.
    let _ = node
        .reports
        .send(CommandReport {
            device: "dust".into(),
            field: "gear".into(),
            applied: false,
        })
        .await;
    let republished = host
        .wait_for_new(DDATA, WAIT, |m| {
            decode(m)
                .metrics
                .iter()
                .any(|metric| metric.value == Some(MetricValue::Int(5)))
        })
        .await;
    assert!(decode(&republished).seq > Some(after_birth));

    // NCMD rebirth: NBIRTH and DBIRTH again, same bdSeq, seq from 0.
    host.drain();
    host.forget();
    host.publish(
        "spBv1.0/plant/NCMD/gw1",
        command(
            "Node Control/Rebirth",
            DataType::Boolean,
            MetricValue::Boolean(true),
        ),
        false,
    )
    .await;
    let reborn = decode(&host.next_on(NBIRTH, WAIT).await);
    assert_eq!(
        (reborn.seq, value_of(&reborn, "bdSeq")),
        (Some(0), bd_seq.clone())
    );
    let dbirth = decode(&host.next_on(DBIRTH, WAIT).await);
    assert_eq!(value_of(&dbirth, "gear"), Some(MetricValue::Int(5)));

    // The node dies without a word: the broker publishes its Will, the NDEATH of this bdSeq.
    node.task.abort();
    let death = decode(&host.next_on(NDEATH, WAIT).await);
    assert_eq!(value_of(&death, "bdSeq"), bd_seq);
    node.trigger.cancel();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_orderly_shutdown_publishes_the_ndeath_itself() {
    let broker = Mosquitto::start();
    let mut host = TestClient::connect(broker.port, "observer").await;
    host.subscribe("spBv1.0/plant/#").await;
    let node = start(session(None), broker.port);
    let nbirth = decode(&host.next_on(NBIRTH, WAIT).await);
    node.trigger.cancel();
    let death = decode(&host.next_on(NDEATH, WAIT).await);
    assert_eq!(value_of(&death, "bdSeq"), value_of(&nbirth, "bdSeq"));
    let ended = tokio::time::timeout(WAIT, node.task).await;
    assert!(
        matches!(ended, Ok(Ok(()))),
        "the node did not end: {ended:?}"
    );
}

/// The NBIRTH of the node's current connection, asking for a rebirth until one arrives (the
/// observer may have subscribed after the node's own births).
async fn current_nbirth(host: &mut TestClient) -> Payload {
    for _ in 0..10 {
        let rebirth = command(
            "Node Control/Rebirth",
            DataType::Boolean,
            MetricValue::Boolean(true),
        );
        host.publish("spBv1.0/plant/NCMD/gw1", rebirth, false).await;
        if let Some(message) = host
            .try_wait_for(NBIRTH, Duration::from_secs(1), |_| true)
            .await
        {
            return decode(&message);
        }
    }
    panic!("no NBIRTH from the node");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_connection_gets_the_next_bd_seq_and_its_will_carries_it() {
    let mut broker = Mosquitto::start();
    let mut host = TestClient::connect(broker.port, "observer").await;
    host.subscribe("spBv1.0/plant/#").await;
    let node = start(session(None), broker.port);
    let first = decode(&host.next_on(NBIRTH, WAIT).await);
    assert_eq!(value_of(&first, "bdSeq"), Some(MetricValue::Long(0)));

    broker.kill();
    broker.restart();
    let mut host = TestClient::connect(broker.port, "observer-2").await;
    host.subscribe("spBv1.0/plant/#").await;
    let second = current_nbirth(&mut host).await;
    let Some(MetricValue::Long(bd_seq)) = value_of(&second, "bdSeq") else {
        panic!("no bdSeq in {second:?}");
    };
    // One CONNECT since the first: the attempts the dead broker refused sent none.
    assert_eq!(bd_seq, 1, "bdSeq after a reconnect");
    assert_eq!(second.seq, Some(0));

    node.task.abort();
    let death = decode(&host.next_on(NDEATH, WAIT).await);
    assert_eq!(value_of(&death, "bdSeq"), Some(MetricValue::Long(bd_seq)));
}

/// Line events the node could not keep up with (the broadcast overflowed): it cannot know
/// what it missed, so it tells the host everything again with a rebirth.
#[tokio::test]
async fn missed_line_events_bring_a_rebirth() {
    let broker = Mosquitto::start();
    let mut host = TestClient::connect(broker.port, "lag-host").await;
    host.subscribe("spBv1.0/plant/#").await;
    let node = start(session(None), broker.port);
    host.next_on(NBIRTH, WAIT).await;
    let _ = node.events.send(dust(3));
    host.next_on(DBIRTH, WAIT).await;
    // More events than the channel holds, without letting the node run in between (this
    // test's runtime has one thread).
    for gear in 0..200 {
        let _ = node.events.send(dust(1 + gear % 10));
    }
    let reborn = decode(&host.next_on(NBIRTH, WAIT).await);
    assert_eq!(reborn.seq, Some(0));
    assert_eq!(value_of(&reborn, "bdSeq"), Some(MetricValue::Long(0)));
    host.next_on(DBIRTH, WAIT).await;
    node.trigger.cancel();
    let _ = tokio::time::timeout(WAIT, node.task).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bd_seq_goes_on_counting_across_restarts() {
    let broker = Mosquitto::start();
    let state = tempfile::tempdir().expect("state dir");
    let store = BdSeqStore::in_dir(state.path());
    let mut host = TestClient::connect(broker.port, "scada-host").await;
    host.subscribe("spBv1.0/plant/#").await;
    for expected in [0, 1, 2] {
        // A new process: the session starts from what the store kept.
        let session = session_from(None, store.load());
        let node = start_with(session, broker.port, Some(store.clone()));
        let nbirth = decode(&host.next_on(NBIRTH, WAIT).await);
        assert_eq!(
            value_of(&nbirth, "bdSeq"),
            Some(MetricValue::Long(expected))
        );
        // Killed, not stopped: no orderly NDEATH, the kept number is all that remains.
        node.task.abort();
        let _ = node.task.await;
        host.forget();
    }
}

/// A node killed during a broker outage, after many refused reconnect attempts, starts again
/// with the bdSeq after the last one it connected with: Sparkplug counts CONNECT packets, and
/// a refused TCP connection sends none.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restart_during_an_outage_takes_the_bd_seq_after_the_last_connection() {
    let mut broker = Mosquitto::start();
    let state = tempfile::tempdir().expect("state dir");
    let store = BdSeqStore::in_dir(state.path());
    let mut host = TestClient::connect(broker.port, "outage-host").await;
    host.subscribe("spBv1.0/plant/#").await;
    let node = start_with(session_from(None, 6), broker.port, Some(store.clone()));
    let nbirth = decode(&host.next_on(NBIRTH, WAIT).await);
    assert_eq!(value_of(&nbirth, "bdSeq"), Some(MetricValue::Long(6)));

    broker.kill();
    // The back-off starts at 250 ms: several refused attempts in this time.
    tokio::time::sleep(Duration::from_secs(4)).await;
    assert_eq!(store.load(), 7, "the next start's bdSeq during the outage");
    node.task.abort();
    let _ = node.task.await;

    broker.restart();
    let mut host = TestClient::connect(broker.port, "outage-host-2").await;
    host.subscribe("spBv1.0/plant/#").await;
    let node = start_with(
        session_from(None, store.load()),
        broker.port,
        Some(store.clone()),
    );
    let nbirth = decode(&host.next_on(NBIRTH, WAIT).await);
    assert_eq!(value_of(&nbirth, "bdSeq"), Some(MetricValue::Long(7)));
    assert_eq!(store.load(), 8);
    node.trigger.cancel();
    let _ = tokio::time::timeout(WAIT, node.task).await;
}
