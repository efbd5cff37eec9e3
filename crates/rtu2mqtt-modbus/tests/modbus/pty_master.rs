//! The master against a scripted device on the other end of a real pseudo-terminal pair: normal
//! and exception answers, timeouts, late answers, bad CRC, truncated answers, garbage before a
//! request, frames for another address, adapter echo, broadcast, the frame recorder, and the
//! t3.5 silence the device observes before every request.

use std::io::Write;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use mio_serial::SerialStream;
use rtu2mqtt_modbus::clock::sleep_until_precise;
use rtu2mqtt_modbus::codec::{self, request_frame_len};
use rtu2mqtt_modbus::serial::master::{Master, MasterOptions};
use rtu2mqtt_modbus::serial::transport::{Port, SerialSettings};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_modbus::{Error, Reply};
use rtu2mqtt_modbus::{ExceptionCode, Request, Response, Transact};
use tokio::task::JoinHandle;
use tokio::time::Instant;

const DEVICE: u8 = 0x11;
/// Generous for a busy 2-core machine; the late answer comes at 1.3 × this.
const TIMEOUT: Duration = Duration::from_millis(300);

const BAUD: u32 = 9600;

/// 8N1, on both ends of the pair.
fn char_format() -> CharFormat {
    CharFormat {
        data_bits: 8,
        parity: Parity::None,
        stop_bits: 1,
    }
}

fn timing() -> LineTiming {
    LineTiming::new(BAUD, char_format())
}

fn settings(label: &str) -> SerialSettings {
    SerialSettings {
        path: label.into(),
        baud: BAUD,
        format: char_format(),
        rs485: None,
    }
}

/// What the scripted device does with one request.
#[derive(Debug, Clone)]
enum Act {
    /// Answers normally: every register holds the request's sequence number (1-based).
    Answer,
    Exception(ExceptionCode),
    /// Says nothing.
    Silent,
    /// Answers normally after this delay.
    Late(Duration),
    /// Answers with the CRC's high byte flipped.
    BadCrc,
    /// Sends only the first bytes of its answer.
    Truncated(usize),
    /// Answers normally, then sends garbage after a pause.
    AnswerThenGarbage(Vec<u8>, Duration),
    /// An answer from another address first, t3.5 of silence, then the real answer.
    WrongAddressFirst(u8),
    /// Sends the request back (as an echoing adapter would), then the answer.
    EchoThenAnswer,
    /// Sends nothing (a broadcast).
    Ignore,
    /// Sends these bytes instead of an answer.
    Raw(Vec<u8>),
    /// Sends these bytes in pieces without a gap for this long, then nothing.
    Babble(Duration),
    /// Sends the answer's first bytes, pauses, then the rest.
    PauseMidAnswer(usize, Duration),
    /// Sends these bytes and the answer right behind them, as one burst.
    NoiseThenAnswer(Vec<u8>),
    /// Sends the answer one byte at a time at the wire's character rate, as a UART without a
    /// deep FIFO hands it over, with a pause of this long after the given byte when set.
    BytePaced(Option<(usize, Duration)>),
}

/// What the device saw of one request.
#[derive(Debug)]
struct Seen {
    frame: Vec<u8>,
    /// From the drain of the device's previous transmission to this request's first byte.
    silence_before: Option<Duration>,
    /// When the request's first and last bytes were read.
    first_byte_at: Instant,
    last_byte_at: Instant,
}

fn answer_for(sequence: u16, request: &Request) -> Response {
    match request {
        Request::ReadHoldingRegisters { quantity, .. } => {
            Response::HoldingRegisters(vec![sequence; usize::from(*quantity)])
        }
        Request::WriteSingleRegister { address, value } => Response::WriteSingleRegister {
            address: *address,
            value: *value,
        },
        Request::WriteMultipleCoils { start, values } => Response::WriteMultipleCoils {
            start: *start,
            quantity: values.len() as u16,
        },
        other => panic!("the scripted device does not serve {other:?}"),
    }
}

/// Runs the script on `port`: one act per request, then returns what it saw.
/// The device's end is handed back with what it saw, so it stays open until the master is
/// done: closing a pty end can make the other end's pending input unreadable (EIO).
type DeviceRun = JoinHandle<(Vec<Seen>, Port)>;

