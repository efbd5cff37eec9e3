//! One Modbus RTU transaction at a time on a [`Port`], with exact timing: the line is driven
//! no sooner than t3.5 after the last byte seen on it (measured from when the transmit buffer
//! drained), stray bytes are flushed and counted before a request, answers are framed by
//! expected length (from the request, 5 bytes for an exception) and CRC with a response
//! timeout, and an answer arriving after its timeout is discarded and counted, never taken for
//! the next request's.
//!
//! A pause inside an answer does not end it: the rest is waited for up to the byte timeout
//! (USB adapters hand bytes over in latency-timer batches, slow devices pause mid-answer), and
//! pauses longer than t1.5 are counted. After a failed, truncated or foreign answer the line is
//! driven again only once it has been silent for t3.5 after the last byte heard. A new master
//! (a start, a reopened port) first listens until the line has been silent for the byte timeout,
//! so that an answer still on the wire from before is heard out, not collided with.
//!
//! While an answer is awaited: frames from other addresses are read to their end and ignored
//! (serial-line specification 2.4.1), noise just before the answer is skipped, and an adapter's
//! echo of the request is stripped (announced with `echo`, or detected and reported once).
//! After a timeout, the next request to the same address waits out a late-answer guard; the
//! late answer, whenever it comes, is counted in `late_answers`.
//!
//! The master learns when each device's answers begin (`serial::answer_onset`) and plans the
//! first read of the next answer by it: one wake-up for all of an answer but its last byte.

use std::time::Duration;

use tokio::time::Instant;
use tracing::Instrument;

use crate::clock::PreciseTimer;
use crate::codec::{self, DecodeError, MAX_FRAME_LEN};
use crate::frame::{FunctionCode, Request, SlaveId};
use crate::serial::answer_onset::AnswerOnsets;
use crate::serial::reception::{AnswerTiming, Heard, Next, Reception};
use crate::transaction::{Ask, Direction, Exchange, LinkCore};
// How a transaction ends: the outcome types every link shares, where callers have always
// found them.
use crate::outcome::{Error, Reply, WireCounters};
use crate::serial::transport::Port;
use crate::timing::LineTiming;

/// The default byte timeout: the longest silence inside an answer before it is declared
/// truncated. USB serial adapters hand received bytes over in bursts (CP210x/CH340 about every
/// 1–2 ms, FTDI every `latency_timer` ms, 16 by default), so the host sees gaps of up to 16 ms
/// inside a good answer; twice that leaves as much again for a busy host and a device that
/// pauses mid-answer. Only a really truncated answer pays for it, once. Lines at very low baud
/// rates use at least t3.5.
pub(crate) const DEFAULT_BYTE_TIMEOUT: Duration = Duration::from_millis(32);

/// Per-line behaviour of the master.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MasterOptions {
    /// The adapter echoes what it sends (2-wire adapters): strip the echo before the answer.
    pub echo: bool,
    /// Silence after a broadcast before the line is driven again.
    pub broadcast_turnaround: Duration,
    /// The byte timeout: the longest silence between two bytes of one answer before it is
    /// declared truncated, and the silence a new master listens for before its first request.
    /// `None`: 32 ms, or t3.5 where that is longer (below about 1100 baud).
    pub inter_char_timeout: Option<Duration>,
    /// After a timeout, how long the line is watched for the late answer before the next
    /// request to the same address goes out (counted from the timeout). `None`: the timed-out
    /// request's own timeout, so answers up to twice the timeout late are caught and never
    /// taken for the next request's. Only paid when the next request to that address follows
    /// at once (a retry); requests to other addresses go out after t3.5 as usual, and a late
    /// answer heard during them is ignored as a frame from another address.
    pub late_answer_guard: Option<Duration>,
}

impl Default for MasterOptions {
    fn default() -> Self {
        MasterOptions {
            echo: false,
            // The serial-line specification suggests 100–200 ms for a broadcast's turnaround.
            broadcast_turnaround: Duration::from_millis(100),
            inter_char_timeout: None,
            late_answer_guard: None,
        }
    }
}

