//! Serves simulated devices on one byte stream (a pty end or a real serial port): frames the
//! requests, hands each to the device it addresses, and answers after the line's t3.5 silence,
//! optionally paced as a wire would (the request ends one request-wire-time after its first
//! byte; the answer's bytes are handed over as its [`Pace`] says: whole once its wire time is
//! over, byte by byte, or in USB-adapter chunks), with the line's faults applied and
//! everything written into its journal.
//!
//! While an answer goes out the line is still listened to, so a request sent into it is
//! journalled as arriving then.
//!
//! Framing follows a real device: a frame's length is known from its function code, a bad CRC
//! makes the device ignore everything up to the next silence, and a function code it does not
//! know ends at the next silence.

use std::time::{Duration, Instant};

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

use super::device::{lock, Addressing, Reply, SharedDevice};
use super::faults::{random_bytes, AnswerChunks, FaultHandle};
use super::journal::{AnswerTiming, Journal, RequestRecord};
use super::pace::Pace;
use super::pty_settings::{garble, BaudWatch};
use super::wire::{self, FrameLen, RequestError};
use rtu2mqtt_modbus::clock::sleep_until_precise;
use rtu2mqtt_modbus::codec::{encode_answer, encode_exception, hex};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use tokio_util::sync::CancellationToken;

/// The longest RTU frame (address, PDU of at most 253 bytes, CRC).
const MAX_FRAME_LEN: usize = 256;

/// How often the idle loop looks at the faults again.
const FAULT_RECHECK: Duration = Duration::from_millis(50);

/// How a line is served.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServeOptions {
    pub timing: LineTiming,
    /// When an answer's bytes are handed over (a pty delivers them instantly).
    pub pace: Pace,
    /// Garble the answers while the pty's baud rate, as the master set it, differs from the
    /// line's: what a device hears at the wrong baud rate. Only a [`VirtualLine`](super::virtual_line::VirtualLine) can
    /// look at its pty's settings; elsewhere this does nothing.
    pub enforce_baud: bool,
}

impl ServeOptions {
    /// `baud` with 8 data bits, `parity` and 1 stop bit, unpaced.
    pub fn new(baud: u32, parity: Parity) -> Self {
        let format = CharFormat {
            data_bits: 8,
            parity,
            stop_bits: 1,
        };
        Self {
            timing: LineTiming::new(baud, format),
            pace: Pace::Instant,
            enforce_baud: false,
        }
    }

    /// `true`: each answer whole once its wire time is over ([`Pace::Frame`]); `false`: at once.
    pub fn paced(self, pace: bool) -> Self {
        self.pacing(if pace { Pace::Frame } else { Pace::Instant })
    }

    /// See [`ServeOptions::pace`].
    pub fn pacing(mut self, pace: Pace) -> Self {
        self.pace = pace;
        self
    }

    /// See [`ServeOptions::enforce_baud`].
    pub fn enforcing_baud(mut self, enforce: bool) -> Self {
        self.enforce_baud = enforce;
        self
    }
}

/// Serves `devices` on `stream` until `shutdown` fires or the stream ends (EOF: Ok; an I/O
/// error: Err).
pub async fn serve<S>(
    stream: S,
    options: ServeOptions,
    devices: Vec<SharedDevice>,
    faults: FaultHandle,
    journal: Journal,
    shutdown: CancellationToken,
) -> std::io::Result<()>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    serve_watching(stream, options, None, devices, faults, journal, shutdown).await
}

