//! The serial port: the only code in the crate that opens or touches one (mio-serial, on the
//! tokio reactor).
//! Opens a line with its character format (a pseudo-terminal that refuses parity runs without
//! it, said once at INFO; a real UART that refuses a setting is an error), writes a frame and
//! waits until the transmit buffer has drained (tcdrain), reads bytes with deadlines, discards
//! stray input, and optionally switches the kernel's RS485 mode on.
//!
//! Why mio-serial under an `AsyncFd` and not tokio-serial: tokio-serial registers the port for
//! read and write readiness, but a frame is written whole (a few bytes into a kernel buffer of
//! kilobytes) and its end awaited with tcdrain, so no task ever waits to write, and each
//! "writable" signal (on a pty: each time the other end reads) would only wake the runtime's
//! thread for nothing. The port is registered for read interest alone. Measured against
//! tokio-serial running the same transactions, that saves the runtime one wake-up per
//! transaction and the kernel's share of the CPU it costs, with the same timing; a small
//! saving, seen only on a quiet machine. The figures and their command are in
//! docs/performance.md ("Read interest alone").
//!
//! The registration is dropped while the master waits for the rest of an answer whose length
//! it knows (`Port::stop_listening`): a UART or a pty signals each byte it receives, and
//! each signal would wake the runtime's thread for a byte nobody reads yet. The next read
//! registers the port again (docs/performance.md, "Beside the C++ peer, in one run").

use std::io::{self, Read, Write};
use std::os::fd::{AsRawFd, BorrowedFd, RawFd};
use std::time::Duration;

use mio_serial::{DataBits, SerialPort, SerialStream, StopBits};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;
use tokio::time::Instant;

use crate::timing::{CharFormat, Parity};

/// Kernel RS485 mode (TIOCSRS485) for boards whose UART drives the transceiver.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rs485Settings {
    /// RTS is driven high while sending (`true`, most transceivers) or low (`false`).
    pub rts_on_send: bool,
    /// How long RTS is switched before the first bit goes out. The kernel takes whole
    /// milliseconds; finer parts are dropped.
    pub delay_before_send: Duration,
    /// How long RTS is held after the last bit before the transceiver is released, in whole
    /// milliseconds as before.
    pub delay_after_send: Duration,
}

/// Everything needed to open one line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialSettings {
    /// The device to open (`/dev/ttyUSB0`, `/dev/serial/by-id/…`, a pty's `/dev/pts/N`); it
    /// also names the port in logs and errors.
    pub path: String,
    /// Bits per second.
    pub baud: u32,
    /// Data bits, parity and stop bits.
    pub format: CharFormat,
    /// The kernel's RS485 mode, for a UART that drives the transceiver itself; `None` leaves
    /// the port as it is (a USB adapter switches its transceiver on its own).
    pub rs485: Option<Rs485Settings>,
}

/// Why a serial port could not be opened as configured.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The port could not be opened: missing (an adapter not plugged in yet), busy (another
    /// program holds it), or not permitted. Worth trying again later.
    #[error("cannot open {path}: {source}")]
    Open {
        /// The path that was opened.
        path: String,
        /// The system's error.
        source: std::io::Error,
    },
    /// The path exists but is no serial port (a regular file, a directory, `/dev/null`): no
    /// amount of waiting fixes that, unlike a missing path or a port that is busy.
    #[error("{path} is not a serial port (not a terminal device): {source}")]
    NotATerminal {
        /// The path that was opened.
        path: String,
        /// The system's error.
        source: std::io::Error,
    },
    /// A real port (not a pseudo-terminal) refused a line setting, or accepted it and reads
    /// back another value: the adapter cannot run the line as configured.
    #[error("{path}: {setting} refused by the port: {source}")]
    SettingRefused {
        /// The port's path.
        path: String,
        /// The setting: `baud rate`, `data bits`, `parity`, `stop bits` or `rs485 mode`.
        setting: &'static str,
        /// The system's error.
        source: std::io::Error,
    },
    /// The opened port could not be registered with the runtime's reactor.
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
}

