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
//! go, not with a wake-up per byte. Where the master knows when the device's answers begin
//! ([`Reception::expecting_first_byte_at`], learned from how its last answer came:
//! [`Reception::arrival`]), the wait for all but the last byte starts with the request.

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

/// How a complete answer's bytes came, for the master to expect the next answer of the same
/// device. Either way its first byte was due at most `first_byte_after` the request's drain
/// (the instant its last byte was seen, less the wire time of the rest).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Arrival {
    /// The latest the first byte can have come, from the request's drain.
    pub first_byte_after: Duration,
    /// The last byte came on its own, as a wire (or an adapter that passes bytes on as they
    /// come) delivers it; otherwise with others, as an adapter's latency timer hands bytes
    /// over in batches (or because a read was late), and the bound is loose.
    pub paced: bool,
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
    /// When the answer's first byte is expected, until the first read has been planned by it.
    first_byte_expected: Option<Instant>,
    /// How many bytes the last read brought.
    last_read_len: usize,
    /// How the answer came, once it is complete.
    arrival: Option<Arrival>,
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
            first_byte_expected: None,
            last_read_len: 0,
            arrival: None,
            heard: Vec::new(),
        }
    }

    /// The device's answers have begun no sooner than `first_byte_at`: instead of a wake-up on
    /// the first byte and another on the answer's head, the first read waits until all but the
    /// last byte of the answer of its expected length are due from then, and half a character
    /// more. An answer that comes sooner (an exception, a quicker device) is complete at that
    /// read and ends there; one that comes later is read as it comes.
    pub fn expecting_first_byte_at(mut self, first_byte_at: Instant) -> Self {
        if self.request.answer_len() < MAX_FRAME_LEN {
            self.first_byte_expected = Some(first_byte_at);
        }
        self
    }

    /// How the answer's bytes came, once it is complete (`None` before, and for no answer).
    pub fn arrival(&self) -> Option<Arrival> {
        self.arrival
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
                    let wire_time = self.timing.line.frame_time(length.saturating_sub(1));
                    self.arrival = Some(Arrival {
                        first_byte_after: self
                            .last_byte_at
                            .saturating_duration_since(self.timing.sent_at + wire_time),
                        paced: self.last_read_len == 1,
                    });
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
            if self.received.is_empty() {
                if let Some(first_byte_at) = self.first_byte_expected.take() {
                    // Half a character on, so that a byte handed over a little late is in and
                    // the last one, a little early, is not yet.
                    let all_but_last = self.request.answer_len().saturating_sub(2);
                    let due = first_byte_at
                        + self.timing.line.frame_time(all_but_last)
                        + self.timing.line.frame_time(1) / 2;
                    if due > now {
                        rest_due = Some(due.min(until));
                    }
                }
            }
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
        self.last_read_len = bytes.len();
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
    fn an_answer_expected_to_begin_is_first_read_when_all_but_its_last_byte_are_due() {
        let start = Instant::now();
        let char_time = reception(start).timing.line.frame_time(1);
        let frame = answer();
        let first_byte_at = start + ms(4);
        let mut reception = reception(start).expecting_first_byte_at(first_byte_at);
        // A 9-byte answer: its eighth byte is due seven characters after its first, and the
        // read half a character later.
        let Next::Read { until, rest_due } = reception.next(start) else {
            panic!("the answer is awaited");
        };
        assert_eq!(until, start + ms(300));
        let read_at = first_byte_at + char_time * 7 + char_time / 2;
        assert_eq!(rest_due, Some(read_at));
        reception.heard(&frame[..8], read_at);
        // Its last byte is listened for at once.
        let Next::Read { rest_due, .. } = reception.next(read_at) else {
            panic!("the last byte is awaited");
        };
        assert_eq!(rest_due, None);
        let last_seen = read_at + char_time / 2 + ms(1) / 10;
        reception.heard(&frame[8..], last_seen);
        let Next::Done(result) = reception.next(last_seen) else {
            panic!("complete");
        };
        assert_eq!(result, Ok(Ok(Response::HoldingRegisters(vec![7, 8]))));
        // The first byte came at most the wire time of the other eight before the last.
        assert_eq!(
            reception.arrival(),
            Some(Arrival {
                first_byte_after: last_seen - char_time * 8 - start,
                paced: true
            })
        );
    }

    #[test]
    fn an_answer_later_than_expected_is_read_as_it_comes_and_a_sooner_one_is_taken_whole() {
        let start = Instant::now();
        let char_time = reception(start).timing.line.frame_time(1);
        let frame = answer();
        let mut reception = reception(start).expecting_first_byte_at(start + ms(4));
        let planned_read = start + ms(4) + char_time * 7 + char_time / 2;
        reception.next(start);
        // Nothing had come by the planned read: the next read waits for the first byte.
        assert!(matches!(
            reception.next(planned_read),
            Next::Read { rest_due: None, until } if until == start + ms(300)
        ));
        reception.heard(&frame[..1], start + ms(20));
        let Next::Read { rest_due, .. } = reception.next(start + ms(20)) else {
            panic!("the answer is awaited");
        };
        assert_eq!(rest_due, Some(start + ms(20) + char_time * 3));

        // An exception, sooner than the 9-byte answer expected, is whole at the planned read.
        let exception = codec::encode_exception(1, 0x03, ExceptionCode::IllegalDataAddress);
        let mut reception = self::reception(start).expecting_first_byte_at(start + ms(4));
        reception.next(start);
        reception.heard(&exception, planned_read);
        let Next::Done(result) = reception.next(planned_read) else {
            panic!("complete");
        };
        assert_eq!(result, Ok(Err(ExceptionCode::IllegalDataAddress)));
        assert_eq!(
            reception.arrival(),
            Some(Arrival {
                first_byte_after: planned_read - char_time * 4 - start,
                paced: false
            })
        );
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
