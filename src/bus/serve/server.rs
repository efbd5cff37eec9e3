//! The listening side of a served line: accepts up to `max_clients` connections, frames each
//! client's requests (Modbus TCP or RTU over TCP), answers what the [`policy`] refuses at once,
//! and hands the rest to the line task, one request per client at a time, so clients take turns
//! and none can fill the line's queue. Answers go back in the order the requests came (none to
//! a broadcast in RTU framing, as on the serial line). A client
//! may have [`PIPELINE`] requests waiting for the line; one that pipelines more gets exception
//! 06 (server device busy) for them, and while [`HELD`] of its requests are unanswered its
//! socket is not read, so a flood waits in the client's own buffers, not in the daemon.
//! Bad input closes the client's connection or gets an exception; the line never sees it.
//! Places are [`super::places`]': a client that has completed a request keeps its own, one
//! that has not can lose it to a newcomer.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, TcpSocket};
use tokio::sync::{mpsc, oneshot};

use rtu2mqtt_modbus::codec::{self, DecodeError};
use rtu2mqtt_modbus::tcp::mbap::{self, Header};
use rtu2mqtt_modbus::Reply;
use rtu2mqtt_modbus::{ExceptionCode, FunctionCode, Request, SlaveId};

use super::places::{NoPlace, Place, Places, PLACE_GRACE, PLACE_WAIT};
use super::policy::{self, Verdict};
use super::{Access, ClientRequest, ServeFraming, ServeSpec};
use crate::bus::device_spec::DeviceSpec;
use tokio_util::sync::CancellationToken;

/// Once a request has started, the rest of it must arrive within this time: a torn frame
/// must not hold the connection's place forever.
pub(crate) const FRAME_PATIENCE: Duration = Duration::from_secs(2);
/// A client that does not take its answer within this time is disconnected.
pub(crate) const WRITE_PATIENCE: Duration = Duration::from_secs(5);
/// Requests of one client that may wait for the line at once; more are answered 06.
pub(crate) const PIPELINE: usize = 8;
/// Requests of one client read and not yet answered (busy answers included); with this many
/// the client's socket is not read until answers have gone out.
pub(crate) const HELD: usize = 64;
/// The kernel's buffers of each client's socket, each way. Requests and answers are small: a
/// client that does not take its answers is found out once this much waits, and one whose
/// requests are not being read holds no more than this in the daemon's kernel.
const SOCKET_BUFFER: u32 = 8 * 1024;

/// What the server counts for the line's statistics.
#[derive(Debug, Default)]
pub(crate) struct ServeCounters {
    /// Requests clients sent that were framed and judged.
    pub requests: AtomicU64,
    /// Requests refused by the access policy (no frame on the line).
    pub refusals: AtomicU64,
    /// Reads answered from the poll cache.
    pub cache_hits: AtomicU64,
    /// Requests answered 06 (server device busy): their client had [`PIPELINE`] waiting, or
    /// a field it writes was inside its write interval.
    pub busy: AtomicU64,
    /// Connections closed to give their place to a newcomer (they had completed no request).
    pub evicted: AtomicU64,
}

/// What a connection needs of its server.
#[derive(Debug, Clone)]
struct Context {
    access: Access,
    framing: ServeFraming,
    devices: Arc<Vec<DeviceSpec>>,
    line: mpsc::Sender<Box<ClientRequest>>,
    counters: Arc<ServeCounters>,
}