/// How long a write waits for room in the kernel's transmit buffer before the port counts as
/// gone. A frame fits that buffer many times over, so only a port that sends nothing (a pty
/// whose other end stopped reading) ever waits.
const WRITE_PATIENCE: Duration = Duration::from_secs(1);

/// How often a write that found the transmit buffer full tries again.
const WRITE_RETRY: Duration = Duration::from_millis(1);

/// An open serial port, registered with the tokio reactor of the runtime that opened it: it
/// writes a frame and tells when its last bit left, and reads with deadlines. A
/// [`Master`](crate::serial::master::Master) runs transactions on it.
pub struct Port {
    /// The port's registration with the reactor, for reading only, while the port listens
    /// (see [`Port::stop_listening`]). The transmit side signals "writable" each time the
    /// driver moves bytes out (on a pty: each time the other end reads), and with write
    /// interest such a signal wakes the runtime for nothing (see the module's documentation);
    /// writes never need the reactor (see [`Port::write_all`]). Declared before `stream`, so
    /// that it is deregistered before the descriptor is closed.
    listening: Option<AsyncFd<Descriptor>>,
    /// Not listening, and the last read took everything the port had: the next read
    /// registers the port and waits without asking it first, since registering reports any
    /// byte that came since. A wait without listening ([`Port::stop_listening`]) clears it.
    drained: bool,
    stream: SerialStream,
    path: String,
    pseudo_terminal: bool,
}

/// The port's descriptor as the reactor knows it; the [`SerialStream`] beside it owns it.
struct Descriptor(RawFd);

impl AsRawFd for Descriptor {
    fn as_raw_fd(&self) -> RawFd {
        self.0
    }
}

/// The registration in `listening`, made for `fd` if there is none.
fn listening(
    listening: &mut Option<AsyncFd<Descriptor>>,
    fd: RawFd,
) -> io::Result<&AsyncFd<Descriptor>> {
    match listening {
        Some(registration) => Ok(registration),
        None => {
            // SAFETY: `fd` is the descriptor of the port's stream, open until the stream is
            // dropped, which happens after this registration is (field order in `Port`).
            let registration =
                unsafe { AsyncFd::register_with_interest(Descriptor(fd), Interest::READABLE) }?;
            Ok(listening.insert(registration))
        }
    }
}

/// Whether a read's error only says that nothing is waiting (or that a signal came first).
fn nothing_waiting(error: &io::Error) -> bool {
    matches!(
        error.kind(),
        io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
    )
}

impl std::fmt::Debug for Port {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Port")
            .field("path", &self.path)
            .field("pseudo_terminal", &self.pseudo_terminal)
            .finish()
    }
}

/// The error a read gets when the port has gone away (EOF: the other end of a pty closed, a
/// USB adapter was unplugged). Never retried in a loop by this module.
fn port_gone(path: &str) -> io::Error {
    io::Error::new(
        io::ErrorKind::UnexpectedEof,
        format!("{path}: serial port closed"),
    )
}

fn io_error(error: mio_serial::Error) -> io::Error {
    io::Error::from(error)
}

/// Whether `path`, which could not be opened as a serial port, exists and is something else.
/// The serial crate's error has lost the errno (ENOTTY), so the path is looked at again. A missing
/// path, or one that cannot be opened at all (busy, permissions not yet set by udev), is not
/// known to be a non-terminal: it is worth waiting for.
fn is_not_a_terminal(path: &str) -> bool {
    use std::io::IsTerminal;
    use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};

    let Ok(metadata) = std::fs::metadata(path) else {
        return false;
    };
    if !metadata.file_type().is_char_device() {
        return true;
    }
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
        .open(path)
        .is_ok_and(|device| !device.is_terminal())
}

