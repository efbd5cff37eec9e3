//! The one answer framer of every link: where the bytes received so far stand as the answer to
//! a request. Complete (and how long), needing more (how many in all), another device's frame
//! (and, once whole with a good CRC, how long), noise to drop before the answer, or an
//! adapter's echo of the request. The expected length comes from the request (the byte count
//! for reads, 5 bytes for an exception), or for Read Device Identification from the answer's
//! own bytes (its number of objects and their lengths, as they arrive).
//!
//! Pure byte work, no I/O and no clock: the serial master decides *when* to read and asks
//! `AnswerFramer::frame` *what* the bytes are after every read; a raw RTU stream without
//! silences (a serial device server's TCP socket) uses [`AnswerFramer::poll`], which drops
//! what cannot be the answer, up to a bound, and leaves the bytes behind the answer in the
//! buffer; a Modbus TCP link checks the RTU frame of an MBAP-framed answer with `frame`.

use crate::codec::{self, Answer, EXCEPTION_FRAME_LEN, MAX_FRAME_LEN};
use crate::crc::carried_and_computed;
use crate::device_id;
use crate::frame::{FunctionCode, Request, SlaveId};

/// Default bound on the bytes [`AnswerFramer::poll`] drops while looking for one answer: a
/// whole frame's worth.
pub(crate) const DEFAULT_MAX_SKIP: usize = MAX_FRAME_LEN;

/// Where the bytes received so far stand, as [`AnswerFramer::frame`] sees them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Framing {
    /// Not enough bytes to tell: `needed` in all are expected (a line gives up at its gap
    /// limit).
    NeedMore { needed: usize },
    /// An answer of this many bytes is complete at the start (its content is not checked).
    Complete(usize),
    /// A frame for another device. `frame_len`: its length once it is whole with a good CRC
    /// (what follows it may be ours); `None`: read it to its end (a gap), then drop it.
    Foreign { frame_len: Option<usize> },
    /// This many bytes at the start are noise before the head of our answer.
    Noise(usize),
    /// Our request, echoed by an adapter not announced as echoing, is this long at the start.
    Echo(usize),
    /// The bytes so far repeat the start of our request: possibly its echo.
    EchoCandidate,
    /// Our address with a function code that is neither ours nor our exception: read to a gap,
    /// then reject.
    UnknownLength,
}

/// What [`AnswerFramer::poll`] found in a stream buffer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Framed {
    /// No complete answer yet: read more (the buffer keeps the candidate's bytes).
    NeedMore,
    /// The answer (normal or exception), taken off the front of the buffer after `skipped`
    /// bytes of garbage.
    Answer {
        /// The decoded answer, checked against the request.
        answer: Answer,
        /// Its RTU frame as received, CRC included (for the frame log).
        frame: Vec<u8>,
        /// Bytes dropped before it.
        skipped: usize,
    },
    /// More than the bound of bytes were dropped without finding the answer: the stream is
    /// out of step (the caller fails the transaction and flushes or reconnects).
    OutOfStep {
        /// Bytes dropped, more than the framer's bound.
        skipped: usize,
    },
}

/// Frames the answer to one request sent to one device.
#[derive(Debug, Clone)]
pub struct AnswerFramer {
    slave: SlaveId,
    request: Request,
    /// Our request as sent, while an unannounced echo of it is watched for.
    echo_watch: Option<Vec<u8>>,
    max_skip: usize,
    skipped: usize,
}

impl AnswerFramer {
    /// The framer of the answer to `request` sent to `slave`, on a link that never echoes.
    pub fn new(slave: SlaveId, request: &Request) -> Self {
        Self::with_max_skip(slave, request, DEFAULT_MAX_SKIP)
    }

    /// As [`AnswerFramer::new`], dropping at most `max_skip` bytes in [`AnswerFramer::poll`].
    pub(crate) fn with_max_skip(slave: SlaveId, request: &Request, max_skip: usize) -> Self {
        AnswerFramer {
            slave,
            request: request.clone(),
            echo_watch: None,
            max_skip,
            skipped: 0,
        }
    }

