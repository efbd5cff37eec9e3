//! The plant of a soak run: the seed plant on ptys (both lines served to Modbus TCP clients),
//! [`TCP_LINES`] Modbus TCP simulators of [`PER_TCP_LINE`] devices each, the gateway's
//! configuration for all of it, the line server's clients, and the audit of every frame the
//! simulated devices heard (a write answered with an exception is a refused write).

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_sim::{
    self as sim, DustCollector, Journal, Protocol, SeedPlant, ServeOptions, TcpSimulator, Valve,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_util::sync::CancellationToken;

use crate::{Mosquitto, PlantConfig};

/// Modbus TCP lines, each one simulator.
pub const TCP_LINES: usize = 10;
/// Devices on each, at addresses 1–10.
pub const PER_TCP_LINE: u8 = 10;
/// The first lines hold dust collectors, the others valves.
const DUST_LINES: usize = TCP_LINES / 2;

/// Every simulated device and line.
pub struct Rig {
    pub seed: SeedPlant,
    pub tcp: Vec<TcpSimulator>,
    /// The line server's ports of line-a and line-b.
    pub serve_ports: [u16; 2],
}

/// The name of device `address` on TCP line `line`.
pub fn tcp_device(line: usize, address: u8) -> String {
    format!("tcp{line:02}_{address:02}")
}

/// The dust collectors on the TCP lines (they take `gear` commands).
pub fn tcp_dust_collectors() -> Vec<String> {
    (0..DUST_LINES)
        .flat_map(|line| (1..=PER_TCP_LINE).map(move |address| tcp_device(line, address)))
        .collect()
}

impl Rig {
    /// Starts every simulator on the current runtime.
    pub async fn start() -> anyhow::Result<Rig> {
        let seed = SeedPlant::spawn(false)?;
        sim::lock(&seed.dust_collector).set_power(true);
        let mut tcp = Vec::with_capacity(TCP_LINES);
        for line in 0..TCP_LINES {
            let mut devices = Vec::new();
            for address in 1..=PER_TCP_LINE {
                if line < DUST_LINES {
                    let (dust, shared) = sim::share(DustCollector::new(address));
                    sim::lock(&dust).set_power(true);
                    devices.push(shared);
                } else {
                    devices.push(sim::share(Valve::new(address)).1);
                }
            }
            let options = ServeOptions::new(9600, Parity::None);
            tcp.push(
                TcpSimulator::bind("127.0.0.1:0", Protocol::ModbusTcp, options, devices).await?,
            );
        }
        Ok(Rig {
            seed,
            tcp,
            serve_ports: [crate::free_port(), crate::free_port()],
        })
    }

    /// The gateway's configuration: MQTT at `broker`, the journal in `journal`, the first TCP
    /// line's response timeout `timeout_ms` (what a reload changes).
    pub fn config(&self, broker: &Mosquitto, journal: &Path, timeout_ms: u64) -> String {
        let serve =
            |port: u16| format!("\n[lines.serve]\nlisten = \"modbus-tcp://127.0.0.1:{port}\"");
        let (serve_a, serve_b) = (serve(self.serve_ports[0]), serve(self.serve_ports[1]));
        let mut text = PlantConfig {
            discovery: true,
            gateway: "stats_interval = \"5s\"",
            line_a_keys: &serve_a,
            line_b_keys: &serve_b,
            ..PlantConfig::default()
        }
        .text(broker, &self.seed, "soak-gw");
        text.push_str(&format!("\n[history]\npath = \"{}\"\n", journal.display()));
        for (line, simulator) in self.tcp.iter().enumerate() {
            let timeout = if line == 0 { timeout_ms } else { 500 };
            let profile = if line < DUST_LINES {
                "ruiwan-dust-collector"
            } else {
                "wuzhou-valve"
            };
            // A Modbus TCP gateway's serial side is its own: no parity here.
            text.push_str(&format!(
                "\n[[lines]]\nname = \"tcp{line:02}\"\nurl = \"{}\"\n\
                 response_timeout = \"{timeout}ms\"\nconnect_timeout = \"1s\"\n",
                simulator.url()
            ));
            for address in 1..=PER_TCP_LINE {
                text.push_str(&format!(
                    "\n[[lines.devices]]\nname = \"{}\"\nprofile = \"{profile}\"\naddress = {address}\n",
                    tcp_device(line, address)
                ));
            }
        }
        text
    }

    /// Every line's journal of frames heard.
    pub fn journals(&self) -> Vec<&Journal> {
        let mut journals = vec![self.seed.line_a.journal(), self.seed.line_b.journal()];
        journals.extend(self.tcp.iter().map(TcpSimulator::journal));
        journals
    }
}

/// Write frames the simulated devices heard, and those they refused.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct WireAudit {
    pub frames: u64,
    pub writes: u64,
    pub refused_writes: u64,
}