/// Binds `spec.listen` and serves clients until `shutdown`.
pub(crate) async fn run(
    spec: ServeSpec,
    devices: Vec<DeviceSpec>,
    line: mpsc::Sender<Box<ClientRequest>>,
    counters: Arc<ServeCounters>,
    shutdown: CancellationToken,
) {
    // A line restarted by a reload binds again while its old server may still be closing.
    let mut attempts = 0;
    let listener = loop {
        match listen(&spec.listen).await {
            Ok(listener) => break listener,
            Err(error) if error.kind() == std::io::ErrorKind::AddrInUse && attempts < 20 => {
                attempts += 1;
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            Err(error) => {
                tracing::error!(listen = %spec.url(), "cannot serve the line: {error}");
                return;
            }
        }
    };
    tracing::info!(listen = %spec.url(), access = spec.access.word(), "serving the line");
    let places = Places::new(spec.max_clients, PLACE_GRACE, PLACE_WAIT);
    let context = Context {
        access: spec.access,
        framing: spec.framing,
        devices: Arc::new(devices),
        line,
        counters,
    };
    loop {
        let accepted = tokio::select! {
            accepted = listener.accept() => accepted,
            () = shutdown.cancelled() => break,
        };
        let (socket, peer) = match accepted {
            Ok(accepted) => accepted,
            Err(error) => {
                tracing::warn!("accepting a client failed: {error}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let _ = socket.set_nodelay(true);
        let context = context.clone();
        let places = Arc::clone(&places);
        let max_clients = spec.max_clients;
        let client_shutdown = shutdown.clone();
        tokio::spawn(async move {
            let client = peer.to_string();
            let counters = Arc::clone(&context.counters);
            let evicted = move || {
                counters.evicted.fetch_add(1, Ordering::Relaxed);
            };
            let place = tokio::select! {
                place = places.take(evicted) => place,
                () = client_shutdown.cancelled() => return,
            };
            let mut place = match place {
                Ok(place) => place,
                Err(why) => {
                    let why = match why {
                        NoPlace::QueueFull => "too many clients waiting",
                        NoPlace::TimedOut => "no place came free",
                    };
                    tracing::warn!(%client, max_clients, "client refused: {why}");
                    return;
                }
            };
            tracing::info!(%client, "client connected");
            let (read_half, write_half) = socket.into_split();
            tokio::select! {
                end = serve_client(read_half, write_half, &client, &context, &mut place) => {
                    tracing::info!(%client, "client disconnected: {end}");
                }
                () = client_shutdown.cancelled() => {}
            }
            drop(place);
        });
    }
}

/// One connection's whole life without a listening socket: the client's requests come on
/// `read_half`, the answers go on `write_half`, as on a connection of a server with `access`,
/// `framing` and `devices` whose line takes its requests on `line` (the served line's fuzz
/// target drives it with bytes, `super::fuzzing`). Returns why it ended.
pub(crate) async fn serve_connection(
    read_half: impl AsyncRead + Unpin + Send + 'static,
    write_half: impl AsyncWrite + Unpin,
    framing: ServeFraming,
    access: Access,
    devices: Vec<DeviceSpec>,
    line: mpsc::Sender<Box<ClientRequest>>,
    counters: Arc<ServeCounters>,
) -> String {
    let places = Places::new(1, PLACE_GRACE, PLACE_WAIT);
    let Ok(mut place) = places.take(|| {}).await else {
        return "no place".to_string();
    };
    let context = Context {
        access,
        framing,
        devices: Arc::new(devices),
        line,
        counters,
    };
    serve_client(read_half, write_half, "client", &context, &mut place)
        .await
        .to_string()
}

/// Why a client's connection ended.
#[derive(Debug, thiserror::Error)]
enum End {
    #[error("closed by the client")]
    Closed,
    #[error("{0}")]
    Io(#[from] std::io::Error),
    #[error("the rest of a request did not come within {FRAME_PATIENCE:?}")]
    Torn,
    #[error("the answer was not taken within {WRITE_PATIENCE:?}")]
    NotReading,
    #[error("unusable request: {0}")]
    Garbage(String),
    #[error("the line has stopped")]
    LineGone,
    #[error("its place went to a newcomer before it completed a request")]
    Evicted,
}

/// One request as it came, in RTU form, with what its answer needs.
struct Framed {
    /// The MBAP transaction id (Modbus TCP only).
    transaction: Option<u16>,
    unit: SlaveId,
    function: u8,
    decoded: Result<Request, DecodeError>,
}

/// A client's request read and not yet answered.
struct Held {
    transaction: Option<u16>,
    unit: SlaveId,
    function: u8,
    state: HeldState,
}

enum HeldState {
    /// The answer, to be written when every earlier request has been answered.
    Answered(Reply),
    /// To go to the line when every earlier request has been answered.
    ForTheLine(Request),
    /// On the line; its answer comes on the connection's `on_line` receiver.
    OnTheLine,
}

/// What a connection waited for.
enum Event {
    Read(Option<Result<Framed, End>>),
    LineAnswered(Option<Reply>),
    Evicted,
}

/// Ends the task that reads a connection's requests when the connection's task ends.
struct AbortOnDrop(tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// Serves one client, whose requests come on `read_half` and answers go on `write_half`,
/// until the connection ends.
async fn serve_client(
    read_half: impl AsyncRead + Unpin + Send + 'static,
    mut write_half: impl AsyncWrite + Unpin,
    client: &str,
    context: &Context,
    place: &mut Place,
) -> End {
    let (framed_tx, mut framed_rx) = mpsc::channel(1);
    let _reader = AbortOnDrop(tokio::spawn(read_requests(
        read_half,
        context.framing,
        framed_tx,
    )));
    let mut held: VecDeque<Held> = VecDeque::with_capacity(HELD);
    let mut on_line: Option<oneshot::Receiver<Reply>> = None;
    // Why reading stopped: the requests read before it are still answered.
    let mut ended: Option<End> = None;
    // The client has completed a request: its place is its own.
    let mut settled = false;
    loop {
        while let Some(Held {
            state: HeldState::Answered(_),
            ..
        }) = held.front()
        {
            let Some(answered) = held.pop_front() else {
                break;
            };
            if let Err(end) = write_answer(&mut write_half, answered).await {
                return end;
            }
        }
        if let Some(front) = held.front_mut() {
            if matches!(front.state, HeldState::ForTheLine(_)) {
                let state = std::mem::replace(&mut front.state, HeldState::OnTheLine);
                if let HeldState::ForTheLine(request) = state {
                    match to_the_line(front.unit, request, client, context).await {
                        Some(receiver) => on_line = Some(receiver),
                        None => return End::LineGone,
                    }
                }
            }
        }
        if held.is_empty() {
            if let Some(end) = ended {
                return end;
            }
        }
        let reading = ended.is_none() && held.len() < HELD;
        let event = tokio::select! {
            framed = framed_rx.recv(), if reading => Event::Read(framed),
            reply = line_answer(&mut on_line) => Event::LineAnswered(reply),
            _ = &mut place.evicted, if !settled => Event::Evicted,
        };
        match event {
            Event::Evicted => return End::Evicted,
            Event::Read(Some(Ok(framed))) => {
                if !settled {
                    if !place.complete() {
                        return End::Evicted;
                    }
                    settled = true;
                }
                let waiting = held
                    .iter()
                    .filter(|h| !matches!(h.state, HeldState::Answered(_)))
                    .count();
                held.push_back(judge(framed, waiting, client, context));
            }
            Event::Read(Some(Err(end))) => ended = Some(end),
            Event::Read(None) => ended = Some(End::Closed),
            Event::LineAnswered(reply) => {
                on_line = None;
                let Some(reply) = reply else {
                    return End::LineGone;
                };
                if let Some(front) = held.front_mut() {
                    front.state = HeldState::Answered(reply);
                }
            }
        }
    }
}

/// The answer of the request on the line; never ready while none is.
async fn line_answer(on_line: &mut Option<oneshot::Receiver<Reply>>) -> Option<Reply> {
    match on_line.as_mut() {
        Some(receiver) => receiver.await.ok(),
        None => std::future::pending().await,
    }
}

/// Reads a connection's requests and hands them over one by one, until the first that ends
/// the connection (handed over too) or until nobody takes them.
async fn read_requests(
    mut socket: impl AsyncRead + Unpin,
    framing: ServeFraming,
    framed_tx: mpsc::Sender<Result<Framed, End>>,
) {
    loop {
        let framed = read_request(&mut socket, framing).await;
        let last = framed.is_err();
        if framed_tx.send(framed).await.is_err() || last {
            return;
        }
    }
}

/// Writes one answer in the client's framing within [`WRITE_PATIENCE`].
async fn write_answer(socket: &mut (impl AsyncWrite + Unpin), answered: Held) -> Result<(), End> {
    let HeldState::Answered(reply) = answered.state else {
        return Ok(());
    };
    // RTU over TCP is the serial line's own framing, where nothing ever answers address 0: a
    // master that sent a broadcast listens for no answer, and one arriving would be taken
    // for the answer to its next request.
    if answered.transaction.is_none() && answered.unit == 0 {
        return Ok(());
    }
    let rtu = match &reply {
        Ok(response) => codec::encode_answer(answered.unit, response),
        Err(code) => codec::encode_exception(answered.unit, answered.function, *code),
    };
    let bytes = match answered.transaction {
        Some(transaction) => {
            mbap::rtu_to_adu(transaction, &rtu).map_err(|error| End::Garbage(error.to_string()))?
        }
        None => rtu,
    };
    match tokio::time::timeout(WRITE_PATIENCE, socket.write_all(&bytes)).await {
        Ok(Ok(())) => Ok(()),
        Ok(Err(error)) => Err(End::Io(error)),
        Err(_) => Err(End::NotReading),
    }
}

/// What becomes of one framed request: refused here (the policy, or busy with `waiting`
/// requests of its client before it), or held for the line.
fn judge(framed: Framed, waiting: usize, client: &str, context: &Context) -> Held {
    let Framed {
        transaction,
        unit,
        function,
        decoded,
    } = framed;
    context.counters.requests.fetch_add(1, Ordering::Relaxed);
    let held = |state| Held {
        transaction,
        unit,
        function,
        state,
    };
    let request = match decoded {
        Ok(request) => request,
        Err(error) => {
            let code = if FunctionCode::from_u8(function).is_none() {
                ExceptionCode::IllegalFunction
            } else {
                ExceptionCode::IllegalDataValue
            };
            tracing::debug!(%client, unit, function, "request refused: {error}");
            context.counters.refusals.fetch_add(1, Ordering::Relaxed);
            return held(HeldState::Answered(Err(code)));
        }
    };
    match policy::judge(context.access, &context.devices, unit, &request) {
        Verdict::Refuse(code) => {
            tracing::debug!(%client, unit, ?request, "request refused: {code}");
            context.counters.refusals.fetch_add(1, Ordering::Relaxed);
            held(HeldState::Answered(Err(code)))
        }
        Verdict::Forward | Verdict::ProfileWrite if waiting >= PIPELINE => {
            tracing::debug!(%client, unit, ?request, waiting, "request refused: busy");
            context.counters.busy.fetch_add(1, Ordering::Relaxed);
            held(HeldState::Answered(Err(ExceptionCode::ServerDeviceBusy)))
        }
        Verdict::Forward | Verdict::ProfileWrite => held(HeldState::ForTheLine(request)),
    }
}

/// Hands a request to the line task; `None`: the line is gone.
async fn to_the_line(
    unit: SlaveId,
    request: Request,
    client: &str,
    context: &Context,
) -> Option<oneshot::Receiver<Reply>> {
    let (reply_tx, reply_rx) = oneshot::channel();
    let slot = ClientRequest {
        client: client.to_string(),
        unit,
        request,
        probe: false,
        reply: reply_tx,
    };
    context.line.send(Box::new(slot)).await.ok()?;
    Some(reply_rx)
}

/// A listening socket on `listen` whose connections get small buffers ([`SOCKET_BUFFER`]):
/// the first of the addresses the name resolves to that can be bound, as `TcpListener::bind`
/// does (`localhost` may name `::1` first on a host without IPv6).
async fn listen(listen: &str) -> std::io::Result<TcpListener> {
    let mut last_error = None;
    for address in tokio::net::lookup_host(listen).await? {
        match listen_on(address) {
            Ok(listener) => return Ok(listener),
            Err(error) => last_error = Some(error),
        }
    }
    Err(last_error.unwrap_or_else(|| std::io::Error::other(format!("{listen} names no address"))))
}

fn listen_on(address: SocketAddr) -> std::io::Result<TcpListener> {
    let socket = if address.is_ipv4() {
        TcpSocket::new_v4()?
    } else {
        TcpSocket::new_v6()?
    };
    socket.set_reuseaddr(true)?;
    // Connections accepted on this socket inherit its buffer sizes.
    socket.set_send_buffer_size(SOCKET_BUFFER)?;
    socket.set_recv_buffer_size(SOCKET_BUFFER)?;
    socket.bind(address)?;
    socket.listen(1024)
}

/// Reads the first byte without a deadline (a client may stay idle), the rest within
/// [`FRAME_PATIENCE`].
async fn read_request(
    socket: &mut (impl AsyncRead + Unpin),
    framing: ServeFraming,
) -> Result<Framed, End> {
    let mut first = [0u8; 1];
    match socket.read(&mut first).await {
        Ok(0) => return Err(End::Closed),
        Ok(_) => {}
        Err(error) => return Err(End::Io(error)),
    }
    let rest = async {
        match framing {
            ServeFraming::ModbusTcp => read_adu(socket, first[0]).await,
            ServeFraming::RawRtu => read_rtu(socket, first[0]).await,
        }
    };
    tokio::time::timeout(FRAME_PATIENCE, rest)
        .await
        .unwrap_or(Err(End::Torn))
}

async fn read_exact(socket: &mut (impl AsyncRead + Unpin), buf: &mut [u8]) -> Result<(), End> {
    match socket.read_exact(buf).await {
        Ok(_) => Ok(()),
        Err(error) if error.kind() == std::io::ErrorKind::UnexpectedEof => Err(End::Torn),
        Err(error) => Err(End::Io(error)),
    }
}

/// A Modbus TCP ADU. A header that cannot be right (protocol, length) leaves the stream out of
/// step: the connection closes.
async fn read_adu(socket: &mut (impl AsyncRead + Unpin), first: u8) -> Result<Framed, End> {
    let mut adu = vec![0u8; mbap::HEADER_LEN];
    adu[0] = first;
    read_exact(socket, &mut adu[1..]).await?;
    let header = Header::decode(&adu).map_err(|error| End::Garbage(error.to_string()))?;
    adu.resize(header.adu_len(), 0);
    read_exact(socket, &mut adu[mbap::HEADER_LEN..]).await?;
    let (header, rtu) = mbap::adu_to_rtu(&adu).map_err(|error| End::Garbage(error.to_string()))?;
    let function = rtu.get(1).copied().unwrap_or_default();
    let decoded = codec::decode_request(&rtu).map(|(_, request)| request);
    Ok(Framed {
        transaction: Some(header.transaction),
        unit: header.unit,
        function,
        decoded,
    })
}

/// An RTU frame over TCP: its length follows from its function code; a frame this codec
/// cannot delimit or whose CRC is wrong leaves the stream out of step.
async fn read_rtu(socket: &mut (impl AsyncRead + Unpin), first: u8) -> Result<Framed, End> {
    let mut frame = vec![first];
    let len = loop {
        match codec::request_frame_len(&frame) {
            Ok(Some(len)) => break len,
            Ok(None) => {
                let mut byte = [0u8; 1];
                read_exact(socket, &mut byte).await?;
                frame.push(byte[0]);
            }
            Err(error) => return Err(End::Garbage(error.to_string())),
        }
    };
    if len > codec::MAX_FRAME_LEN {
        return Err(End::Garbage(format!("a frame of {len} bytes")));
    }
    let have = frame.len();
    frame.resize(len, 0);
    read_exact(socket, &mut frame[have..]).await?;
    match codec::decode_request(&frame) {
        Ok((unit, request)) => Ok(Framed {
            transaction: None,
            unit,
            function: frame[1],
            decoded: Ok(request),
        }),
        Err(error) => Err(End::Garbage(error.to_string())),
    }
}
