//! Where a commissioning command talks ([`Target`]: `--port` or `--url`) and how it opens it:
//! through the wire crate's [`Link::open`], after refusing a port another rtu2mqtt process
//! holds (a running gateway) and naming the holder; a busy port or an unreachable server is
//! said in the command line's words.

use std::path::Path;

use anyhow::bail;

use rtu2mqtt_modbus::link::{Link, LinkSpec, OpenError, TcpEndpoint};
use rtu2mqtt_modbus::serial::master::MasterOptions;
use rtu2mqtt_modbus::serial::transport::{SerialSettings, TransportError};
use rtu2mqtt_modbus::tcp::masters::TcpOptions;
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};

/// A gateway (or another rtu2mqtt command on this very port) holding `path` open, as
/// `pid N (command line)`. Exclusive access (TIOCEXCL) does not stop root, so the holder is
/// looked for in /proc as well: an rtu2mqtt process with the port open that is a gateway
/// (`rtu2mqtt run`, the demo `rtu2mqtt-demo`) or names the port on its command line
/// (`rtu2mqtt-demo simulate`). (Other rtu2mqtt processes may hold it only by inheritance.)
fn rtu2mqtt_holder(path: &Path) -> Option<String> {
    let target = std::fs::canonicalize(path).ok()?;
    let own = std::process::id().to_string();
    for entry in std::fs::read_dir("/proc").ok()?.flatten() {
        let pid = entry.file_name().to_string_lossy().into_owned();
        if pid == own || !pid.bytes().all(|b| b.is_ascii_digit()) {
            continue;
        }
        let comm = std::fs::read_to_string(entry.path().join("comm")).unwrap_or_default();
        let demo = match comm.trim() {
            "rtu2mqtt" => false,
            "rtu2mqtt-demo" => true,
            _ => continue,
        };
        let cmdline = std::fs::read(entry.path().join("cmdline")).unwrap_or_default();
        let args: Vec<String> = cmdline
            .split(|&b| b == 0)
            .map(|arg| String::from_utf8_lossy(arg).into_owned())
            .collect();
        let concerned = (demo && !args.iter().any(|arg| arg == "simulate"))
            || args.iter().skip(1).any(|arg| {
                arg == "run" || std::fs::canonicalize(arg).is_ok_and(|named| named == target)
            });
        if !concerned {
            continue;
        }
        let Ok(fds) = std::fs::read_dir(entry.path().join("fd")) else {
            continue;
        };
        if fds
            .flatten()
            .any(|fd| std::fs::read_link(fd.path()).is_ok_and(|link| link == target))
        {
            return Some(format!("pid {pid} ({})", args.join(" ").trim()));
        }
    }
    None
}

/// Refuses `path` when a running gateway holds it, naming the holder.
fn refuse_held_port(path: &Path) -> anyhow::Result<()> {
    if let Some(holder) = rtu2mqtt_holder(path) {
        bail!(
            "{} is in use by rtu2mqtt {holder}; stop the gateway first (systemctl stop rtu2mqtt)",
            path.display()
        );
    }
    Ok(())
}

/// The port at `path` with `baud`/`parity` and default options, as the commissioning commands
/// open it.
fn serial_spec(path: &Path, baud: u32, parity: Parity) -> LinkSpec {
    LinkSpec::Serial {
        port: SerialSettings {
            path: path.to_string_lossy().into_owned(),
            baud,
            format: char_format(parity),
            rs485: None,
        },
        options: MasterOptions::default(),
    }
}

/// Why the commissioning link could not be opened, in the words of the command line.
fn open_failed(error: OpenError, target: &Target<'_>) -> anyhow::Error {
    match error {
        OpenError::Serial(TransportError::Open { path, source }) if is_busy(&source) => {
            anyhow::anyhow!(
                "{path} is busy: another program holds it with exclusive access (a running \
                 rtu2mqtt gateway, ModemManager or a terminal program); stop it first"
            )
        }
        OpenError::Serial(error) => anyhow::Error::new(error).context("opening the port"),
        OpenError::Connect { source, .. } => {
            let place = match target {
                Target::Port(path) => path.display().to_string(),
                Target::Url(url) => url.to_string(),
            };
            anyhow::Error::new(source).context(format!("connecting to {place}"))
        }
    }
}

/// EBUSY, whichever way the serial library reports it.
fn is_busy(error: &std::io::Error) -> bool {
    error.raw_os_error() == Some(libc::EBUSY)
        || error.to_string().to_ascii_lowercase().contains("busy")
}

pub fn char_format(parity: Parity) -> CharFormat {
    CharFormat {
        data_bits: 8,
        parity,
        stop_bits: 1,
    }
}

/// Where a commissioning command talks: `--port` or `--url`.
#[derive(Debug, Clone, Copy)]
pub enum Target<'a> {
    Port(&'a Path),
    Url(&'a str),
}

impl<'a> Target<'a> {
    /// The one of `port` and `url` given (the command line requires exactly one).
    pub fn of(port: Option<&'a Path>, url: Option<&'a str>) -> anyhow::Result<Self> {
        match (port, url) {
            (Some(port), None) => Ok(Target::Port(port)),
            (None, Some(url)) => Ok(Target::Url(url)),
            _ => bail!("give either --port or --url"),
        }
    }

    /// A Modbus TCP gateway: baud and parity are its own, not ours to try.
    pub fn is_modbus_tcp(&self) -> anyhow::Result<bool> {
        Ok(match self {
            Target::Port(_) => false,
            Target::Url(url) => TcpEndpoint::parse(url)?.kind.times_its_serial_side(),
        })
    }

    /// Opens the port (refusing one a running gateway holds) or connects to the server, at
    /// `baud`/`parity` (the server's serial side on `tcp://`; unused on `modbus-tcp://`).
    pub async fn open(&self, baud: u32, parity: Parity) -> anyhow::Result<Link> {
        let spec = match self {
            Target::Port(path) => {
                refuse_held_port(path)?;
                serial_spec(path, baud, parity)
            }
            Target::Url(url) => LinkSpec::Tcp {
                endpoint: TcpEndpoint::parse(url)?,
                options: TcpOptions::default(),
            },
        };
        let timing = LineTiming::new(baud, char_format(parity));
        Link::open(&spec, timing)
            .await
            .map_err(|error| open_failed(error, self))
    }
}
