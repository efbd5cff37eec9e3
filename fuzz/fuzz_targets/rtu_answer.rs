//! A Modbus RTU answer as the serial master frames it (`serial::reception`: echo, noise,
//! other devices' frames, pauses inside the answer, the response and byte timeouts), the bytes
//! arriving with pauses the input chooses on a simulated port and clock that behave as the
//! master's port does (bytes that arrived while it slept are read at once, at most a frame's
//! worth per read). Input: the request (`[length][address, PDU]`, CRC added here), a byte of
//! options (baud rate, echo announced), the response timeout (2 ms steps over 20 ms), then
//! the bytes as chunks `[pause since the previous chunk, 250 µs steps][length][bytes]`.
//!
//! Asserted: the reception ends; every byte heard is accounted for, in order, exactly once (as
//! echo, noise, another device's frame, dropped bytes, the answer or what trailed it); an
//! answer taken re-encodes to its frame and none of its bytes came after a pause longer than
//! the byte timeout; a truncated answer is shorter than needed.

#![no_main]

use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use rtu2mqtt_fuzz::{assert_reencodes, request_of, Input};
use rtu2mqtt_modbus::codec::{self, Answer, MAX_FRAME_LEN};
use rtu2mqtt_modbus::serial::reception::{AnswerTiming, Heard, Next, Reception};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_modbus::Error;
use tokio::time::Instant;

const BAUDS: [u32; 4] = [9600, 19200, 115_200, 1200];
/// The master's default byte timeout.
const BYTE_TIMEOUT: Duration = Duration::from_millis(32);

fuzz_target!(|data: &[u8]| {
    let mut input = Input::new(data);
    let Some((slave, request)) = request_of(&mut input) else {
        return;
    };
    let options = input.u8();
    let line = LineTiming::new(
        BAUDS[usize::from(options & 3)],
        CharFormat {
            data_bits: 8,
            parity: Parity::Even,
            stop_bits: 1,
        },
    );
    let echo_announced = options & 4 != 0;
    let timeout = Duration::from_millis(20 + 2 * u64::from(input.u8()));
    let sent_at = Instant::now();
    // Every byte with the instant it reaches the port.
    let mut arrivals: Vec<(u8, Instant)> = Vec::new();
    let mut at = sent_at;
    while !input.is_empty() {
        at += Duration::from_micros(250 * u64::from(input.u8()));
        arrivals.extend(input.part().iter().map(|&byte| (byte, at)));
    }
    let sent = codec::encode_request(slave, &request).expect("a request the master sends");
    let timing = AnswerTiming {
        sent_at,
        timeout,
        byte_timeout: BYTE_TIMEOUT.max(line.t3_5),
        line,
    };
    let mut reception = Reception::new(slave, &request, &sent, echo_announced, timing);

    let mut now = sent_at;
    // Bytes read so far, each with the instant the master saw it.
    let mut read: Vec<(u8, Instant)> = Vec::new();
    let mut heard: Vec<Heard> = Vec::new();
    let mut result = None;
    for _ in 0..10_000 {
        let (until, rest_due) = match reception.next(now) {
            Next::Done(done) => {
                result = Some(done);
                break;
            }
            Next::Read { until, rest_due } => (until, rest_due),
        };
        heard.extend(reception.take_heard());
        if let Some(due) = rest_due {
            assert!(due <= until, "a rest due after the read's end");
            now = now.max(due);
        }
        match arrivals.get(read.len()) {
            Some(&(_, arrival)) if arrival <= now.max(until) => {
                now = now.max(arrival);
                let ready = arrivals[read.len()..]
                    .iter()
                    .take(MAX_FRAME_LEN)
                    .take_while(|(_, arrival)| *arrival <= now)
                    .map(|&(byte, _)| (byte, now))
                    .collect::<Vec<_>>();
                let bytes: Vec<u8> = ready.iter().map(|(byte, _)| *byte).collect();
                reception.heard(&bytes, now);
                read.extend(ready);
            }
            _ => {
                now = now.max(until);
                if let Some(done) = reception.silence(now) {
                    result = Some(done);
                    break;
                }
            }
        }
        heard.extend(reception.take_heard());
    }
    let result = result.expect("the reception ended");
    heard.extend(reception.take_heard());

    // Every byte read is accounted for, in order, once.
    let mut accounted: Vec<u8> = Vec::new();
    let mut answer_span = None;
    for event in &heard {
        let bytes = match event {
            Heard::Echo(bytes)
            | Heard::Foreign(bytes)
            | Heard::Noise { bytes, .. }
            | Heard::Unframed { bytes, .. }
            | Heard::Trailing { bytes, .. } => bytes,
            Heard::Frame(bytes) => {
                answer_span = Some(accounted.len()..accounted.len() + bytes.len());
                bytes
            }
            Heard::LongGap => continue,
        };
        accounted.extend_from_slice(bytes);
    }
    let bytes_read: Vec<u8> = read.iter().map(|(byte, _)| *byte).collect();
    assert_eq!(
        codec::hex(&accounted),
        codec::hex(&bytes_read),
        "the bytes read and those accounted for differ"
    );

    match result {
        Ok(reply) => {
            let span = answer_span.expect("an answer without its frame");
            let frame = &bytes_read[span.clone()];
            let answer = match reply {
                Ok(response) => Answer::Normal(response),
                Err(code) => Answer::Exception(code),
            };
            assert_reencodes(slave, &request, &answer, frame, true);
            for pair in read[span].windows(2) {
                let pause = pair[1].1 - pair[0].1;
                assert!(
                    pause <= timing.byte_timeout,
                    "a pause of {pause:?} inside the answer"
                );
            }
        }
        Err(Error::Truncated { needed, got }) => assert!(got < needed),
        Err(_) => {}
    }
});
