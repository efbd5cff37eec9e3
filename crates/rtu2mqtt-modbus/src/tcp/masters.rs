//! Modbus transactions over TCP, one at a time: raw RTU frames on the stream of a serial device
//! server (`tcp://`, [`RawTcpMaster`]) and Modbus TCP to a TCP-to-RTU gateway (`modbus-tcp://`,
//! [`ModbusTcpMaster`]). Both keep one connection (`Connection`: connect timeout, TCP
//! keepalive, reconnected inside the next transaction after it dropped).
//!
//! A connection that drops while an answer is awaited fails that transaction with
//! [`Error::ConnectionLost`] (the line retries it under its rules); only a reconnect that fails
//! is [`Error::PortGone`], which makes the line close the link and try again with back-off.
//! No partial answer is ever decoded: raw answers are framed by expected length and CRC
//! ([`AnswerFramer`]), Modbus TCP answers by their MBAP length and matched by transaction id.
//!
//! Nothing here knows about devices, polls or the bridge.

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::time::Instant;

use crate::answer_framing::{AnswerFramer, Framed};
use crate::clock::PreciseTimer;
use crate::codec::{self, Answer, DecodeError};
use crate::frame::{Request, SlaveId};
use crate::outcome::{reply_of, Error, PortFault, Reply};
use crate::tcp::mbap::{self, Matched, MbapError};
use crate::timing::LineTiming;
use crate::transaction::{Ask, Direction, Exchange, LinkCore};

/// The server a TCP master connects to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TcpServer {
    /// `host:port` as `TcpStream::connect` takes it (IPv6 hosts in brackets).
    pub address: String,
    /// The url that named it, for logs and the frame log.
    pub url: String,
}

/// Settings shared by both kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TcpOptions {
    /// Quiet time after a broadcast before the next request.
    pub broadcast_turnaround: Duration,
    /// Longest wait for the server to accept a connection.
    pub connect_timeout: Duration,
    /// Idle time before TCP keepalive probes start (and the interval between them): a server
    /// that vanished without closing is noticed even when no transaction is running.
    pub keepalive: Duration,
}

impl Default for TcpOptions {
    fn default() -> Self {
        TcpOptions {
            broadcast_turnaround: Duration::from_millis(100),
            connect_timeout: Duration::from_secs(3),
            keepalive: Duration::from_secs(10),
        }
    }
}

/// One TCP connection to the server, reopened on demand, with the link's counters, frame
/// recording and late-answer guard.
pub(crate) struct Connection {
    server: TcpServer,
    options: TcpOptions,
    stream: Option<TcpStream>,
    /// Bytes read and not yet framed.
    buffer: Vec<u8>,
    /// Counters, frame recorder and late-answer guard; labelled with the url.
    pub(crate) core: LinkCore,
}

impl std::fmt::Debug for Connection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Connection")
            .field("core", &self.core)
            .finish_non_exhaustive()
    }
}

impl Connection {
    fn label(&self) -> &str {
        self.core.label()
    }

    async fn open(server: TcpServer, options: TcpOptions) -> std::io::Result<Connection> {
        let core = LinkCore::new(server.url.clone());
        let mut connection = Connection {
            server,
            options,
            stream: None,
            buffer: Vec::new(),
            core,
        };
        connection.connect().await?;
        Ok(connection)
    }

