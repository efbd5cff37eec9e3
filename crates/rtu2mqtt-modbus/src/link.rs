//! What a line talks through: a serial port ([`Master`]), a serial device server's raw TCP
//! stream ([`RawTcpMaster`]) or a Modbus TCP gateway ([`ModbusTcpMaster`]). [`Link::open`]
//! opens any of them from a [`LinkSpec`]; the line task then runs the same transactions,
//! counters and frame log on each. Only this file knows which transports there are: the
//! `on_master!` dispatch names each once.

use std::time::Duration;

use super::frame::Request;
use super::outcome::{Error, Reply, WireCounters};
use crate::serial::master::{Master, MasterOptions};
use crate::serial::transport::{Port, SerialSettings, TransportError};
use crate::tcp::masters::{ModbusTcpMaster, RawTcpMaster, TcpEndpoint, TcpKind, TcpOptions};
use crate::timing::LineTiming;
use crate::transaction::{Ask, Exchange, LinkCore};

/// What a link is opened on, with its transport's settings.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkSpec {
    /// A serial port, with the master's options.
    Serial {
        /// The port's path and character format.
        port: SerialSettings,
        /// The master's per-line behaviour.
        options: MasterOptions,
    },
    /// A TCP server: a serial device server (`tcp://`) or a Modbus TCP gateway
    /// (`modbus-tcp://`), as its endpoint's kind says.
    Tcp {
        /// Where the server is and what its stream carries.
        endpoint: TcpEndpoint,
        /// The connection's settings.
        options: TcpOptions,
    },
}

/// Why a link could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The serial port could not be opened as configured.
    #[error(transparent)]
    Serial(#[from] TransportError),
    /// The TCP server refused the connection or did not accept it in time.
    #[error("cannot connect to {url}: {source}")]
    Connect {
        /// The server's url.
        url: String,
        /// The system's error.
        source: std::io::Error,
    },
}

/// One line's open link, whichever of the three it is. It runs transactions through
/// [`Transact::transact`](crate::Transact::transact).
#[derive(Debug)]
pub enum Link {
    /// A serial port (`/dev/ttyUSB0`, a pty), with the serial-line specification's timing.
    Serial(Master),
    /// A serial device server's TCP stream carrying raw RTU frames (`tcp://`).
    RawTcp(RawTcpMaster),
    /// A Modbus TCP gateway (`modbus-tcp://`).
    ModbusTcp(ModbusTcpMaster),
}

/// Runs `$body` with `$master` bound to whichever master `$link` holds: the one place that
/// lists the transports, without a box or a virtual call per transaction.
macro_rules! on_master {
    ($link:expr, $master:ident => $body:expr) => {
        match $link {
            Link::Serial($master) => $body,
            Link::RawTcp($master) => $body,
            Link::ModbusTcp($master) => $body,
        }
    };
}

impl Link {
    /// Opens the serial port, or connects to the TCP server, that `spec` names; the
    /// transactions are timed by `timing` (on `tcp://`, the server's serial side).
    pub async fn open(spec: &LinkSpec, timing: LineTiming) -> Result<Link, OpenError> {
        match spec {
            LinkSpec::Serial { port, options } => Ok(Link::Serial(Master::new(
                Port::open(port)?,
                timing,
                options.clone(),
            ))),
            LinkSpec::Tcp { endpoint, options } => {
                let connected = match endpoint.kind {
                    TcpKind::RawRtu => RawTcpMaster::connect(endpoint.clone(), *options, timing)
                        .await
                        .map(Link::RawTcp),
                    TcpKind::ModbusTcp => {
                        ModbusTcpMaster::connect(endpoint.clone(), *options, timing)
                            .await
                            .map(Link::ModbusTcp)
                    }
                };
                connected.map_err(|source| OpenError::Connect {
                    url: endpoint.url(),
                    source,
                })
            }
        }
    }

    /// Sends `request` to every device (address 0) and keeps the line quiet for the
    /// broadcast turnaround.
    pub async fn broadcast(&mut self, request: &Request) -> Result<(), Error> {
        self.broadcast_then(request, || {}).await
    }

    /// [`Link::broadcast`], calling `sent` as soon as the request is on its way and before
    /// the turnaround: no device answers a broadcast, so there is nothing more to wait for
    /// before whoever asked is told. It is sent once, never repeated: a broadcast has no
    /// answer whose absence could call for another attempt.
    pub async fn broadcast_then(
        &mut self,
        request: &Request,
        sent: impl FnOnce() + Send,
    ) -> Result<(), Error> {
        on_master!(self, master => master.broadcast_then(request, sent).await)
    }

    /// Waits until the link could take the next request (the silence after the last frame),
    /// at most `patience`. Cancel-safe. A Modbus TCP gateway keeps its own line's timing, so
    /// it is ready at once.
    pub async fn wait_until_quiet(&mut self, patience: Duration) -> Result<(), Error> {
        on_master!(self, master => master.wait_until_quiet(patience).await)
    }

    /// The link's counters since it was opened.
    pub fn counters(&self) -> WireCounters {
        self.core().counters()
    }

    /// Writes one text line per frame sent or heard, `<unix time with µs> <tx|rx> <hex>`, to
    /// `writer` (the frame log, for bug reports: [`crate::frame_log::FrameLog::writer`]). The
    /// write happens on the line's own task, so `writer` must not block. A write error stops
    /// the recording with a warning.
    pub fn record_frames_to(&mut self, writer: Box<dyn crate::FrameSink>) {
        self.core_mut().record_frames_to(writer);
    }
}

impl Exchange for Link {
    fn core(&self) -> &LinkCore {
        on_master!(self, master => master.core())
    }

    fn core_mut(&mut self) -> &mut LinkCore {
        on_master!(self, master => master.core_mut())
    }

    fn late_answer_guard(&self, timeout: Duration) -> Option<Duration> {
        on_master!(self, master => master.late_answer_guard(timeout))
    }

    async fn exchange(&mut self, ask: Ask<'_>) -> Result<Reply, Error> {
        on_master!(self, master => master.exchange(ask).await)
    }
}