/// [`serve`], garbling the answers while `baud_watch` sees the master at another baud rate.
pub(crate) async fn serve_watching<S>(
    stream: S,
    options: ServeOptions,
    baud_watch: Option<BaudWatch>,
    devices: Vec<SharedDevice>,
    faults: FaultHandle,
    journal: Journal,
    shutdown: CancellationToken,
) -> std::io::Result<()>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    let mut server = Server {
        stream,
        options,
        baud_watch,
        devices,
        faults,
        journal,
        buffer: Vec::new(),
        first_byte_at: Instant::now(),
        last_byte_at: Instant::now(),
        idle_since: None,
        discarding: false,
        epoch: Instant::now(),
    };
    let mut chunk = [0u8; 512];
    // When idle garbage goes out next (or, without it, when to look at the faults again).
    let mut idle_wake: Option<tokio::time::Instant> = None;
    loop {
        let silence_at = (!server.buffer.is_empty()).then(|| {
            tokio::time::Instant::from_std(server.last_byte_at + server.options.timing.t3_5)
        });
        // Faults change at run time: without idle garbage the loop still wakes now and then to
        // notice it being switched on.
        let idle_garbage = server.faults.idle_garbage_every();
        let wake_at = *idle_wake.get_or_insert_with(|| {
            tokio::time::Instant::now() + idle_garbage.unwrap_or(FAULT_RECHECK)
        });
        tokio::select! {
            _ = shutdown.cancelled() => return Ok(()),
            read = server.stream.read(&mut chunk) => {
                let count = read?;
                if count == 0 {
                    return Ok(());
                }
                server.received(&chunk[..count]).await?;
            }
            _ = sleep_until_opt(silence_at), if silence_at.is_some() => {
                server.silence().await?;
            }
            _ = tokio::time::sleep_until(wake_at) => {
                idle_wake = None;
                if idle_garbage.is_some() && server.buffer.is_empty() {
                    let noise = random_bytes(&mut rand::thread_rng(), 3);
                    tracing::debug!(bytes = %hex(&noise), "idle garbage");
                    server.stream.write_all(&noise).await?;
                    server.stream.flush().await?;
                }
            }
        }
    }
}

async fn sleep_until_opt(deadline: Option<tokio::time::Instant>) {
    if let Some(deadline) = deadline {
        tokio::time::sleep_until(deadline).await;
    }
}

struct Server<S> {
    stream: S,
    options: ServeOptions,
    /// The virtual line's pty settings, when it enforces its baud rate.
    baud_watch: Option<BaudWatch>,
    devices: Vec<SharedDevice>,
    faults: FaultHandle,
    journal: Journal,
    /// Bytes of the frame being received.
    buffer: Vec<u8>,
    first_byte_at: Instant,
    last_byte_at: Instant,
    /// When the line last fell silent (end of the previous frame either way).
    idle_since: Option<Instant>,
    /// After a bad CRC a device ignores everything until the next silence.
    discarding: bool,
    /// Where a USB adapter's polling ticks are counted from.
    epoch: Instant,
}

impl<S: AsyncRead + AsyncWrite + Unpin> Server<S> {
    async fn received(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let now = Instant::now();
        if self.discarding
            && now.saturating_duration_since(self.last_byte_at) >= self.options.timing.t3_5
        {
            // The silence that ended the bad burst came while nothing was pending.
            self.discarding = false;
        }
        if self.buffer.is_empty() {
            self.first_byte_at = now;
        }
        self.buffer.extend_from_slice(bytes);
        self.last_byte_at = now;
        if self.buffer.len() > MAX_FRAME_LEN && !self.discarding {
            // Longer than any RTU frame: noise. Ignore it up to the next silence.
            self.journal.count_discarded(self.buffer.len());
            self.buffer.clear();
            self.discarding = true;
        }
        if self.discarding {
            self.journal.count_discarded(self.buffer.len());
            self.buffer.clear();
            return Ok(());
        }
        // Frames whose length is known are handled as soon as they are complete, as a device
        // would after its t3.5 (the wait is added before the answer).
        while !self.discarding {
            match wire::request_frame_len(&self.buffer) {
                FrameLen::Known(len) if self.buffer.len() >= len => {
                    let frame: Vec<u8> = self.buffer.drain(..len).collect();
                    let arrived = self.first_byte_at;
                    self.first_byte_at = self.last_byte_at;
                    self.frame(frame, arrived).await?;
                }
                _ => break,
            }
        }
        Ok(())
    }

