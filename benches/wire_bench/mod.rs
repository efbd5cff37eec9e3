//! What the benches that run the built gateway against simulated lines share: the gateway as
//! its own process, a command publisher, and the line's load as the simulator's journal shows
//! it.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use rtu2mqtt::sim::RequestRecord;
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rumqttc::{AsyncClient, MqttOptions};

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

/// The gateway as its own process (`binary run --config …`), stopped with SIGTERM when
/// dropped.
pub struct Gateway {
    pub child: Child,
}

impl Gateway {
    pub fn start_binary(binary: &Path, config: &Path) -> anyhow::Result<Gateway> {
        let child = Command::new(binary)
            .arg("run")
            .arg("--config")
            .arg(config)
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()?;
        Ok(Gateway { child })
    }

    /// SIGTERM, then SIGKILL when it has not ended within 5 s.
    pub fn stop(&mut self) {
        let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
        let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.stop();
        }
    }
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

/// What the requests in a journal cost the line.
pub struct WireLoad {
    /// Wire time of every request and answer plus the two t3.5 silences of each transaction.
    pub busy: Duration,
    /// The silence before each request, shortest first.
    pub gaps: Vec<Duration>,
    /// Requests sooner than t3.5 after the line's last byte.
    pub early: usize,
}

pub fn wire_load(records: &[RequestRecord], timing: &LineTiming) -> WireLoad {
    let busy: Duration = records
        .iter()
        .map(|r| {
            timing.frame_time(r.frame.len())
                + timing.frame_time(r.answer.as_ref().map_or(0, Vec::len))
                + 2 * timing.t3_5
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