impl Port {
    /// Opens the port with `settings`: exclusive access (TIOCEXCL), baud, character format and
    /// the optional kernel RS485 mode.
    pub fn open(settings: &SerialSettings) -> Result<Port, TransportError> {
        // Opened as 8N1 first (every port takes that), then each setting is applied and checked
        // on its own so that a refusal names the setting.
        let builder = mio_serial::new(&settings.path, settings.baud)
            .data_bits(DataBits::Eight)
            .parity(mio_serial::Parity::None)
            .stop_bits(StopBits::One)
            .flow_control(mio_serial::FlowControl::None);
        let stream = SerialStream::open(&builder).map_err(|source| {
            let path = settings.path.clone();
            let source = io_error(source);
            if is_not_a_terminal(&path) {
                TransportError::NotATerminal { path, source }
            } else {
                TransportError::Open { path, source }
            }
        })?;
        Port::from_stream(stream, settings)
    }

    /// Wraps an already open stream (one end of `mio_serial::SerialStream::pair()` in tests)
    /// and applies `settings` to it; `settings.path` only names it in logs and errors.
    pub fn from_stream(
        mut stream: SerialStream,
        settings: &SerialSettings,
    ) -> Result<Port, TransportError> {
        let path = settings.path.clone();
        let pseudo_terminal = is_pseudo_terminal(&stream, &path);
        if let Err(error) = stream.set_exclusive(true) {
            // Exclusive access is a safeguard, not a requirement for talking on the line.
            tracing::warn!(path = %path, %error, "cannot get exclusive access (TIOCEXCL)");
        }
        let mut port = Port {
            listening: None,
            drained: false,
            stream,
            path,
            pseudo_terminal,
        };
        // Registered at once (with the runtime's I/O driver), so that a failure to register
        // is an error of the opening, not of the first read.
        listening(&mut port.listening, port.stream.as_raw_fd())?;
        if !pseudo_terminal {
            port.request_low_latency();
        }
        port.apply_format(settings.baud, settings.format)?;
        if let Some(rs485) = &settings.rs485 {
            port.enable_rs485(rs485)?;
        }
        Ok(port)
    }

    /// The path (or label) the port was opened with.
    pub(crate) fn path(&self) -> &str {
        &self.path
    }

    fn apply_format(&mut self, baud: u32, format: CharFormat) -> Result<(), TransportError> {
        let data_bits = match format.data_bits {
            5 => DataBits::Five,
            6 => DataBits::Six,
            7 => DataBits::Seven,
            _ => DataBits::Eight,
        };
        let parity = match format.parity {
            Parity::None => mio_serial::Parity::None,
            Parity::Even => mio_serial::Parity::Even,
            Parity::Odd => mio_serial::Parity::Odd,
        };
        let stop_bits = if format.stop_bits >= 2 {
            StopBits::Two
        } else {
            StopBits::One
        };
        let results = [
            (
                "baud rate",
                baud.to_string(),
                self.stream
                    .set_baud_rate(baud)
                    .and_then(|()| self.check(self.stream.baud_rate()? == baud)),
            ),
            (
                "data bits",
                format.data_bits.to_string(),
                self.stream
                    .set_data_bits(data_bits)
                    .and_then(|()| self.check(self.stream.data_bits()? == data_bits)),
            ),
            (
                "parity",
                format.parity.to_string(),
                self.stream
                    .set_parity(parity)
                    .and_then(|()| self.check(self.stream.parity()? == parity)),
            ),
            (
                "stop bits",
                format.stop_bits.to_string(),
                self.stream
                    .set_stop_bits(stop_bits)
                    .and_then(|()| self.check(self.stream.stop_bits()? == stop_bits)),
            ),
        ];
        let mut not_applied = Vec::new();
        for (setting, value, result) in results {
            if let Err(error) = result {
                let source = io_error(error);
                if !self.pseudo_terminal {
                    return Err(TransportError::SettingRefused {
                        path: self.path.clone(),
                        setting,
                        source,
                    });
                }
                tracing::debug!(path = %self.path, setting, %source, "pseudo-terminal refuses a setting");
                not_applied.push(format!("{setting} {value}"));
            }
        }
        if !not_applied.is_empty() {
            // Expected on a simulated line: a pty carries bytes, not bits, and the line's
            // timing is computed from the configured format, not read from the port.
            let verb = if not_applied.len() == 1 { "is" } else { "are" };
            tracing::info!(
                path = %self.path,
                "{} {verb} not applied by a pseudo-terminal (simulated line); timing still \
                 follows {format} at {baud} baud",
                not_applied.join(", ")
            );
        }
        Ok(())
    }

