//! Where the bytes heard so far on a serial line stand as the answer awaited: complete, needing
//! more, another device's frame, an echo of our request, noise before the answer. Pure byte
//! work, no I/O and no clock: the serial master asks after every read and decides what to wait
//! for from the answer.

use crate::codec::{self, MAX_FRAME_LEN};
use crate::crc::carried_and_computed;
use crate::frame::{FunctionCode, Request, SlaveId};

/// How far the bytes received so far go towards an answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Framing {
    /// Not enough bytes to tell; wait for more (or give up at the gap limit).
    NeedMore { needed: usize },
    /// An answer of this many bytes is complete at the start of the buffer.
    Complete(usize),
    /// A frame for someone else: read it to its end (a gap), then drop it.
    Foreign,
    /// The bytes so far repeat our own request: possibly an echo.
    EchoCandidate,
    /// A function code that is neither ours nor our exception: read to a gap, then reject.
    UnknownLength,
}

/// Where the bytes `received` so far stand as the answer to `request`, sent to `slave` as
/// `sent`; `echo`: the adapter is known to echo (its echo is stripped before this is asked).
pub(crate) fn framing(
    slave: SlaveId,
    request: &Request,
    sent: &[u8],
    received: &[u8],
    echo: bool,
) -> Framing {
    let function = request.function();
    let (Some(&address), Some(&found_function)) = (received.first(), received.get(1)) else {
        return match received.first() {
            Some(&address) if address != slave => Framing::Foreign,
            _ => Framing::NeedMore {
                needed: request.answer_len(),
            },
        };
    };
    if address != slave {
        return Framing::Foreign;
    }
    // Single writes are answered with a copy of the request: no echo can be told from them.
    let answer_may_equal_request = matches!(
        function,
        FunctionCode::WriteSingleCoil | FunctionCode::WriteSingleRegister
    );
    if !echo
        && !answer_may_equal_request
        && received.len() < sent.len()
        && sent.starts_with(received)
    {
        return Framing::EchoCandidate;
    }
    let needed = if found_function == function.value() | 0x80 {
        codec::EXCEPTION_FRAME_LEN
    } else if found_function == function.value() {
        if request.is_read() {
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

/// The length of the answer frame at the start of `received` when its function code gives the
/// length, all of it has arrived and its CRC is right (`None` otherwise).
pub(crate) fn complete_foreign_frame(received: &[u8]) -> Option<usize> {
    let function = *received.get(1)?;
    let length = if function & 0x80 != 0 {
        codec::EXCEPTION_FRAME_LEN
    } else {
        match FunctionCode::from_u8(function)? {
            FunctionCode::ReadCoils
            | FunctionCode::ReadDiscreteInputs
            | FunctionCode::ReadHoldingRegisters
            | FunctionCode::ReadInputRegisters => 5 + usize::from(*received.get(2)?),
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
pub(crate) fn noise_before_answer(
    slave: SlaveId,
    function: FunctionCode,
    received: &[u8],
) -> Option<usize> {
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
                match framing(slave, &request, &sent, prefix, false) {
                    Framing::NeedMore { needed } => prop_assert_eq!(needed, whole.len()),
                    // Our address and function are also how our request starts.
                    Framing::EchoCandidate => prop_assert!(sent.starts_with(prefix)),
                    other => prop_assert!(false, "prefix of {} bytes: {:?}", end, other),
                }
            }
            let mut followed = whole.clone();
            followed.extend_from_slice(&trailing);
            prop_assert_eq!(
                framing(slave, &request, &sent, &followed, false),
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
            prop_assert_eq!(framing(slave, &request, &sent, &exception, false), Framing::Complete(5));
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
            prop_assert_eq!(framing(ours, &request, &sent, &heard, false), Framing::Foreign);
            prop_assert_eq!(complete_foreign_frame(&heard), Some(foreign_len));
        }
    }
}