/// The master of one serial line: runs one RTU transaction at a time on its [`Port`] through
/// [`Transact::transact`](crate::Transact::transact), with the silences, answer framing and
/// late-answer handling this module describes.
pub struct Master {
    port: Port,
    timing: LineTiming,
    options: MasterOptions,
    /// Counters, frame recorder and late-answer guard.
    pub(crate) core: LinkCore,
    /// Last instant a byte was seen on the line in either direction (drain instant for ours).
    last_activity: Instant,
    /// Nothing has been sent since the port was opened: the line's state is unknown, and the
    /// first request waits for a silence of the byte timeout.
    quiet_start: bool,
    /// The precise timer of every silence and wait of this master.
    timer: PreciseTimer,
    /// The address whose request timed out last, until a request is sent to it again: its late
    /// answer is told from another device's frame by it.
    timed_out_slave: Option<SlaveId>,
    /// The previous transaction timed out and no request has been sent since.
    late_window_open: bool,
    /// The late answer of the previous transaction has already been counted.
    late_answer_counted: bool,
    /// An unannounced adapter echo has been reported.
    echo_warned: bool,
    /// When each device's answers begin, to plan the first read of its next answer by.
    answer_onsets: AnswerOnsets,
}

impl std::fmt::Debug for Master {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Master")
            .field("port", &self.port)
            .field("timing", &self.timing)
            .field("options", &self.options)
            .field("core", &self.core)
            .finish_non_exhaustive()
    }
}

impl Master {
    /// The master of the line on `port`, whose silences follow `timing` (computed from the
    /// line's configured format, also on a pseudo-terminal that ignores it). The first
    /// request waits until the line has been silent for the byte timeout.
    pub fn new(port: Port, timing: LineTiming, options: MasterOptions) -> Self {
        let core = LinkCore::new(port.path().to_string());
        Master {
            port,
            timing,
            options,
            core,
            // The line's state before we opened it is unknown: treat it as just used.
            last_activity: Instant::now(),
            quiet_start: true,
            timer: PreciseTimer::default(),
            timed_out_slave: None,
            late_window_open: false,
            late_answer_counted: false,
            echo_warned: false,
            answer_onsets: AnswerOnsets::default(),
        }
    }

    /// Writes one line per frame, `<unix time with µs> <tx|rx> <hex>`, to `writer` (for bug
    /// reports). A write error stops the recording with a warning.
    pub fn record_frames_to(&mut self, writer: Box<dyn crate::FrameSink>) {
        self.core.record_frames_to(writer);
    }

    /// The gap between two bytes of one answer beyond which it is declared truncated.
    pub(crate) fn inter_char_timeout(&self) -> Duration {
        self.options
            .inter_char_timeout
            .unwrap_or(DEFAULT_BYTE_TIMEOUT.max(self.timing.t3_5))
    }

    /// Silence, request, answer: the transaction without its accounting.
    async fn silence_request_answer(&mut self, ask: Ask<'_>) -> Result<Reply, Error> {
        let frame = codec::encode_request(ask.slave, ask.request)?;
        // Only a request to the address that timed out could take its late answer for its own:
        // the guard applies to it alone; for any other address the late answer is a frame
        // from another address, ignored (and counted late).
        let guard = self.core.take_late_guard(ask.slave);
        self.wait_for_silence(guard, ask.timeout).await?;
        if self.timed_out_slave == Some(ask.slave) {
            self.timed_out_slave = None;
        }
        let drained_at = self.send(&frame).await?;
        let answer = self.receive_answer(ask, &frame, drained_at).await;
        self.timer.disarm();
        answer
    }

    /// Sends `request` to address 0 without waiting for an answer, then keeps the line silent
    /// for the turnaround delay.
    pub async fn broadcast(&mut self, request: &Request) -> Result<(), Error> {
        self.broadcast_then(request, || {}).await
    }