    /// A setting that was accepted but reads back different was silently ignored.
    fn check(&self, applied: bool) -> mio_serial::Result<()> {
        if applied {
            Ok(())
        } else {
            Err(mio_serial::Error::new(
                mio_serial::ErrorKind::InvalidInput,
                "accepted but not applied",
            ))
        }
    }

    /// Switches the kernel's RS485 mode on (TIOCSRS485). A pty or a UART driver without RS485
    /// support answers ENOTTY: on a pty that is an expected fact, on a real port an error.
    fn enable_rs485(&mut self, rs485: &Rs485Settings) -> Result<(), TransportError> {
        let mut config = SerialRs485 {
            flags: SER_RS485_ENABLED
                | if rs485.rts_on_send {
                    SER_RS485_RTS_ON_SEND
                } else {
                    SER_RS485_RTS_AFTER_SEND
                },
            delay_rts_before_send: u32::try_from(rs485.delay_before_send.as_millis())
                .unwrap_or(u32::MAX),
            delay_rts_after_send: u32::try_from(rs485.delay_after_send.as_millis())
                .unwrap_or(u32::MAX),
            padding: [0; 5],
        };
        // SAFETY: TIOCSRS485 reads a `struct serial_rs485`, which `SerialRs485` lays out exactly
        // (repr(C), 32 bytes); the fd is open for the lifetime of `self.stream`.
        let status = unsafe { libc::ioctl(self.stream.as_raw_fd(), libc::TIOCSRS485, &mut config) };
        if status == 0 {
            return Ok(());
        }
        let source = io::Error::last_os_error();
        if self.pseudo_terminal {
            // Expected on a simulated line: a pty has no transceiver to drive.
            tracing::info!(path = %self.path, %source, "rs485 mode is not applied by a pseudo-terminal (simulated line)");
            Ok(())
        } else {
            Err(TransportError::SettingRefused {
                path: self.path.clone(),
                setting: "rs485 mode",
                source,
            })
        }
    }

    /// Asks the driver to hand received bytes over at once (ASYNC_LOW_LATENCY: FTDI adapters
    /// then use a 1 ms latency timer instead of 16 ms, so answers arrive without a batching
    /// delay). Best effort: many drivers do not support it, and the line works without it.
    fn request_low_latency(&mut self) {
        let fd = self.stream.as_raw_fd();
        let mut serial = std::mem::MaybeUninit::<SerialStruct>::zeroed();
        // SAFETY: TIOCGSERIAL fills a `struct serial_struct`, which `SerialStruct` lays out
        // exactly (repr(C)); TIOCSSERIAL writes the same structure back with one flag changed,
        // as setserial does. The fd is open for the lifetime of `self.stream`.
        let result = unsafe {
            if libc::ioctl(fd, libc::TIOCGSERIAL, serial.as_mut_ptr()) != 0 {
                Err(io::Error::last_os_error())
            } else {
                let mut serial = serial.assume_init();
                if serial.flags & ASYNC_LOW_LATENCY != 0 {
                    Ok(())
                } else {
                    serial.flags |= ASYNC_LOW_LATENCY;
                    if libc::ioctl(fd, libc::TIOCSSERIAL, &serial) != 0 {
                        Err(io::Error::last_os_error())
                    } else {
                        Ok(())
                    }
                }
            }
        };
        match result {
            Ok(()) => tracing::debug!(path = %self.path, "low-latency receive mode on"),
            Err(error) => {
                tracing::debug!(path = %self.path, %error, "low-latency receive mode not available")
            }
        }
    }