    /// The line fell silent for t3.5 with bytes pending: they end here.
    async fn silence(&mut self) -> std::io::Result<()> {
        let pending = std::mem::take(&mut self.buffer);
        let was_discarding = std::mem::replace(&mut self.discarding, false);
        if was_discarding {
            self.journal.count_discarded(pending.len());
            return Ok(());
        }
        match wire::request_frame_len(&pending) {
            FrameLen::UntilSilence => self.frame(pending, self.first_byte_at).await,
            _ => {
                tracing::debug!(bytes = %hex(&pending), "incomplete frame discarded");
                self.journal.count_discarded(pending.len());
                self.idle_since = Some(self.last_byte_at);
                Ok(())
            }
        }
    }

    /// One complete frame that arrived with its first byte at `arrived`.
    async fn frame(&mut self, frame: Vec<u8>, arrived: Instant) -> std::io::Result<()> {
        let timing = self.options.timing;
        let silence_before = self
            .idle_since
            .map(|idle| arrived.saturating_duration_since(idle));
        // When the request is over on the wire.
        let ended = if self.options.pace.takes_wire_time() {
            self.last_byte_at
                .max(arrived + timing.frame_time(frame.len()))
        } else {
            self.last_byte_at
        };
        let mut record = RequestRecord {
            frame: frame.clone(),
            arrived,
            silence_before,
            crc_ok: wire::crc_ok(&frame),
            answer: None,
            answer_timing: None,
        };
        tracing::debug!(frame = %hex(&frame), crc_ok = record.crc_ok, "request");
        if self.faults.echo() {
            // The adapter hears whatever goes out, valid or not.
            self.stream.write_all(&frame).await?;
        }
        if !record.crc_ok {
            // Like a device framing by silence, ignore the rest of this burst.
            self.discarding = true;
            self.journal.count_discarded(self.buffer.len());
            self.buffer.clear();
            self.idle_since = Some(ended);
            self.journal.record(record);
            return Ok(());
        }
        let answer = self.dispatch(&frame);
        let Some((address, mut bytes)) = answer else {
            self.idle_since = Some(ended);
            self.journal.record(record);
            return Ok(());
        };
        let faults = self.faults.for_answer(address);
        if let Some(code) = faults.exception {
            bytes = encode_exception(address, frame[1], code);
        }
        if let Some(wrong) = faults.wrong_address {
            bytes[0] = wrong;
            bytes.truncate(bytes.len() - 2);
            bytes = wire::with_crc(bytes);
        }
        if let Some(peer) = self.baud_watch.as_ref().and_then(BaudWatch::mismatch) {
            tracing::debug!(
                peer,
                own = timing.baud,
                "answer garbled: the master's baud rate differs"
            );
            garble(&mut bytes);
        }
        if faults.corrupt_crc {
            if let Some(last) = bytes.last_mut() {
                *last ^= 0x01;
            }
        }
        if faults.truncate_bytes > 0 {
            let keep = bytes.len().saturating_sub(faults.truncate_bytes).max(1);
            bytes.truncate(keep);
        }
        if faults.drop {
            tracing::debug!("answer dropped by fault injection");
            self.idle_since = Some(ended);
            self.journal.record(record);
            return Ok(());
        }
        let mut out = faults.garbage_before;
        out.extend_from_slice(&bytes);
        let starts = ended + timing.t3_5 + faults.delay;
        let timing = self
            .send(&out, starts, faults.pause_mid_answer, faults.answer_chunks)
            .await?;
        record.answer = Some(out);
        record.answer_timing = Some(timing);
        self.journal.record(record);
        Ok(())
    }

