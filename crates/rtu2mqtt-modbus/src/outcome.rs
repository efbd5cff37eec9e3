//! How a transaction ends, whichever link ran it: the device's [`Reply`], or the [`Error`]
//! that kept it from being heard, and the [`WireCounters`] every link keeps of both.

use std::time::Duration;

use crate::codec::{Answer, DecodeError, EncodeError};
use crate::frame::{ExceptionCode, Response};

/// A device's word on a request: its normal answer, or the exception it answered with. Both
/// are valid answers (the device is there and has spoken); only [`Error`] means it was not
/// heard.
pub type Reply = Result<Response, ExceptionCode>;

/// Why a transaction gave no answer from the device: the transport's failures, each its own
/// variant for callers to count and match on. A device's exception answer is never one of them
/// (see [`Reply`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Error {
    /// No answer (not its first byte, or not its end) within the response timeout, which
    /// it carries. The device may be off the line, at another address or baud rate.
    #[error("no answer within {0:?}")]
    Timeout(Duration),
    /// An answer of the expected length came whose CRC does not match: a byte was corrupted
    /// on the line (noise, a missing terminator, two devices at one address).
    #[error("bad CRC")]
    Crc,
    /// The answer stopped short: a silence longer than the byte timeout (or the connection's
    /// end) came before its last byte.
    #[error("truncated answer ({got} of {needed} bytes)")]
    Truncated {
        /// Bytes the answer should have had.
        needed: usize,
        /// Bytes that came.
        got: usize,
    },
    /// From the wrong address or function, with the wrong byte count, or malformed.
    #[error("unexpected answer: {0}")]
    UnexpectedReply(DecodeError),
    /// The port failed (EOF, EIO, the adapter vanished): it must be closed and reopened.
    #[error("serial i/o: {0}")]
    PortGone(PortFault),
    /// The request cannot be framed (quantity out of the specification's range); nothing sent.
    #[error("request not sent: {0}")]
    InvalidRequest(#[from] EncodeError),
    /// Bytes kept arriving for this long without a t3.5 silence; nothing sent.
    #[error("line never went silent within {0:?}")]
    LineBusy(Duration),
    /// A network link's connection dropped while the answer was awaited (the next
    /// transaction reconnects).
    #[error("connection lost: {0}")]
    ConnectionLost(PortFault),
}

impl From<std::io::Error> for Error {
    fn from(error: std::io::Error) -> Self {
        Error::PortGone(PortFault::from(error))
    }
}

impl From<DecodeError> for Error {
    /// Why answer bytes were refused, as the transaction's failure.
    fn from(error: DecodeError) -> Self {
        match error {
            DecodeError::BadCrc { .. } => Error::Crc,
            DecodeError::Truncated { needed, got } => Error::Truncated { needed, got },
            other => Error::UnexpectedReply(other),
        }
    }
}

/// A decoded answer as the device's word on the request.
pub(crate) fn reply_of(answer: Answer) -> Reply {
    match answer {
        Answer::Normal(response) => Ok(response),
        Answer::Exception(code) => Err(code),
    }
}

/// An I/O failure of the serial port, kept as its kind and the system's words for it (so that
/// outcomes that carry it can be compared and cloned).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct PortFault {
    /// What kind of failure the system reported (`UnexpectedEof` for a port that closed).
    pub kind: std::io::ErrorKind,
    message: String,
}

impl From<std::io::Error> for PortFault {
    fn from(error: std::io::Error) -> Self {
        PortFault {
            kind: error.kind(),
            message: error.to_string(),
        }
    }
}

/// Wire-level counters kept by every link since it was opened; each only grows. A line that
/// reopens its link adds the old link's counters to the new one's (`+`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WireCounters {
    /// Requests sent, broadcasts included.
    pub requests: u64,
    /// Transactions that ended in [`Error::Timeout`].
    pub timeouts: u64,
    /// Transactions that ended in [`Error::Crc`].
    pub crc_errors: u64,
    /// Transactions that ended in [`Error::Truncated`] or [`Error::ConnectionLost`].
    pub truncated: u64,
    /// Transactions that ended in [`Error::UnexpectedReply`].
    pub unexpected: u64,
    /// Exception answers: the device answered, with an [`ExceptionCode`].
    pub exceptions: u64,
    /// Answers (or parts) that arrived after their request's timeout.
    pub late_answers: u64,
    /// Bytes found on the line outside any frame: before a request was sent, or as noise just
    /// before an answer.
    pub stray_bytes: u64,
    /// Frames from another address heard while waiting for an answer (ignored, as the
    /// serial-line specification says).
    pub wrong_address: u64,
    /// Silences longer than t1.5 inside an answer, tolerated up to the byte timeout (an
    /// adapter's latency timer, a device pausing mid-answer).
    pub long_gaps: u64,
    /// Wire time of all frames sent and received plus the mandatory silences, for bus load.
    pub wire_time: Duration,
}

impl WireCounters {
    /// Counts how one transaction ended (every link counts the same way).
    pub(crate) fn count(&mut self, result: &Result<Reply, Error>) {
        match result {
            Ok(Ok(_)) => {}
            Ok(Err(_)) => self.exceptions += 1,
            Err(Error::Timeout(_)) => self.timeouts += 1,
            Err(Error::Crc) => self.crc_errors += 1,
            // A connection lost mid-answer is an answer cut short.
            Err(Error::Truncated { .. } | Error::ConnectionLost(_)) => self.truncated += 1,
            Err(Error::UnexpectedReply(_)) => self.unexpected += 1,
            Err(Error::PortGone(_) | Error::InvalidRequest(_) | Error::LineBusy(_)) => {}
        }
    }
}

impl std::ops::AddAssign for WireCounters {
    /// Adds another master's counters: a line sums the masters of every port it opened.
    fn add_assign(&mut self, other: WireCounters) {
        let WireCounters {
            requests,
            timeouts,
            crc_errors,
            truncated,
            unexpected,
            exceptions,
            late_answers,
            stray_bytes,
            wrong_address,
            long_gaps,
            wire_time,
        } = other;
        self.requests += requests;
        self.timeouts += timeouts;
        self.crc_errors += crc_errors;
        self.truncated += truncated;
        self.unexpected += unexpected;
        self.exceptions += exceptions;
        self.late_answers += late_answers;
        self.stray_bytes += stray_bytes;
        self.wrong_address += wrong_address;
        self.long_gaps += long_gaps;
        self.wire_time += wire_time;
    }
}

impl std::ops::Add for WireCounters {
    type Output = WireCounters;

    fn add(mut self, other: WireCounters) -> WireCounters {
        self += other;
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counters_add_field_by_field() {
        let one = WireCounters {
            requests: 3,
            timeouts: 1,
            crc_errors: 2,
            truncated: 1,
            unexpected: 4,
            exceptions: 1,
            late_answers: 2,
            stray_bytes: 7,
            wrong_address: 1,
            long_gaps: 3,
            wire_time: Duration::from_millis(5),
        };
        let sum = one + one;
        assert_eq!(
            sum,
            WireCounters {
                requests: 6,
                timeouts: 2,
                crc_errors: 4,
                truncated: 2,
                unexpected: 8,
                exceptions: 2,
                late_answers: 4,
                stray_bytes: 14,
                wrong_address: 2,
                long_gaps: 6,
                wire_time: Duration::from_millis(10),
            }
        );
        assert_eq!(WireCounters::default() + one, one);
    }
}