    async fn connect(&mut self) -> std::io::Result<()> {
        let connecting = TcpStream::connect(&self.server.address);
        let stream = match tokio::time::timeout(self.options.connect_timeout, connecting).await {
            Ok(connected) => connected?,
            Err(_) => {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    format!("no connection within {:?}", self.options.connect_timeout),
                ))
            }
        };
        // Requests are small and must leave at once.
        stream.set_nodelay(true)?;
        let keepalive = socket2::TcpKeepalive::new()
            .with_time(self.options.keepalive)
            .with_interval(self.options.keepalive);
        socket2::SockRef::from(&stream).set_tcp_keepalive(&keepalive)?;
        self.buffer.clear();
        self.stream = Some(stream);
        tracing::debug!(url = %self.label(), "connected");
        Ok(())
    }

    /// The stream, reconnected when the previous one dropped; a failed reconnect is the link
    /// gone (the line backs off).
    async fn ensure(&mut self) -> Result<(), Error> {
        if self.stream.is_none() {
            tracing::info!(url = %self.label(), "reconnecting");
            self.connect().await.map_err(Error::from)?;
        }
        Ok(())
    }

    fn lost(&mut self, error: std::io::Error) -> Error {
        tracing::warn!(url = %self.label(), %error, "connection lost");
        self.stream = None;
        self.buffer.clear();
        Error::ConnectionLost(PortFault::from(error))
    }

    /// Takes whatever already arrived (late answers, garbage) without waiting.
    fn take_pending(&mut self) -> Result<Vec<u8>, Error> {
        let mut pending = std::mem::take(&mut self.buffer);
        let Some(stream) = self.stream.as_ref() else {
            return Ok(pending);
        };
        let mut chunk = [0u8; 512];
        loop {
            match stream.try_read(&mut chunk) {
                Ok(0) => {
                    return Err(self.lost(std::io::ErrorKind::UnexpectedEof.into()));
                }
                Ok(count) => pending.extend_from_slice(&chunk[..count]),
                Err(error) if error.kind() == std::io::ErrorKind::WouldBlock => return Ok(pending),
                Err(error) => return Err(self.lost(error)),
            }
        }
    }

    async fn send(&mut self, bytes: &[u8]) -> Result<Instant, Error> {
        let Some(stream) = self.stream.as_mut() else {
            return Err(self.lost(std::io::ErrorKind::NotConnected.into()));
        };
        match stream.write_all(bytes).await {
            Ok(()) => Ok(Instant::now()),
            Err(error) => Err(self.lost(error)),
        }
    }

    /// Appends what arrives before `deadline` to the buffer. `Ok(false)`: the deadline passed.
    async fn read_until(&mut self, deadline: Instant) -> Result<bool, Error> {
        let Some(stream) = self.stream.as_mut() else {
            return Err(self.lost(std::io::ErrorKind::NotConnected.into()));
        };
        let mut chunk = [0u8; 512];
        match tokio::time::timeout_at(deadline, stream.read(&mut chunk)).await {
            Err(_) => Ok(false),
            Ok(Ok(0)) => Err(self.lost(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "closed by the server",
            ))),
            Ok(Ok(count)) => {
                self.buffer.extend_from_slice(&chunk[..count]);
                Ok(true)
            }
            Ok(Err(error)) => Err(self.lost(error)),
        }
    }
}

/// RTU frames over a raw TCP stream (a serial device server). The stream has no silences, so
/// answers are framed by expected length and CRC; the server's serial side still needs them,
/// so requests go out no sooner than t3.5 after the previous answer was received (or after
/// the previous request's wire time, when nothing answered).
///
/// Raw RTU carries no transaction id: a late answer is told from the current one only when it
/// arrives before the next request is sent (it is then drained and counted late), or together
/// with the current answer in one segment (the last complete answer is taken, the earlier one
/// counted late).
#[derive(Debug)]
pub struct RawTcpMaster {
    pub(crate) connection: Connection,
    timing: LineTiming,
    /// The server's serial side may be driven again from this instant.
    next_send_at: Instant,
    /// The precise timer of the link's own t3.5 spacing.
    timer: PreciseTimer,
}

impl RawTcpMaster {
    /// Connects to the device server. `timing` is the server's serial side (baud, parity).
    /// An error is the connection's failure (refused, no route, no answer within the connect
    /// timeout).
    pub async fn connect(
        server: TcpServer,
        options: TcpOptions,
        timing: LineTiming,
    ) -> std::io::Result<Self> {
        Ok(RawTcpMaster {
            connection: Connection::open(server, options).await?,
            timing,
            next_send_at: Instant::now(),
            timer: PreciseTimer::default(),
        })
    }