/// What the device saw, once its script is done; closes its end.
async fn seen_by(device: DeviceRun) -> Vec<Seen> {
    device.await.unwrap().0
}

fn spawn_device(mut port: Port, script: Vec<Act>) -> DeviceRun {
    tokio::spawn(async move {
        let t3_5 = timing().t3_5;
        let mut seen = Vec::new();
        let mut last_sent_drained: Option<Instant> = None;
        let mut buf = [0u8; 300];
        for (index, act) in script.into_iter().enumerate() {
            let sequence = index as u16 + 1;
            // Read one request frame, noting when its first byte arrived.
            let mut frame = Vec::new();
            let mut first_byte_at = None;
            let mut last_byte_read = Instant::now();
            loop {
                if let Ok(Some(length)) = request_frame_len(&frame) {
                    if frame.len() >= length {
                        assert_eq!(frame.len(), length, "bytes after the request: {frame:02X?}");
                        break;
                    }
                }
                let (count, at) = port
                    .read_until(&mut buf, Instant::now() + Duration::from_secs(10))
                    .await
                    .unwrap()
                    .expect("the master sent the next request");
                first_byte_at.get_or_insert(at);
                last_byte_read = at;
                frame.extend_from_slice(&buf[..count]);
            }
            // None when the device's own last transmission ended after this request began to
            // arrive (it talked over the master: nothing the master could have heard first).
            let silence_before = last_sent_drained
                .and_then(|drained| first_byte_at.unwrap().checked_duration_since(drained));
            let (slave, request) = codec::decode_request(&frame).unwrap();
            seen.push(Seen {
                frame: frame.clone(),
                silence_before,
                first_byte_at: first_byte_at.unwrap(),
                last_byte_at: last_byte_read,
            });
            let answer = codec::encode_answer(slave, &answer_for(sequence, &request));
            // A device waits t3.5 after the request before it answers.
            let request_end = Instant::now();
            sleep_until_precise(request_end + t3_5).await;
            let drained = match act {
                Act::Answer => Some(send(&mut port, answer).await),
                Act::Exception(code) => Some(
                    send(
                        &mut port,
                        codec::encode_exception(slave, request.function().value(), code),
                    )
                    .await,
                ),
                Act::Silent | Act::Ignore => None,
                Act::Late(delay) => {
                    tokio::time::sleep_until(request_end + delay).await;
                    Some(send(&mut port, answer).await)
                }
                Act::BadCrc => {
                    let mut bad = answer;
                    let last = bad.len() - 1;
                    bad[last] ^= 0xFF;
                    Some(send(&mut port, bad).await)
                }
                Act::Truncated(keep) => Some(send(&mut port, answer[..keep].to_vec()).await),
                Act::AnswerThenGarbage(garbage, pause) => {
                    let drained = send(&mut port, answer).await;
                    sleep_until_precise(drained + pause).await;
                    Some(drained.max(send(&mut port, garbage).await))
                }
                Act::WrongAddressFirst(other) => {
                    let foreign = codec::encode_answer(other, &answer_for(999, &request));
                    let drained = send(&mut port, foreign).await;
                    sleep_until_precise(drained + t3_5).await;
                    Some(send(&mut port, answer).await)
                }
                Act::NoiseThenAnswer(mut noise) => {
                    noise.extend_from_slice(&answer);
                    Some(send(&mut port, noise).await)
                }
                Act::Babble(duration) => {
                    let until = Instant::now() + duration;
                    let mut drained = Instant::now();
                    while Instant::now() < until {
                        drained = send(&mut port, vec![0x42; 16]).await;
                        tokio::time::sleep(Duration::from_millis(1)).await;
                    }
                    Some(drained)
                }
                Act::PauseMidAnswer(split, pause) => {
                    let drained = send(&mut port, answer[..split].to_vec()).await;
                    sleep_until_precise(drained + pause).await;
                    Some(send(&mut port, answer[split..].to_vec()).await)
                }
                Act::BytePaced(pause) => {
                    let character = timing().char_time;
                    let mut drained = Instant::now();
                    for (index, byte) in answer.iter().enumerate() {
                        let mut due = drained + character;
                        if let Some((after, length)) = pause {
                            if index == after {
                                due += length;
                            }
                        }
                        if index > 0 {
                            sleep_until_precise(due).await;
                        }
                        drained = send(&mut port, vec![*byte]).await;
                    }
                    Some(drained)
                }
                Act::Raw(bytes) if bytes.is_empty() => None,
                Act::Raw(bytes) => Some(send(&mut port, bytes).await),
                Act::EchoThenAnswer => {
                    send(&mut port, frame).await;
                    Some(send(&mut port, answer).await)
                }
            };
            if drained.is_some() {
                last_sent_drained = drained;
            }
        }
        (seen, port)
    })
}