    /// The framer on a serial line that sent `request` to `slave` as `sent`. Unless the
    /// adapter is known to echo (`echo_announced`: its echo is stripped before framing), an
    /// echo of `sent` is recognised; single writes excepted, whose answer is a copy of the
    /// request.
    pub(crate) fn on_serial_line(
        slave: SlaveId,
        request: &Request,
        sent: &[u8],
        echo_announced: bool,
    ) -> Self {
        let answer_may_equal_request = matches!(
            request.function(),
            FunctionCode::WriteSingleCoil | FunctionCode::WriteSingleRegister
        );
        let mut framer = Self::new(slave, request);
        if !echo_announced && !answer_may_equal_request {
            framer.echo_watch = Some(sent.to_vec());
        }
        framer
    }

    /// Bytes dropped so far by [`AnswerFramer::poll`].
    pub(crate) fn skipped(&self) -> usize {
        self.skipped
    }

    /// Where `received` stands as our answer; what to do next is the caller's (drop the
    /// echo, the noise or the foreign frame and ask again, or wait for more).
    pub(crate) fn frame(&self, received: &[u8]) -> Framing {
        if let Some(sent) = &self.echo_watch {
            if received.starts_with(sent) {
                return Framing::Echo(sent.len());
            }
        }
        if let Some(noise) = noise_before_answer(self.slave, self.request.function(), received) {
            return Framing::Noise(noise);
        }
        match self.head(received) {
            Framing::Foreign { .. } => Framing::Foreign {
                frame_len: complete_foreign_frame(received),
            },
            framing => framing,
        }
    }

    /// Looks for the answer at the front of `buffer`, a stream without silences, dropping
    /// what cannot start it (another device's frame byte by byte, so that no answer hidden
    /// behind a false frame is lost); on [`Framed::Answer`] the answer's bytes are removed
    /// and anything after them stays.
    pub fn poll(&mut self, buffer: &mut Vec<u8>) -> Framed {
        loop {
            let drop = match self.frame(buffer) {
                Framing::NeedMore { .. } if !self.claims_other_length(buffer) => {
                    return Framed::NeedMore
                }
                Framing::Complete(len) if !self.claims_other_length(buffer) => {
                    match codec::decode_answer(self.slave, &self.request, &buffer[..len]) {
                        Ok(answer) => {
                            return Framed::Answer {
                                answer,
                                frame: buffer.drain(..len).collect(),
                                skipped: self.skipped,
                            }
                        }
                        // Right length, wrong CRC or content (a write answer that does not
                        // repeat the request): its first byte is garbage.
                        Err(_) => 1,
                    }
                }
                Framing::Noise(len) => len,
                _ => 1,
            };
            buffer.drain(..drop);
            self.skipped += drop;
            if self.skipped > self.max_skip {
                return Framed::OutOfStep {
                    skipped: self.skipped,
                };
            }
        }
    }

    /// A normal answer to our read whose byte count is not the one the request asked for: on
    /// a stream it cannot be the answer (a serial line frames it by the count it claims and
    /// lets the decoder refuse it).
    fn claims_other_length(&self, received: &[u8]) -> bool {
        self.request.is_read()
            && received.get(1) == Some(&self.request.function().value())
            && received
                .get(2)
                .is_some_and(|&count| 5 + usize::from(count) != self.request.answer_len())
    }