    /// Hands a CRC-valid frame to the devices; the answer's address and bytes, if any.
    fn dispatch(&mut self, frame: &[u8]) -> Option<(u8, Vec<u8>)> {
        let now = Instant::now();
        let decoded = wire::decode_request(frame);
        let target = frame[0];
        let function = frame[1];
        let mut answer = None;
        for device in &self.devices {
            let mut device = lock(device);
            if self.faults.is_silenced(device.address()) {
                continue;
            }
            let addressing = device.addressing(target);
            if addressing == Addressing::NotMine {
                continue;
            }
            let reply = match &decoded {
                Ok((_, request)) => {
                    if request.is_write() {
                        self.journal.count_write(device.address());
                    }
                    device.handle(request, now)
                }
                Err(RequestError::UnknownFunction(code)) => {
                    device.handle_unknown_function(*code, now)
                }
                Err(RequestError::Malformed) => Reply::Silent,
            };
            // The address after handling: a device whose address was just changed answers
            // from the new one.
            let address = device.address();
            if addressing == Addressing::Answer && answer.is_none() {
                answer = match reply {
                    Reply::Normal(response) => Some((address, encode_answer(address, &response))),
                    Reply::Exception(code) => {
                        Some((address, encode_exception(address, function, code)))
                    }
                    Reply::Silent => None,
                };
            }
        }
        answer
    }

    /// Sends `bytes` so that they start at `starts`, handed over as the line's [`Pace`] says:
    /// whole, in two halves around `pause`, or in `chunks` with a gap after each. No flush
    /// follows the writes: on a pty it is a tcdrain system call with nothing to drain, and the
    /// bytes are readable on the other end as soon as the write returns.
    ///
    /// The line is listened to all the while: a request that arrives while the answer is
    /// still going out is journalled with its true arrival (and no silence before it), as a
    /// collision on a real wire would garble both.
    async fn send(
        &mut self,
        bytes: &[u8],
        starts: Instant,
        pause: Option<Duration>,
        chunks: Option<AnswerChunks>,
    ) -> std::io::Result<AnswerTiming> {
        let (burst, gap) = match (chunks, pause) {
            (Some(chunks), _) => (chunks.bytes.max(1), chunks.gap),
            (None, Some(pause)) => ((bytes.len() / 2).max(1), pause),
            (None, None) => (bytes.len().max(1), Duration::ZERO),
        };
        let parts = self.options.pace.schedule(
            &self.options.timing,
            starts,
            bytes.len(),
            burst,
            gap,
            self.epoch,
        );
        let mut at = starts;
        let mut handed_over = Instant::now();
        for (ready, range) in parts {
            at = ready;
            self.listen_until(at).await?;
            handed_over = Instant::now();
            self.stream.write_all(&bytes[range]).await?;
        }
        let write_returned = Instant::now();
        tracing::debug!(answer = %hex(bytes), "answer");
        // The silence starts when the last byte is on the wire and the master can have it:
        // from the write on, not from when this thread got to run again after it.
        self.idle_since = Some(handed_over.max(at));
        Ok(AnswerTiming {
            due: at,
            handed_over: handed_over.max(at),
            write_returned,
        })
    }

    /// Waits precisely until `at`, taking in whatever arrives meanwhile (framed once the answer
    /// is out).
    async fn listen_until(&mut self, at: Instant) -> std::io::Result<()> {
        let mut chunk = [0u8; MAX_FRAME_LEN];
        loop {
            tokio::select! {
                biased;
                () = sleep_until_precise(tokio::time::Instant::from_std(at)) => return Ok(()),
                read = self.stream.read(&mut chunk) => {
                    let count = read?;
                    if count == 0 {
                        // The other end closed: the serving loop's next read sees it too.
                        sleep_until_precise(tokio::time::Instant::from_std(at)).await;
                        return Ok(());
                    }
                    let now = Instant::now();
                    if self.buffer.is_empty() {
                        self.first_byte_at = now;
                    }
                    self.buffer.extend_from_slice(&chunk[..count]);
                    self.last_byte_at = now;
                }
            }
        }
    }
}
