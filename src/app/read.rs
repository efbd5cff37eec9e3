//! `rtu2mqtt read`: one raw read on a serial port or over TCP (`--url`), shown as hex and decoded every way a profile
//! could (u16, i16, u32/i32/f32 in both word orders, packed BCD, characters, bits), to help
//! write a profile. Also the port opening both commissioning commands share ([`Target`]): it
//! refuses a port another rtu2mqtt process holds (a running gateway) and names the holder, or
//! connects to a serial device server or a Modbus TCP gateway.
//!
//! Read functions only: this module never builds a write request.

use std::fmt::Write as _;
use std::path::Path;
use std::process::ExitCode;

use anyhow::{bail, Context as _};

use crate::cli::{parse_parity, ReadArgs};
use rtu2mqtt_modbus::codec::{encode_answer, encode_request, hex};
use rtu2mqtt_modbus::link::{Link, LinkSpec, OpenError};
use rtu2mqtt_modbus::serial::master::MasterOptions;
use rtu2mqtt_modbus::serial::transport::{SerialSettings, TransportError};
use rtu2mqtt_modbus::tcp::masters::{TcpEndpoint, TcpKind, TcpOptions};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_modbus::{Request, Response, SlaveId, Transact};
use rtu2mqtt_profile::bcd;

/// The read request for `function` 1–4 (anything else is refused: this tool never writes).
pub fn read_request(function: u8, start: u16, quantity: u16) -> anyhow::Result<Request> {
    Ok(match function {
        1 => Request::ReadCoils { start, quantity },
        2 => Request::ReadDiscreteInputs { start, quantity },
        3 => Request::ReadHoldingRegisters { start, quantity },
        4 => Request::ReadInputRegisters { start, quantity },
        other => bail!("function {other}: only the read functions 1, 2, 3 and 4 are allowed"),
    })
}

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
            Target::Url(url) => TcpEndpoint::parse(url)?.kind == TcpKind::ModbusTcp,
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

pub fn read(args: &ReadArgs) -> anyhow::Result<ExitCode> {
    let parity = parse_parity(&args.parity)?;
    let request = read_request(args.function, args.start, args.count)?;
    let frame = encode_request(args.address, &request).context("the read cannot be sent")?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the runtime")?;
    let result = runtime.block_on(async {
        // The serial stream registers with the runtime's reactor: opened inside it.
        let target = Target::of(args.link.port.as_deref(), args.link.url.as_deref())?;
        let mut master = target.open(args.baud, parity).await?;
        anyhow::Ok(master.transact(args.address, &request, args.timeout).await)
    })?;
    println!("request  {}", hex(&frame));
    match result {
        Ok(Ok(response)) => {
            print!("{}", render(args.address, &request, &response));
            Ok(ExitCode::SUCCESS)
        }
        Ok(Err(code)) => {
            println!("answer   device answered {code}");
            Ok(ExitCode::from(2))
        }
        Err(error) => bail!("no valid answer: {error}"),
    }
}

/// The answer as hex, then every decoding a profile could use.
pub fn render(slave: SlaveId, request: &Request, response: &Response) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "answer   {}", hex(&encode_answer(slave, response)));
    let start = request.read_span().map_or(0, |(start, _)| start);
    if let Some(words) = response.registers() {
        out.push_str(&render_registers(start, words));
    } else if let Some(bits) = response.bits() {
        out.push_str(&render_bits(start, bits));
    }
    out
}

/// A bus address as the manuals' two readers look for it: hex and decimal (`0x0c83  3203`).
fn place(address: u16) -> String {
    format!("{address:#06x} {address:>5}")
}

/// One line per register, then one per register pair, then the block as characters.
pub fn render_registers(start: u16, words: &[u16]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "\nregister          hex      u16     i16  bits                 bcd  chars"
    );
    for (i, &word) in words.iter().enumerate() {
        let bcd =
            bcd::decode(word, bcd::WORD_DIGITS).map_or_else(|_| "-".to_string(), |v| v.to_string());
        let _ = writeln!(
            out,
            "{}    {word:#06x}  {word:>7}  {:>6}  {:04b} {:04b} {:04b} {:04b}  {bcd:>4}  \"{}\"",
            place(start.wrapping_add(i as u16)),
            word as i16,
            word >> 12,
            (word >> 8) & 0xF,
            (word >> 4) & 0xF,
            word & 0xF,
            printable(&word.to_be_bytes()),
        );
    }
    if words.len() >= 2 {
        let _ = writeln!(
            out,
            "\npair           u32 (high word first)  i32             f32  | u32 (low word first)  i32             f32"
        );
        for (i, pair) in words.windows(2).enumerate() {
            let high_first = (u32::from(pair[0]) << 16) | u32::from(pair[1]);
            let low_first = (u32::from(pair[1]) << 16) | u32::from(pair[0]);
            let _ = writeln!(
                out,
                "{}    {high_first:>21}  {:>11}  {:>14}  | {low_first:>20}  {:>11}  {:>14}",
                place(start.wrapping_add(i as u16)),
                high_first as i32,
                float(high_first),
                low_first as i32,
                float(low_first),
            );
        }
    }
    if words.len() >= 4 {
        let _ = writeln!(
            out,
            "\nfour           u64 (high word first)            i64                   f64  | u64 (low word first)             i64                   f64"
        );
        for (i, four) in words.windows(4).enumerate() {
            let high_first = four.iter().fold(0u64, |acc, &w| (acc << 16) | u64::from(w));
            let low_first = four
                .iter()
                .rev()
                .fold(0u64, |acc, &w| (acc << 16) | u64::from(w));
            let _ = writeln!(
                out,
                "{}    {high_first:>20}  {:>20}  {:>20}  | {low_first:>20}  {:>20}  {:>20}",
                place(start.wrapping_add(i as u16)),
                high_first as i64,
                crate::web::decode::float(f64::from_bits(high_first)),
                low_first as i64,
                crate::web::decode::float(f64::from_bits(low_first)),
            );
        }
    }
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_be_bytes()).collect();
    let swapped: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let _ = writeln!(out, "\ntext (high byte first) \"{}\"", printable(&bytes));
    let _ = writeln!(out, "text (low byte first)  \"{}\"", printable(&swapped));
    out
}