    /// Writes `frame` and waits until the transmit buffer has drained (tcdrain), returning the
    /// instant it drained: the last stop bit has left the UART, the line's silence starts then.
    /// On a pseudo-terminal the instant the write returned. An error means the port failed,
    /// or took no byte for a second (a pty whose other end stopped reading).
    pub async fn write_frame(&mut self, frame: &[u8]) -> io::Result<Instant> {
        // No `flush()`: mio-serial's flush is a blocking tcdrain, which would stall the runtime
        // for the frame's whole wire time. The drain is awaited below on the blocking pool.
        self.write_all(frame).await?;
        if self.pseudo_terminal {
            // A pty has no transmitter: the bytes are readable on the other side as soon as
            // the write returns, and tcdrain there would only add the blocking pool's latency.
            return Ok(Instant::now());
        }
        // tcdrain blocks the calling thread for the frame's wire time; it runs on the blocking
        // pool on a duplicate of the descriptor, which works on a current_thread runtime too.
        // SAFETY: the descriptor is open for the lifetime of `self.stream`, which outlives this
        // borrow; the duplicate is owned and closed by the blocking task.
        let duplicate =
            unsafe { BorrowedFd::borrow_raw(self.stream.as_raw_fd()) }.try_clone_to_owned()?;
        let drained = tokio::task::spawn_blocking(move || {
            nix::sys::termios::tcdrain(&duplicate).map(|()| Instant::now())
        })
        .await
        .map_err(io::Error::other)?;
        drained.map_err(io::Error::from)
    }

    /// Reads what has arrived into `buf`, waiting until `deadline` for at least one byte.
    /// `Ok(Some((count, seen)))`: `count` bytes at the start of `buf`, seen at `seen`;
    /// `Ok(None)` when the deadline passed first. An error means the port is gone (EOF: the
    /// other end of a pty closed, a USB adapter was unplugged) or failed.
    pub async fn read_until(
        &mut self,
        buf: &mut [u8],
        deadline: Instant,
    ) -> io::Result<Option<(usize, Instant)>> {
        match tokio::time::timeout_at(deadline, self.receive(buf)).await {
            Err(_elapsed) => Ok(None),
            Ok(received) => received.map(Some),
        }
    }

    /// Reads what has arrived into `buf`, waiting as long as it takes for at least one byte:
    /// `count` bytes at the start of `buf`, seen at the instant returned. For a caller that
    /// ends the wait with a timer of its own (a `select!` beside the master's precise timer),
    /// which spares the runtime's timer wheel a deadline per read. Errors as
    /// [`Port::read_until`].
    pub(crate) async fn receive(&mut self, buf: &mut [u8]) -> io::Result<(usize, Instant)> {
        match self.read(buf).await {
            Ok(0) if !buf.is_empty() => Err(port_gone(&self.path)),
            Ok(count) => Ok((count, Instant::now())),
            Err(error) => Err(error),
        }
    }

    /// Stops the runtime hearing of bytes that arrive until the port is read again: for a
    /// wait whose end is known (the rest of an answer of known length), during which each
    /// byte would otherwise wake the runtime's thread for nothing (a UART or a pty signals
    /// every byte it receives). The next read registers the port again, and hears what has
    /// arrived meanwhile at once.
    pub(crate) fn stop_listening(&mut self) {
        self.listening = None;
        self.drained = false;
    }

