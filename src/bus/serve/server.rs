//! The listening side of a served line: accepts up to `max_clients` connections, frames each
//! client's requests (Modbus TCP or RTU over TCP), answers what the [`policy`] refuses at once,
//! and hands the rest to the line task, one request per client at a time (a client's further
//! requests wait in its own socket, so clients take turns and none can fill the line's queue).
//! Bad input closes the client's connection or gets an exception; the line never sees it.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, oneshot, Semaphore};

use rtu2mqtt_modbus::codec::{self, DecodeError};
use rtu2mqtt_modbus::master::Reply;
use rtu2mqtt_modbus::mbap::{self, Header};
use rtu2mqtt_modbus::{ExceptionCode, FunctionCode, Request, SlaveId};

use super::policy::{self, Verdict};
use super::{Access, ClientRequest, ServeFraming, ServeSpec};
use crate::bus::DeviceSpec;
use crate::shutdown::Shutdown;

/// Once a request has started, the rest of it must arrive within this time: a torn frame
/// must not hold the connection's place forever.
pub const FRAME_PATIENCE: Duration = Duration::from_secs(2);
/// A client that does not take its answer within this time is disconnected.
pub const WRITE_PATIENCE: Duration = Duration::from_secs(5);

/// What the server counts for the line's statistics.
#[derive(Debug, Default)]
pub struct ServeCounters {
    /// Requests clients sent that were framed and judged.
    pub requests: AtomicU64,
    /// Requests refused by the access policy (no frame on the line).
    pub refusals: AtomicU64,
    /// Reads answered from the poll cache.
    pub cache_hits: AtomicU64,
}

/// What a connection needs of its server.
#[derive(Debug, Clone)]
struct Context {
    access: Access,
    framing: ServeFraming,
    devices: Arc<Vec<DeviceSpec>>,
    line: mpsc::Sender<ClientRequest>,
    counters: Arc<ServeCounters>,
}

/// Binds `spec.listen` and serves clients until `shutdown`.
pub async fn run(
    spec: ServeSpec,
    devices: Vec<DeviceSpec>,
    line: mpsc::Sender<ClientRequest>,
    counters: Arc<ServeCounters>,
    mut shutdown: Shutdown,
) {
    let listener = match TcpListener::bind(&spec.listen).await {
        Ok(listener) => listener,
        Err(error) => {
            tracing::error!(listen = %spec.url(), "cannot serve the line: {error}");
            return;
        }
    };
    tracing::info!(listen = %spec.url(), access = spec.access.word(), "serving the line");
    let places = Arc::new(Semaphore::new(spec.max_clients));
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
            () = shutdown.fired() => break,
        };
        let (socket, peer) = match accepted {
            Ok(accepted) => accepted,
            Err(error) => {
                tracing::warn!("accepting a client failed: {error}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let Ok(place) = Arc::clone(&places).try_acquire_owned() else {
            tracing::warn!(client = %peer, max_clients = spec.max_clients, "client refused: too many clients");
            drop(socket);
            continue;
        };
        let _ = socket.set_nodelay(true);
        let context = context.clone();
        let mut client_shutdown = shutdown.clone();
        tokio::spawn(async move {
            let client = peer.to_string();
            tracing::info!(%client, "client connected");
            tokio::select! {
                end = serve_client(socket, &client, &context) => {
                    tracing::info!(%client, "client disconnected: {end}");
                }
                () = client_shutdown.fired() => {}
            }
            drop(place);
        });
    }
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
}

/// One request as it came, in RTU form, with what its answer needs.
struct Framed {
    /// The MBAP transaction id (Modbus TCP only).
    transaction: Option<u16>,
    unit: SlaveId,
    function: u8,
    decoded: Result<Request, DecodeError>,
}

async fn serve_client(mut socket: TcpStream, client: &str, context: &Context) -> End {
    loop {
        let framed = match read_request(&mut socket, context.framing).await {
            Ok(framed) => framed,
            Err(end) => return end,
        };
        context.counters.requests.fetch_add(1, Ordering::Relaxed);
        let reply = answer(
            framed.unit,
            framed.function,
            framed.decoded,
            client,
            context,
        )
        .await;
        let Some(reply) = reply else {
            return End::LineGone;
        };
        let rtu = match &reply {
            Ok(response) => codec::encode_answer(framed.unit, response),
            Err(code) => codec::encode_exception(framed.unit, framed.function, *code),
        };
        let bytes = match framed.transaction {
            Some(transaction) => match mbap::rtu_to_adu(transaction, &rtu) {
                Ok(adu) => adu,
                Err(error) => return End::Garbage(error.to_string()),
            },
            None => rtu,
        };
        match tokio::time::timeout(WRITE_PATIENCE, socket.write_all(&bytes)).await {
            Ok(Ok(())) => {}
            Ok(Err(error)) => return End::Io(error),
            Err(_) => return End::NotReading,
        }
    }
}

/// The reply to one framed request: refused here, or run by the line (`None`: the line is gone).
async fn answer(
    unit: SlaveId,
    function: u8,
    decoded: Result<Request, DecodeError>,
    client: &str,
    context: &Context,
) -> Option<Reply> {
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
            return Some(Err(code));
        }
    };
    match policy::judge(context.access, &context.devices, unit, &request) {
        Verdict::Refuse(code) => {
            tracing::debug!(%client, unit, ?request, "request refused: {code}");
            context.counters.refusals.fetch_add(1, Ordering::Relaxed);
            return Some(Err(code));
        }
        Verdict::Forward | Verdict::ProfileWrite => {}
    }
    let (reply_tx, reply_rx) = oneshot::channel();
    let slot = ClientRequest {
        client: client.to_string(),
        unit,
        request,
        reply: reply_tx,
    };
    context.line.send(slot).await.ok()?;
    reply_rx.await.ok()
}

/// Reads the first byte without a deadline (a client may stay idle), the rest within
/// [`FRAME_PATIENCE`].
async fn read_request(socket: &mut TcpStream, framing: ServeFraming) -> Result<Framed, End> {
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
async fn read_adu(socket: &mut TcpStream, first: u8) -> Result<Framed, End> {
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
async fn read_rtu(socket: &mut TcpStream, first: u8) -> Result<Framed, End> {
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
