//! What every link keeps beside its transport, whichever it is (serial master, raw RTU over
//! TCP, Modbus TCP): the wire counters, the frame recorder with its record format, the
//! late-answer guard a timeout arms, and [`Transact`], the one transaction wrapper that counts
//! and guards around each transport's exchange. Written once here so that the three links
//! count, record and guard alike.

use std::future::Future;
use std::io::Write;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use tokio::time::Instant;

use crate::codec;
use crate::frame::{Request, SlaveId};
use crate::outcome::{Error, Reply, WireCounters};

/// Which way a recorded frame went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Direction {
    /// Sent by this master.
    Tx,
    /// Heard on the line or the stream.
    Rx,
}

impl Direction {
    fn word(self) -> &'static str {
        match self {
            Direction::Tx => "tx",
            Direction::Rx => "rx",
        }
    }
}

/// Where a link's frame records go (the frame log, the console's live view): one text line per
/// frame, `<unix time with µs> <tx|rx> <hex>`, written on the link's own thread, so a sink
/// must never block.
pub trait FrameSink: Write + Send {
    /// Whether a record would go anywhere now: while it would not, the link does not format
    /// one (a live view nobody watches costs nothing).
    fn listening(&self) -> bool {
        true
    }
}

/// The counters, the frame recorder and the late-answer guard of one link.
pub(crate) struct LinkCore {
    /// The port's path or the url, for logs.
    label: String,
    counters: WireCounters,
    /// Receives one text line per frame, `<unix time with µs> <tx|rx> <hex>`.
    recorder: Option<Box<dyn FrameSink>>,
    /// After a timeout: the address that timed out and until when its late answer is awaited
    /// before the next request to that address goes out.
    late_guard: Option<(SlaveId, Instant)>,
}

impl std::fmt::Debug for LinkCore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LinkCore")
            .field("label", &self.label)
            .field("counters", &self.counters)
            .field("recording", &self.recorder.is_some())
            .field("late_guard", &self.late_guard)
            .finish()
    }
}

impl LinkCore {
    pub(crate) fn new(label: String) -> Self {
        LinkCore {
            label,
            counters: WireCounters::default(),
            recorder: None,
            late_guard: None,
        }
    }

    /// The port's path or the url, for logs.
    pub(crate) fn label(&self) -> &str {
        &self.label
    }

    pub(crate) fn counters(&self) -> WireCounters {
        self.counters
    }

    pub(crate) fn counters_mut(&mut self) -> &mut WireCounters {
        &mut self.counters
    }

    /// Writes one line per frame, `<unix time with µs> <tx|rx> <hex>`, to `writer` (the frame
    /// log, for bug reports). The write happens on the link's own thread, so `writer` must not
    /// block (see [`crate::frame_log`]). A write error stops the recording with a warning.
    pub(crate) fn record_frames_to(&mut self, writer: Box<dyn FrameSink>) {
        self.recorder = Some(writer);
    }

    /// Logs a frame at debug level and hands it to the recorder, if any.
    pub(crate) fn record(&mut self, direction: Direction, bytes: &[u8]) {
        tracing::debug!(link = %self.label, frame = %codec::hex(bytes), "{}", direction.word());
        let Some(writer) = self.recorder.as_mut().filter(|sink| sink.listening()) else {
            return;
        };
        let line = format!(
            "{} {} {}\n",
            unix_time_micros(),
            direction.word(),
            codec::hex(bytes).replace(' ', "")
        );
        if let Err(error) = writer
            .write_all(line.as_bytes())
            .and_then(|()| writer.flush())
        {
            tracing::warn!(link = %self.label, %error, "frame recording stopped");
            self.recorder = None;
        }
    }

    /// Counts how a transaction to `slave` ended; a timeout arms the late-answer guard for
    /// `guard` from now (`None`: no guard, the link tells late answers apart by itself).
    pub(crate) fn settle(
        &mut self,
        slave: SlaveId,
        result: &Result<Reply, Error>,
        guard: Option<Duration>,
    ) {
        self.counters.count(result);
        if let (Err(Error::Timeout(_)), Some(guard)) = (result, guard) {
            self.late_guard = Some((slave, Instant::now() + guard));
        }
    }

    /// Until when a request to `slave` must wait for the late answer of its timed-out
    /// predecessor: the guard is taken by the next request to that address alone; requests to
    /// other addresses leave it in place.
    pub(crate) fn take_late_guard(&mut self, slave: SlaveId) -> Option<Instant> {
        match self.late_guard {
            Some((timed_out, until)) if timed_out == slave => {
                self.late_guard = None;
                Some(until)
            }
            _ => None,
        }
    }
}

/// One transaction as a link is asked it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Ask<'a> {
    /// The device's address (the unit id on Modbus TCP).
    pub(crate) slave: SlaveId,
    /// The request sent to it.
    pub(crate) request: &'a Request,
    /// How long the answer is awaited.
    pub(crate) timeout: Duration,
}