async fn send(port: &mut Port, bytes: Vec<u8>) -> Instant {
    port.write_frame(&bytes).await.unwrap()
}

fn connect(script: Vec<Act>, options: MasterOptions) -> (Master, DeviceRun) {
    let (near, far) = SerialStream::pair().unwrap();
    let master = Master::new(
        Port::from_stream(near, &settings("master-pty")).unwrap(),
        timing(),
        options,
    );
    let device = spawn_device(
        Port::from_stream(far, &settings("device-pty")).unwrap(),
        script,
    );
    (master, device)
}

fn read_two() -> Request {
    Request::ReadHoldingRegisters {
        start: 0x0100,
        quantity: 2,
    }
}

/// The master's transaction of `read_two()` with the device, within `TIMEOUT`.
async fn read_from_device(master: &mut Master) -> Result<Reply, Error> {
    master.transact(DEVICE, &read_two(), TIMEOUT).await
}

/// `read_two()` gets the scripted device's normal answer to its `sequence`-th request (1-based):
/// both registers hold that number.
async fn assert_answered(master: &mut Master, sequence: u16) {
    let response = read_from_device(master).await.unwrap().unwrap();
    assert_eq!(
        response,
        Response::HoldingRegisters(vec![sequence; 2]),
        "answer to request {sequence}"
    )
}

/// Every request the device saw came after at least t3.5 of silence since its last transmission.
fn assert_silences(seen: &[Seen]) {
    let t3_5 = timing().t3_5;
    for (index, request) in seen.iter().enumerate() {
        if let Some(silence) = request.silence_before {
            assert!(
                silence >= t3_5,
                "request {index}: only {silence:?} of silence, t3.5 is {t3_5:?}"
            );
        }
    }
}

#[tokio::test(flavor = "current_thread")]
async fn normal_answer() {
    let (mut master, device) = connect(vec![Act::Answer], MasterOptions::default());
    assert_answered(&mut master, 1).await;
    let seen = seen_by(device).await;
    assert_eq!(
        seen[0].frame,
        codec::encode_request(DEVICE, &read_two()).unwrap()
    );
    let counters = master.counters();
    assert_eq!(
        (counters.requests, counters.timeouts, counters.stray_bytes),
        (1, 0, 0)
    );
    let timing = timing();
    assert_eq!(
        counters.wire_time,
        timing.frame_time(8) + timing.frame_time(9) + 2 * timing.t3_5
    );
}