    /// [`Master::broadcast`], calling `sent` once the frame has left the port and before the
    /// turnaround: nothing will answer, so whoever asked for it can be told at once.
    pub async fn broadcast_then(
        &mut self,
        request: &Request,
        sent: impl FnOnce() + Send,
    ) -> Result<(), Error> {
        let frame = codec::encode_request(0, request)?;
        // Nothing answers a broadcast, so no late answer can be taken for its: no guard.
        let patience = self
            .options
            .broadcast_turnaround
            .max(Duration::from_secs(1));
        self.wait_for_silence(None, patience).await?;
        let drained_at = self.send(&frame).await?;
        sent();
        self.timer
            .sleep_until(drained_at + self.options.broadcast_turnaround)
            .await;
        Ok(())
    }

    /// Waits until the line could take the next request: t3.5 of silence (the byte timeout
    /// after the port was opened), taking and counting whatever arrives meanwhile, as every
    /// transaction does first. Cancel-safe: the line listens for commands beside it and drops
    /// this wait when one arrives, so that the command, not a poll chosen before the silence,
    /// takes the free line. A late-answer guard is not waited for here; the transaction to
    /// that address still waits it out.
    pub async fn wait_until_quiet(&mut self, patience: Duration) -> Result<(), Error> {
        self.wait_for_silence(None, patience).await
    }

    /// The master's counters since it was made.
    pub fn counters(&self) -> WireCounters {
        self.core.counters()
    }

    /// Waits until the line has been silent for t3.5 (and until `guard`, a late-answer guard,
    /// has passed), taking and counting every byte that arrives meanwhile; each byte restarts
    /// the silence. Before the first request after the port was opened the silence is the byte
    /// timeout: a device may still be answering a request from before, with pauses inside.
    async fn wait_for_silence(
        &mut self,
        guard: Option<Instant>,
        patience: Duration,
    ) -> Result<(), Error> {
        let give_up = guard.unwrap_or_else(Instant::now).max(Instant::now()) + patience;
        let mut chunk = [0u8; MAX_FRAME_LEN];
        loop {
            let pending = self.port.take_pending()?;
            if !pending.is_empty() {
                self.absorb_unsolicited(&pending, Instant::now());
            }
            let silence = if self.quiet_start {
                self.inter_char_timeout().max(self.timing.t3_5)
            } else {
                self.timing.t3_5
            };
            let mut quiet_at = self.last_activity + silence;
            if let Some(guard) = guard {
                quiet_at = quiet_at.max(guard);
            }
            let now = Instant::now();
            if now >= quiet_at {
                return Ok(());
            }
            if now >= give_up {
                return Err(Error::LineBusy(patience));
            }
            // Listen all through the silence; the precise timer (a timerfd, not the
            // millisecond tokio timer) ends the wait as soon as the silence is complete, or
            // when patience runs out.
            let heard = tokio::select! {
                biased;
                read = self.port.receive(&mut chunk) => Some(read?),
                () = self.timer.sleep_until_sharp(quiet_at.min(give_up)) => None,
            };
            if let Some((count, seen)) = heard {
                let bytes = chunk[..count].to_vec();
                self.absorb_unsolicited(&bytes, seen);
            }
        }
    }

    /// Bytes nobody asked for: part of a late answer while the late window is open, stray
    /// bytes otherwise. Either way they restart the line's silence.
    fn absorb_unsolicited(&mut self, bytes: &[u8], seen: Instant) {
        self.last_activity = self.last_activity.max(seen);
        self.core.counters_mut().wire_time += self.timing.frame_time(bytes.len());
        self.core.record(Direction::Rx, bytes);
        if self.late_window_open {
            if !self.late_answer_counted {
                self.core.counters_mut().late_answers += 1;
                self.late_answer_counted = true;
            }
            tracing::debug!(port = %self.port.path(), frame = %codec::hex(bytes), "late answer discarded");
        } else {
            self.core.counters_mut().stray_bytes += bytes.len() as u64;
            tracing::debug!(port = %self.port.path(), frame = %codec::hex(bytes), "stray bytes discarded");
        }
    }

