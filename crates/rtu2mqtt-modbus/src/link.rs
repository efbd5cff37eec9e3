//! What a line talks through: a serial port ([`Master`]), a serial device server's raw TCP
//! stream ([`RawTcpMaster`]) or a Modbus TCP gateway ([`ModbusTcpMaster`]). The line task runs
//! the same transactions, counters and frame log on each; only this enum knows which it is.

use std::io::Write;
use std::time::Duration;

use super::frame::{Request, SlaveId};
use super::link_core::LinkCore;
use super::master::{Error, Master, Reply, WireCounters};
use super::tcp_link::{ModbusTcpMaster, RawTcpMaster};

/// One line's open link.
#[derive(Debug)]
pub enum Link {
    Serial(Master),
    RawTcp(RawTcpMaster),
    ModbusTcp(ModbusTcpMaster),
}

impl Link {
    /// One transaction: `request` to `slave` (the unit id on Modbus TCP), its answer within
    /// `timeout`.
    pub async fn transact(
        &mut self,
        slave: SlaveId,
        request: &Request,
        timeout: Duration,
    ) -> Result<Reply, Error> {
        match self {
            Link::Serial(master) => master.transact(slave, request, timeout).await,
            Link::RawTcp(master) => master.transact(slave, request, timeout).await,
            Link::ModbusTcp(master) => master.transact(slave, request, timeout).await,
        }
    }

    /// Sends `request` to every device (address 0) and keeps the line quiet for the
    /// broadcast turnaround.
    pub async fn broadcast(&mut self, request: &Request) -> Result<(), Error> {
        match self {
            Link::Serial(master) => master.broadcast(request).await,
            Link::RawTcp(master) => master.broadcast(request).await,
            Link::ModbusTcp(master) => master.broadcast(request).await,
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

    /// The link's counters, frame recorder and late-answer guard.
    pub fn core(&self) -> &LinkCore {
        match self {
            Link::Serial(master) => &master.core,
            Link::RawTcp(master) => &master.connection.core,
            Link::ModbusTcp(master) => &master.connection.core,
        }
    }

    pub fn core_mut(&mut self) -> &mut LinkCore {
        match self {
            Link::Serial(master) => &mut master.core,
            Link::RawTcp(master) => &mut master.connection.core,
            Link::ModbusTcp(master) => &mut master.connection.core,
        }
    }

    pub fn counters(&self) -> WireCounters {
        self.core().counters()
    }

    /// Writes every frame to `writer` (the frame log).
    pub fn record_frames_to(&mut self, writer: Box<dyn Write + Send>) {
        self.core_mut().record_frames_to(writer);
    }
}