    /// Sends `request` to address 0; nothing answers. `sent` is called once the frame is
    /// sent; the line is then kept silent for the request's wire time and the broadcast
    /// turnaround.
    pub(crate) async fn broadcast_then(
        &mut self,
        request: &Request,
        sent: impl FnOnce() + Send,
    ) -> Result<(), Error> {
        let turnaround = self.connection.options.broadcast_turnaround;
        let frame = codec::encode_request(0, request)?;
        self.connection.ensure().await?;
        let sent_at = self.send(&frame).await?;
        sent();
        self.next_send_at = sent_at + self.timing.frame_time(frame.len()) + turnaround;
        self.timer.sleep_until(self.next_send_at).await;
        Ok(())
    }

    /// Before a request to the address that timed out last: its late answer, if it comes
    /// within the guard, is drained and counted, never taken for this request's. Bytes
    /// already waiting are drained before any request.
    async fn wait_out_late_answer(&mut self, slave: SlaveId) -> Result<(), Error> {
        if let Some(until) = self.connection.core.take_late_guard(slave) {
            // Until the late answer starts to arrive or the guard ends.
            while self.connection.buffer.is_empty() && self.connection.read_until(until).await? {}
        }
        self.sleep_out_spacing().await;
        let pending = self.connection.take_pending()?;
        if !pending.is_empty() {
            self.connection.core.record(Direction::Rx, &pending);
            if pending.first() == Some(&slave) {
                self.connection.core.counters_mut().late_answers += 1;
            } else {
                self.connection.core.counters_mut().stray_bytes += pending.len() as u64;
            }
            tracing::debug!(url = %self.connection.label(), bytes = pending.len(), "bytes before the request dropped");
        }
        Ok(())
    }

    /// Waits until the link's own t3.5 spacing after the last answer has passed
    /// (cancel-safe; see [`crate::serial::master::Master::wait_until_quiet`]). That spacing is
    /// never longer than the line's silence, so `patience` cannot run out first.
    pub(crate) async fn wait_until_quiet(&mut self, _patience: Duration) -> Result<(), Error> {
        self.sleep_out_spacing().await;
        Ok(())
    }

    async fn sleep_out_spacing(&mut self) {
        self.timer.sleep_until(self.next_send_at).await;
    }

    async fn send(&mut self, frame: &[u8]) -> Result<Instant, Error> {
        self.connection.core.record(Direction::Tx, frame);
        let sent_at = self.connection.send(frame).await?;
        self.connection.core.counters_mut().requests += 1;
        self.connection.core.counters_mut().wire_time +=
            self.timing.frame_time(frame.len()) + self.timing.t3_5;
        Ok(sent_at)
    }

    /// An answer followed in the same read by another complete answer to the same request:
    /// the first was the late answer of an earlier one (it is counted late and dropped).
    fn newest_answer(
        &mut self,
        slave: SlaveId,
        request: &Request,
        mut answer: Answer,
        mut frame: Vec<u8>,
    ) -> (Answer, Vec<u8>) {
        while !self.connection.buffer.is_empty() {
            let mut rest = self.connection.buffer.clone();
            let mut framer = AnswerFramer::with_max_skip(slave, request, 0);
            match framer.poll(&mut rest) {
                Framed::Answer {
                    answer: newer,
                    frame: newer_frame,
                    ..
                } => {
                    self.connection.core.record(Direction::Rx, &frame);
                    self.connection.core.counters_mut().late_answers += 1;
                    answer = newer;
                    frame = newer_frame;
                    self.connection.buffer = rest;
                }
                _ => break,
            }
        }
        (answer, frame)
    }

    fn took_answer(&mut self, frame: &[u8]) {
        self.connection.core.record(Direction::Rx, frame);
        self.connection.core.counters_mut().wire_time +=
            self.timing.frame_time(frame.len()) + self.timing.t3_5;
        self.next_send_at = Instant::now() + self.timing.t3_5;
    }
}