    /// How far `received` goes towards our answer, judged by its address and function code.
    fn head(&self, received: &[u8]) -> Framing {
        let slave = self.slave;
        let request = &self.request;
        let function = request.function();
        let (Some(&address), Some(&found_function)) = (received.first(), received.get(1)) else {
            return match received.first() {
                Some(&address) if address != slave => Framing::Foreign { frame_len: None },
                _ => Framing::NeedMore {
                    needed: request.answer_len(),
                },
            };
        };
        if address != slave {
            return Framing::Foreign { frame_len: None };
        }
        if let Some(sent) = &self.echo_watch {
            if received.len() < sent.len() && sent.starts_with(received) {
                return Framing::EchoCandidate;
            }
        }
        let needed = if found_function == function.value() | 0x80 {
            EXCEPTION_FRAME_LEN
        } else if found_function == function.value() {
            if function == FunctionCode::EncapsulatedInterface {
                // Framed by the lengths its bytes give so far; bytes that cannot be such an
                // answer are read to a gap and rejected.
                match device_id_frame_len(received) {
                    Some(needed) => needed,
                    None => return Framing::UnknownLength,
                }
            } else if request.is_read() {
                match received.get(2) {
                    // Framed by the byte count the device claims; the decoder checks it.
                    Some(&count) => 5 + usize::from(count),
                    None => {
                        return Framing::NeedMore {
                            needed: request.answer_len(),
                        }
                    }
                }
            } else {
                request.answer_len()
            }
        } else {
            return if received.len() >= MAX_FRAME_LEN {
                Framing::Complete(MAX_FRAME_LEN)
            } else {
                Framing::UnknownLength
            };
        };
        if received.len() >= needed {
            Framing::Complete(needed)
        } else {
            Framing::NeedMore { needed }
        }
    }
}

/// The length of the Read Device Identification answer frame at the start of `received`
/// (address, PDU, CRC) as far as its bytes tell; `None` when they cannot be one.
fn device_id_frame_len(received: &[u8]) -> Option<usize> {
    let pdu = received.get(1..)?;
    device_id::answer_pdu_len(pdu).ok().map(|len| 1 + len + 2)
}

/// The length of the answer frame at the start of `received` when its function code gives the
/// length, all of it has arrived and its CRC is right (`None` otherwise).
fn complete_foreign_frame(received: &[u8]) -> Option<usize> {
    let function = *received.get(1)?;
    let length = if function & 0x80 != 0 {
        EXCEPTION_FRAME_LEN
    } else {
        match FunctionCode::from_u8(function)? {
            FunctionCode::ReadCoils
            | FunctionCode::ReadDiscreteInputs
            | FunctionCode::ReadHoldingRegisters
            | FunctionCode::ReadInputRegisters => 5 + usize::from(*received.get(2)?),
            FunctionCode::EncapsulatedInterface => device_id_frame_len(received)?,
            _ => 8,
        }
    };
    let frame = received.get(..length)?;
    let (carried, computed) = carried_and_computed(frame)?;
    (carried == computed).then_some(length)
}

