//! What the benches that run the built gateway against simulated lines share: their runtime,
//! a command publisher, a subscriber that notes arrivals (testkit's recorder), and the line's load as the simulator's journal shows it (the gateway
//! process itself is `gateway_process`).

// Each bench compiles this module as its own and uses a part of it.
#![allow(dead_code)]

use std::time::{Duration, Instant};

use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_sim::RequestRecord;
use rtu2mqtt_testkit::Recorder;
use rumqttc::{AsyncClient, MqttOptions, QoS};
use tokio::sync::mpsc;

pub const EIGHT_N_ONE: CharFormat = CharFormat {
    data_bits: 8,
    parity: Parity::None,
    stop_bits: 1,
};

/// The runtime of a bench's simulators and clients (the gateway is another process).
pub fn runtime() -> std::io::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
}

/// A publisher of commands whose socket sends at once.
pub async fn command_client(port: u16, client_id: &str) -> AsyncClient {
    let options = MqttOptions::new(client_id, "127.0.0.1", port);
    let (client, mut eventloop) = AsyncClient::new(options, 64);
    let mut network = eventloop.network_options();
    network.set_tcp_nodelay(true);
    eventloop.set_network_options(network);
    tokio::spawn(async move {
        loop {
            if eventloop.poll().await.is_err() {
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    });
    client
}

/// A subscriber that notes when each message on its topic arrived (the instants come while the
/// returned [`Recorder`] is held).
pub async fn timed_subscriber(
    port: u16,
    topic: &str,
    client_id: &str,
    qos: QoS,
) -> anyhow::Result<(Recorder, mpsc::UnboundedReceiver<Instant>)> {
    let mut options = MqttOptions::new(client_id, "127.0.0.1", port);
    options.set_keep_alive(Duration::from_secs(30));
    let (tx, rx) = mpsc::unbounded_channel();
    let recorder = Recorder::start(options, true, &[(topic, qos)], move |_, _| {
        let _ = tx.send(Instant::now());
    })
    .await?;
    Ok((recorder, rx))
}

/// What the requests in a journal cost the line.
pub struct WireLoad {
    /// Wire time of every request and answer (pauses inside answers included) plus the two
    /// t3.5 silences of each transaction.
    pub busy: Duration,
    /// The silence before each request, shortest first.
    pub gaps: Vec<Duration>,
    /// Requests sooner than t3.5 after the line's last byte.
    pub early: usize,
}

/// The load of `records`; `pause` is the simulator's pause inside every answer, which keeps
/// the line as busy as the answer's bytes do (it pauses after every half of the answer that
/// has more bytes after it).
pub fn wire_load(
    records: &[RequestRecord],
    timing: &LineTiming,
    pause: Option<Duration>,
) -> WireLoad {
    let busy: Duration = records
        .iter()
        .map(|r| {
            let answer = r.answer.as_ref().map_or(0, Vec::len);
            let pauses = answer.saturating_sub(1) / (answer / 2).max(1);
            let paused = pause.unwrap_or_default() * pauses as u32;
            timing.frame_time(r.frame.len()) + timing.frame_time(answer) + paused + 2 * timing.t3_5
        })
        .sum();
    let mut gaps: Vec<Duration> = records.iter().filter_map(|r| r.silence_before).collect();
    gaps.sort();
    let early = gaps.iter().filter(|gap| **gap < timing.t3_5).count();
    WireLoad { busy, gaps, early }
}

pub fn percentile(sorted: &[Duration], p: usize) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    let index = (sorted.len() * p).div_ceil(100).saturating_sub(1);
    sorted[index.min(sorted.len() - 1)]
}