impl Exchange for RawTcpMaster {
    fn core(&self) -> &LinkCore {
        &self.connection.core
    }

    fn core_mut(&mut self) -> &mut LinkCore {
        &mut self.connection.core
    }

    fn late_answer_guard(&self, timeout: Duration) -> Option<Duration> {
        Some(timeout)
    }

    /// Sends the request and waits up to its timeout (from the instant it was handed to the
    /// network) for its complete answer.
    async fn exchange(&mut self, ask: Ask<'_>) -> Result<Reply, Error> {
        let Ask {
            slave,
            request,
            timeout,
        } = ask;
        let frame = codec::encode_request(slave, request)?;
        self.connection.ensure().await?;
        self.wait_out_late_answer(slave).await?;
        let sent_at = self.send(&frame).await?;
        let deadline = sent_at + timeout;
        let mut framer = AnswerFramer::new(slave, request);
        loop {
            match framer.poll(&mut self.connection.buffer) {
                Framed::Answer {
                    answer,
                    frame,
                    skipped,
                } => {
                    self.connection.core.counters_mut().stray_bytes += skipped as u64;
                    let (answer, frame) = self.newest_answer(slave, request, answer, frame);
                    self.took_answer(&frame);
                    return Ok(reply_of(answer));
                }
                Framed::OutOfStep { skipped } => {
                    self.connection.core.counters_mut().stray_bytes += skipped as u64;
                    let garbage = std::mem::take(&mut self.connection.buffer);
                    self.connection.core.record(Direction::Rx, &garbage);
                    self.next_send_at = Instant::now() + self.timing.t3_5;
                    return Err(Error::UnexpectedReply(DecodeError::Malformed(
                        "no answer among the bytes received",
                    )));
                }
                Framed::NeedMore => {}
            }
            if !self.connection.read_until(deadline).await? {
                self.next_send_at = Instant::now() + self.timing.t3_5;
                let got = self.connection.buffer.len();
                if got > 0 {
                    let partial = std::mem::take(&mut self.connection.buffer);
                    self.connection.core.record(Direction::Rx, &partial);
                    return Err(Error::Truncated {
                        needed: request.answer_len(),
                        got,
                    });
                }
                if framer.skipped() > 0 {
                    return Err(Error::UnexpectedReply(DecodeError::Malformed(
                        "no answer among the bytes received",
                    )));
                }
                return Err(Error::Timeout(timeout));
            }
        }
    }
}

/// Modbus TCP to a TCP-to-RTU gateway: each request carries a new transaction id, answers are
/// framed by their MBAP length and matched by id; an answer with another id (the late answer of
/// a request that timed out) is discarded and counted in `late_answers`. The gateway paces its
/// own serial side. The wire time counted is what that side carries: each request and each
/// answer as an RTU frame (the ADU's unit id and PDU with a CRC) at the line's serial format,
/// with its t3.5, the same model as a serial line's and as a poll plan's estimate; the network's
/// delays are no part of it.
#[derive(Debug)]
pub struct ModbusTcpMaster {
    pub(crate) connection: Connection,
    next_transaction: u16,
    /// The gateway's serial side, as the line configures it.
    timing: LineTiming,
}

impl ModbusTcpMaster {
    /// Connects to the gateway, whose serial side runs at `timing` (for the wire time counted).
    /// An error is the connection's failure (refused, no route, no answer within the connect
    /// timeout).
    pub async fn connect(
        server: TcpServer,
        options: TcpOptions,
        timing: LineTiming,
    ) -> std::io::Result<Self> {
        Ok(ModbusTcpMaster {
            connection: Connection::open(server, options).await?,
            // Not 0: some gateways treat id 0 specially.
            next_transaction: 1,
            timing,
        })
    }

    /// Counts the serial wire time of the ADU `adu` (sent or received): its RTU frame and the
    /// t3.5 after it.
    fn count_wire_time(&mut self, adu: &[u8]) {
        let serial = self.timing.frame_time(mbap::rtu_frame_len(adu.len())) + self.timing.t3_5;
        self.connection.core.counters_mut().wire_time += serial;
    }