    /// Bytes before an answer that belong to no frame (a transceiver's turn-around glitch,
    /// a stray byte just as the answer starts): counted as stray and dropped.
    fn absorb_noise(&mut self, bytes: &[u8], seen: Instant) {
        let late_window_open = std::mem::replace(&mut self.late_window_open, false);
        self.absorb_unsolicited(bytes, seen);
        self.late_window_open = late_window_open;
    }

    /// Writes `frame`, waits for the drain and returns its instant.
    async fn send(&mut self, frame: &[u8]) -> Result<Instant, Error> {
        self.core.record(Direction::Tx, frame);
        self.core.counters_mut().requests += 1;
        self.late_window_open = false;
        self.quiet_start = false;
        let drained_at = self.port.write_frame(frame).await?;
        self.last_activity = drained_at;
        self.core.counters_mut().wire_time +=
            self.timing.frame_time(frame.len()) + self.timing.t3_5;
        Ok(drained_at)
    }

    /// Reads the answer to the request asked (sent as `sent` at `drained_at`) and decodes it:
    /// the port's reads and silences handed to a [`Reception`], which frames them.
    async fn receive_answer(
        &mut self,
        ask: Ask<'_>,
        sent: &[u8],
        drained_at: Instant,
    ) -> Result<Reply, Error> {
        let Ask {
            slave,
            request,
            timeout,
        } = ask;
        if self.options.echo {
            self.strip_echo(sent, drained_at + timeout, timeout).await?;
        }
        let timing = AnswerTiming {
            sent_at: drained_at,
            timeout,
            byte_timeout: self.inter_char_timeout(),
            line: self.timing,
        };
        let mut reception = Reception::new(slave, request, sent, self.options.echo, timing);
        // An echo comes before the answer: the answer's onset is planned for only without one.
        if !self.options.echo {
            if let Some(first_byte_after) = self.answer_onsets.expected(slave) {
                reception = reception.expecting_first_byte_at(drained_at + first_byte_after);
            }
        }
        let result = self.read_answer(&mut reception).await;
        if let Some(arrival) = reception.arrival() {
            self.answer_onsets.learn(slave, arrival);
        }
        result
    }

    /// Reads from the port until `reception` has the answer or knows there is none.
    async fn read_answer(&mut self, reception: &mut Reception) -> Result<Reply, Error> {
        let mut chunk = [0u8; MAX_FRAME_LEN];
        loop {
            let next = reception.next(Instant::now());
            self.account(reception);
            let (until, rest_due) = match next {
                Next::Done(result) => return result,
                Next::Read { until, rest_due } => (until, rest_due),
            };
            if let Some(due) = rest_due {
                // Bytes that arrive meanwhile would each wake the runtime for nothing.
                self.port.stop_listening();
                self.timer.sleep_until(due).await;
            }
            // The precise timer ends the read: a tokio deadline sooner than the runtime's
            // planned wake-up would cost the runtime a wake-up of its own to plan again.
            let heard = tokio::select! {
                biased;
                read = self.port.receive(&mut chunk) => Some(read?),
                () = self.timer.sleep_until(until) => None,
            };
            if let Some((count, seen)) = heard {
                reception.heard(&chunk[..count], seen);
                self.last_activity = seen;
            } else if let Some(result) = reception.silence(Instant::now()) {
                self.account(reception);
                return result;
            }
            self.account(reception);
        }
    }

    /// Counts, logs and records what the reception made of the bytes heard.
    fn account(&mut self, reception: &mut Reception) {
        for heard in reception.take_heard() {
            match heard {
                Heard::Echo(_) => {
                    if !self.echo_warned {
                        self.echo_warned = true;
                        tracing::warn!(port = %self.port.path(), "the adapter echoes what is sent; set echo = true for this line");
                    }
                }
                Heard::Noise { bytes, seen } => self.absorb_noise(&bytes, seen),
                Heard::Foreign(frame) => self.ignore_foreign_frame(&frame),
                Heard::Unframed { bytes, seen } => self.drop_unframed(&bytes, seen),
                Heard::Frame(frame) => self.took_frame(&frame),
                Heard::Trailing { bytes, seen } => self.absorb_unsolicited(&bytes, seen),
                Heard::LongGap => self.core.counters_mut().long_gaps += 1,
            }
        }
    }

