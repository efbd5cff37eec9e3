//! RTU answers on a byte stream without silences (a serial device server's raw TCP socket):
//! an answer is found by its expected length (known from the request) and its CRC, not by a
//! t3.5 gap. Bytes that cannot start the answer are dropped one at a time, up to a bound, so
//! the framer resynchronises after garbage; an exception answer (5 bytes) is recognised by its
//! function code; bytes after the answer stay in the buffer (a second answer in the same
//! segment) and an answer split across segments simply waits for more bytes.
//!
//! Pure byte work, no I/O and no clock: the caller appends what it reads and gives up on its
//! own timeout.

use super::codec::{self, Answer, EXCEPTION_FRAME_LEN};
use super::crc::carried_and_computed;
use super::frame::{Request, SlaveId};

/// Default bound on the bytes dropped while looking for one answer: a whole frame's worth.
pub const DEFAULT_MAX_SKIP: usize = codec::MAX_FRAME_LEN;

/// What the buffer holds so far for the answer awaited.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Framed {
    /// No complete answer yet: read more (the buffer keeps the candidate's bytes).
    NeedMore,
    /// The answer (normal or exception), taken off the front of the buffer after `skipped`
    /// bytes of garbage.
    Answer {
        answer: Answer,
        frame: Vec<u8>,
        skipped: usize,
    },
    /// More than the bound of bytes were dropped without finding the answer: the stream is
    /// out of step (the caller fails the transaction and flushes or reconnects).
    OutOfStep { skipped: usize },
}

/// Finds the answer to `request` sent to `slave` in a stream buffer.
#[derive(Debug, Clone)]
pub struct AnswerFramer {
    slave: SlaveId,
    request: Request,
    normal_len: usize,
    max_skip: usize,
    skipped: usize,
}

/// Whether the bytes at the front of the buffer can be the answer.
enum Candidate {
    /// Not enough bytes to tell.
    Incomplete,
    /// A complete frame of this many bytes with a good CRC.
    Complete(usize),
    /// Cannot be the answer: drop the first byte.
    No,
}

impl AnswerFramer {
    pub fn new(slave: SlaveId, request: &Request) -> Self {
        Self::with_max_skip(slave, request, DEFAULT_MAX_SKIP)
    }

    pub fn with_max_skip(slave: SlaveId, request: &Request, max_skip: usize) -> Self {
        AnswerFramer {
            slave,
            request: request.clone(),
            normal_len: request.answer_len(),
            max_skip,
            skipped: 0,
        }
    }

    /// Bytes dropped so far while looking for this answer.
    pub fn skipped(&self) -> usize {
        self.skipped
    }

    /// Looks for the answer at the front of `buffer`, dropping garbage from it; on
    /// [`Framed::Answer`] the answer's bytes are removed and anything after them stays.
    pub fn poll(&mut self, buffer: &mut Vec<u8>) -> Framed {
        loop {
            match self.candidate(buffer) {
                Candidate::Incomplete => return Framed::NeedMore,
                Candidate::Complete(len) => {
                    let frame: Vec<u8> = buffer.drain(..len).collect();
                    match codec::decode_answer(self.slave, &self.request, &frame) {
                        Ok(answer) => {
                            return Framed::Answer {
                                answer,
                                frame,
                                skipped: self.skipped,
                            }
                        }
                        Err(_) => {
                            // Right length and CRC, wrong content (a write answer that does
                            // not echo the request): treat its first byte as garbage.
                            let mut rest = frame[1..].to_vec();
                            rest.extend_from_slice(buffer);
                            *buffer = rest;
                            self.skipped += 1;
                        }
                    }
                }
                Candidate::No => {
                    buffer.remove(0);
                    self.skipped += 1;
                }
            }
            if self.skipped > self.max_skip {
                return Framed::OutOfStep {
                    skipped: self.skipped,
                };
            }
        }
    }