    fn take_transaction(&mut self) -> u16 {
        let transaction = self.next_transaction;
        self.next_transaction = self.next_transaction.wrapping_add(1).max(1);
        transaction
    }

    /// Ready at once: a gateway keeps its own line's timing.
    pub(crate) async fn wait_until_quiet(&mut self, _patience: Duration) -> Result<(), Error> {
        Ok(())
    }

    /// Sends `request` to unit 0 (broadcast), calls `sent` and waits the broadcast
    /// turnaround; nothing answers.
    pub(crate) async fn broadcast_then(
        &mut self,
        request: &Request,
        sent: impl FnOnce() + Send,
    ) -> Result<(), Error> {
        let turnaround = self.connection.options.broadcast_turnaround;
        let transaction = self.take_transaction();
        let adu = mbap::encode_request(transaction, 0, request)?;
        self.connection.ensure().await?;
        self.drop_pending()?;
        self.send(&adu).await?;
        sent();
        tokio::time::sleep(turnaround).await;
        Ok(())
    }

    async fn send(&mut self, adu: &[u8]) -> Result<Instant, Error> {
        self.connection.core.record(Direction::Tx, adu);
        let sent_at = self.connection.send(adu).await?;
        self.connection.core.counters_mut().requests += 1;
        self.count_wire_time(adu);
        Ok(sent_at)
    }

    /// Late answers already waiting are dropped whole (counted late); a header out of step
    /// ends the connection.
    fn drop_pending(&mut self) -> Result<(), Error> {
        self.connection.buffer = self.connection.take_pending()?;
        while let Some(adu) = self.next_adu()? {
            self.connection.core.record(Direction::Rx, &adu);
            self.connection.core.counters_mut().late_answers += 1;
        }
        Ok(())
    }

    /// The next complete ADU in the buffer (its serial wire time counted: the gateway's line
    /// carried it, late or not). A header that cannot be right means the stream is out of
    /// step: the connection is dropped (the next transaction reconnects).
    fn next_adu(&mut self) -> Result<Option<Vec<u8>>, Error> {
        match mbap::adu_len(&self.connection.buffer) {
            Ok(Some(len)) if self.connection.buffer.len() >= len => {
                let adu: Vec<u8> = self.connection.buffer.drain(..len).collect();
                self.count_wire_time(&adu);
                Ok(Some(adu))
            }
            Ok(_) => Ok(None),
            Err(error) => {
                self.connection.core.counters_mut().stray_bytes +=
                    self.connection.buffer.len() as u64;
                let garbage = std::mem::take(&mut self.connection.buffer);
                self.connection.core.record(Direction::Rx, &garbage);
                Err(self.connection.lost(std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    error.to_string(),
                )))
            }
        }
    }
}

impl Exchange for ModbusTcpMaster {
    fn core(&self) -> &LinkCore {
        &self.connection.core
    }

    fn core_mut(&mut self) -> &mut LinkCore {
        &mut self.connection.core
    }

    /// Answers carry their transaction id: a late one is told apart without a guard.
    fn late_answer_guard(&self, _timeout: Duration) -> Option<Duration> {
        None
    }

