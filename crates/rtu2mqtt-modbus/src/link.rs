//! What a line talks through: a serial port ([`Master`]), a serial device server's raw TCP
//! stream ([`RawTcpMaster`]) or a Modbus TCP gateway ([`ModbusTcpMaster`]). A line's `url`
//! names its server and kind ([`TcpEndpoint::parse`]); [`Link::open`] opens any of them from a
//! [`LinkSpec`]; the line task then runs the same transactions, counters and frame log on each.
//! This file is the one list of the transports: their url schemes and names ([`TcpKind`]),
//! how each is opened, and the `on_master!` dispatch that names each once.

use std::time::Duration;

use super::frame::Request;
use super::outcome::{Error, Reply, WireCounters};
use crate::serial::master::{Master, MasterOptions};
use crate::serial::transport::{Port, SerialSettings, TransportError};
use crate::tcp::masters::{ModbusTcpMaster, RawTcpMaster, TcpOptions, TcpServer};
use crate::timing::LineTiming;
use crate::transaction::{Ask, Exchange, LinkCore};

/// What a TCP line's stream carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TcpKind {
    /// RTU frames with their CRC, as a serial device server in transparent mode passes them.
    RawRtu,
    /// Modbus TCP (MBAP header, unit id = the device's address).
    ModbusTcp,
}

impl TcpKind {
    /// The url scheme that names this kind: `tcp` or `modbus-tcp`.
    pub fn scheme(self) -> &'static str {
        match self {
            TcpKind::RawRtu => "tcp",
            TcpKind::ModbusTcp => "modbus-tcp",
        }
    }

    /// What sits at the other end, as `check` and the logs name it.
    pub fn server_name(self) -> &'static str {
        match self {
            TcpKind::RawRtu => "serial device server",
            TcpKind::ModbusTcp => "Modbus TCP gateway",
        }
    }

    /// How the stream carries a device's frames, as `check` says it.
    pub fn framing(self) -> &'static str {
        match self {
            TcpKind::RawRtu => "raw RTU",
            TcpKind::ModbusTcp => "unit id = address",
        }
    }

    /// The server runs the serial line's timing itself (a Modbus TCP gateway); otherwise the
    /// link times the frames it passes through with the line's baud and format.
    pub fn times_its_serial_side(self) -> bool {
        match self {
            TcpKind::RawRtu => false,
            TcpKind::ModbusTcp => true,
        }
    }
}

/// Why a line's `url` is not usable.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UrlError {
    /// No `://` in the url, which it carries.
    #[error("{0:?} has no scheme: use tcp://host:port or modbus-tcp://host:port")]
    NoScheme(String),
    /// A scheme other than `tcp` or `modbus-tcp`.
    #[error("unknown scheme {scheme:?} in {url:?}: use tcp:// or modbus-tcp://")]
    UnknownScheme {
        /// The url as given.
        url: String,
        /// Its scheme.
        scheme: String,
    },
    /// Nothing between `://` and the port (or an IPv6 host without its closing `]`).
    #[error("{0:?} has no host")]
    NoHost(String),
    /// No port number after the host.
    #[error("{0:?} has no port number (such as tcp://10.0.0.5:4001)")]
    NoPort(String),
    /// The port is not a number from 1 to 65535.
    #[error("{url:?}: port {port:?} is not 1–65535")]
    BadPort {
        /// The url as given.
        url: String,
        /// The text where the port number should be.
        port: String,
    },
    /// A path, user, query or fragment after the host and port.
    #[error("{0:?}: give only host and port")]
    ExtraParts(String),
}

/// A parsed `tcp://host:port` or `modbus-tcp://host:port`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TcpEndpoint {
    /// What the stream carries, from the scheme.
    pub kind: TcpKind,
    /// `host:port` as `TcpStream::connect` takes it (IPv6 hosts in brackets).
    pub address: String,
}