    /// Reads our own frame back from an echoing adapter.
    async fn strip_echo(
        &mut self,
        sent: &[u8],
        deadline: Instant,
        timeout: Duration,
    ) -> Result<(), Error> {
        let mut echoed = Vec::with_capacity(sent.len());
        let mut chunk = [0u8; MAX_FRAME_LEN];
        while echoed.len() < sent.len() {
            let want = sent.len() - echoed.len();
            match self.port.read_until(&mut chunk[..want], deadline).await? {
                Some((count, seen)) => {
                    echoed.extend_from_slice(&chunk[..count]);
                    self.last_activity = seen;
                }
                None => break,
            }
        }
        if echoed == sent {
            return Ok(());
        }
        self.core.record(Direction::Rx, &echoed);
        tracing::warn!(port = %self.port.path(), sent = %codec::hex(sent), echoed = %codec::hex(&echoed), "echo differs from the frame sent");
        if echoed.is_empty() {
            return Err(Error::Timeout(timeout));
        }
        Err(Error::UnexpectedReply(DecodeError::Malformed(
            "adapter echo differs from the frame sent",
        )))
    }

    /// A frame for another address: counted and dropped; listening goes on (serial-line
    /// specification 2.4.1).
    fn ignore_foreign_frame(&mut self, frame: &[u8]) {
        let from_timed_out_slave = frame
            .first()
            .is_some_and(|&address| Some(address) == self.timed_out_slave);
        if from_timed_out_slave && !self.late_answer_counted {
            self.core.counters_mut().late_answers += 1;
            self.late_answer_counted = true;
        } else {
            self.core.counters_mut().wrong_address += 1;
        }
        self.took_frame(frame);
        tracing::debug!(port = %self.port.path(), frame = %codec::hex(frame), "frame for another address ignored");
    }

    /// Bytes for another address that never made a whole frame: a frame for another device
    /// when they start like one (a known function code), noise otherwise.
    fn drop_unframed(&mut self, bytes: &[u8], seen: Instant) {
        let starts_like_a_frame = bytes
            .get(1)
            .is_some_and(|&code| FunctionCode::from_u8(code & 0x7F).is_some());
        if starts_like_a_frame {
            self.ignore_foreign_frame(bytes);
        } else {
            self.absorb_noise(bytes, seen);
        }
    }

    /// Accounts for a received frame (log, recorder, wire time).
    fn took_frame(&mut self, frame: &[u8]) {
        self.core.record(Direction::Rx, frame);
        self.core.counters_mut().wire_time +=
            self.timing.frame_time(frame.len()) + self.timing.t3_5;
    }
}

impl Exchange for Master {
    fn core(&self) -> &LinkCore {
        &self.core
    }

    fn core_mut(&mut self) -> &mut LinkCore {
        &mut self.core
    }

    fn late_answer_guard(&self, timeout: Duration) -> Option<Duration> {
        Some(self.options.late_answer_guard.unwrap_or(timeout))
    }

    /// Sends the request and waits for its answer. `timeout` runs from the instant the
    /// request left the transmit buffer until the answer's first byte is seen (USB adapters
    /// may hand that byte over only with the whole frame: see
    /// [`LineTiming::default_response_timeout`]); once the answer has started, only the
    /// inter-character gap limit applies.
    async fn exchange(&mut self, ask: Ask<'_>) -> Result<Reply, Error> {
        let span = tracing::debug_span!(
            "transaction",
            port = %self.port.path(),
            slave = ask.slave,
            function = ?ask.request.function()
        );
        let result = self.silence_request_answer(ask).instrument(span).await;
        if let Err(Error::Timeout(_)) = &result {
            self.timed_out_slave = Some(ask.slave);
            self.late_window_open = true;
            self.late_answer_counted = false;
        }
        result
    }
}
