//! Simulated devices behind a TCP port, as a serial device server (`tcp://`: raw RTU frames on
//! the stream) or a Modbus TCP-to-RTU gateway (`modbus-tcp://`: MBAP framing, unit id = RTU
//! address) would put them.
//!
//! Each connection gets its own [`serve`] of the same devices, faults and journal on an
//! in-memory stream; a relay between the socket and that stream passes one request at a time
//! and applies the faults only a network link has ([`TcpFaults`]: a connection closed
//! mid-answer, answers swallowed, an answer split across segments, two answers in one segment,
//! garbage before an answer). The journal records what the devices heard and answered, before
//! the network faults.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;

use super::device::{lock, SharedDevice};
use super::faults::{random_bytes, FaultHandle, Occurrence};
use super::journal::Journal;
use super::server::{serve, ServeOptions};
use super::wire::{self, FrameLen};
use rtu2mqtt_modbus::answer_framing::{AnswerFramer, Framed};
use rtu2mqtt_modbus::codec::{self, MAX_FRAME_LEN};
use rtu2mqtt_modbus::tcp::mbap;
use tokio_util::sync::CancellationToken;

/// Longest wait for the devices' answer to one request. A new request from the client ends
/// the wait earlier (the master has given up on the previous one).
const ANSWER_WAIT: Duration = Duration::from_secs(5);
/// Without a decodable request to frame the answer by, the answer ends after this silence.
const ANSWER_QUIET: Duration = Duration::from_millis(50);

/// What the TCP stream carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    /// RTU frames, CRC included, as a serial device server passes them (`tcp://`).
    RawRtu,
    /// Modbus TCP ADUs (`modbus-tcp://`).
    ModbusTcp,
}

impl Protocol {
    pub fn scheme(self) -> &'static str {
        match self {
            Protocol::RawRtu => "tcp",
            Protocol::ModbusTcp => "modbus-tcp",
        }
    }

    /// Splits `tcp://host:port` or `modbus-tcp://host:port` into the protocol and the address.
    pub fn parse_url(url: &str) -> Option<(Protocol, &str)> {
        [Protocol::RawRtu, Protocol::ModbusTcp]
            .into_iter()
            .find_map(|protocol| {
                url.strip_prefix(protocol.scheme())
                    .and_then(|rest| rest.strip_prefix("://"))
                    .map(|address| (protocol, address))
            })
    }
}

/// Faults of the network link, on top of the line's [`Faults`](super::faults::Faults). `Default` is healthy.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TcpFaults {
    /// Half the answer is sent, then the connection is closed.
    pub close_mid_answer: Occurrence,
    /// The answer is never sent (the connection stays open).
    pub never_answer: Occurrence,
    /// The answer goes out in two segments, `split_gap` apart.
    pub split_answer: Occurrence,
    pub split_gap: Duration,
    /// The answer is held back and sent in one segment with the next one.
    pub hold_for_next: Occurrence,
    /// `garbage_bytes` random bytes go out right before the answer, in its segment.
    pub garbage_before: Occurrence,
    pub garbage_bytes: usize,
}

/// What the relay does to one answer, decided once per answer.
#[derive(Debug, Clone, Default, PartialEq)]
struct AnswerDecision {
    close_mid_answer: bool,
    never_answer: bool,
    split_gap: Option<Duration>,
    hold_for_next: bool,
    garbage: Vec<u8>,
}

/// The shared, run-time changeable [`TcpFaults`] of one simulator.
#[derive(Debug, Clone, Default)]
pub struct TcpFaultHandle {
    inner: Arc<Mutex<TcpFaults>>,
}

impl TcpFaultHandle {
    pub fn update(&self, change: impl FnOnce(&mut TcpFaults)) {
        change(&mut lock(&self.inner));
    }

    pub fn clear(&self) {
        *lock(&self.inner) = TcpFaults::default();
    }

    fn for_answer(&self) -> AnswerDecision {
        let mut faults = lock(&self.inner);
        let mut rng = rand::thread_rng();
        let split = faults.split_answer.strike(&mut rng);
        let garbage = faults.garbage_before.strike(&mut rng);
        AnswerDecision {
            close_mid_answer: faults.close_mid_answer.strike(&mut rng),
            never_answer: faults.never_answer.strike(&mut rng),
            split_gap: split.then_some(faults.split_gap),
            hold_for_next: faults.hold_for_next.strike(&mut rng),
            garbage: if garbage {
                random_bytes(&mut rng, faults.garbage_bytes.max(1))
            } else {
                Vec::new()
            },
        }
    }
}

