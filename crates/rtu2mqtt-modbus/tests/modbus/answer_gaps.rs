//! Answers that pause inside, and a master that starts while an answer is still on the wire,
//! against a paced simulated device on a real pseudo-terminal. What counts is what the
//! simulator saw: it listens while it answers, so a request sent into an answer is journalled
//! as arriving then, with no silence before it.
//!
//! - An answer delivered in chunks with 2, 5 and 16 ms pauses (a slow device, a USB adapter's
//!   latency timer) is taken whole every time, and no request starts while it is going out.
//! - A master opened while a device is still answering an earlier request (with pauses inside)
//!   hears that answer out before its first request, which comes t3.5 or more after its last
//!   byte.
//! - A device that answers sooner than the master has learned to expect (a quicker turnaround,
//!   an exception instead of the answer) has its answer taken whole, and the request after it
//!   still comes t3.5 or more after its last byte; so does one that answers later.

use std::time::Duration;

use rtu2mqtt_modbus::serial::master::{Master, MasterOptions};
use rtu2mqtt_modbus::serial::transport::{Port, SerialSettings};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_modbus::{codec, ExceptionCode, Request, Response, Transact};
use rtu2mqtt_sim::faults::{AnswerChunks, Occurrence};
use rtu2mqtt_sim::{share, GenericDevice, RequestRecord, ServeOptions, VirtualLine};

const BAUD: u32 = 9600;
const DEVICE: u8 = 1;
const REGISTERS: [u16; 6] = [0x0300, 0x0001, 0x1234, 0xBEEF, 0x0042, 0x7FFF];
/// Generous for a busy machine: the response timeout runs to the answer's first byte.
const TIMEOUT: Duration = Duration::from_millis(500);

fn format() -> CharFormat {
    CharFormat {
        data_bits: 8,
        parity: Parity::None,
        stop_bits: 1,
    }
}

fn timing() -> LineTiming {
    LineTiming::new(BAUD, format())
}

fn read_block() -> Request {
    Request::ReadHoldingRegisters {
        start: 0,
        quantity: REGISTERS.len() as u16,
    }
}

/// A paced 9600 8N1 line with one device holding [`REGISTERS`], its answers sent in `chunks`
/// (byte by byte at the wire's rate without).
fn line(chunks: Option<AnswerChunks>) -> VirtualLine {
    let mut device = GenericDevice::from_blocks(&[], DEVICE);
    for (at, value) in REGISTERS.iter().enumerate() {
        device.set_holding(at as u16, *value);
    }
    let (_device, shared) = share(device);
    let line = VirtualLine::spawn(
        ServeOptions::new(BAUD, Parity::None).paced(true),
        vec![shared],
    )
    .expect("virtual line");
    line.faults().update(|f| f.answer_chunks = chunks);
    line
}

fn open(line: &VirtualLine) -> Port {
    Port::open(&SerialSettings {
        path: line.path().to_string_lossy().into_owned(),
        baud: BAUD,
        format: format(),
        rs485: None,
    })
    .expect("open the pty")
}

/// Every request after the first arrived after the previous answer was out and the line had
/// been silent for t3.5.
fn assert_no_request_into_an_answer(records: &[RequestRecord]) {
    let t3_5 = timing().t3_5;
    for (i, pair) in records.windows(2).enumerate() {
        let answer_out = pair[0]
            .answer_timing
            .expect("every request was answered")
            .handed_over;
        assert!(
            pair[1].arrived >= answer_out,
            "request {} arrived {:?} before the end of the answer to request {i}",
            i + 1,
            answer_out.saturating_duration_since(pair[1].arrived),
        );
        let silence = pair[1].silence_before.unwrap_or_default();
        assert!(
            silence >= t3_5,
            "request {} after {silence:?} of silence (t3.5 is {t3_5:?})",
            i + 1
        );
    }
}