    /// Takes every byte already waiting in the receive buffer without waiting for more. The
    /// port itself is asked, not the reactor's readiness: this is the master's last look at
    /// the line before it sends, and the reactor hears of a byte only on its next turn, which
    /// does not come while the thread watches the clock for the end of a silence.
    pub(crate) fn take_pending(&mut self) -> io::Result<Vec<u8>> {
        let mut pending = Vec::new();
        let mut chunk = [0u8; 256];
        let mut reader = &self.stream;
        loop {
            match reader.read(&mut chunk) {
                Ok(0) => return Err(port_gone(&self.path)),
                Ok(count) => pending.extend_from_slice(&chunk[..count]),
                Err(error) if error.kind() == io::ErrorKind::Interrupted => continue,
                Err(error) if error.kind() == io::ErrorKind::WouldBlock => break,
                Err(error) => return Err(error),
            }
        }
        // Drained: from here the reactor hears of every byte that arrives.
        listening(&mut self.listening, self.stream.as_raw_fd())?;
        self.drained = false;
        Ok(pending)
    }

    /// Waits for received bytes and reads them into `buf`.
    ///
    /// While the port does not listen, the bytes that came meanwhile are read from the port
    /// itself (the reactor would report them only on its next turn, after a deadline that has
    /// passed would have ended the read). Once a read has found the port drained, it is
    /// registered when the next read has to wait: a registration made when nothing is waiting
    /// starts without news of bytes already read (which would cost the runtime a turn and a
    /// read that finds nothing), and reports any byte that came since. The port is not
    /// registered at once after such a read, because the master often stops listening right
    /// after it, for the wire time of the answer's rest.
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if self.listening.is_none() && !self.drained {
            match (&self.stream).read(buf) {
                // More may be waiting: the next read asks the port again.
                Ok(count) if count == buf.len() => return Ok(count),
                Ok(count) => {
                    self.drained = true;
                    return Ok(count);
                }
                Err(error) if nothing_waiting(&error) => {}
                Err(error) => return Err(error),
            }
        }
        self.drained = false;
        let registration = listening(&mut self.listening, self.stream.as_raw_fd())?;
        let mut reader = &self.stream;
        loop {
            let mut ready = registration.readable().await?;
            match ready.try_io(|_| reader.read(buf)) {
                Ok(Ok(count)) => {
                    // A read that did not fill `buf` took everything the port had: the next
                    // read waits for the reactor's news of a new byte (each arrival is an
                    // edge) instead of first asking the port and finding nothing. A byte that
                    // came since is not lost: its edge is reported on the reactor's next turn.
                    if count < buf.len() {
                        ready.clear_ready();
                    }
                    return Ok(count);
                }
                Ok(Err(error)) => return Err(error),
                Err(_would_block) => continue,
            }
        }
    }

    /// Writes all of `frame` into the kernel's transmit buffer. It has room for a frame
    /// practically always; when it has not, the write is tried again on a short timer instead
    /// of waiting on the reactor (see [`Port::stream`]), until [`WRITE_PATIENCE`] has passed.
    async fn write_all(&self, frame: &[u8]) -> io::Result<()> {
        let give_up = Instant::now() + WRITE_PATIENCE;
        let mut rest = frame;
        while !rest.is_empty() {
            match (&self.stream).write(rest) {
                Ok(0) => return Err(io::ErrorKind::WriteZero.into()),
                Ok(count) => rest = &rest[count..],
                Err(error) if error.kind() == io::ErrorKind::Interrupted => {}
                Err(error) if error.kind() == io::ErrorKind::WouldBlock => {
                    if Instant::now() >= give_up {
                        return Err(io::Error::new(
                            io::ErrorKind::TimedOut,
                            format!(
                                "{}: the port took no bytes for {WRITE_PATIENCE:?}",
                                self.path
                            ),
                        ));
                    }
                    tokio::time::sleep(WRITE_RETRY).await;
                }
                Err(error) => return Err(error),
            }
        }
        Ok(())
    }
}