/// Simulated devices served on a TCP port on 127.0.0.1 (or any address given).
#[derive(Debug)]
pub struct TcpSimulator {
    local: SocketAddr,
    protocol: Protocol,
    faults: FaultHandle,
    tcp_faults: TcpFaultHandle,
    journal: Journal,
    stop: CancellationToken,
    task: Option<JoinHandle<()>>,
}

impl TcpSimulator {
    /// Listens on `address` (port 0: any free port) and serves `devices` on every connection.
    pub async fn bind(
        address: &str,
        protocol: Protocol,
        options: ServeOptions,
        devices: Vec<SharedDevice>,
    ) -> std::io::Result<Self> {
        let listener = TcpListener::bind(address).await?;
        let local = listener.local_addr()?;
        let faults = FaultHandle::default();
        let tcp_faults = TcpFaultHandle::default();
        let journal = Journal::new();
        let token = CancellationToken::new();
        let stop = token.clone();
        let link = Link {
            protocol,
            options,
            devices,
            faults: faults.clone(),
            tcp_faults: tcp_faults.clone(),
            journal: journal.clone(),
        };
        let task = tokio::spawn(accept_loop(listener, link, token));
        tracing::debug!(%local, scheme = protocol.scheme(), "TCP simulator listening");
        Ok(TcpSimulator {
            local,
            protocol,
            faults,
            tcp_faults,
            journal,
            stop,
            task: Some(task),
        })
    }

    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    /// `tcp://127.0.0.1:PORT` or `modbus-tcp://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("{}://{}", self.protocol.scheme(), self.local)
    }

    /// The line's faults (as on a serial line).
    pub fn faults(&self) -> &FaultHandle {
        &self.faults
    }

    /// The network link's faults.
    pub fn tcp_faults(&self) -> &TcpFaultHandle {
        &self.tcp_faults
    }

    pub fn journal(&self) -> &Journal {
        &self.journal
    }

    /// Stops listening and closes every connection.
    pub async fn stop(&mut self) {
        self.stop.cancel();
        if let Some(task) = self.task.take() {
            if let Err(error) = task.await {
                tracing::warn!(%error, "TCP simulator task ended abnormally");
            }
        }
    }

    /// Runs until the simulator is stopped (for `simulate`).
    pub async fn wait(&mut self) {
        if let Some(task) = self.task.take() {
            if let Err(error) = task.await {
                tracing::warn!(%error, "TCP simulator task ended abnormally");
            }
        }
    }

    /// A trigger that stops the simulator from elsewhere (Ctrl-C).
    pub fn stopper(&self) -> CancellationToken {
        self.stop.clone()
    }
}

impl Drop for TcpSimulator {
    fn drop(&mut self) {
        self.stop.cancel();
    }
}

/// Everything a connection needs, shared by all of them.
#[derive(Clone)]
struct Link {
    protocol: Protocol,
    options: ServeOptions,
    devices: Vec<SharedDevice>,
    faults: FaultHandle,
    tcp_faults: TcpFaultHandle,
    journal: Journal,
}

async fn accept_loop(listener: TcpListener, link: Link, shutdown: CancellationToken) {
    let mut connections = Vec::new();
    loop {
        tokio::select! {
            _ = shutdown.cancelled() => break,
            accepted = listener.accept() => match accepted {
                Ok((socket, peer)) => {
                    tracing::debug!(%peer, "TCP simulator connection");
                    // Segments go out as written, so the split and coalesce faults are real.
                    if let Err(error) = socket.set_nodelay(true) {
                        tracing::debug!(%error, "TCP_NODELAY refused");
                    }
                    connections.push(tokio::spawn(connection(socket, link.clone(), shutdown.clone())));
                }
                Err(error) => {
                    tracing::warn!(%error, "accept failed");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                }
            }
        }
    }
    for connection in connections {
        connection.abort();
    }
}

async fn connection(socket: TcpStream, link: Link, shutdown: CancellationToken) {
    let (device_end, relay_end) = tokio::io::duplex(4 * MAX_FRAME_LEN);
    let server = tokio::spawn(serve(
        device_end,
        link.options,
        link.devices.clone(),
        link.faults.clone(),
        link.journal.clone(),
        shutdown.clone(),
    ));
    let mut relay = Relay {
        socket,
        device: relay_end,
        protocol: link.protocol,
        tcp_faults: link.tcp_faults,
        inbox: Vec::new(),
        held: Vec::new(),
    };
    if let Err(error) = relay.run(shutdown).await {
        tracing::debug!(%error, "TCP simulator connection ended");
    }
    // Dropping the relay's end ends the device's serve with EOF.
    drop(relay);
    let _ = server.await;
}