    /// Sends the request to its unit and waits up to its timeout for the answer with its id.
    async fn exchange(&mut self, ask: Ask<'_>) -> Result<Reply, Error> {
        let Ask {
            slave: unit,
            request,
            timeout,
        } = ask;
        let transaction = self.take_transaction();
        let adu = mbap::encode_request(transaction, unit, request)?;
        self.connection.ensure().await?;
        self.drop_pending()?;
        let sent_at = self.send(&adu).await?;
        let deadline = sent_at + timeout;
        loop {
            while let Some(answer) = self.next_adu()? {
                self.connection.core.record(Direction::Rx, &answer);
                match mbap::decode_answer(transaction, unit, request, &answer) {
                    Ok(Matched::Current(answer)) => return Ok(reply_of(answer)),
                    Ok(Matched::Stale { transaction: old }) => {
                        self.connection.core.counters_mut().late_answers += 1;
                        tracing::debug!(url = %self.connection.label(), transaction = old, "answer to an earlier request dropped");
                    }
                    Err(MbapError::WrongUnit { expected, found }) => {
                        return Err(Error::UnexpectedReply(DecodeError::WrongAddress {
                            expected,
                            found,
                        }))
                    }
                    Err(MbapError::Pdu(error)) => return Err(error.into()),
                    Err(_) => {
                        return Err(Error::UnexpectedReply(DecodeError::Malformed(
                            "unusable MBAP header",
                        )))
                    }
                }
            }
            if !self.connection.read_until(deadline).await? {
                let got = self.connection.buffer.len();
                if got > 0 {
                    return Err(Error::Truncated {
                        needed: mbap::HEADER_LEN + request.answer_len() - 3,
                        got,
                    });
                }
                return Err(Error::Timeout(timeout));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Response;
    use crate::timing::{CharFormat, Parity};
    use crate::transaction::Transact;

    /// A Modbus TCP gateway on loopback that answers each ADU after `delay` with `answer`'s
    /// PDU (the request's transaction id and unit kept), as often as it is asked.
    async fn gateway(answer: Response, delay: Duration) -> String {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let address = listener.local_addr().unwrap().to_string();
        tokio::spawn(async move {
            let (mut stream, _) = listener.accept().await.unwrap();
            let mut request = [0u8; 12];
            while stream.read_exact(&mut request).await.is_ok() {
                tokio::time::sleep(delay).await;
                let rtu = codec::encode_answer(request[6], &answer);
                let transaction = u16::from_be_bytes([request[0], request[1]]);
                let adu = mbap::rtu_to_adu(transaction, &rtu).unwrap();
                if stream.write_all(&adu).await.is_err() {
                    break;
                }
            }
        });
        address
    }

    /// The wire time counted is the gateway's serial side carrying the request and the answer
    /// as RTU frames with their t3.5, whatever the network and the gateway took; a timeout
    /// counts the request alone.
    #[tokio::test(flavor = "current_thread")]
    async fn a_modbus_tcp_transaction_counts_its_serial_wire_time() {
        let read = Request::ReadHoldingRegisters {
            start: 0x1000,
            quantity: 6,
        };
        let timing = LineTiming::new(
            9600,
            CharFormat {
                data_bits: 8,
                parity: Parity::None,
                stop_bits: 1,
            },
        );
        // Slow on purpose: 40 ms for an answer whose serial wire time is under 30 ms.
        let address = gateway(
            Response::HoldingRegisters(vec![3, 5, 2, 10, 1500, 25]),
            Duration::from_millis(40),
        )
        .await;
        let server = TcpServer {
            url: format!("modbus-tcp://{address}"),
            address,
        };
        let mut master = ModbusTcpMaster::connect(server, TcpOptions::default(), timing)
            .await
            .unwrap();
        let one = timing.frame_time(read.frame_len())
            + timing.frame_time(read.answer_len())
            + 2 * timing.t3_5;
        for round in 1..=3u32 {
            let answer = master
                .transact(1, &read, Duration::from_secs(2))
                .await
                .unwrap();
            assert!(answer.is_ok());
            assert_eq!(master.connection.core.counters().wire_time, one * round);
        }
        // 8 + 17 bytes of 10 bits at 9600 baud (1.04 ms each) and two t3.5 of 3.65 ms.
        assert_eq!(one.as_micros(), 33_333);
        let before = master.connection.core.counters().wire_time;
        let timed_out = master.transact(1, &read, Duration::from_millis(5)).await;
        assert!(matches!(timed_out, Err(Error::Timeout(_))), "{timed_out:?}");
        assert_eq!(
            master.connection.core.counters().wire_time - before,
            timing.frame_time(read.frame_len()) + timing.t3_5
        );
    }
}