const SER_RS485_ENABLED: u32 = 1;
const SER_RS485_RTS_ON_SEND: u32 = 1 << 1;
const SER_RS485_RTS_AFTER_SEND: u32 = 1 << 2;

/// Linux `struct serial_rs485` (include/uapi/linux/serial.h).
#[repr(C)]
struct SerialRs485 {
    flags: u32,
    /// Milliseconds.
    delay_rts_before_send: u32,
    /// Milliseconds.
    delay_rts_after_send: u32,
    padding: [u32; 5],
}

/// `ASYNC_LOW_LATENCY` in `serial_struct.flags` (include/uapi/linux/tty_flags.h).
const ASYNC_LOW_LATENCY: libc::c_int = 1 << 13;

/// Linux `struct serial_struct` (include/uapi/linux/serial.h), for TIOCGSERIAL/TIOCSSERIAL.
#[repr(C)]
struct SerialStruct {
    kind: libc::c_int,
    line: libc::c_int,
    port: libc::c_uint,
    irq: libc::c_int,
    flags: libc::c_int,
    xmit_fifo_size: libc::c_int,
    custom_divisor: libc::c_int,
    baud_base: libc::c_int,
    close_delay: libc::c_ushort,
    io_type: libc::c_char,
    reserved_char: [libc::c_char; 1],
    hub6: libc::c_int,
    closing_wait: libc::c_ushort,
    closing_wait2: libc::c_ushort,
    iomem_base: *mut libc::c_uchar,
    iomem_reg_shift: libc::c_ushort,
    port_high: libc::c_uint,
    iomap_base: libc::c_ulong,
}