/// One request taken off the socket: the RTU frame for the devices and, for Modbus TCP, the
/// transaction id its answer must carry.
struct Incoming {
    rtu: Vec<u8>,
    transaction: Option<u16>,
}

/// What became of waiting for an answer.
enum Collected {
    /// The answer's bytes as the devices sent them (garbage included), or nothing.
    Answer(Vec<u8>),
    /// The client sent another request first: nothing to send for this one.
    Superseded,
}

struct Relay {
    socket: TcpStream,
    device: DuplexStream,
    protocol: Protocol,
    tcp_faults: TcpFaultHandle,
    /// Bytes from the client not yet passed on.
    inbox: Vec<u8>,
    /// An answer held back to go out with the next one.
    held: Vec<u8>,
}

impl Relay {
    async fn run(&mut self, shutdown: CancellationToken) -> std::io::Result<()> {
        let mut chunk = [0u8; 1024];
        loop {
            while let Some(incoming) = self.next_request()? {
                self.exchange(incoming).await?;
            }
            tokio::select! {
                _ = shutdown.cancelled() => return Ok(()),
                read = self.socket.read(&mut chunk) => {
                    let count = read?;
                    if count == 0 {
                        return Ok(());
                    }
                    self.inbox.extend_from_slice(&chunk[..count]);
                }
            }
        }
    }

    /// The next complete request in the inbox, if any. A Modbus TCP header that cannot be
    /// right closes the connection, as a gateway does.
    fn next_request(&mut self) -> std::io::Result<Option<Incoming>> {
        match self.protocol {
            Protocol::RawRtu => Ok(match wire::request_frame_len(&self.inbox) {
                FrameLen::NeedMore => None,
                FrameLen::Known(len) if self.inbox.len() < len => None,
                FrameLen::Known(len) => Some(Incoming {
                    rtu: self.inbox.drain(..len).collect(),
                    transaction: None,
                }),
                // A function the devices cannot frame by length: pass on what came.
                FrameLen::UntilSilence => Some(Incoming {
                    rtu: std::mem::take(&mut self.inbox),
                    transaction: None,
                }),
            }),
            Protocol::ModbusTcp => {
                let len = match mbap::adu_len(&self.inbox) {
                    Ok(Some(len)) if self.inbox.len() >= len => len,
                    Ok(_) => return Ok(None),
                    Err(error) => return Err(std::io::Error::other(error)),
                };
                let adu: Vec<u8> = self.inbox.drain(..len).collect();
                let (header, rtu) = mbap::adu_to_rtu(&adu).map_err(std::io::Error::other)?;
                Ok(Some(Incoming {
                    rtu,
                    transaction: Some(header.transaction),
                }))
            }
        }
    }

    async fn exchange(&mut self, incoming: Incoming) -> std::io::Result<()> {
        self.device.write_all(&incoming.rtu).await?;
        // Nothing answers a broadcast.
        if incoming.rtu.first() == Some(&0) {
            return Ok(());
        }
        let answer = match self.collect_answer(&incoming.rtu).await? {
            Collected::Answer(answer) if !answer.is_empty() => answer,
            _ => return Ok(()),
        };
        let encoded = match incoming.transaction {
            None => answer,
            Some(transaction) => match modbus_answer(&incoming.rtu, &answer, transaction) {
                Some(adu) => adu,
                // A truncated or corrupted answer: a gateway sends nothing for it.
                None => return Ok(()),
            },
        };
        self.send(encoded).await
    }

