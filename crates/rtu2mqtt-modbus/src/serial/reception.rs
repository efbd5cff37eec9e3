//! The reception of one answer on a serial line, without I/O and without a clock: the serial
//! [`Master`](super::master::Master) hands it the bytes its port read (with the instant they
//! were seen) and the silences, and it says when to read next ([`Next`]) and what became of
//! the bytes ([`Heard`]: noise, another device's frame, an adapter's echo, the answer).
//!
//! The rules: the response timeout runs from the request's drain until the answer's first
//! byte; once bytes have come, a silence longer than the byte timeout ends what is there (a
//! pause inside an answer up to it is tolerated, and one longer than t1.5 is counted as a long
//! gap); the answer is complete at its expected length (from the request, 5 bytes for an
//! exception), framed by [`AnswerFramer`]; once it has begun, the wire time of the shortest
//! length it can still have (an exception's, until its length is known) is waited for in one
//! go, not with a wake-up per byte.

use std::time::Duration;

use tokio::time::Instant;

use crate::answer_framing::{AnswerFramer, Framing};
use crate::codec::{self, EXCEPTION_FRAME_LEN, MAX_FRAME_LEN};
use crate::frame::{Request, SlaveId};
use crate::outcome::{reply_of, Error, Reply};
use crate::timing::LineTiming;

/// When the answer to a request is due and how long a pause inside it may be.
#[derive(Debug, Clone, Copy)]
pub struct AnswerTiming {
    /// When the request's last byte left the port.
    pub sent_at: Instant,
    /// From `sent_at` until the answer's first byte.
    pub timeout: Duration,
    /// The longest silence between two bytes of the answer.
    pub byte_timeout: Duration,
    /// The line's character timing (wire time of the answer's rest, t1.5).
    pub line: LineTiming,
}

/// What the reception asks of its port next.
#[derive(Debug)]
pub enum Next {
    /// Read, waiting until `until` for bytes; when `rest_due` is set, first wait until then
    /// without listening: the rest of an answer of known length cannot have come sooner.
    Read {
        /// When to give up waiting and report the silence ([`Reception::silence`]).
        until: Instant,
        /// The wire time of the answer's rest, when it is still to come.
        rest_due: Option<Instant>,
    },
    /// The transaction's end: the answer, or why there is none.
    Done(Result<Reply, Error>),
}

/// What became of bytes received, in the order it happened: for the master's counters, log
/// and frame recorder. Every byte heard ends up in exactly one of them (or in the answer).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Heard {
    /// Our request as echoed by an adapter not announced as echoing, stripped.
    Echo(Vec<u8>),
    /// Bytes before our answer's head that belong to no frame, seen at `seen`.
    Noise {
        /// The bytes dropped.
        bytes: Vec<u8>,
        /// When the last of them was seen.
        seen: Instant,
    },
    /// A whole frame (length and CRC check) from another address, ignored.
    Foreign(Vec<u8>),
    /// Bytes for another address that never made a whole frame, ended by a silence or by
    /// their number.
    Unframed {
        /// The bytes dropped.
        bytes: Vec<u8>,
        /// When the last of them was seen.
        seen: Instant,
    },
    /// The frame taken as the answer (decoded, or refused by the decoder).
    Frame(Vec<u8>),
    /// Bytes behind the complete answer.
    Trailing {
        /// The bytes dropped.
        bytes: Vec<u8>,
        /// When they were seen.
        seen: Instant,
    },
    /// A pause longer than t1.5 inside the bytes of the answer.
    LongGap,
}

/// The reception of the answer to one request sent to one device.
#[derive(Debug)]
pub struct Reception {
    slave: SlaveId,
    request: Request,
    framer: AnswerFramer,
    timing: AnswerTiming,
    deadline: Instant,
    received: Vec<u8>,
    last_byte_at: Instant,
    /// The length up to which the answer has had its wait for its wire time (0: none yet).
    waited_for: usize,
    /// Where `received` stood when the last read was asked for.
    framing: Framing,
    heard: Vec<Heard>,
}