/// How many bytes at the start of `received` are noise before our answer: the head is neither
/// our answer's (our address, our function or its exception) nor another device's frame
/// (a known function code), and our answer's head starts further on. `None`: nothing to skip
/// (yet).
fn noise_before_answer(slave: SlaveId, function: FunctionCode, received: &[u8]) -> Option<usize> {
    let ours = |code: u8| code == function.value() || code == function.value() | 0x80;
    let known = |code: u8| FunctionCode::from_u8(code & 0x7F).is_some();
    let head_function = *received.get(1)?;
    let plausible_head = if received[0] == slave {
        ours(head_function)
    } else {
        known(head_function)
    };
    if plausible_head {
        return None;
    }
    (1..received.len()).find(|&start| {
        received[start] == slave && received.get(start + 1).map_or(true, |&code| ours(code))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::{encode_answer, encode_exception};
    use crate::frame::{ExceptionCode, Response};
    use proptest::prelude::*;

    fn answer(slave: SlaveId, words: &[u16]) -> Vec<u8> {
        codec::encode_answer(slave, &Response::HoldingRegisters(words.to_vec()))
    }

    #[test]
    fn noise_is_found_only_before_our_answer_head() {
        let ours = answer(0x11, &[1, 2]);
        let read = FunctionCode::ReadHoldingRegisters;
        assert_eq!(noise_before_answer(0x11, read, &ours), None);
        let mut noisy = vec![0x00, 0xFF];
        noisy.extend_from_slice(&ours);
        assert_eq!(noise_before_answer(0x11, read, &noisy), Some(2));
        // Another device's frame is not noise: it is read to its end.
        let foreign = answer(0x22, &[1, 2]);
        assert_eq!(noise_before_answer(0x11, read, &foreign), None);
        // Our address with a wrong function and no answer head behind it: not skipped.
        assert_eq!(
            noise_before_answer(0x11, read, &[0x11, 0x04, 0x04, 0x00]),
            None
        );
        // Too little to tell.
        assert_eq!(noise_before_answer(0x11, read, &[0x00]), None);
    }

    #[test]
    fn foreign_frame_is_complete_only_with_its_length_and_crc() {
        let foreign = answer(0x22, &[7, 8]);
        assert_eq!(complete_foreign_frame(&foreign[..foreign.len() - 1]), None);
        let mut followed = foreign.clone();
        followed.extend_from_slice(&answer(0x11, &[1, 2]));
        assert_eq!(complete_foreign_frame(&followed), Some(foreign.len()));
        let mut corrupted = foreign.clone();
        corrupted[3] ^= 0x01;
        assert_eq!(complete_foreign_frame(&corrupted), None);
        let exception = codec::encode_exception(0x22, 0x03, ExceptionCode::IllegalDataAddress);
        assert_eq!(complete_foreign_frame(&exception), Some(5));
    }

    proptest! {
        /// Every prefix of our answer needs more, up to the answer's length (or may still be
        /// our request's echo); the whole answer, with anything behind it, is complete at
        /// exactly its length, with no noise skipped before it.
        #[test]
        fn our_answer_is_complete_exactly_at_its_end(
            slave in 1u8..=247,
            words in proptest::collection::vec(any::<u16>(), 1..=125),
            trailing in proptest::collection::vec(any::<u8>(), 0..8),
        ) {
            let request = Request::ReadHoldingRegisters { start: 0, quantity: words.len() as u16 };
            let sent = codec::encode_request(slave, &request).unwrap();
            let whole = answer(slave, &words);
            for end in 0..whole.len() {
                let prefix = &whole[..end];
                match AnswerFramer::on_serial_line(slave, &request, &sent, false).frame(prefix) {
                    Framing::NeedMore { needed } => prop_assert_eq!(needed, whole.len()),
                    // Our address and function are also how our request starts.
                    Framing::EchoCandidate => prop_assert!(sent.starts_with(prefix)),
                    other => prop_assert!(false, "prefix of {} bytes: {:?}", end, other),
                }
            }
            let mut followed = whole.clone();
            followed.extend_from_slice(&trailing);
            prop_assert_eq!(
                AnswerFramer::on_serial_line(slave, &request, &sent, false).frame(&followed),
                Framing::Complete(whole.len())
            );
            prop_assert_eq!(noise_before_answer(slave, request.function(), &followed), None);
        }

        /// An exception answer is complete at five bytes, whatever the request read.
        #[test]
        fn an_exception_is_complete_at_five_bytes(slave in 1u8..=247, quantity in 1u16..=125) {
            let request = Request::ReadHoldingRegisters { start: 0, quantity };
            let sent = codec::encode_request(slave, &request).unwrap();
            let exception = codec::encode_exception(slave, 0x03, ExceptionCode::IllegalDataAddress);
            let framer = AnswerFramer::on_serial_line(slave, &request, &sent, false);
            prop_assert_eq!(framer.frame(&exception), Framing::Complete(5));
        }

        /// Another device's whole answer is foreign and complete at its length, so that what
        /// follows it can be ours.
        #[test]
        fn another_devices_answer_is_foreign_and_ends_at_its_length(
            ours in 1u8..=247,
            theirs in 1u8..=247,
            words in proptest::collection::vec(any::<u16>(), 1..=125),
        ) {
            prop_assume!(ours != theirs);
            let request = Request::ReadHoldingRegisters { start: 0, quantity: 2 };
            let sent = codec::encode_request(ours, &request).unwrap();
            let mut heard = answer(theirs, &words);
            let foreign_len = heard.len();
            heard.extend_from_slice(&answer(ours, &[1, 2]));
            let framer = AnswerFramer::on_serial_line(ours, &request, &sent, false);
            prop_assert_eq!(framer.frame(&heard), Framing::Foreign { frame_len: Some(foreign_len) });
            prop_assert_eq!(framer.frame(&heard[foreign_len..]), Framing::Complete(heard.len() - foreign_len));
        }
    }

    #[test]
    fn an_unannounced_echo_is_recognised_whole_and_in_part() {
        let request = Request::ReadHoldingRegisters {
            start: 0,
            quantity: 2,
        };
        let sent = codec::encode_request(0x11, &request).unwrap();
        let framer = AnswerFramer::on_serial_line(0x11, &request, &sent, false);
        assert_eq!(framer.frame(&sent[..4]), Framing::EchoCandidate);
        let mut heard = sent.clone();
        heard.extend_from_slice(&answer(0x11, &[1, 2]));
        assert_eq!(framer.frame(&heard), Framing::Echo(sent.len()));
        assert_eq!(framer.frame(&heard[sent.len()..]), Framing::Complete(9));
        // Announced, the echo is stripped before framing; single writes are never echoes.
        let announced = AnswerFramer::on_serial_line(0x11, &request, &sent, true);
        assert_eq!(announced.frame(&sent[..2]), Framing::NeedMore { needed: 9 });
        let write = Request::WriteSingleRegister {
            address: 1,
            value: 2,
        };
        let sent = codec::encode_request(0x11, &write).unwrap();
        let framer = AnswerFramer::on_serial_line(0x11, &write, &sent, false);
        assert_eq!(framer.frame(&sent), Framing::Complete(8));
    }

    proptest! {
        /// However a valid answer arrives in chunks, the stream framer waits until its last
        /// byte and then gives exactly that answer, with nothing skipped.
        #[test]
        fn any_split_of_an_answer_gives_the_same_answer(
            slave in 1u8..=247,
            words in proptest::collection::vec(any::<u16>(), 1..=125),
            cuts in proptest::collection::vec(1usize..20, 1..40),
        ) {
            let request = Request::ReadHoldingRegisters { start: 0, quantity: words.len() as u16 };
            let whole = answer(slave, &words);
            let mut framer = AnswerFramer::new(slave, &request);
            let mut buffer = Vec::new();
            let mut fed = 0;
            for cut in cuts.iter().cycle() {
                let end = (fed + cut).min(whole.len());
                buffer.extend_from_slice(&whole[fed..end]);
                fed = end;
                let framed = framer.poll(&mut buffer);
                if fed < whole.len() {
                    prop_assert_eq!(framed, Framed::NeedMore);
                    continue;
                }
                prop_assert_eq!(framed, Framed::Answer {
                    answer: Answer::Normal(Response::HoldingRegisters(words.clone())),
                    frame: whole.clone(),
                    skipped: 0,
                });
                break;
            }
            prop_assert!(buffer.is_empty());
        }

        /// No bytes make either way of framing panic.
        #[test]
        fn garbage_never_panics(
            slave in any::<u8>(),
            bytes in proptest::collection::vec(any::<u8>(), 0..300),
        ) {
            let request = Request::ReadHoldingRegisters { start: 0, quantity: 2 };
            let sent = codec::encode_request(slave, &request).unwrap_or_default();
            let _ = AnswerFramer::on_serial_line(slave, &request, &sent, false).frame(&bytes);
            let _ = AnswerFramer::new(slave, &request).poll(&mut bytes.clone());
        }
    }

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