    /// Reads the devices' answer to `request`: framed by expected length and CRC when the
    /// request decodes, else ended by a short silence.
    async fn collect_answer(&mut self, request: &[u8]) -> std::io::Result<Collected> {
        let mut framer = codec::decode_request(request)
            .ok()
            .map(|(slave, request)| AnswerFramer::new(slave, &request));
        let mut raw = Vec::new();
        let mut framing = Vec::new();
        let deadline = tokio::time::Instant::now() + ANSWER_WAIT;
        let mut chunk = [0u8; 512];
        let mut client_chunk = [0u8; 512];
        loop {
            let quiet_at = (!raw.is_empty()).then(|| tokio::time::Instant::now() + ANSWER_QUIET);
            let wake = match (&framer, quiet_at) {
                (None, Some(quiet)) => quiet.min(deadline),
                _ => deadline,
            };
            tokio::select! {
                read = self.device.read(&mut chunk) => {
                    let count = read?;
                    if count == 0 {
                        return Ok(Collected::Answer(raw));
                    }
                    raw.extend_from_slice(&chunk[..count]);
                    framing.extend_from_slice(&chunk[..count]);
                    if let Some(framer) = &mut framer {
                        match framer.poll(&mut framing) {
                            Framed::NeedMore => {}
                            Framed::Answer { .. } | Framed::OutOfStep { .. } => {
                                // Whatever followed the answer in the same read stays with it.
                                return Ok(Collected::Answer(raw));
                            }
                        }
                    }
                }
                read = self.socket.read(&mut client_chunk) => {
                    let count = read?;
                    if count == 0 {
                        return Err(std::io::ErrorKind::UnexpectedEof.into());
                    }
                    self.inbox.extend_from_slice(&client_chunk[..count]);
                    // Partial answers already read go out: the stream carries them as a wire
                    // would.
                    return Ok(if raw.is_empty() { Collected::Superseded } else { Collected::Answer(raw) });
                }
                _ = tokio::time::sleep_until(wake) => return Ok(Collected::Answer(raw)),
            }
        }
    }

    /// Sends one encoded answer with the network faults of the moment.
    async fn send(&mut self, encoded: Vec<u8>) -> std::io::Result<()> {
        let decision = self.tcp_faults.for_answer();
        if decision.never_answer {
            tracing::debug!("answer swallowed by fault injection");
            return Ok(());
        }
        let mut out = decision.garbage;
        out.extend_from_slice(&encoded);
        if decision.hold_for_next {
            tracing::debug!("answer held for the next segment");
            self.held.extend_from_slice(&out);
            return Ok(());
        }
        let mut segment = std::mem::take(&mut self.held);
        segment.extend_from_slice(&out);
        let (head, tail) = segment.split_at(segment.len() - encoded.len() / 2);
        if decision.close_mid_answer {
            self.socket.write_all(head).await?;
            self.socket.flush().await?;
            self.socket.shutdown().await?;
            return Err(std::io::Error::new(
                std::io::ErrorKind::ConnectionAborted,
                "closed mid-answer by fault injection",
            ));
        }
        match decision.split_gap {
            Some(gap) => {
                self.socket.write_all(head).await?;
                self.socket.flush().await?;
                tokio::time::sleep(gap).await;
                self.socket.write_all(tail).await?;
            }
            None => self.socket.write_all(&segment).await?,
        }
        self.socket.flush().await
    }
}

/// The Modbus TCP answer to the RTU `request` from the devices' RTU `answer` bytes: the framed
/// answer (garbage before it dropped, as a gateway's serial side would), with `transaction`.
/// None when no valid answer is among the bytes.
fn modbus_answer(request: &[u8], answer: &[u8], transaction: u16) -> Option<Vec<u8>> {
    let frame = match codec::decode_request(request) {
        Ok((slave, request)) => {
            let mut buffer = answer.to_vec();
            match AnswerFramer::new(slave, &request).poll(&mut buffer) {
                Framed::Answer { frame, .. } => frame,
                _ => return None,
            }
        }
        // Requests the codec refuses get an exception from the devices: pass it if its CRC
        // holds.
        Err(_) => wire::crc_ok(answer).then(|| answer.to_vec())?,
    };
    mbap::rtu_to_adu(transaction, &frame).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_parse() {
        assert_eq!(
            Protocol::parse_url("tcp://127.0.0.1:5020"),
            Some((Protocol::RawRtu, "127.0.0.1:5020"))
        );
        assert_eq!(
            Protocol::parse_url("modbus-tcp://[::1]:502"),
            Some((Protocol::ModbusTcp, "[::1]:502"))
        );
        assert_eq!(Protocol::parse_url("udp://x:1"), None);
        assert_eq!(Protocol::parse_url("/dev/ttyUSB0"), None);
    }

    #[test]
    fn modbus_answer_drops_garbage_and_keeps_transaction() {
        let request = [0x01, 0x03, 0x10, 0x00, 0x00, 0x01, 0x80, 0xCA];
        let answer = codec::encode_answer(
            1,
            &rtu2mqtt_modbus::frame::Response::HoldingRegisters(vec![0x0102]),
        );
        let mut with_garbage = vec![0xFF, 0x00];
        with_garbage.extend_from_slice(&answer);
        assert_eq!(
            modbus_answer(&request, &with_garbage, 9),
            Some(vec![0, 9, 0, 0, 0, 5, 1, 3, 2, 1, 2])
        );
        assert_eq!(modbus_answer(&request, &answer[..4], 9), None);
    }
}