impl Reception {
    /// The reception of the answer to `request`, sent to `slave` as `sent`. Unless the adapter
    /// is announced as echoing (`echo_announced`: the master strips its echo first), an echo
    /// of `sent` is recognised and stripped.
    pub fn new(
        slave: SlaveId,
        request: &Request,
        sent: &[u8],
        echo_announced: bool,
        timing: AnswerTiming,
    ) -> Self {
        Reception {
            slave,
            request: request.clone(),
            framer: AnswerFramer::on_serial_line(slave, request, sent, echo_announced),
            deadline: timing.sent_at + timing.timeout,
            timing,
            received: Vec::new(),
            last_byte_at: timing.sent_at,
            waited_for: 0,
            framing: Framing::NeedMore {
                needed: request.answer_len(),
            },
            heard: Vec::new(),
        }
    }

    /// What became of the bytes since this was last asked, oldest first.
    pub fn take_heard(&mut self) -> std::vec::Drain<'_, Heard> {
        self.heard.drain(..)
    }

    /// Frames what has been received, at `now`: the end of the transaction, or the next read.
    pub fn next(&mut self, now: Instant) -> Next {
        loop {
            let framing = self.framer.frame(&self.received);
            match framing {
                Framing::Echo(length) => {
                    let echo = self.received.drain(..length).collect();
                    self.heard.push(Heard::Echo(echo));
                    continue;
                }
                Framing::Noise(length) => {
                    let rest = self.received.split_off(length);
                    let bytes = std::mem::replace(&mut self.received, rest);
                    let seen = self.last_byte_at;
                    self.heard.push(Heard::Noise { bytes, seen });
                    continue;
                }
                // Another device's frame whose length and CRC check out ends here; whatever
                // follows may be our answer.
                Framing::Foreign {
                    frame_len: Some(length),
                } => {
                    let rest = self.received.split_off(length);
                    let frame = std::mem::replace(&mut self.received, rest);
                    self.heard.push(Heard::Foreign(frame));
                    continue;
                }
                // No frame is longer: a line that babbles without a gap is dropped in pieces,
                // and the response timeout still ends the wait.
                Framing::Foreign { frame_len: None } if self.received.len() >= MAX_FRAME_LEN => {
                    self.drop_unframed();
                    if now >= self.deadline {
                        return Next::Done(Err(Error::Timeout(self.timing.timeout)));
                    }
                    continue;
                }
                Framing::Complete(length) => {
                    let trailing = self.received.split_off(length);
                    self.heard.push(Heard::Frame(self.received.clone()));
                    if !trailing.is_empty() {
                        self.heard.push(Heard::Trailing {
                            bytes: trailing,
                            seen: self.last_byte_at,
                        });
                    }
                    return Next::Done(self.decode());
                }
                _ => {}
            }
            self.framing = framing;
            let until = if self.received.is_empty() {
                self.deadline
            } else {
                self.last_byte_at + self.timing.byte_timeout
            };
            // Once the answer has begun, it cannot be complete before the wire time of its
            // shortest possible length: that is waited for in one go, not with a wake-up per
            // byte (a rest longer than the byte timeout in steps of it, each from the bytes
            // that came in the one before, so that a silence inside it is still noticed at the
            // limit). Until its function code and byte count are in, the answer may yet be an
            // exception, the shortest there is; from the third byte on its length is known.
            // Only until the wire time of all but its last byte: that byte's own arrival wakes
            // the read, so that the answer ends, and t3.5 starts, when it came. Waking at the
            // whole rest's wire time would start t3.5 late by the wake-up's own lag and by
            // the lag with which the byte the wait is counted from was seen.
            let soonest_end = match framing {
                Framing::NeedMore { needed } if self.received.len() < 3 => {
                    Some(needed.min(EXCEPTION_FRAME_LEN))
                }
                Framing::EchoCandidate if self.received.len() < 3 => Some(EXCEPTION_FRAME_LEN),
                Framing::NeedMore { needed } => Some(needed),
                _ => None,
            };
            let mut rest_due = None;
            if let Some(soonest_end) = soonest_end {
                if !self.received.is_empty() && self.waited_for < soonest_end {
                    let remaining = soonest_end.saturating_sub(self.received.len());
                    let due = self.last_byte_at
                        + self.timing.line.frame_time(remaining.saturating_sub(1));
                    if due <= until {
                        self.waited_for = soonest_end;
                    }
                    if due > now {
                        rest_due = Some(due.min(until));
                    }
                }
            }
            return Next::Read { until, rest_due };
        }
    }

    /// `bytes` were read, seen at `seen`.
    pub fn heard(&mut self, bytes: &[u8], seen: Instant) {
        // These bytes took their wire time to arrive; anything beyond it plus t1.5 was a
        // silence inside the answer.
        if !self.received.is_empty()
            && seen.duration_since(self.last_byte_at)
                > self.timing.line.frame_time(bytes.len()) + self.timing.line.t1_5
        {
            self.heard.push(Heard::LongGap);
        }
        self.received.extend_from_slice(bytes);
        self.last_byte_at = seen;
    }

    /// Nothing came until the read's `until`, now `now`: the transaction's end, or `None`
    /// when the answer is still awaited (a foreign frame's bytes were dropped before the
    /// response timeout).
    pub fn silence(&mut self, now: Instant) -> Option<Result<Reply, Error>> {
        if self.received.is_empty() {
            return Some(Err(Error::Timeout(self.timing.timeout)));
        }
        if let Framing::Foreign { .. } = self.framing {
            self.drop_unframed();
            return (now >= self.deadline).then_some(Err(Error::Timeout(self.timing.timeout)));
        }
        // A short answer that happened to match the start of our request, a frame cut short,
        // or one of unknown length: decode what there is.
        self.heard.push(Heard::Frame(self.received.clone()));
        let needed = match self.framing {
            Framing::NeedMore { needed } => needed,
            _ => self.received.len(),
        };
        if self.received.len() < needed {
            return Some(Err(Error::Truncated {
                needed,
                got: self.received.len(),
            }));
        }
        Some(self.decode())
    }

    fn drop_unframed(&mut self) {
        let bytes = std::mem::take(&mut self.received);
        let seen = self.last_byte_at;
        self.heard.push(Heard::Unframed { bytes, seen });
    }

    fn decode(&self) -> Result<Reply, Error> {
        codec::decode_answer(self.slave, &self.request, &self.received)
            .map(reply_of)
            .map_err(Error::from)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::encode_answer;
    use crate::frame::{ExceptionCode, Response};
    use crate::timing::{CharFormat, Parity};

    const READ: Request = Request::ReadHoldingRegisters {
        start: 0x1000,
        quantity: 2,
    };

    fn reception(start: Instant) -> Reception {
        let sent = codec::encode_request(1, &READ).unwrap();
        let timing = AnswerTiming {
            sent_at: start,
            timeout: Duration::from_millis(300),
            byte_timeout: Duration::from_millis(32),
            line: LineTiming::new(
                9600,
                CharFormat {
                    data_bits: 8,
                    parity: Parity::None,
                    stop_bits: 1,
                },
            ),
        };
        Reception::new(1, &READ, &sent, false, timing)
    }

    fn answer() -> Vec<u8> {
        encode_answer(1, &Response::HoldingRegisters(vec![7, 8]))
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    #[test]
    fn an_answer_with_a_pause_inside_the_byte_timeout_is_taken() {
        let start = Instant::now();
        let mut reception = reception(start);
        let frame = answer();
        assert!(
            matches!(reception.next(start), Next::Read { until, rest_due: None } if until == start + ms(300))
        );
        reception.heard(&frame[..3], start + ms(20));
        // The rest's wire time is waited for in one go.
        let Next::Read { until, rest_due } = reception.next(start + ms(20)) else {
            panic!("the rest is awaited");
        };
        assert_eq!(until, start + ms(52));
        assert!(rest_due.is_some());
        reception.heard(&frame[3..], start + ms(50));
        let Next::Done(result) = reception.next(start + ms(50)) else {
            panic!("complete");
        };
        assert_eq!(result, Ok(Ok(Response::HoldingRegisters(vec![7, 8]))));
        let heard: Vec<Heard> = reception.take_heard().collect();
        assert_eq!(heard, [Heard::LongGap, Heard::Frame(frame)]);
    }

    #[test]
    fn from_the_first_byte_on_the_shortest_answer_still_possible_is_waited_for_in_one_go() {
        let start = Instant::now();
        let char_time = reception(start).timing.line.frame_time(1);
        let frame = answer();
        let mut reception = reception(start);
        reception.next(start);
        reception.heard(&frame[..1], start + ms(10));
        // The function code and byte count are not in: it may yet be a 5-byte exception,
        // whose first four bytes are due three characters after the first.
        let Next::Read { rest_due, .. } = reception.next(start + ms(10)) else {
            panic!("the answer is awaited");
        };
        assert_eq!(rest_due, Some(start + ms(10) + char_time * 3));
        let head_seen = start + ms(10) + char_time * 3;
        reception.heard(&frame[1..4], head_seen);
        // Now it is a 9-byte answer: all but its last byte are due four characters on.
        let Next::Read { rest_due, .. } = reception.next(head_seen) else {
            panic!("the rest is awaited");
        };
        assert_eq!(rest_due, Some(head_seen + char_time * 4));

        let exception = codec::encode_exception(1, 0x03, ExceptionCode::IllegalDataAddress);
        let mut reception = self::reception(start);
        reception.next(start);
        reception.heard(&exception[..1], start + ms(10));
        reception.next(start + ms(10));
        reception.heard(&exception[1..4], head_seen);
        // An exception's last byte is listened for at once.
        let Next::Read { rest_due, .. } = reception.next(head_seen) else {
            panic!("the last byte is awaited");
        };
        assert_eq!(rest_due, None);
        reception.heard(&exception[4..], head_seen + char_time);
        let Next::Done(result) = reception.next(head_seen + char_time) else {
            panic!("complete");
        };
        assert_eq!(result, Ok(Err(ExceptionCode::IllegalDataAddress)));
    }

    #[test]
    fn a_pause_beyond_the_byte_timeout_truncates_the_answer() {
        let start = Instant::now();
        let mut reception = reception(start);
        let frame = answer();
        reception.next(start);
        reception.heard(&frame[..5], start + ms(10));
        let Next::Read { until, .. } = reception.next(start + ms(10)) else {
            panic!("the rest is awaited");
        };
        assert_eq!(
            reception.silence(until),
            Some(Err(Error::Truncated { needed: 9, got: 5 }))
        );
    }

    #[test]
    fn another_devices_frame_and_noise_before_the_answer_are_dropped() {
        let start = Instant::now();
        let mut reception = reception(start);
        let foreign = encode_answer(2, &Response::HoldingRegisters(vec![1]));
        let mut bytes = foreign.clone();
        bytes.extend_from_slice(&[0x00, 0xFF]);
        bytes.extend_from_slice(&answer());
        reception.next(start);
        reception.heard(&bytes, start + ms(30));
        let Next::Done(result) = reception.next(start + ms(30)) else {
            panic!("complete");
        };
        assert_eq!(result, Ok(Ok(Response::HoldingRegisters(vec![7, 8]))));
        let heard: Vec<Heard> = reception.take_heard().collect();
        assert_eq!(
            heard,
            [
                Heard::Foreign(foreign),
                Heard::Noise {
                    bytes: vec![0x00, 0xFF],
                    seen: start + ms(30)
                },
                Heard::Frame(answer()),
            ]
        );
    }

    #[test]
    fn silence_before_any_byte_is_a_timeout() {
        let start = Instant::now();
        let mut reception = reception(start);
        let Next::Read { until, .. } = reception.next(start) else {
            panic!("the answer is awaited");
        };
        assert_eq!(reception.silence(until), Some(Err(Error::Timeout(ms(300)))));
    }
}