/// The Modbus write functions.
fn is_write(function: u8) -> bool {
    matches!(function, 5 | 6 | 15 | 16 | 22 | 23)
}

impl WireAudit {
    /// Takes what `journals` recorded since the last call (their records are bounded, so this
    /// runs every few seconds) into the counts; returns the refused writes' frames, as hex.
    pub fn take(&mut self, journals: &[&Journal]) -> Vec<String> {
        let mut refused = Vec::new();
        for journal in journals {
            for record in journal.drain_requests() {
                self.frames += 1;
                let Some(&function) = record.frame.get(1) else {
                    continue;
                };
                if !record.crc_ok || !is_write(function) {
                    continue;
                }
                self.writes += 1;
                let exception = record
                    .answer
                    .as_ref()
                    .and_then(|answer| answer.get(1))
                    .is_some_and(|answered| answered & 0x80 != 0);
                if exception {
                    self.refused_writes += 1;
                    refused.push(crate::hex::encode(&record.frame));
                }
            }
        }
        refused
    }
}

/// What the line server's clients got.
#[derive(Debug, Default)]
pub struct ClientCounts {
    pub answers: AtomicU64,
    pub exceptions: AtomicU64,
    pub failures: AtomicU64,
}

/// One read a line server client repeats: port, unit, function 3 start and count.
#[derive(Debug, Clone, Copy)]
pub struct ClientRead {
    pub port: u16,
    pub unit: u8,
    pub start: u16,
    pub count: u16,
}

/// A Modbus TCP client of the line server: `read` once a second until `stop`, connecting
/// again after any failure.
pub fn spawn_client(read: ClientRead, counts: Arc<ClientCounts>, stop: CancellationToken) {
    tokio::spawn(async move {
        let mut transaction: u16 = 0;
        while !stop.is_cancelled() {
            let Ok(mut stream) = TcpStream::connect(("127.0.0.1", read.port)).await else {
                counts.failures.fetch_add(1, Ordering::Relaxed);
                tokio::time::sleep(Duration::from_secs(1)).await;
                continue;
            };
            loop {
                if stop.is_cancelled() {
                    return;
                }
                transaction = transaction.wrapping_add(1);
                let asked = exchange(&mut stream, transaction, read).await;
                match asked {
                    Some(function) if function & 0x80 != 0 => {
                        counts.exceptions.fetch_add(1, Ordering::Relaxed);
                    }
                    Some(_) => {
                        counts.answers.fetch_add(1, Ordering::Relaxed);
                    }
                    None => {
                        counts.failures.fetch_add(1, Ordering::Relaxed);
                        break;
                    }
                }
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
            tokio::time::sleep(Duration::from_secs(1)).await;
        }
    });
}

/// One request and its answer; the answer's function code, None when the exchange failed.
async fn exchange(stream: &mut TcpStream, transaction: u16, read: ClientRead) -> Option<u8> {
    let mut request = Vec::with_capacity(12);
    request.extend_from_slice(&transaction.to_be_bytes());
    request.extend_from_slice(&[0, 0, 0, 6, read.unit, 3]);
    request.extend_from_slice(&read.start.to_be_bytes());
    request.extend_from_slice(&read.count.to_be_bytes());
    let answered = async {
        stream.write_all(&request).await.ok()?;
        let mut header = [0u8; 7];
        stream.read_exact(&mut header).await.ok()?;
        let length = usize::from(u16::from_be_bytes([header[4], header[5]]));
        let mut pdu = vec![0u8; length.checked_sub(1)?];
        stream.read_exact(&mut pdu).await.ok()?;
        (header[..2] == transaction.to_be_bytes()).then(|| pdu.first().copied())?
    };
    tokio::time::timeout(Duration::from_secs(10), answered)
        .await
        .ok()
        .flatten()
}

/// The newest state of the outcome counts of `…/result` documents, shared with the observer.
pub type Outcomes = Arc<Mutex<std::collections::BTreeMap<String, u64>>>;