/// Whether `stream` is a pseudo-terminal: the device number of a Unix98 pty slave (majors
/// 136–143), a BSD-style pty (majors 2 and 3), the pty multiplexer (5, 2), or a path that
/// resolves under /dev/pts (socat links).
fn is_pseudo_terminal(stream: &SerialStream, path: &str) -> bool {
    let by_device = nix::sys::stat::fstat(stream.as_raw_fd()).is_ok_and(|status| {
        let device = status.st_rdev;
        let (major, minor) = (libc::major(device), libc::minor(device));
        (136..=143).contains(&major) || major == 2 || major == 3 || (major == 5 && minor == 2)
    });
    let by_path =
        std::fs::canonicalize(path).is_ok_and(|resolved| resolved.starts_with("/dev/pts"));
    by_device || by_path
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(parity: Parity) -> SerialSettings {
        SerialSettings {
            path: "pty".into(),
            baud: 9600,
            format: CharFormat {
                data_bits: 8,
                parity,
                stop_bits: 1,
            },
            rs485: Some(Rs485Settings {
                rts_on_send: true,
                delay_before_send: Duration::ZERO,
                delay_after_send: Duration::ZERO,
            }),
        }
    }

    fn settings_at(path: &std::path::Path) -> SerialSettings {
        SerialSettings {
            path: path.display().to_string(),
            rs485: None,
            ..settings(Parity::None)
        }
    }

    #[tokio::test]
    async fn a_regular_file_is_not_a_terminal() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("passwd");
        std::fs::write(&path, "root:x:0:0::/root:/bin/sh\n").unwrap();
        let error = Port::open(&settings_at(&path)).unwrap_err();
        assert!(
            matches!(error, TransportError::NotATerminal { .. }),
            "{error:?}"
        );
        assert!(
            error.to_string().contains("is not a serial port"),
            "{error}"
        );
        // Nothing was written to it.
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "root:x:0:0::/root:/bin/sh\n"
        );
    }

    #[tokio::test]
    async fn a_directory_is_not_a_terminal() {
        let dir = tempfile::tempdir().unwrap();
        let error = Port::open(&settings_at(dir.path())).unwrap_err();
        assert!(
            matches!(error, TransportError::NotATerminal { .. }),
            "{error:?}"
        );
    }

    #[tokio::test]
    async fn a_pty_is_a_terminal() {
        let (_ours, theirs) = SerialStream::pair().unwrap();
        let path = theirs.name().unwrap();
        drop(theirs);
        assert!(!is_not_a_terminal(&path));
    }

    #[test]
    fn rs485_struct_has_the_kernel_size() {
        assert_eq!(std::mem::size_of::<SerialRs485>(), 32);
    }

    #[cfg(target_pointer_width = "64")]
    #[test]
    fn serial_struct_has_the_kernel_layout() {
        assert_eq!(std::mem::size_of::<SerialStruct>(), 72);
        assert_eq!(std::mem::offset_of!(SerialStruct, flags), 16);
        assert_eq!(std::mem::offset_of!(SerialStruct, iomem_base), 48);
    }

    #[tokio::test(flavor = "current_thread")]
    async fn pty_with_parity_and_rs485_opens_and_carries_bytes() {
        let (near, far) = SerialStream::pair().unwrap();
        let mut near = Port::from_stream(near, &settings(Parity::Even)).unwrap();
        let mut far = Port::from_stream(far, &settings(Parity::None)).unwrap();
        assert!(near.pseudo_terminal && far.pseudo_terminal);
        let sent = near.write_frame(&[0x01, 0x03, 0x10, 0x00]).await.unwrap();
        let mut buf = [0u8; 16];
        let mut got = Vec::new();
        while got.len() < 4 {
            let (count, seen) = far
                .read_until(&mut buf, Instant::now() + Duration::from_secs(5))
                .await
                .unwrap()
                .unwrap();
            assert!(seen >= sent);
            got.extend_from_slice(&buf[..count]);
        }
        assert_eq!(got, [0x01, 0x03, 0x10, 0x00]);
        assert_eq!(
            far.read_until(&mut buf, Instant::now() + Duration::from_millis(20))
                .await
                .unwrap(),
            None
        );
    }

    #[tokio::test(flavor = "current_thread")]
    async fn pending_input_is_counted_and_discarded() {
        let (near, far) = SerialStream::pair().unwrap();
        let mut near = Port::from_stream(near, &settings(Parity::None)).unwrap();
        let mut far = Port::from_stream(far, &settings(Parity::None)).unwrap();
        near.write_frame(&[0xAA; 7]).await.unwrap();
        // The bytes cross the pty at once, but give a busy machine time to move them.
        let mut discarded = 0;
        let give_up = Instant::now() + Duration::from_secs(5);
        while discarded < 7 && Instant::now() < give_up {
            discarded += far.take_pending().unwrap().len();
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        assert_eq!(discarded, 7);
        assert_eq!(far.take_pending().unwrap().len(), 0);
    }

    #[tokio::test(flavor = "current_thread")]
    async fn closed_other_end_is_an_error_not_a_spin() {
        let (near, far) = SerialStream::pair().unwrap();
        let near = Port::from_stream(near, &settings(Parity::None)).unwrap();
        let mut far = Port::from_stream(far, &settings(Parity::None)).unwrap();
        drop(near);
        let mut buf = [0u8; 8];
        let result = far
            .read_until(&mut buf, Instant::now() + Duration::from_secs(5))
            .await;
        assert!(result.is_err(), "{result:?}");
    }

    #[test]
    fn a_character_device_that_is_no_tty_is_not_a_terminal() {
        let mut not_a_tty = settings(Parity::None);
        not_a_tty.path = "/dev/null".into();
        not_a_tty.rs485 = None;
        assert!(matches!(
            Port::open(&not_a_tty),
            Err(TransportError::NotATerminal { .. })
        ));
    }

    #[test]
    fn missing_device_is_an_open_error() {
        let mut missing = settings(Parity::None);
        missing.path = "/dev/does-not-exist-rtu2mqtt".into();
        missing.rs485 = None;
        assert!(matches!(
            Port::open(&missing),
            Err(TransportError::Open { .. })
        ));
    }
}