    fn candidate(&self, buffer: &[u8]) -> Candidate {
        let Some(&address) = buffer.first() else {
            return Candidate::Incomplete;
        };
        if address != self.slave {
            return Candidate::No;
        }
        let Some(&function) = buffer.get(1) else {
            return Candidate::Incomplete;
        };
        let ours = self.request.function().value();
        let len = if function == ours | 0x80 {
            EXCEPTION_FRAME_LEN
        } else if function == ours {
            if self.request.is_read() {
                match buffer.get(2) {
                    None => return Candidate::Incomplete,
                    Some(&count) if usize::from(count) + 5 != self.normal_len => {
                        return Candidate::No
                    }
                    Some(_) => {}
                }
            }
            self.normal_len
        } else {
            return Candidate::No;
        };
        let Some(frame) = buffer.get(..len) else {
            return Candidate::Incomplete;
        };
        match carried_and_computed(frame) {
            Some((carried, computed)) if carried == computed => Candidate::Complete(len),
            _ => Candidate::No,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::{encode_answer, encode_exception};
    use crate::frame::{ExceptionCode, Response};
    use proptest::prelude::*;

    const READ_DUST: Request = Request::ReadHoldingRegisters {
        start: 0x1000,
        quantity: 6,
    };

    fn dust_words() -> Vec<u16> {
        vec![0x0003, 0x0005, 0x0002, 0x000A, 0x05DC, 0x0019]
    }

    /// The dust collector's answer to its block read, byte for byte.
    fn dust_answer() -> Vec<u8> {
        let mut frame = vec![
            0x01, 0x03, 0x0C, 0x00, 0x03, 0x00, 0x05, 0x00, 0x02, 0x00, 0x0A, 0x05, 0xDC, 0x00,
            0x19,
        ];
        crate::crc::append_crc(&mut frame);
        assert_eq!(
            frame,
            encode_answer(1, &Response::HoldingRegisters(dust_words()))
        );
        frame
    }

    fn normal(words: Vec<u16>) -> Answer {
        Answer::Normal(Response::HoldingRegisters(words))
    }

    /// The dust collector's answer, found after `skipped` bytes of garbage.
    fn dust_found(skipped: usize) -> Framed {
        Framed::Answer {
            answer: normal(dust_words()),
            frame: dust_answer(),
            skipped,
        }
    }

    #[test]
    fn whole_answer_in_one_segment() {
        let mut buffer = dust_answer();
        let mut framer = AnswerFramer::new(1, &READ_DUST);
        assert_eq!(framer.poll(&mut buffer), dust_found(0));
        assert!(buffer.is_empty());
    }

    #[test]
    fn answer_split_across_segments() {
        let answer = dust_answer();
        let mut framer = AnswerFramer::new(1, &READ_DUST);
        let mut buffer = Vec::new();
        for byte in &answer[..answer.len() - 1] {
            buffer.push(*byte);
            assert_eq!(framer.poll(&mut buffer), Framed::NeedMore);
        }
        buffer.push(answer[answer.len() - 1]);
        assert!(matches!(
            framer.poll(&mut buffer),
            Framed::Answer { skipped: 0, .. }
        ));
    }

    #[test]
    fn exception_answer_is_five_bytes() {
        let exception = encode_exception(1, 0x03, ExceptionCode::IllegalDataAddress);
        assert_eq!(exception, [0x01, 0x83, 0x02, 0xC0, 0xF1]);
        let mut buffer = exception.clone();
        buffer.extend_from_slice(&[0x01, 0x03]);
        let mut framer = AnswerFramer::new(1, &READ_DUST);
        assert_eq!(
            framer.poll(&mut buffer),
            Framed::Answer {
                answer: Answer::Exception(ExceptionCode::IllegalDataAddress),
                frame: exception,
                skipped: 0
            }
        );
        assert_eq!(buffer, [0x01, 0x03]);
    }

    #[test]
    fn two_answers_in_one_segment() {
        let read_valve = Request::ReadHoldingRegisters {
            start: 0x0000,
            quantity: 1,
        };
        let second = encode_answer(1, &Response::HoldingRegisters(vec![0x0102]));
        let mut buffer = dust_answer();
        buffer.extend_from_slice(&second);
        let mut first_framer = AnswerFramer::new(1, &READ_DUST);
        assert!(matches!(
            first_framer.poll(&mut buffer),
            Framed::Answer { skipped: 0, .. }
        ));
        assert_eq!(buffer, second);
        let mut second_framer = AnswerFramer::new(1, &read_valve);
        assert_eq!(
            second_framer.poll(&mut buffer),
            Framed::Answer {
                answer: normal(vec![0x0102]),
                frame: second,
                skipped: 0
            }
        );
    }

    #[test]
    fn garbage_before_the_answer_is_skipped() {
        // Garbage that looks like the start of our answer (address, function) and of an
        // exception, then the answer.
        let garbage = [0x01, 0x03, 0x0C, 0x55, 0x01, 0x83, 0xFF];
        let mut buffer = garbage.to_vec();
        buffer.extend_from_slice(&dust_answer());
        let mut framer = AnswerFramer::new(1, &READ_DUST);
        assert_eq!(framer.poll(&mut buffer), dust_found(garbage.len()));
    }

    #[test]
    fn endless_garbage_is_out_of_step() {
        let mut buffer = vec![0xAA; 40];
        let mut framer = AnswerFramer::with_max_skip(1, &READ_DUST, 16);
        assert_eq!(framer.poll(&mut buffer), Framed::OutOfStep { skipped: 17 });
    }

    #[test]
    fn bad_crc_is_never_an_answer() {
        let mut answer = dust_answer();
        let last = answer.len() - 1;
        answer[last] ^= 0x01;
        let mut framer = AnswerFramer::new(1, &READ_DUST);
        let mut buffer = answer;
        assert!(!matches!(framer.poll(&mut buffer), Framed::Answer { .. }));
    }

    proptest! {
        #[test]
        fn answer_found_after_any_garbage_in_any_segments(
            garbage in proptest::collection::vec(any::<u8>(), 0..64),
            cuts in proptest::collection::vec(1usize..8, 1..40),
        ) {
            let mut stream = garbage.clone();
            stream.extend_from_slice(&dust_answer());
            let mut framer = AnswerFramer::new(1, &READ_DUST);
            let mut buffer = Vec::new();
            let mut fed = 0;
            let mut found = None;
            for cut in cuts.iter().cycle() {
                let end = (fed + cut).min(stream.len());
                buffer.extend_from_slice(&stream[fed..end]);
                fed = end;
                match framer.poll(&mut buffer) {
                    Framed::NeedMore if fed < stream.len() => continue,
                    other => { found = Some(other); break; }
                }
            }
            // Garbage may by chance hold a valid answer of its own; the real one is never
            // lost or altered otherwise.
            match found {
                Some(Framed::Answer { answer, frame, skipped }) => {
                    if skipped == garbage.len() {
                        prop_assert_eq!(frame, dust_answer());
                        prop_assert_eq!(answer, normal(dust_words()));
                    } else {
                        prop_assert!(skipped < garbage.len());
                    }
                }
                other => prop_assert!(false, "no answer: {:?}", other),
            }
        }

        #[test]
        fn any_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let mut buffer = bytes;
            let _ = AnswerFramer::new(1, &READ_DUST).poll(&mut buffer);
        }
    }
}