async fn chunked_answers_are_taken_whole(gap: Duration) {
    const TRANSACTIONS: usize = 12;
    let line = line(Some(AnswerChunks { bytes: 5, gap }));
    let mut master = Master::new(open(&line), timing(), MasterOptions::default());
    let mut replies = Vec::new();
    for _ in 0..TRANSACTIONS {
        replies.push(master.transact(DEVICE, &read_block(), TIMEOUT).await);
    }
    // The simulator journals a request once its answer is out, just after the master has it.
    line.journal()
        .wait_for_requests(TRANSACTIONS, Duration::from_secs(1))
        .await;
    let records = line.journal().requests();
    assert_eq!(records.len(), TRANSACTIONS, "gap {gap:?}");
    assert_no_request_into_an_answer(&records);
    for (i, reply) in replies.into_iter().enumerate() {
        assert_eq!(
            reply,
            Ok(Ok(Response::HoldingRegisters(REGISTERS.to_vec()))),
            "transaction {i} with {gap:?} pauses inside the answer"
        );
    }
    let counters = master.counters();
    assert_eq!(
        (counters.truncated, counters.stray_bytes, counters.timeouts),
        (0, 0, 0)
    );
    // 17 bytes in chunks of 5: three pauses per answer, each longer than t1.5 (fewer are seen
    // when the host is late and takes two chunks in one read).
    assert!(
        (1..=3 * TRANSACTIONS as u64).contains(&counters.long_gaps),
        "{} long gaps with {gap:?} pauses",
        counters.long_gaps
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pauses_of_2_ms_inside_answers() {
    chunked_answers_are_taken_whole(Duration::from_millis(2)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pauses_of_5_ms_inside_answers() {
    chunked_answers_are_taken_whole(Duration::from_millis(5)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pauses_of_16_ms_inside_answers() {
    chunked_answers_are_taken_whole(Duration::from_millis(16)).await;
}

/// A gateway restarted mid-transaction: the previous process's request is being answered,
/// slowly, when the new master opens the port. Its first request comes t3.5 or more after the
/// answer's last byte; what it heard is counted as stray.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_master_started_during_an_answer_waits_for_the_line_to_fall_silent() {
    // One byte every 5 ms plus its wire time: about 100 ms for the 17-byte answer, with
    // pauses longer than t3.5 inside it, as a USB adapter hands an answer over.
    let line = line(Some(AnswerChunks {
        bytes: 1,
        gap: Duration::from_millis(5),
    }));
    let mut previous = open(&line);
    let frame = codec::encode_request(DEVICE, &read_block()).expect("a valid request");
    previous.write_frame(&frame).await.expect("request written");
    // The previous process dies once the answer has started.
    let mut first = [0u8; 1];
    let heard = previous
        .read_until(&mut first, tokio::time::Instant::now() + TIMEOUT)
        .await
        .expect("read");
    assert!(heard.is_some(), "the device started answering");
    drop(previous);

    let mut master = Master::new(open(&line), timing(), MasterOptions::default());
    let reply = master.transact(DEVICE, &read_block(), TIMEOUT).await;
    line.journal()
        .wait_for_requests(2, Duration::from_secs(1))
        .await;
    let records = line.journal().requests();
    assert_eq!(records.len(), 2);
    let answer_out = records[0]
        .answer_timing
        .expect("the first request was answered")
        .handed_over;
    assert!(
        records[1].arrived >= answer_out + timing().t3_5,
        "first request {:?} after the previous answer's last byte (t3.5 is {:?})",
        records[1].arrived.checked_duration_since(answer_out),
        timing().t3_5
    );
    assert_eq!(
        reply,
        Ok(Ok(Response::HoldingRegisters(REGISTERS.to_vec())))
    );
    // The rest of the old answer (16 bytes, fewer if some came before the port was open).
    let heard = master.counters().stray_bytes;
    assert!((1..=16).contains(&heard), "{heard} stray bytes");
}

/// The master plans the first read of an answer by when the device's answers have begun
/// before. Answers that come sooner than that (the device's turnaround 5 ms shorter, an
/// exception of 5 bytes where 17 were expected) are whole at the planned read, and later ones
/// are read as they come: every answer is taken, and every request waits t3.5 after the last
/// byte before it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn answers_sooner_or_later_than_expected_are_taken_and_heard_out() {
    let line = line(None);
    let mut master = Master::new(open(&line), timing(), MasterOptions::default());
    let registers = Ok(Ok(Response::HoldingRegisters(REGISTERS.to_vec())));
    let exception = Ok(Err(ExceptionCode::ServerDeviceBusy));
    // (the device's extra turnaround, its answer is an exception, transactions)
    let phases = [
        (Duration::from_millis(5), false, 6),
        (Duration::ZERO, false, 4),
        (Duration::ZERO, true, 3),
        (Duration::from_millis(8), false, 3),
        (Duration::ZERO, false, 3),
    ];
    let mut expected = Vec::new();
    let mut replies = Vec::new();
    for (delay, as_exception, transactions) in phases {
        line.faults().update(|f| {
            f.delay = delay;
            f.exception = if as_exception {
                Occurrence::ALWAYS
            } else {
                Occurrence::NEVER
            };
            f.exception_code = Some(ExceptionCode::ServerDeviceBusy);
        });
        for _ in 0..transactions {
            replies.push(master.transact(DEVICE, &read_block(), TIMEOUT).await);
            expected.push(if as_exception {
                exception.clone()
            } else {
                registers.clone()
            });
        }
    }
    line.journal()
        .wait_for_requests(expected.len(), Duration::from_secs(1))
        .await;
    let records = line.journal().requests();
    assert_eq!(records.len(), expected.len());
    assert_no_request_into_an_answer(&records);
    assert_eq!(replies, expected);
    let counters = master.counters();
    assert_eq!(
        (
            counters.truncated,
            counters.stray_bytes,
            counters.timeouts,
            counters.late_answers
        ),
        (0, 0, 0, 0)
    );
}
