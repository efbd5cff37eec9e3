//! One Modbus RTU transaction at a time on a [`Port`], with exact timing: the line is driven
//! no sooner than t3.5 after the last byte seen on it (measured from when the transmit buffer
//! drained), stray bytes are flushed and counted before a request, answers are framed by
//! expected length with an inter-character gap limit and a response timeout, and an answer
//! arriving after its timeout is discarded and counted, never taken for the next request's.

use std::time::Duration;

use super::codec::DecodeError;
use super::frame::{ExceptionCode, Request, Response, SlaveId};
use super::timing::LineTiming;
use super::transport::Port;

/// Why a transaction gave no normal answer.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("no answer within {0:?}")]
    Timeout(Duration),
    #[error("bad CRC")]
    Crc,
    #[error("truncated answer ({got} of {needed} bytes)")]
    Truncated { needed: usize, got: usize },
    #[error("unexpected answer: {0}")]
    UnexpectedReply(DecodeError),
    #[error("device answered {0}")]
    Exception(ExceptionCode),
    #[error("serial i/o: {0}")]
    Io(#[from] std::io::Error),
}

/// Per-line behaviour of the master.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MasterOptions {
    /// The adapter echoes what it sends (2-wire adapters): strip the echo before the answer.
    pub echo: bool,
    /// Silence after a broadcast before the line is driven again.
    pub broadcast_turnaround: Duration,
}

/// Wire-level counters kept by the master (monotonic).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WireCounters {
    pub requests: u64,
    pub timeouts: u64,
    pub crc_errors: u64,
    pub truncated: u64,
    pub unexpected: u64,
    pub exceptions: u64,
    /// Answers (or parts) that arrived after their request's timeout.
    pub late_answers: u64,
    /// Bytes found on the line before a request was sent.
    pub stray_bytes: u64,
    /// Wire time of all frames sent and received plus the mandatory silences, for bus load.
    pub wire_time: Duration,
}

pub struct Master {}

impl Master {
    pub fn new(port: Port, timing: LineTiming, options: MasterOptions) -> Self {
        todo!("rtu helper")
    }

    /// Sends `request` to `slave` and waits for its answer.
    pub async fn transact(
        &mut self,
        slave: SlaveId,
        request: &Request,
        timeout: Duration,
    ) -> Result<Response, Error> {
        todo!("rtu helper")
    }

    /// Sends `request` to address 0 without waiting for an answer, then keeps the line silent
    /// for the turnaround delay.
    pub async fn broadcast(&mut self, request: &Request) -> Result<(), Error> {
        todo!("rtu helper")
    }

    pub fn counters(&self) -> WireCounters {
        todo!("rtu helper")
    }

    pub fn timing(&self) -> LineTiming {
        todo!("rtu helper")
    }
}
