//! The simulators behind a TCP port, talked to over real sockets on 127.0.0.1: raw RTU frames
//! (a serial device server) and Modbus TCP (a gateway), byte for byte, with each network fault.

use std::time::Duration;

use rtu2mqtt_modbus::answer_framing::{AnswerFramer, Framed};
use rtu2mqtt_modbus::codec::{decode_answer, encode_request, Answer};
use rtu2mqtt_modbus::tcp::mbap;
use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_modbus::{Request, Response};
use rtu2mqtt_sim::{
    share, AirShower, DustCollector, Occurrence, Protocol, ServeOptions, TcpSimulator,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const READ_DUST: Request = Request::ReadHoldingRegisters {
    start: 0x1000,
    quantity: 6,
};
/// The dust collector's block read, as printed in the device documentation.
const READ_DUST_FRAME: [u8; 8] = [0x01, 0x03, 0x10, 0x00, 0x00, 0x06, 0xC1, 0x08];
/// Its answer to a read just below its table: exception 02.
const READ_BELOW_TABLE_FRAME: [u8; 8] = [0x01, 0x03, 0x0F, 0xFF, 0x00, 0x01, 0xB7, 0x2E];
const EXCEPTION_02_FRAME: [u8; 5] = [0x01, 0x83, 0x02, 0xC0, 0xF1];

/// Line A of the seed plant (dust collector at 1, air shower at 0x81) on a TCP port.
async fn line_a(protocol: Protocol) -> TcpSimulator {
    let devices = vec![share(DustCollector::new(1)).1, share(AirShower::new()).1];
    TcpSimulator::bind(
        "127.0.0.1:0",
        protocol,
        ServeOptions::new(9600, Parity::None),
        devices,
    )
    .await
    .unwrap()
}

async fn connect(sim: &TcpSimulator) -> TcpStream {
    let stream = TcpStream::connect(sim.local_addr()).await.unwrap();
    stream.set_nodelay(true).unwrap();
    stream
}

/// Reads until `len` bytes are in, the peer closes, or `patience` passes; returns the bytes and
/// how many reads they took.
async fn read_bytes(stream: &mut TcpStream, len: usize, patience: Duration) -> (Vec<u8>, usize) {
    let mut bytes = Vec::new();
    let mut reads = 0;
    let deadline = tokio::time::Instant::now() + patience;
    let mut chunk = [0u8; 512];
    while bytes.len() < len {
        match tokio::time::timeout_at(deadline, stream.read(&mut chunk)).await {
            Ok(Ok(0)) | Ok(Err(_)) | Err(_) => break,
            Ok(Ok(count)) => {
                reads += 1;
                bytes.extend_from_slice(&chunk[..count]);
            }
        }
    }
    (bytes, reads)
}

fn dust_answer_len() -> usize {
    READ_DUST.answer_len()
}

#[tokio::test]
async fn raw_rtu_stream_carries_frames_byte_for_byte() {
    let sim = line_a(Protocol::RawRtu).await;
    assert!(sim.url().starts_with("tcp://127.0.0.1:"));
    let mut stream = connect(&sim).await;
    assert_eq!(encode_request(1, &READ_DUST).unwrap(), READ_DUST_FRAME);
    stream.write_all(&READ_DUST_FRAME).await.unwrap();
    let (answer, _) = read_bytes(&mut stream, dust_answer_len(), Duration::from_secs(2)).await;
    let journal = sim.journal().requests();
    assert_eq!(journal.len(), 1);
    assert_eq!(journal[0].frame, READ_DUST_FRAME);
    assert_eq!(Some(&answer), journal[0].answer.as_ref());
    assert!(matches!(
        decode_answer(1, &READ_DUST, &answer),
        Ok(Answer::Normal(Response::HoldingRegisters(words))) if words.len() == 6
    ));

    stream.write_all(&READ_BELOW_TABLE_FRAME).await.unwrap();
    let (exception, _) = read_bytes(&mut stream, 5, Duration::from_secs(2)).await;
    assert_eq!(exception, EXCEPTION_02_FRAME);
}

#[tokio::test]
async fn modbus_tcp_frames_byte_for_byte() {
    let sim = line_a(Protocol::ModbusTcp).await;
    assert!(sim.url().starts_with("modbus-tcp://127.0.0.1:"));
    let mut stream = connect(&sim).await;
    let request = [
        0x12, 0x34, // transaction
        0x00, 0x00, // protocol
        0x00, 0x06, // length: unit and PDU
        0x01, // unit id = RTU address
        0x03, 0x10, 0x00, 0x00, 0x06,
    ];
    assert_eq!(
        mbap::encode_request(0x1234, 1, &READ_DUST).unwrap(),
        request
    );
    stream.write_all(&request).await.unwrap();
    let (answer, _) = read_bytes(&mut stream, 7 + 2 + 12, Duration::from_secs(2)).await;
    assert_eq!(
        &answer[..9],
        &[0x12, 0x34, 0x00, 0x00, 0x00, 0x0F, 0x01, 0x03, 0x0C]
    );
    // The devices heard the RTU frame of the request; the ADU carries their answer's PDU.
    let journal = sim.journal().requests();
    assert_eq!(journal[0].frame, READ_DUST_FRAME);
    let rtu_answer = journal[0].answer.clone().unwrap();
    assert_eq!(&answer[7..], &rtu_answer[1..rtu_answer.len() - 2]);

    let below_table = [
        0x00, 0x02, 0x00, 0x00, 0x00, 0x06, 0x01, 0x03, 0x0F, 0xFF, 0x00, 0x01,
    ];
    stream.write_all(&below_table).await.unwrap();
    let (exception, _) = read_bytes(&mut stream, 9, Duration::from_secs(2)).await;
    assert_eq!(
        exception,
        [0x00, 0x02, 0x00, 0x00, 0x00, 0x03, 0x01, 0x83, 0x02]
    );
    assert_eq!(sim.journal().frames()[1], READ_BELOW_TABLE_FRAME);
}

#[tokio::test]
async fn answer_split_across_segments() {
    let sim = line_a(Protocol::RawRtu).await;
    sim.tcp_faults().update(|f| {
        f.split_answer = Occurrence::next(1);
        f.split_gap = Duration::from_millis(150);
    });
    let mut stream = connect(&sim).await;
    stream.write_all(&READ_DUST_FRAME).await.unwrap();
    let (answer, reads) = read_bytes(&mut stream, dust_answer_len(), Duration::from_secs(2)).await;
    assert_eq!(reads, 2, "the answer came in {reads} reads");
    assert_eq!(Some(&answer), sim.journal().requests()[0].answer.as_ref());
}

#[tokio::test]
async fn two_answers_in_one_segment_keep_their_transaction_ids() {
    let sim = line_a(Protocol::ModbusTcp).await;
    sim.tcp_faults()
        .update(|f| f.hold_for_next = Occurrence::next(1));
    let mut stream = connect(&sim).await;
    stream
        .write_all(&mbap::encode_request(1, 1, &READ_DUST).unwrap())
        .await
        .unwrap();
    let (nothing, _) = read_bytes(&mut stream, 1, Duration::from_millis(300)).await;
    assert!(nothing.is_empty());
    stream
        .write_all(&mbap::encode_request(2, 1, &READ_DUST).unwrap())
        .await
        .unwrap();
    let (both, reads) = read_bytes(&mut stream, 2 * 21, Duration::from_secs(2)).await;
    assert_eq!(reads, 1, "both answers in one segment");
    assert_eq!(both.len(), 42);
    let (first, second) = both.split_at(21);
    assert_eq!(
        mbap::decode_answer(2, 1, &READ_DUST, first).unwrap(),
        mbap::Matched::Stale { transaction: 1 }
    );
    assert!(matches!(
        mbap::decode_answer(2, 1, &READ_DUST, second).unwrap(),
        mbap::Matched::Current(Answer::Normal(_))
    ));
}

#[tokio::test]
async fn garbage_before_an_answer_is_resynchronised() {
    let sim = line_a(Protocol::RawRtu).await;
    sim.tcp_faults().update(|f| {
        f.garbage_before = Occurrence::next(1);
        f.garbage_bytes = 7;
    });
    let mut stream = connect(&sim).await;
    stream.write_all(&READ_DUST_FRAME).await.unwrap();
    let (bytes, _) = read_bytes(&mut stream, 7 + dust_answer_len(), Duration::from_secs(2)).await;
    assert_eq!(bytes.len(), 7 + dust_answer_len());
    let mut buffer = bytes.clone();
    match AnswerFramer::new(1, &READ_DUST).poll(&mut buffer) {
        Framed::Answer { frame, .. } => {
            assert_eq!(Some(&frame), sim.journal().requests()[0].answer.as_ref());
        }
        other => panic!("no answer in {bytes:02X?}: {other:?}"),
    }
}

#[tokio::test]
async fn connection_closed_mid_answer() {
    let sim = line_a(Protocol::RawRtu).await;
    sim.tcp_faults()
        .update(|f| f.close_mid_answer = Occurrence::next(1));
    let mut stream = connect(&sim).await;
    stream.write_all(&READ_DUST_FRAME).await.unwrap();
    let (bytes, _) = read_bytes(&mut stream, dust_answer_len(), Duration::from_secs(2)).await;
    assert!(!bytes.is_empty() && bytes.len() < dust_answer_len());
    let mut eof = [0u8; 1];
    assert_eq!(stream.read(&mut eof).await.unwrap_or(0), 0, "closed");
    // A new connection is served again.
    let mut again = connect(&sim).await;
    again.write_all(&READ_DUST_FRAME).await.unwrap();
    let (answer, _) = read_bytes(&mut again, dust_answer_len(), Duration::from_secs(2)).await;
    assert_eq!(answer.len(), dust_answer_len());
}

#[tokio::test]
async fn accepted_but_never_answered() {
    let sim = line_a(Protocol::ModbusTcp).await;
    sim.tcp_faults()
        .update(|f| f.never_answer = Occurrence::ALWAYS);
    let mut stream = connect(&sim).await;
    stream
        .write_all(&mbap::encode_request(1, 1, &READ_DUST).unwrap())
        .await
        .unwrap();
    let (bytes, _) = read_bytes(&mut stream, 1, Duration::from_millis(500)).await;
    assert!(bytes.is_empty());
    assert_eq!(sim.journal().request_count(), 1, "the device heard it");
}