/// The bits in groups of eight, first bit first, with their addresses.
pub fn render_bits(start: u16, bits: &[bool]) -> String {
    let mut out = String::from("\nbit            values (first bit first)\n");
    for (i, group) in bits.chunks(8).enumerate() {
        let text: String = group.iter().map(|&on| if on { '1' } else { '0' }).collect();
        let _ = writeln!(out, "{}    {text}", place(start.wrapping_add(8 * i as u16)));
    }
    let on: Vec<String> = bits
        .iter()
        .enumerate()
        .filter(|(_, on)| **on)
        .map(|(i, _)| {
            let address = start.wrapping_add(i as u16);
            format!("{address:#06x} ({address})")
        })
        .collect();
    let _ = writeln!(
        out,
        "on: {}",
        if on.is_empty() {
            "none".into()
        } else {
            on.join(", ")
        }
    );
    out
}

/// An f32 from its bits: plain for ordinary magnitudes, with an exponent for tiny or huge
/// ones (register pairs that are no float show up as such), non-finite values by name.
fn float(bits: u32) -> String {
    let value = f32::from_bits(bits);
    let magnitude = value.abs();
    if !value.is_finite() {
        format!("{value:?}")
    } else if magnitude != 0.0 && !(1e-4..1e9).contains(&magnitude) {
        format!("{value:e}")
    } else {
        format!("{value}")
    }
}

/// Printable ASCII as itself, anything else as `.`.
fn printable(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|&b| {
            if (0x20..0x7F).contains(&b) && b != b'"' {
                b as char
            } else {
                '.'
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_are_refused() {
        assert!(read_request(6, 0, 1).is_err());
        assert!(read_request(16, 0, 1).is_err());
        assert!(read_request(3, 0x1000, 6).is_ok());
    }

    #[test]
    fn registers_decoded_every_way() {
        let text = render_registers(0x1000, &[0x4148, 0x0000, 0x1234, 0xFFFE]);
        // u16 and i16
        assert!(text.contains("0xfffe    65534      -2"), "{text}");
        // f32 high word first: 0x41480000 = 12.5
        assert!(
            text.contains("1095237632   1095237632            12.5"),
            "{text}"
        );
        // BCD
        assert!(text.contains(" 1234  \".4\""), "{text}");
        assert!(
            text.contains("text (high byte first) \"AH...4..\""),
            "{text}"
        );
    }

    #[test]
    fn four_registers_read_as_64_bits_in_both_word_orders() {
        // An energy counter of 65,538 Wh, high word first; and 2.5 as f64 (0x4004_0000_0000_0000).
        let counter = render_registers(0, &[0x0000, 0x0000, 0x0001, 0x0002]);
        assert!(
            counter.contains("0x0000     0                   65538"),
            "{counter}"
        );
        let swapped = render_registers(0, &[0x0002, 0x0001, 0x0000, 0x0000]);
        assert!(swapped.contains("|                65538"), "{swapped}");
        let float = render_registers(0, &[0x4004, 0x0000, 0x0000, 0x0000]);
        assert!(float.contains("                   2.5  |"), "{float}");
        let negative = render_registers(0, &[0xFFFF, 0xFFFF, 0xFFFF, 0xFFFE]);
        assert!(
            negative.contains("18446744073709551614                    -2"),
            "{negative}"
        );
    }

    #[test]
    fn bits_listed() {
        let text = render_bits(
            0,
            &[true, false, false, true, false, false, false, false, true],
        );
        assert!(text.contains("0x0000     0    10010000"));
        assert!(text.contains("0x0008     8    1"));
        assert!(
            text.contains("on: 0x0000 (0), 0x0003 (3), 0x0008 (8)"),
            "{text}"
        );
    }
}