#[tokio::test(flavor = "current_thread")]
async fn exception_answer() {
    let (mut master, device) = connect(
        vec![
            Act::Exception(ExceptionCode::IllegalDataAddress),
            Act::Answer,
        ],
        MasterOptions::default(),
    );
    let result = read_from_device(&mut master).await;
    assert!(
        matches!(result, Ok(Err(ExceptionCode::IllegalDataAddress))),
        "{result:?}"
    );
    assert_answered(&mut master, 2).await;
    assert_eq!(master.counters().exceptions, 1);
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn timeout_then_recovery() {
    let (mut master, device) = connect(vec![Act::Silent, Act::Answer], MasterOptions::default());
    let started = Instant::now();
    let result = read_from_device(&mut master).await;
    assert!(matches!(result, Err(Error::Timeout(_))), "{result:?}");
    assert!(started.elapsed() >= TIMEOUT);
    assert_answered(&mut master, 2).await;
    let counters = master.counters();
    assert_eq!((counters.timeouts, counters.late_answers), (1, 0));
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn late_answer_is_counted_and_never_taken_for_the_next() {
    let late = TIMEOUT.mul_f64(1.3);
    let (mut master, device) =
        connect(vec![Act::Late(late), Act::Answer], MasterOptions::default());
    let result = read_from_device(&mut master).await;
    assert!(matches!(result, Err(Error::Timeout(_))), "{result:?}");
    // Asked again at once: the same request, so only the sequence number in the registers
    // tells the late answer (1) from this request's own (2).
    assert_answered(&mut master, 2).await;
    let counters = master.counters();
    assert_eq!(
        (
            counters.timeouts,
            counters.late_answers,
            counters.stray_bytes
        ),
        (1, 1, 0)
    );
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn late_answer_heard_while_talking_to_another_address() {
    // The next request goes to another address: no guard, it goes out after t3.5; the late
    // answer arrives while that request's answer is awaited and is ignored, counted late.
    let late = TIMEOUT.mul_f64(1.3);
    let (mut master, device) =
        connect(vec![Act::Late(late), Act::Answer], MasterOptions::default());
    let result = read_from_device(&mut master).await;
    assert!(matches!(result, Err(Error::Timeout(_))), "{result:?}");
    let response = master
        .transact(DEVICE + 1, &read_two(), TIMEOUT)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(response, Response::HoldingRegisters(vec![2, 2]));
    let counters = master.counters();
    assert_eq!(
        (
            counters.timeouts,
            counters.late_answers,
            counters.wrong_address
        ),
        (1, 1, 0)
    );
    let seen = seen_by(device).await;
    assert_eq!(seen[1].frame[0], DEVICE + 1);
}

#[tokio::test(flavor = "current_thread")]
async fn bad_crc() {
    let (mut master, device) = connect(vec![Act::BadCrc, Act::Answer], MasterOptions::default());
    let result = read_from_device(&mut master).await;
    assert!(matches!(result, Err(Error::Crc)), "{result:?}");
    assert_answered(&mut master, 2).await;
    assert_eq!(master.counters().crc_errors, 1);
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn truncated_answer() {
    let (mut master, device) = connect(
        vec![Act::Truncated(5), Act::Answer],
        MasterOptions::default(),
    );
    let result = read_from_device(&mut master).await;
    assert!(
        matches!(result, Err(Error::Truncated { needed: 9, got: 5 })),
        "{result:?}"
    );
    assert_answered(&mut master, 2).await;
    assert_eq!(master.counters().truncated, 1);
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn garbage_before_a_request_is_flushed_and_counted() {
    let garbage = vec![0xDE, 0xAD, 0xBE];
    let (mut master, device) = connect(
        vec![
            Act::AnswerThenGarbage(garbage, Duration::from_millis(20)),
            Act::Answer,
        ],
        MasterOptions::default(),
    );
    assert_answered(&mut master, 1).await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_answered(&mut master, 2).await;
    let counters = master.counters();
    assert_eq!((counters.stray_bytes, counters.late_answers), (3, 0));
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn garbage_during_the_silence_restarts_it() {
    // The garbage comes 1 ms after the answer, while the master is already waiting out t3.5
    // for its next request: the device must still see t3.5 after the garbage.
    let (mut master, device) = connect(
        vec![
            Act::AnswerThenGarbage(vec![0x55], Duration::from_millis(1)),
            Act::Answer,
        ],
        MasterOptions::default(),
    );
    read_from_device(&mut master).await.unwrap().unwrap();
    assert_answered(&mut master, 2).await;
    assert_eq!(master.counters().stray_bytes, 1);
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn answer_from_another_address_is_ignored() {
    let (mut master, device) = connect(
        vec![Act::WrongAddressFirst(0x22), Act::Answer],
        MasterOptions::default(),
    );
    assert_answered(&mut master, 1).await;
    assert_answered(&mut master, 2).await;
    let counters = master.counters();
    assert_eq!((counters.wrong_address, counters.unexpected), (1, 0));
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn noise_just_before_the_answer_is_skipped() {
    // A turn-around glitch (0x00, 0xFF) and a byte that is our address but not followed by our
    // function: both dropped, counted as stray, and the answer behind them is taken.
    let (mut master, device) = connect(
        vec![
            Act::NoiseThenAnswer(vec![0x00, 0xFF]),
            Act::NoiseThenAnswer(vec![DEVICE]),
        ],
        MasterOptions::default(),
    );
    assert_answered(&mut master, 1).await;
    assert_answered(&mut master, 2).await;
    let counters = master.counters();
    assert_eq!(
        (
            counters.stray_bytes,
            counters.unexpected,
            counters.crc_errors
        ),
        (3, 0, 0)
    );
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn answer_with_another_function_is_unexpected() {
    let other_function = {
        let mut frame = vec![DEVICE, 0x04, 0x04, 0x00, 0x01, 0x00, 0x01];
        let crc = rtu2mqtt_modbus::crc::crc16(&frame);
        frame.extend(crc.to_le_bytes());
        frame
    };
    let (mut master, device) = connect(
        vec![Act::Raw(other_function), Act::Answer],
        MasterOptions::default(),
    );
    let result = read_from_device(&mut master).await;
    assert!(
        matches!(
            result,
            Err(Error::UnexpectedReply(codec::DecodeError::WrongFunction {
                expected: 0x03,
                found: 0x04
            }))
        ),
        "{result:?}"
    );
    assert_answered(&mut master, 2).await;
    assert_eq!(master.counters().unexpected, 1);
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn babbling_line_ends_in_timeout_then_recovers() {
    let (mut master, device) = connect(
        vec![Act::Babble(TIMEOUT * 2), Act::Answer],
        MasterOptions::default(),
    );
    let result = read_from_device(&mut master).await;
    assert!(matches!(result, Err(Error::Timeout(_))), "{result:?}");
    assert_answered(&mut master, 2).await;
    assert!(master.counters().stray_bytes >= 256);
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn gap_inside_an_answer_follows_the_inter_character_limit() {
    // Default byte timeout (32 ms): a 50 ms pause cuts the answer, whose rest
    // is then discarded as stray before the next request; a 100 ms limit takes it whole.
    let script = vec![
        Act::PauseMidAnswer(4, Duration::from_millis(50)),
        Act::Answer,
    ];
    let (mut master, device) = connect(script, MasterOptions::default());
    let result = read_from_device(&mut master).await;
    assert!(
        matches!(result, Err(Error::Truncated { needed: 9, got: 4 })),
        "{result:?}"
    );
    assert_answered(&mut master, 2).await;
    assert_eq!(
        (master.counters().truncated, master.counters().stray_bytes),
        (1, 5)
    );
    // No silence check here: the device broke its own frame, so the master rightly sent the
    // next request after t3.5 of silence while the device was still pausing; the device only
    // reads that request after its late rest, which the harness cannot tell from a late request.
    seen_by(device).await;

    let lenient = MasterOptions {
        inter_char_timeout: Some(Duration::from_millis(100)),
        ..MasterOptions::default()
    };
    let (mut master, device) = connect(
        vec![Act::PauseMidAnswer(4, Duration::from_millis(50))],
        lenient,
    );
    assert_answered(&mut master, 1).await;
    assert_silences(&seen_by(device).await);
}

/// The silences a device saw before each request after the first, in a run of `transactions`
/// reads of six registers answered byte by byte at the wire's rate (with `pause` inside each
/// answer), sorted. Also checks every answer and that none was shorter than t3.5.
async fn silences_after_byte_paced_answers(
    transactions: usize,
    pause: Option<(usize, Duration)>,
) -> Vec<Duration> {
    let six_registers = Request::ReadHoldingRegisters {
        start: 0x0100,
        quantity: 6,
    };
    let script = vec![Act::BytePaced(pause); transactions];
    let (mut master, device) = connect(script, MasterOptions::default());
    for sequence in 1..=transactions as u16 {
        let response = master
            .transact(DEVICE, &six_registers, TIMEOUT)
            .await
            .unwrap()
            .unwrap();
        assert_eq!(response, Response::HoldingRegisters(vec![sequence; 6]));
    }
    assert_eq!(master.counters().truncated, 0, "pause {pause:?}");
    let seen = seen_by(device).await;
    assert_silences(&seen);
    let mut silences: Vec<Duration> = seen
        .iter()
        .filter_map(|request| request.silence_before)
        .collect();
    assert_eq!(silences.len(), transactions - 1, "pause {pause:?}");
    silences.sort();
    silences
}

/// The answer ends when its last byte arrives: on a line that hands the answer over byte by
/// byte at the wire's rate (with and without pauses inside it), the next request follows the
/// last byte after t3.5 and not a character time more, so the median silence the device sees
/// stays within half a character of t3.5, and none is shorter than t3.5. A master that counts
/// t3.5 from a read one character late misses that bound in every run; a run on a loaded
/// machine may miss it by scheduling delays, so each case gets three runs to meet it once.
#[tokio::test(flavor = "current_thread")]
async fn a_byte_paced_answer_ends_with_its_last_byte() {
    const TRANSACTIONS: usize = 15;
    const RUNS: usize = 3;
    let t3_5 = timing().t3_5;
    let bound = t3_5 + timing().char_time / 2;
    for pause in [
        None,
        Some((8, Duration::from_millis(5))),
        Some((8, Duration::from_millis(16))),
    ] {
        let mut medians = Vec::new();
        for _ in 0..RUNS {
            let silences = silences_after_byte_paced_answers(TRANSACTIONS, pause).await;
            medians.push(silences[silences.len() / 2]);
            if medians.last() <= Some(&bound) {
                break;
            }
        }
        assert!(
            medians.iter().any(|median| *median <= bound),
            "pause {pause:?}: median silences {medians:?} after byte-paced answers, t3.5 is \
             {t3_5:?}"
        );
    }
}

/// An answer whose rest takes longer on the wire than the gap limit (38 registers: 81 bytes,
/// 84 ms at 9600 against 32 ms), handed over byte by byte, with and without a pause inside it:
/// read whole, never taken for truncated where the wait for its rest reaches the gap limit
/// while the port is not being watched.
#[tokio::test(flavor = "current_thread")]
async fn a_long_byte_paced_answer_is_read_whole() {
    const TRANSACTIONS: u16 = 3;
    let registers = Request::ReadHoldingRegisters {
        start: 0x0100,
        quantity: 38,
    };
    for pause in [None, Some((40, Duration::from_millis(20)))] {
        let script = vec![Act::BytePaced(pause); usize::from(TRANSACTIONS)];
        let (mut master, device) = connect(script, MasterOptions::default());
        for sequence in 1..=TRANSACTIONS {
            let response = master.transact(DEVICE, &registers, TIMEOUT).await.unwrap();
            assert_eq!(
                response,
                Ok(Response::HoldingRegisters(vec![sequence; 38])),
                "pause {pause:?}"
            );
        }
        assert_eq!(master.counters().truncated, 0, "pause {pause:?}");
        assert_silences(&seen_by(device).await);
    }
}

#[tokio::test(flavor = "current_thread")]
async fn echo_is_stripped_when_configured() {
    let options = MasterOptions {
        echo: true,
        ..MasterOptions::default()
    };
    let write = Request::WriteMultipleCoils {
        start: 0,
        values: vec![true, false, true],
    };
    let (mut master, device) = connect(vec![Act::EchoThenAnswer, Act::EchoThenAnswer], options);
    assert_answered(&mut master, 1).await;
    assert_eq!(
        master
            .transact(DEVICE, &write, TIMEOUT)
            .await
            .unwrap()
            .unwrap(),
        Response::WriteMultipleCoils {
            start: 0,
            quantity: 3
        }
    );
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn unannounced_echo_is_detected_and_stripped() {
    let (mut master, device) = connect(
        vec![Act::EchoThenAnswer, Act::Answer],
        MasterOptions::default(),
    );
    assert_answered(&mut master, 1).await;
    assert_answered(&mut master, 2).await;
    let counters = master.counters();
    assert_eq!((counters.unexpected, counters.stray_bytes), (0, 0));
    assert_silences(&seen_by(device).await);
}

#[tokio::test(flavor = "current_thread")]
async fn silence_of_t3_5_before_every_request_in_a_burst() {
    let script = vec![Act::Answer; 12];
    let (mut master, device) = connect(script, MasterOptions::default());
    let started = Instant::now();
    for sequence in 1..=12u16 {
        assert_answered(&mut master, sequence).await;
    }
    let elapsed = started.elapsed();
    let seen = seen_by(device).await;
    assert_eq!(seen.len(), 12);
    assert_silences(&seen);
    let t3_5 = timing().t3_5;
    let mut overshoot: Vec<Duration> = seen
        .iter()
        .filter_map(|request| request.silence_before)
        .map(|silence| silence - t3_5)
        .collect();
    overshoot.sort();
    // Figures, not assertions: the pty carries bytes instantly, so this is host overhead only.
    println!(
        "12 transactions in {elapsed:?}; silence beyond t3.5 ({t3_5:?}) before each request: median {:?}, max {:?}",
        overshoot[overshoot.len() / 2],
        overshoot[overshoot.len() - 1]
    );
}

#[tokio::test(flavor = "current_thread")]
async fn broadcast_keeps_the_line_silent_for_the_turnaround() {
    let turnaround = Duration::from_millis(100);
    let options = MasterOptions {
        broadcast_turnaround: turnaround,
        ..MasterOptions::default()
    };
    let (mut master, device) = connect(vec![Act::Ignore, Act::Answer], options);
    let write = Request::WriteSingleRegister {
        address: 1,
        value: 2,
    };
    let sent = Instant::now();
    master.broadcast(&write).await.unwrap();
    assert!(sent.elapsed() >= turnaround);
    assert_answered(&mut master, 2).await;
    let seen = seen_by(device).await;
    assert_eq!(seen[0].frame, codec::encode_request(0, &write).unwrap());
    // The device notes the broadcast when it reads it, which a loaded host can delay well
    // after the master's drain: hence the allowance. A master that
    // skipped the turnaround would leave only t3.5 (3.6 ms), far below it.
    let read_delay_allowance = Duration::from_millis(25);
    let quiet = seen[1].first_byte_at - seen[0].last_byte_at;
    assert!(
        quiet + read_delay_allowance >= turnaround,
        "only {quiet:?} after the broadcast"
    );
}

#[tokio::test(flavor = "current_thread")]
async fn out_of_spec_request_is_refused_before_the_wire() {
    let (mut master, device) = connect(vec![Act::Answer], MasterOptions::default());
    let too_many = Request::ReadHoldingRegisters {
        start: 0,
        quantity: 126,
    };
    assert!(matches!(
        master.transact(DEVICE, &too_many, TIMEOUT).await,
        Err(Error::InvalidRequest(_))
    ));
    assert_eq!(master.counters().requests, 0);
    // The device sees only the valid request that follows.
    read_from_device(&mut master).await.unwrap().unwrap();
    assert_eq!(
        seen_by(device).await[0].frame,
        codec::encode_request(DEVICE, &read_two()).unwrap()
    );
}

/// A `Write` the test can read back.
#[derive(Clone, Default)]
struct SharedBuffer(Arc<Mutex<Vec<u8>>>);

impl rtu2mqtt_modbus::FrameSink for SharedBuffer {}

impl Write for SharedBuffer {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(bytes);
        Ok(bytes.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[tokio::test(flavor = "current_thread")]
async fn frame_recorder_writes_one_line_per_frame() {
    let (mut master, device) = connect(vec![Act::Answer], MasterOptions::default());
    let recording = SharedBuffer::default();
    master.record_frames_to(Box::new(recording.clone()));
    read_from_device(&mut master).await.unwrap().unwrap();
    seen_by(device).await;
    let text = String::from_utf8(recording.0.lock().unwrap().clone()).unwrap();
    let lines: Vec<Vec<&str>> = text.lines().map(|line| line.split(' ').collect()).collect();
    assert_eq!(lines.len(), 2, "{text}");
    assert_eq!(lines[0][1..], ["tx", "110301000002C767"]);
    assert_eq!(lines[1][1..], ["rx", "110304000100017BF2"]);
    for line in &lines {
        let (seconds, micros) = line[0].split_once('.').unwrap();
        assert!(seconds.parse::<u64>().unwrap() > 1_600_000_000);
        assert_eq!(micros.len(), 6);
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 24, ..Default::default() })]

    /// Whatever a device sends back, the master returns (no panic, no hang) and the next
    /// transaction gets its own answer.
    #[test]
    fn any_answer_bytes_leave_the_master_working(
        answer in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..40),
        our_address_first in proptest::prelude::any::<bool>(),
    ) {
        let mut answer = answer;
        if our_address_first && !answer.is_empty() {
            answer[0] = DEVICE;
        }
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        runtime.block_on(async {
            let short = Duration::from_millis(60);
            let (mut master, device) = connect(vec![Act::Raw(answer), Act::Answer], MasterOptions::default());
            let _ = master.transact(DEVICE, &read_two(), short).await;
            assert_answered(&mut master, 2).await;
            assert_silences(&seen_by(device).await);
        });
    }
}

/// Instants at which the master wrote each `tx` line of its frame recording.
#[derive(Clone, Default)]
struct TxInstants(std::sync::Arc<std::sync::Mutex<Vec<Instant>>>);

impl rtu2mqtt_modbus::FrameSink for TxInstants {}

impl Write for TxInstants {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        let line = String::from_utf8_lossy(bytes);
        if line.split_whitespace().nth(1) == Some("tx") {
            self.0.lock().unwrap().push(Instant::now());
        }
        Ok(bytes.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// The master never drives the line sooner than t3.5 after the answer's last byte, checked
/// in the direction that holds on any load: the simulator's hand-over of its answer is the
/// earliest the master can have seen it, and the master records a request before writing
/// it, so `recorded tx − hand-over` is at most the true silence. Likewise the simulator's
/// silence before each request runs from that hand-over to when it read the request,
/// which can only be later than the master's write.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn never_drives_the_line_sooner_than_t3_5_after_the_answer() {
    use rtu2mqtt_sim::{share, AirShower, ServeOptions, VirtualLine};

    const TRANSACTIONS: usize = 40;
    let baud = 38_400;
    let format = CharFormat {
        data_bits: 8,
        parity: Parity::None,
        stop_bits: 1,
    };
    let timing = LineTiming::new(baud, format);
    let (_shower, device) = share(AirShower::new());
    let line = VirtualLine::spawn(
        ServeOptions::new(baud, Parity::None).paced(true),
        vec![device],
    )
    .unwrap();
    let port = Port::open(&SerialSettings {
        path: line.path().to_string_lossy().into_owned(),
        baud,
        format,
        rs485: None,
    })
    .unwrap();
    let mut master = Master::new(port, timing, MasterOptions::default());
    let tx_instants = TxInstants::default();
    master.record_frames_to(Box::new(tx_instants.clone()));
    let read = Request::ReadCoils {
        start: 0,
        quantity: 22,
    };
    for _ in 0..TRANSACTIONS {
        master
            .transact(0x81, &read, Duration::from_secs(1))
            .await
            .unwrap()
            .unwrap();
    }
    // The simulator journals a request once its answer is handed over, which may be a
    // moment after the master already has that answer: wait for the last record.
    let deadline = Instant::now() + Duration::from_secs(2);
    let mut records = line.journal().requests();
    while records.len() < TRANSACTIONS && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(10)).await;
        records = line.journal().requests();
    }
    let sent = tx_instants.0.lock().unwrap().clone();
    assert_eq!(records.len(), TRANSACTIONS);
    assert_eq!(sent.len(), TRANSACTIONS);
    for (i, pair) in records.windows(2).enumerate() {
        let handed_over = pair[0].answer_timing.unwrap().handed_over;
        let next_tx = sent[i + 1];
        assert!(
            next_tx.into_std() >= handed_over + timing.t3_5,
            "request {} recorded {:?} after the answer's hand-over, t3.5 is {:?}",
            i + 1,
            next_tx.into_std().saturating_duration_since(handed_over),
            timing.t3_5
        );
        let silence = pair[1].silence_before.unwrap();
        assert!(
            silence >= timing.t3_5,
            "request {} after {silence:?} of silence",
            i + 1
        );
    }
}