/// What each link implements its own way: the frames of one transaction, and where its
/// counters, frame recorder and late-answer guard are kept. [`Transact`] wraps it for every
/// link alike; callers never run an exchange without that accounting.
pub(crate) trait Exchange: Send {
    /// The link's counters, frame recorder and late-answer guard.
    fn core(&self) -> &LinkCore;

    fn core_mut(&mut self) -> &mut LinkCore;

    /// After a timeout, how long the next request to the same address waits for the late
    /// answer (`None`: the link tells late answers apart by itself).
    fn late_answer_guard(&self, timeout: Duration) -> Option<Duration>;

    /// Request out, answer in: the transaction without its accounting.
    fn exchange(&mut self, ask: Ask<'_>) -> impl Future<Output = Result<Reply, Error>> + Send;
}

/// A link that runs Modbus transactions: [`Link`](crate::link::Link), or one of the links it
/// holds ([`Master`](crate::serial::master::Master) on a serial port,
/// [`RawTcpMaster`](crate::tcp::masters::RawTcpMaster),
/// [`ModbusTcpMaster`](crate::tcp::masters::ModbusTcpMaster)). Every link counts how each
/// transaction ended in its [`WireCounters`] and, after a timeout, guards the next request to
/// the same address against the late answer, the same way.
pub trait Transact: Send {
    /// One transaction: `request` to `slave` (the unit id on Modbus TCP), its answer awaited
    /// for `timeout` (from the end of the request on the wire to the last byte of the
    /// answer).
    ///
    /// `Ok(Ok(_))` is the device's normal answer, `Ok(Err(_))` the exception it answered with
    /// (it is there and has spoken), `Err(_)` why no answer was heard ([`Error`]: nothing was
    /// sent for [`Error::InvalidRequest`] and [`Error::LineBusy`]).
    fn transact(
        &mut self,
        slave: SlaveId,
        request: &Request,
        timeout: Duration,
    ) -> impl Future<Output = Result<Reply, Error>> + Send;
}

impl<L: Exchange> Transact for L {
    async fn transact(
        &mut self,
        slave: SlaveId,
        request: &Request,
        timeout: Duration,
    ) -> Result<Reply, Error> {
        let ask = Ask {
            slave,
            request,
            timeout,
        };
        let result = self.exchange(ask).await;
        let guard = self.late_answer_guard(timeout);
        self.core_mut().settle(slave, &result, guard);
        result
    }
}

fn unix_time_micros() -> String {
    let since_epoch = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default();
    format!(
        "{}.{:06}",
        since_epoch.as_secs(),
        since_epoch.subsec_micros()
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Response;
    use std::sync::{Arc, Mutex};

    #[derive(Clone, Default)]
    struct Lines(Arc<Mutex<Vec<u8>>>);

    impl FrameSink for Lines {}

    impl Write for Lines {
        fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(bytes);
            Ok(bytes.len())
        }

        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn records_are_timestamped_directed_hex_lines() {
        let mut core = LinkCore::new("test".into());
        let lines = Lines::default();
        core.record_frames_to(Box::new(lines.clone()));
        core.record(Direction::Tx, &[0x01, 0x03, 0xAB]);
        core.record(Direction::Rx, &[0x0F]);
        let text = String::from_utf8(lines.0.lock().unwrap().clone()).unwrap();
        let records: Vec<Vec<&str>> = text.lines().map(|line| line.split(' ').collect()).collect();
        assert_eq!(records.len(), 2, "{text}");
        assert_eq!(records[0][1..], ["tx", "0103AB"]);
        assert_eq!(records[1][1..], ["rx", "0F"]);
        let (seconds, micros) = records[0][0].split_once('.').unwrap();
        assert!(seconds.parse::<u64>().unwrap() > 1_600_000_000);
        assert_eq!(micros.len(), 6);
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_timeout_guards_only_the_next_request_to_its_address() {
        let mut core = LinkCore::new("test".into());
        let timeout = Err(Error::Timeout(Duration::from_millis(10)));
        core.settle(0x11, &timeout, Some(Duration::from_millis(50)));
        assert_eq!(core.counters().timeouts, 1);
        assert_eq!(core.take_late_guard(0x22), None);
        let until = core.take_late_guard(0x11).unwrap();
        assert!(until > Instant::now());
        assert_eq!(core.take_late_guard(0x11), None);
        // An answer arms nothing; a timeout without a guard length neither.
        core.settle(
            0x11,
            &Ok(Ok(Response::HoldingRegisters(vec![1]))),
            Some(Duration::from_millis(50)),
        );
        core.settle(0x11, &timeout, None);
        assert_eq!(core.take_late_guard(0x11), None);
        assert_eq!(core.counters().timeouts, 2);
    }
}
