//! The answers a TCP link reads: a Modbus TCP (`modbus-tcp://`) answer ADU as the master
//! matches and decodes it, and the same bytes as a raw RTU stream (`tcp://`, a serial device
//! server) through the stream framer. Input: the request (`[length][address, PDU]`, CRC added
//! here), the transaction id (u16), then the bytes received.
//!
//! Asserted: a current answer re-encodes to the ADU; a stale one carries another transaction
//! id than ours; the stream framer drops no more than its bound before giving up, takes each
//! answer off the front of the buffer after exactly the bytes it says it skipped, and every
//! answer it takes re-encodes to its frame.

#![no_main]

use libfuzzer_sys::fuzz_target;
use rtu2mqtt_fuzz::{assert_reencodes, request_of, Input};
use rtu2mqtt_modbus::answer_framing::{AnswerFramer, Framed};
use rtu2mqtt_modbus::codec::MAX_FRAME_LEN;
use rtu2mqtt_modbus::tcp::mbap::{self, Header, Matched};

fuzz_target!(|data: &[u8]| {
    let mut input = Input::new(data);
    let Some((unit, request)) = request_of(&mut input) else {
        return;
    };
    let transaction = input.u16();
    let received = input.rest();

    match mbap::decode_answer(transaction, unit, &request, received) {
        Ok(Matched::Current(answer)) => {
            assert_eq!(&received[..2], &transaction.to_be_bytes());
            // The unit id and the PDU after it are the RTU frame without its CRC.
            assert_reencodes(unit, &request, &answer, &received[6..], false);
        }
        Ok(Matched::Stale { transaction: stale }) => {
            assert_ne!(stale, transaction);
            assert_eq!(Header::decode(received).map(|h| h.transaction), Ok(stale));
        }
        Err(_) => {}
    }

    // One poll over everything received: a framer serves one transaction.
    let mut buffer = received.to_vec();
    match AnswerFramer::new(unit, &request).poll(&mut buffer) {
        Framed::NeedMore => assert!(received.ends_with(&buffer)),
        Framed::OutOfStep { skipped } => {
            assert!(skipped > MAX_FRAME_LEN, "out of step after {skipped} bytes");
            assert!(received.ends_with(&buffer));
        }
        Framed::Answer {
            answer,
            frame,
            skipped,
        } => {
            assert!(skipped <= MAX_FRAME_LEN, "{skipped} bytes skipped");
            assert_eq!(&received[skipped..skipped + frame.len()], frame.as_slice());
            assert_eq!(&received[skipped + frame.len()..], buffer.as_slice());
            assert_reencodes(unit, &request, &answer, &frame, true);
        }
    }
});