impl TcpEndpoint {
    /// Parses a line's `url`. The port number is required: device servers have no common
    /// default, and a Modbus TCP gateway's 502 is better written out.
    pub fn parse(url: &str) -> Result<TcpEndpoint, UrlError> {
        let Some((scheme, rest)) = url.split_once("://") else {
            return Err(UrlError::NoScheme(url.to_string()));
        };
        let kind = match scheme {
            "tcp" => TcpKind::RawRtu,
            "modbus-tcp" => TcpKind::ModbusTcp,
            other => {
                return Err(UrlError::UnknownScheme {
                    url: url.to_string(),
                    scheme: other.to_string(),
                })
            }
        };
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        if rest.contains(['/', '@', '?', '#']) {
            return Err(UrlError::ExtraParts(url.to_string()));
        }
        let (host, port) = match rest.strip_prefix('[') {
            Some(bracketed) => match bracketed.split_once(']') {
                Some((host, after)) => (host, after.strip_prefix(':')),
                None => return Err(UrlError::NoHost(url.to_string())),
            },
            None => match rest.rsplit_once(':') {
                Some((host, port)) => (host, Some(port)),
                None => (rest, None),
            },
        };
        if host.is_empty() {
            return Err(UrlError::NoHost(url.to_string()));
        }
        let port = match port {
            None | Some("") => return Err(UrlError::NoPort(url.to_string())),
            Some(text) => match text.parse::<u16>() {
                Ok(port) if port > 0 => port,
                _ => {
                    return Err(UrlError::BadPort {
                        url: url.to_string(),
                        port: text.to_string(),
                    })
                }
            },
        };
        let address = if host.contains(':') {
            format!("[{host}]:{port}")
        } else {
            format!("{host}:{port}")
        };
        Ok(TcpEndpoint { kind, address })
    }

    /// The url again, in its normal form.
    pub fn url(&self) -> String {
        format!("{}://{}", self.kind.scheme(), self.address)
    }

    /// How `check` and the logs name the server: `serial device server tcp://… (raw RTU)`,
    /// `Modbus TCP gateway modbus-tcp://…`.
    pub fn describe(&self) -> String {
        let server = format!("{} {}", self.kind.server_name(), self.url());
        if self.kind.times_its_serial_side() {
            server
        } else {
            format!("{server} ({})", self.kind.framing())
        }
    }

    /// The server its master connects to.
    fn server(&self) -> TcpServer {
        TcpServer {
            address: self.address.clone(),
            url: self.url(),
        }
    }
}

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
                    TcpKind::RawRtu => RawTcpMaster::connect(endpoint.server(), *options, timing)
                        .await
                        .map(Link::RawTcp),
                    TcpKind::ModbusTcp => {
                        ModbusTcpMaster::connect(endpoint.server(), *options, timing)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_parse_with_their_kind_and_port() {
        assert_eq!(
            TcpEndpoint::parse("tcp://10.0.0.5:4001"),
            Ok(TcpEndpoint {
                kind: TcpKind::RawRtu,
                address: "10.0.0.5:4001".into()
            })
        );
        assert_eq!(
            TcpEndpoint::parse("modbus-tcp://gw.local:502/").map(|e| e.url()),
            Ok("modbus-tcp://gw.local:502".into())
        );
        assert_eq!(
            TcpEndpoint::parse("tcp://[fe80::1]:4001").map(|e| e.address),
            Ok("[fe80::1]:4001".into())
        );
        assert!(matches!(
            TcpEndpoint::parse("udp://10.0.0.5:4001"),
            Err(UrlError::UnknownScheme { .. })
        ));
        assert!(matches!(
            TcpEndpoint::parse("tcp://10.0.0.5"),
            Err(UrlError::NoPort(_))
        ));
        assert!(matches!(
            TcpEndpoint::parse("tcp://10.0.0.5:"),
            Err(UrlError::NoPort(_))
        ));
        assert!(matches!(
            TcpEndpoint::parse("tcp://10.0.0.5:70000"),
            Err(UrlError::BadPort { .. })
        ));
        assert!(matches!(
            TcpEndpoint::parse("10.0.0.5:4001"),
            Err(UrlError::NoScheme(_))
        ));
        assert!(matches!(
            TcpEndpoint::parse("tcp://:4001"),
            Err(UrlError::NoHost(_))
        ));
        assert!(matches!(
            TcpEndpoint::parse("tcp://user@host:4001"),
            Err(UrlError::ExtraParts(_))
        ));
    }
}
