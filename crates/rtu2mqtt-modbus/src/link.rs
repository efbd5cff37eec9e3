//! What a line talks through: a serial port ([`Master`]), a serial device server's raw TCP
//! stream ([`RawTcpMaster`]) or a Modbus TCP gateway ([`ModbusTcpMaster`]). The line task runs
//! the same transactions, counters and frame log on each; only this enum knows which it is.

use std::time::Duration;

use super::frame::Request;
use super::outcome::{Error, Reply, WireCounters};
use crate::serial::master::Master;
use crate::tcp::masters::{ModbusTcpMaster, RawTcpMaster};
use crate::transaction::{Ask, Exchange, LinkCore};

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

impl Link {
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
        match self {
            Link::Serial(master) => master.broadcast_then(request, sent).await,
            Link::RawTcp(master) => master.broadcast_then(request, sent).await,
            Link::ModbusTcp(master) => master.broadcast_then(request, sent).await,
        }
    }

    /// Waits until the link could take the next request (the silence after the last frame),
    /// at most `patience`. Cancel-safe. A Modbus TCP gateway keeps its own line's timing, so
    /// it is ready at once.
    pub async fn wait_until_quiet(&mut self, patience: Duration) -> Result<(), Error> {
        match self {
            Link::Serial(master) => master.wait_until_quiet(patience).await,
            Link::RawTcp(master) => {
                master.wait_until_quiet().await;
                Ok(())
            }
            Link::ModbusTcp(_) => Ok(()),
        }
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
        match self {
            Link::Serial(master) => master.core(),
            Link::RawTcp(master) => master.core(),
            Link::ModbusTcp(master) => master.core(),
        }
    }

    fn core_mut(&mut self) -> &mut LinkCore {
        match self {
            Link::Serial(master) => master.core_mut(),
            Link::RawTcp(master) => master.core_mut(),
            Link::ModbusTcp(master) => master.core_mut(),
        }
    }

    fn late_answer_guard(&self, timeout: Duration) -> Option<Duration> {
        match self {
            Link::Serial(master) => master.late_answer_guard(timeout),
            Link::RawTcp(master) => master.late_answer_guard(timeout),
            Link::ModbusTcp(master) => master.late_answer_guard(timeout),
        }
    }

    async fn exchange(&mut self, ask: Ask<'_>) -> Result<Reply, Error> {
        match self {
            Link::Serial(master) => master.exchange(ask).await,
            Link::RawTcp(master) => master.exchange(ask).await,
            Link::ModbusTcp(master) => master.exchange(ask).await,
        }
    }
}
