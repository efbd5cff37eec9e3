//! The simulated devices over real pseudo-terminals, driven with raw frames: every golden
//! frame of docs/devices.md gets the device's documented answer, the devices' quirks hold on the
//! wire, and every fault knob does what it says. Expected answers were computed independently
//! of the crate (CRC-16/MODBUS by hand), so a CRC bug in the simulator shows here.

use std::path::Path;
use std::time::{Duration, Instant};

use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_modbus::ExceptionCode;
use rtu2mqtt_sim::AsyncSerial;
use rtu2mqtt_sim::{
    air_shower, lock, share, valve, AirShower, DustCollector, Occurrence, Pace, ServeOptions,
    Valve, VirtualLine,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::hex;

/// How long an expected answer may take on a busy machine.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(3);
/// How long to listen before concluding that nothing is coming.
const QUIET_WINDOW: Duration = Duration::from_millis(300);

fn open(path: &Path) -> AsyncSerial {
    let builder = mio_serial::new(path.to_string_lossy(), 9600);
    AsyncSerial::open(&builder).unwrap()
}

/// Sends `request` and reads exactly `answer_len` bytes.
async fn exchange(port: &mut AsyncSerial, request: &[u8], answer_len: usize) -> Vec<u8> {
    port.write_all(request).await.unwrap();
    read_exactly(port, answer_len).await
}

async fn read_exactly(port: &mut AsyncSerial, len: usize) -> Vec<u8> {
    let mut answer = vec![0u8; len];
    tokio::time::timeout(ANSWER_TIMEOUT, port.read_exact(&mut answer))
        .await
        .unwrap_or_else(|_| panic!("no {len}-byte answer within {ANSWER_TIMEOUT:?}"))
        .unwrap();
    answer
}

/// Whatever arrives within the quiet window.
async fn listen(port: &mut AsyncSerial) -> Vec<u8> {
    let mut got = Vec::new();
    let deadline = tokio::time::Instant::now() + QUIET_WINDOW;
    let mut chunk = [0u8; 256];
    while let Ok(Ok(n)) = tokio::time::timeout_at(deadline, port.read(&mut chunk)).await {
        if n == 0 {
            break;
        }
        got.extend_from_slice(&chunk[..n]);
    }
    got
}

/// Sends `request` and hears nothing within the quiet window.
async fn assert_unanswered(port: &mut AsyncSerial, request: &[u8]) {
    port.write_all(request).await.unwrap();
    assert_eq!(
        listen(port).await,
        Vec::<u8>::new(),
        "answer to {request:02X?}"
    );
}

fn line_a() -> (
    VirtualLine,
    std::sync::Arc<std::sync::Mutex<DustCollector>>,
    std::sync::Arc<std::sync::Mutex<AirShower>>,
) {
    let (dust, dust_shared) = share(DustCollector::new(1));
    let (shower, shower_shared) = share(AirShower::new());
    let line = VirtualLine::spawn(
        ServeOptions::new(9600, Parity::None),
        vec![dust_shared, shower_shared],
    )
    .unwrap();
    (line, dust, shower)
}

const READ_ALL: &str = "01 03 10 00 00 06 C1 08";
const GEAR_8: &str = "01 06 10 02 00 08 2D 0C";
const POWER_ON_FC10: &str = "01 10 10 00 00 04 08 03 00 00 05 00 02 00 0A 25 38";
const SHOWER_WRITE_ANSWER: &str = "81 0F 00 00 00 0C 4A 0E";

#[tokio::test]
async fn dust_collector_golden_frames() {
    let (line, dust, _) = line_a();
    let mut port = open(&line.path());
    // Off, gear 3, PV 10, SV 5, fan 0, 24 °C, internal bits 0x2040.
    assert_eq!(
        exchange(&mut port, &hex::decode(READ_ALL), 17).await,
        hex::decode("01 03 0C 20 40 00 03 00 0A 00 05 00 00 00 18 35 F4")
    );
    // FC06 answers echo the request; in standby the gear stays.
    assert_eq!(
        exchange(&mut port, &hex::decode(GEAR_8), 8).await,
        hex::decode(GEAR_8)
    );
    assert_eq!(lock(&dust).gear(), 3);
    // The FC10 that powers on applies everything.
    assert_eq!(
        exchange(&mut port, &hex::decode(POWER_ON_FC10), 8).await,
        hex::decode("01 10 10 00 00 04 C5 0A")
    );
    {
        let dust = lock(&dust);
        assert!(dust.power() && dust.pulse_cleaning());
        assert_eq!(
            (dust.gear(), dust.pulse_interval(), dust.pulse_duration()),
            (5, 2, 10)
        );
        // The golden frame writes 0x0300 over internal bits 0x2040: recorded.
        assert_eq!(rtu2mqtt_sim::SimDevice::violations(&*dust).len(), 1);
    }
    let answer = exchange(&mut port, &hex::decode(READ_ALL), 17).await;
    assert_eq!(
        &answer[..11],
        &hex::decode("01 03 0C 23 40 00 05 00 02 00 0A")[..]
    );
    // Now on, the gear write is applied.
    assert_eq!(
        exchange(&mut port, &hex::decode(GEAR_8), 8).await,
        hex::decode(GEAR_8)
    );
    assert_eq!(lock(&dust).gear(), 8);
    assert_eq!(line.journal().writes_to(1), 3);
    assert_eq!(line.journal().writes_to(0x81), 0);
}

#[tokio::test]
async fn dust_collector_exceptions() {
    let (line, _, _) = line_a();
    let mut port = open(&line.path());
    // Seven words: bad quantity.
    assert_eq!(
        exchange(&mut port, &hex::decode("01 03 10 00 00 07 00 C8"), 5).await,
        hex::decode("01 83 03 01 31")
    );
    // Gear 11: bad value.
    assert_eq!(
        exchange(&mut port, &hex::decode("01 06 10 02 00 0B 6D 0D"), 5).await,
        hex::decode("01 86 03 02 61")
    );
    // Unknown function 0x2B: bad function.
    assert_eq!(
        exchange(&mut port, &hex::decode("01 2B 0E 01 00 70 77"), 5).await,
        hex::decode("01 AB 01 9E F0")
    );
}

#[tokio::test]
async fn air_shower_golden_frames() {
    let (line, _, shower) = line_a();
    let mut port = open(&line.path());
    lock(&shower).set_coil(air_shower::LIGHT, true);
    // The document's 22-coil read; doors closed (coils 16/17 on) and the light on.
    assert_eq!(
        exchange(&mut port, &hex::decode("81 01 00 00 00 16 A2 04"), 8).await,
        hex::decode("81 01 03 00 01 03 62 1F")
    );
    let writes = [
        "81 0F 00 00 00 0C 02 00 00 84 76",
        "81 0F 00 00 00 0C 02 02 00 85 16",
        "81 0F 00 00 00 0C 02 04 00 86 B6",
        "81 0F 00 00 00 0C 02 08 00 83 B6",
        "81 0F 00 00 00 0C 02 10 00 89 B6",
        "81 0F 00 00 00 0C 02 20 00 9D B6",
        "81 0F 00 00 00 0C 02 40 00 B5 B6",
        "81 0F 00 00 00 0C 02 80 00 E5 B6",
        "81 0F 00 00 00 0C 02 00 01 45 B6",
        "81 0F 00 00 00 0C 02 00 02 05 B7",
        "81 0F 00 00 00 0C 02 00 04 85 B5",
        "81 0F 00 00 00 0C 02 00 08 85 B0",
        "81 0F 00 00 00 0C 02 06 00 87 D6",
        "81 0F 00 00 00 0C 02 0E 00 80 16",
        "81 0F 00 00 00 0C 02 0E 01 41 D6",
    ];
    for frame in writes {
        assert_eq!(
            exchange(&mut port, &hex::decode(frame), 8).await,
            hex::decode(SHOWER_WRITE_ANSWER),
            "{frame}"
        );
    }
    // Read after the voice coils have fallen back (they are buttons).
    let coils = lock(&shower).coils_at(Instant::now() + air_shower::VOICE_HOLD);
    let on: Vec<usize> = (0..12).filter(|i| coils[*i]).collect();
    assert_eq!(on, vec![1, 2, 3, 8], "light + both locks + strong");
    assert_eq!(lock(&shower).voice_presses(), [1, 1]);
    assert_eq!(line.journal().frames()[1..], writes.map(hex::decode)[..]);
}

#[tokio::test]
async fn air_shower_exceptions_and_silence() {
    let (line, _, shower) = line_a();
    let mut port = open(&line.path());
    // Strong wind + breeze: exception 03, nothing applied.
    assert_eq!(
        exchange(
            &mut port,
            &hex::decode("81 0F 00 00 00 0C 02 18 00 8E 76"),
            5
        )
        .await,
        hex::decode("81 8F 03 05 D9")
    );
    assert!(!lock(&shower).coils()[air_shower::STRONG_WIND]);
    // 17 coils from 0: address out of range.
    assert_eq!(
        exchange(
            &mut port,
            &hex::decode("81 0F 00 00 00 11 03 00 00 00 9B 9D"),
            5
        )
        .await,
        hex::decode("81 8F 02 C4 19")
    );
    // A function it does not have.
    assert_eq!(
        exchange(&mut port, &hex::decode("81 03 00 00 00 01 9B CA"), 5).await,
        hex::decode("81 83 01 81 18")
    );
    // Bad CRC: no answer, and the line still works afterwards.
    assert_unanswered(&mut port, &hex::decode("81 0F 00 00 00 0C 02 00 01 45 B7")).await;
    assert!(!lock(&shower).coils()[air_shower::LIGHT]);
    assert_eq!(
        exchange(&mut port, &hex::decode("81 01 00 00 00 18 23 C0"), 8).await[..3],
        hex::decode("81 01 03")[..]
    );
    let records = line.journal().requests();
    assert!(!records[3].crc_ok && records[3].answer.is_none());
}

#[tokio::test]
async fn emergency_stop_toggles_on_the_wire() {
    let (line, _, shower) = line_a();
    let mut port = open(&line.path());
    let estop = hex::decode("81 0F 00 00 00 0C 02 01 00 85 E6");
    assert_eq!(
        exchange(&mut port, &estop, 8).await,
        hex::decode(SHOWER_WRITE_ANSWER)
    );
    // E-stop on, both door-closed sensors 0.
    assert_eq!(
        exchange(&mut port, &hex::decode("81 01 00 00 00 18 23 C0"), 8).await[3..6],
        [0x01, 0x00, 0x00]
    );
    // Writing 0 leaves it; writing 1 again clears it.
    exchange(
        &mut port,
        &hex::decode("81 0F 00 00 00 0C 02 00 00 84 76"),
        8,
    )
    .await;
    assert!(lock(&shower).emergency_stop());
    exchange(&mut port, &estop, 8).await;
    assert!(!lock(&shower).emergency_stop());
    assert_eq!(lock(&shower).toggles(), &[true, false]);
    assert_eq!(
        exchange(&mut port, &hex::decode("81 01 00 00 00 18 23 C0"), 8).await[3..6],
        [0x00, 0x00, 0x03]
    );
}

#[tokio::test]
async fn noise_before_a_request_spoils_it_like_on_a_wire() {
    let (line, dust, _) = line_a();
    let mut port = open(&line.path());
    // Noise and a valid frame in one burst make one bad frame for a device framing by silence.
    let burst = [&hex::decode("5A A5")[..], &hex::decode(GEAR_8)[..]].concat();
    assert_unanswered(&mut port, &burst).await;
    assert_eq!(line.journal().writes_to(1), 0);
    let records = line.journal().requests();
    assert_eq!(records.len(), 1);
    assert_eq!(records[0].frame, burst);
    assert!(!records[0].crc_ok);
    // Noise that looks like the start of a read: the 8 bytes framed are bad, the rest of the
    // burst is ignored up to the silence.
    let burst = [&hex::decode("01 03")[..], &hex::decode(GEAR_8)[..]].concat();
    assert_unanswered(&mut port, &burst).await;
    assert_eq!(line.journal().discarded_bytes(), 2);
    lock(&dust).set_power(true);
    // After the silence the device listens again.
    assert_eq!(
        exchange(&mut port, &hex::decode(GEAR_8), 8).await,
        hex::decode(GEAR_8)
    );
    assert_eq!(lock(&dust).gear(), 8);
}

#[tokio::test]
async fn wrong_address_gets_no_answer() {
    let (line, _, _) = line_a();
    let mut port = open(&line.path());
    // Address 2 and address 9 are nobody on line A.
    assert_unanswered(&mut port, &hex::decode("02 03 10 00 00 06 C1 3B")).await;
    assert_unanswered(&mut port, &hex::decode("09 06 10 02 00 08 2C 44")).await;
    assert_eq!(line.journal().request_count(), 2);
}

fn line_b() -> (VirtualLine, std::sync::Arc<std::sync::Mutex<Valve>>) {
    let (valve, shared) = share(Valve::new(1));
    let line = VirtualLine::spawn(ServeOptions::new(9600, Parity::Even), vec![shared]).unwrap();
    (line, valve)
}

#[tokio::test]
async fn valve_bcd_values_and_exceptions() {
    let (line, valve) = line_b();
    let mut port = open(&line.path());
    // Setpoint 120.00 as the BCD pair 0x0120, 0x0000.
    assert_eq!(
        exchange(&mut port, &hex::decode("01 03 00 B2 00 02 64 2C"), 9).await,
        hex::decode("01 03 04 01 20 00 00 FA 05")
    );
    // Measured values: valid BCD pairs.
    let measured = exchange(&mut port, &hex::decode("01 03 00 A2 00 04 E5 EB"), 13).await;
    for nibble_byte in &measured[3..11] {
        assert!(
            nibble_byte >> 4 <= 9 && nibble_byte & 0xF <= 9,
            "{measured:02X?}"
        );
    }
    // A merged block over unmapped registers: exception 02 when strict…
    assert_eq!(
        exchange(&mut port, &hex::decode("01 03 00 74 00 20 04 08"), 5).await,
        hex::decode("01 83 02 C0 F1")
    );
    // …zeros when lenient.
    lock(&valve).set_lenient(true);
    let block = exchange(&mut port, &hex::decode("01 03 00 74 00 20 04 08"), 5 + 64).await;
    assert_eq!(&block[..5], &[0x01, 0x03, 0x40, 0x00, 30]);
    // Broadcast 0x00 is answered (from the device's own address).
    assert_eq!(
        exchange(&mut port, &hex::decode("00 03 00 B2 00 02 65 FD"), 9).await,
        hex::decode("01 03 04 01 20 00 00 FA 05")
    );
}

#[tokio::test]
async fn valve_silent_broadcast_and_baud_write() {
    let (line, valve) = line_b();
    let mut port = open(&line.path());
    // 0xFF: acted on, not answered.
    assert_unanswered(&mut port, &hex::decode("FF 06 00 74 00 50 DC 32")).await;
    assert_eq!(lock(&valve).target(), 80);
    // A baud write is not answered either.
    assert_unanswered(&mut port, &hex::decode("01 06 00 0A 00 07 E8 0A")).await;
    assert_eq!(lock(&valve).baud_switches(), &[7]);
    assert_eq!(line.journal().writes_to(1), 2);
}

#[tokio::test]
async fn valve_opening_moves_over_the_wire() {
    let (line, valve) = line_b();
    lock(&valve).set_speed(50.0);
    let mut port = open(&line.path());
    // Opening to 0x50 = 80 %.
    let write = hex::decode("01 06 00 74 00 50 C9 EC");
    assert_eq!(exchange(&mut port, &write, 8).await, write);
    let status = exchange(&mut port, &hex::decode("01 03 00 90 00 01 84 27"), 7).await;
    assert_eq!(
        status[4] & 0x0C,
        valve::MOTOR_OPENING as u8,
        "motor opening right after the write"
    );
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let opening = exchange(&mut port, &hex::decode("01 03 00 74 00 01 C4 10"), 7).await;
        if opening[4] == 80 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "never reached 80 %: {opening:02X?}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let status = exchange(&mut port, &hex::decode("01 03 00 90 00 01 84 27"), 7).await;
    assert_eq!(status[4] & 0x0C, 0, "motor stopped");
}

#[tokio::test]
async fn fault_knobs_do_what_they_say() {
    let (line, _, _) = line_a();
    let mut port = open(&line.path());
    let read = hex::decode(READ_ALL);
    let faults = line.faults();

    faults.update(|f| f.drop = Occurrence::next(1));
    port.write_all(&read).await.unwrap();
    assert_eq!(listen(&mut port).await, Vec::<u8>::new(), "dropped");
    assert_eq!(
        exchange(&mut port, &read, 17).await[..3],
        [1, 3, 12],
        "only one dropped"
    );

    faults.update(|f| f.corrupt_crc = Occurrence::next(1));
    let corrupt = exchange(&mut port, &read, 17).await;
    let good = exchange(&mut port, &read, 17).await;
    assert_eq!(corrupt[..15], good[..15]);
    assert_ne!(corrupt[15..], good[15..]);

    faults.update(|f| {
        f.truncate = Occurrence::next(1);
        f.truncate_bytes = 3;
    });
    port.write_all(&read).await.unwrap();
    assert_eq!(
        listen(&mut port).await,
        good[..14].to_vec(),
        "truncated by 3"
    );

    faults.update(|f| {
        f.wrong_address = Occurrence::next(1);
        f.wrong_address_value = 9;
    });
    port.write_all(&read).await.unwrap();
    let misaddressed = listen(&mut port).await;
    assert_eq!(misaddressed[0], 9);
    assert_eq!(misaddressed[1..15], good[1..15]);

    faults.update(|f| {
        f.exception = Occurrence::next(1);
        f.exception_code = Some(ExceptionCode::ServerDeviceBusy);
    });
    assert_eq!(
        exchange(&mut port, &read, 5).await,
        hex::decode("01 83 06 C1 32")
    );

    faults.update(|f| {
        f.garbage_before = Occurrence::next(1);
        f.garbage_bytes = 4;
    });
    port.write_all(&read).await.unwrap();
    let with_garbage = listen(&mut port).await;
    assert_eq!(with_garbage.len(), 4 + 17);
    assert_eq!(with_garbage[4..19], good[..15]);

    faults.update(|f| f.echo = true);
    port.write_all(&read).await.unwrap();
    let echoed = listen(&mut port).await;
    assert_eq!(echoed[..8], read[..]);
    assert_eq!(echoed.len(), 8 + 17);
    faults.update(|f| f.echo = false);

    faults.silence(1, true);
    port.write_all(&read).await.unwrap();
    assert_eq!(listen(&mut port).await, Vec::<u8>::new(), "silenced");
    // The other device on the line still answers.
    assert_eq!(
        exchange(&mut port, &hex::decode("81 01 00 00 00 18 23 C0"), 8).await[..3],
        hex::decode("81 01 03")[..]
    );
    faults.silence(1, false);

    let delay = Duration::from_millis(150);
    faults.update(|f| f.delay = delay);
    let sent = Instant::now();
    exchange(&mut port, &read, 17).await;
    assert!(sent.elapsed() >= delay, "late answer");
    faults.clear();

    let pause = Duration::from_millis(100);
    faults.update(|f| f.pause_mid_answer = Some(pause));
    port.write_all(&read).await.unwrap();
    let mut first = [0u8; 1];
    tokio::time::timeout(ANSWER_TIMEOUT, port.read_exact(&mut first))
        .await
        .unwrap()
        .unwrap();
    let first_byte = Instant::now();
    let rest = read_exactly(&mut port, 16).await;
    assert!(first_byte.elapsed() >= pause / 2, "gap inside the answer");
    assert_eq!([&first[..], &rest[..]].concat()[..15], good[..15]);
    faults.clear();

    faults.update(|f| f.idle_garbage_every = Some(Duration::from_millis(20)));
    assert!(!listen(&mut port).await.is_empty(), "idle garbage");
    faults.clear();
}

#[tokio::test]
async fn pacing_delays_the_answer_by_its_wire_time() {
    let (dust, shared) = share(DustCollector::new(1));
    let options = ServeOptions::new(9600, Parity::None).paced(true);
    let line = VirtualLine::spawn(options, vec![shared]).unwrap();
    let mut port = open(&line.path());
    let timing = options.timing;
    // Request 8 bytes + t3.5 + answer 17 bytes at 9600 8N1: about 29 ms.
    let minimum = timing.frame_time(8) + timing.t3_5 + timing.frame_time(17);
    for _ in 0..3 {
        let sent = Instant::now();
        exchange(&mut port, &hex::decode(READ_ALL), 17).await;
        let took = sent.elapsed();
        assert!(
            took >= minimum,
            "answer after {took:?}, wire needs {minimum:?}"
        );
        println!("paced transaction: {took:?} (wire minimum {minimum:?})");
    }
    drop(dust);
}

/// Sends `request` and reads `len` bytes, noting after each read how many bytes came and
/// when (from the request's sending).
async fn timed_reads(port: &mut AsyncSerial, request: &[u8], len: usize) -> Vec<(Duration, usize)> {
    port.write_all(request).await.unwrap();
    let sent = Instant::now();
    let mut reads = Vec::new();
    let mut got = 0;
    let mut chunk = [0u8; 256];
    while got < len {
        let n = tokio::time::timeout(ANSWER_TIMEOUT, port.read(&mut chunk[..len - got]))
            .await
            .unwrap_or_else(|_| panic!("{got} of {len} answer bytes within {ANSWER_TIMEOUT:?}"))
            .unwrap();
        assert!(n > 0, "the line closed");
        got += n;
        reads.push((sent.elapsed(), n));
    }
    reads
}

#[tokio::test]
async fn byte_pacing_spreads_the_answer_over_its_wire_time() {
    let (_dust, shared) = share(DustCollector::new(1));
    let options = ServeOptions::new(9600, Parity::None).pacing(Pace::Bytes);
    let line = VirtualLine::spawn(options, vec![shared]).unwrap();
    let mut port = open(&line.path());
    let timing = options.timing;
    // The 17-byte answer's last byte comes 16 character times after its first.
    let spread = timing.frame_time(16);
    let mut best = Vec::new();
    for _ in 0..3 {
        let reads = timed_reads(&mut port, &hex::decode(READ_ALL), 17).await;
        let last = reads.last().unwrap().0;
        // No byte before it can be on the wire: request, t3.5, one character.
        let first_possible = timing.frame_time(8) + timing.t3_5 + timing.frame_time(1);
        assert!(reads[0].0 >= first_possible, "{reads:?}");
        assert!(
            last >= first_possible + spread,
            "last byte after {last:?}: {reads:?}"
        );
        if reads.len() > best.len() {
            best = reads;
        }
    }
    // A reader that kept up saw the bytes come one or two at a time, spread over the answer
    // (a late reader finds several waiting: the best of three exchanges is judged).
    let span = best.last().unwrap().0 - best[0].0;
    assert!(best.len() >= 9, "{best:?}");
    assert!(span >= spread.mul_f64(0.8), "span {span:?}: {best:?}");
    assert!(best.iter().all(|&(_, n)| n <= 8), "{best:?}");
}

#[tokio::test]
async fn usb_pacing_hands_over_the_answer_in_chunks_at_its_interval() {
    let (_dust, shared) = share(DustCollector::new(1));
    let every = Duration::from_millis(4);
    let options = ServeOptions::new(9600, Parity::None).pacing(Pace::Usb { every });
    let line = VirtualLine::spawn(options, vec![shared]).unwrap();
    let mut port = open(&line.path());
    let timing = options.timing;
    let mut best: Vec<(Duration, usize)> = Vec::new();
    for _ in 0..3 {
        let reads = timed_reads(&mut port, &hex::decode(READ_ALL), 17).await;
        let last = reads.last().unwrap().0;
        let minimum = timing.frame_time(8) + timing.t3_5 + timing.frame_time(17);
        assert!(last >= minimum, "last byte after {last:?}: {reads:?}");
        if reads.len() > best.len() {
            best = reads;
        }
    }
    // 17.7 ms of answer: four or five chunks about 4 ms apart (a late reader, or a kernel
    // that hands a pty write over late, may merge or split one: the best of three is judged),
    // neither one whole answer nor byte by byte.
    assert!((3..=6).contains(&best.len()), "{best:?}");
    let span = best.last().unwrap().0 - best[0].0;
    assert!(span >= every * 2, "span {span:?}: {best:?}");
}

#[tokio::test]
async fn journal_records_frames_and_silences() {
    let (line, _, _) = line_a();
    let mut port = open(&line.path());
    exchange(&mut port, &hex::decode(READ_ALL), 17).await;
    tokio::time::sleep(Duration::from_millis(20)).await;
    exchange(&mut port, &hex::decode(GEAR_8), 8).await;
    let records = line.journal().requests();
    assert_eq!(records.len(), 2);
    assert_eq!(records[0].frame, hex::decode(READ_ALL));
    assert_eq!(records[1].frame, hex::decode(GEAR_8));
    assert_eq!(records[0].silence_before, None);
    let silence = records[1].silence_before.unwrap();
    assert!(silence >= Duration::from_millis(20), "{silence:?}");
    assert!(records[1].arrived > records[0].arrived);
    assert_eq!(records[1].answer.as_deref(), Some(&hex::decode(GEAR_8)[..]));
}

#[tokio::test]
async fn unplug_and_replug_through_a_stable_link() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyRS485");
    let (_, shared) = share(DustCollector::new(1));
    let mut line =
        VirtualLine::with_link(ServeOptions::new(9600, Parity::None), vec![shared], &link).unwrap();
    let first = line.slave_path().unwrap().to_path_buf();
    let mut port = open(&link);
    exchange(&mut port, &hex::decode(READ_ALL), 17).await;

    line.unplug().await;
    assert!(!line.is_plugged());
    // The gateway's open port is dead: a read ends or fails at once.
    let mut buffer = [0u8; 8];
    let read = tokio::time::timeout(ANSWER_TIMEOUT, port.read(&mut buffer)).await;
    assert!(matches!(read, Ok(Ok(0)) | Ok(Err(_))), "{read:?}");
    drop(port);

    line.replug().await.unwrap();
    let second = line.slave_path().unwrap().to_path_buf();
    assert_eq!(
        std::fs::canonicalize(&link).unwrap(),
        std::fs::canonicalize(&second).unwrap()
    );
    let mut port = open(&link);
    exchange(&mut port, &hex::decode(READ_ALL), 17).await;
    assert_eq!(line.journal().request_count(), 2);
    println!("replugged {} → {}", first.display(), second.display());
}

#[tokio::test]
async fn power_up_handshake_keeps_the_device_quiet() {
    let powered_up = Instant::now();
    let handshake = Duration::from_secs(1);
    let device = DustCollector::new(1).with_power_up_handshake(powered_up, handshake);
    let (_, shared) = share(device);
    let line = VirtualLine::spawn(ServeOptions::new(9600, Parity::None), vec![shared]).unwrap();
    let mut port = open(&line.path());
    port.write_all(&hex::decode(READ_ALL)).await.unwrap();
    assert_eq!(
        listen(&mut port).await,
        Vec::<u8>::new(),
        "quiet during the handshake"
    );
    let record = &line.journal().requests()[0];
    assert!(record.arrived < powered_up + handshake);
    assert!(record.answer.is_none());
    tokio::time::sleep_until(tokio::time::Instant::from_std(powered_up + handshake)).await;
    assert_eq!(
        exchange(&mut port, &hex::decode(READ_ALL), 17).await[..3],
        [1, 3, 12]
    );
}

#[tokio::test]
async fn seed_plant_serves_both_lines() {
    let plant = rtu2mqtt_sim::SeedPlant::spawn(false).unwrap();
    let mut line_a = open(&plant.line_a.path());
    let mut line_b = open(&plant.line_b.path());
    assert_eq!(
        exchange(&mut line_a, &hex::decode(READ_ALL), 17).await[..3],
        [1, 3, 12]
    );
    assert_eq!(
        exchange(&mut line_a, &hex::decode("81 01 00 00 00 16 A2 04"), 8).await[..3],
        hex::decode("81 01 03")[..]
    );
    assert_eq!(
        exchange(&mut line_b, &hex::decode("01 03 00 B2 00 02 64 2C"), 9).await,
        hex::decode("01 03 04 01 20 00 00 FA 05")
    );
    lock(&plant.valve).set_opening(55);
    assert_eq!(
        exchange(&mut line_b, &hex::decode("01 03 00 74 00 01 C4 10"), 7).await[3..5],
        [0, 55]
    );
}

// The built-in profiles driving the simulated devices through the gateway's master: the
// simulators were written from docs/devices.md apart from the profiles, so this is where a profile
// that writes the wrong bits or reads the wrong places shows.

use rtu2mqtt_modbus::serial::master::{Master, MasterOptions};
use rtu2mqtt_modbus::serial::transport::{Port, SerialSettings};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming};
use rtu2mqtt_modbus::{Request, Response, Transact};
use rtu2mqtt_profile::{DeviceState, Profile, Verification};

const MASTER_TIMEOUT: Duration = Duration::from_millis(800);

fn master_on(line: &VirtualLine, parity: Parity) -> Master {
    let format = CharFormat {
        data_bits: 8,
        parity,
        stop_bits: 1,
    };
    let settings = SerialSettings {
        path: line.path().to_string_lossy().into_owned(),
        baud: 9600,
        format,
        rs485: None,
    };
    let port = Port::open(&settings).unwrap();
    Master::new(
        port,
        LineTiming::new(9600, format),
        MasterOptions::default(),
    )
}

/// Reads a block as the line does: when the device refuses the merged block (exception 02),
/// the runs its fields use, one by one.
async fn read_block(
    master: &mut Master,
    address: u8,
    profile: &Profile,
    request: &Request,
) -> Response {
    match master.transact(address, request, MASTER_TIMEOUT).await {
        Ok(Ok(answer)) => answer,
        Ok(Err(ExceptionCode::IllegalDataAddress)) => {
            let block = profile
                .read_blocks()
                .iter()
                .find(|block| block.request == *request)
                .unwrap_or_else(|| panic!("{request:?} refused and not a block"));
            assemble_from_runs(master, address, request, &block.used_runs).await
        }
        Ok(Err(code)) => panic!("{}: {request:?}: device answered {code}", profile.name()),
        Err(error) => panic!("{}: {request:?}: {error}", profile.name()),
    }
}

/// Reads and decodes every block of the profile; every field must decode.
async fn poll(master: &mut Master, address: u8, profile: &Profile) -> DeviceState {
    let mut state = DeviceState::new();
    for (index, block) in profile.read_blocks().iter().enumerate() {
        let answer = read_block(master, address, profile, &block.request).await;
        for reading in profile.decode_block(index, &answer) {
            let value = reading
                .value
                .unwrap_or_else(|e| panic!("{}.{}: {e}", profile.name(), reading.field));
            state.insert(reading.field, value);
        }
    }
    state
}

async fn assemble_from_runs(
    master: &mut Master,
    address: u8,
    request: &Request,
    runs: &[(u16, u16)],
) -> Response {
    let Request::ReadHoldingRegisters { start, quantity } = request else {
        panic!("only register blocks are merged in the seed profiles: {request:?}");
    };
    let mut words = vec![0u16; usize::from(*quantity)];
    for &(offset, length) in runs {
        let run = Request::ReadHoldingRegisters {
            start: start + offset,
            quantity: length,
        };
        let answer = master
            .transact(address, &run, MASTER_TIMEOUT)
            .await
            .unwrap()
            .unwrap();
        let got = answer.registers().unwrap();
        words[usize::from(offset)..usize::from(offset + length)].copy_from_slice(got);
    }
    Response::HoldingRegisters(words)
}

/// The command's read-back shows it applied.
async fn assert_applied(
    master: &mut Master,
    address: u8,
    profile: &Profile,
    field: &str,
    text: &str,
) {
    let (_, verdict) = command(master, address, profile, field, text).await;
    assert_eq!(verdict, Verification::Applied, "{field}={text}");
}

/// Runs one command slot as the line does: reads before, writes, read-back, verdict.
async fn command(
    master: &mut Master,
    address: u8,
    profile: &Profile,
    field: &str,
    text: &str,
) -> (usize, Verification) {
    let plan = profile
        .plan_command(field, text, &DeviceState::new())
        .unwrap_or_else(|r| panic!("{field}={text}: {r}"));
    let mut before = Vec::new();
    for read in plan.reads_before() {
        before.push(read_block(master, address, profile, read).await);
    }
    let writes = plan.writes(&before).unwrap();
    for write in &writes {
        master
            .transact(address, write, MASTER_TIMEOUT)
            .await
            .unwrap()
            .unwrap();
    }
    let mut back = Vec::new();
    for read in plan.readback() {
        back.push(read_block(master, address, profile, read).await);
    }
    (writes.len(), plan.verify(&back))
}

fn built_in(name: &str) -> Profile {
    rtu2mqtt_profile::registry::built_in(name).unwrap()
}

#[tokio::test]
async fn dust_collector_profile_against_the_simulator() {
    let (line, dust, _) = line_a();
    let mut master = master_on(&line, Parity::None);
    let profile = built_in("ruiwan-dust-collector");
    let state = poll(&mut master, 1, &profile).await;
    assert_eq!(state["power"].to_text(), "OFF");
    assert_eq!(state["gear"].to_text(), "3");
    assert_eq!(state["pulse_interval"].to_text(), "10");
    assert_eq!(state["pulse_duration"].to_text(), "5");

    // Standby: acknowledged, not applied.
    let (_, verdict) = command(&mut master, 1, &profile, "gear", "8").await;
    assert!(
        matches!(verdict, Verification::NotApplied(_)),
        "{verdict:?}"
    );
    assert_eq!(lock(&dust).gear(), 3);

    assert_applied(&mut master, 1, &profile, "power", "ON").await;
    assert_applied(&mut master, 1, &profile, "gear", "8").await;
    assert_applied(&mut master, 1, &profile, "pulse_cleaning", "ON").await;
    let dust = lock(&dust);
    assert!(dust.power() && dust.pulse_cleaning());
    assert_eq!(dust.gear(), 8);
    // The status word was written read-modify-write: internal bits untouched.
    assert_eq!(
        rtu2mqtt_sim::SimDevice::violations(&*dust),
        Vec::<String>::new()
    );
}

#[tokio::test]
async fn air_shower_profile_against_the_simulator() {
    let (line, _, shower) = line_a();
    let mut master = master_on(&line, Parity::None);
    let profile = built_in("lixian-air-shower");
    let state = poll(&mut master, 0x81, &profile).await;
    assert_eq!(state["front_door_closed"].to_text(), "ON");
    assert_eq!(state["emergency_stop"].to_text(), "OFF");

    assert_applied(&mut master, 0x81, &profile, "light", "ON").await;
    assert_applied(&mut master, 0x81, &profile, "emergency_stop", "ON").await;
    // Asking for the state it is in writes nothing (a write would toggle it off).
    let (writes, verdict) = command(&mut master, 0x81, &profile, "emergency_stop", "ON").await;
    assert_eq!((writes, verdict), (0, Verification::Applied));
    // Other commands while the e-stop is active must not clear it.
    assert_applied(&mut master, 0x81, &profile, "front_door_lock", "ON").await;
    command(&mut master, 0x81, &profile, "voice_start", "PRESS").await;
    assert_applied(&mut master, 0x81, &profile, "wind", "strong").await;
    {
        let shower = lock(&shower);
        assert_eq!(shower.toggles(), &[true], "exactly one e-stop toggle");
        assert_eq!(shower.voice_presses(), [1, 0]);
        let coils = shower.coils();
        assert!(coils[air_shower::LIGHT] && coils[air_shower::FRONT_DOOR_LOCK]);
        assert!(coils[air_shower::STRONG_WIND] && !coils[air_shower::BREEZE]);
    }
    let state = poll(&mut master, 0x81, &profile).await;
    assert_eq!(
        state["front_door_closed"].to_text(),
        "OFF",
        "e-stop opens the doors"
    );
    assert_applied(&mut master, 0x81, &profile, "emergency_stop", "OFF").await;
    assert_eq!(lock(&shower).toggles(), &[true, false]);
}

#[tokio::test]
async fn valve_profile_against_the_simulator() {
    let (line, valve) = line_b();
    lock(&valve).set_speed(100.0);
    let mut master = master_on(&line, Parity::Even);
    let profile = built_in("wuzhou-valve");
    // Strict about unmapped registers: the merged blocks fall back to their runs.
    let state = poll(&mut master, 1, &profile).await;
    assert_eq!(state["setpoint"].to_text(), "120.00");
    assert_eq!(state["opening"].to_text(), "30");
    assert_eq!(state["motor"].to_text(), "stopped");
    assert_eq!(state["serial_number"].to_text(), "20231122004A5B");

    assert_applied(&mut master, 1, &profile, "setpoint", "12.5").await;
    assert_eq!(lock(&valve).register(valve::REG_SETPOINT), Some(0x0012));
    assert_eq!(lock(&valve).register(valve::REG_SETPOINT + 1), Some(0x0050));

    let (_, verdict) = command(&mut master, 1, &profile, "opening", "90").await;
    assert!(
        matches!(verdict, Verification::Settling | Verification::Applied),
        "{verdict:?}"
    );
    let deadline = Instant::now() + Duration::from_secs(10);
    while lock(&valve).opening() != 90 {
        assert!(Instant::now() < deadline, "valve never reached 90 %");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let state = poll(&mut master, 1, &profile).await;
    assert_eq!(state["opening"].to_text(), "90");
    assert_eq!(state["motor"].to_text(), "stopped");
    assert_eq!(state["fully_open"].to_text(), "OFF");
    assert_eq!(state["fully_closed"].to_text(), "OFF");
    assert_applied(&mut master, 1, &profile, "mode", "auto").await;
    assert!(lock(&valve).mode_auto());
}

#[tokio::test]
async fn master_leaves_t3_5_between_frames_on_a_paced_line() {
    let (_, shared) = share(DustCollector::new(1));
    let options = ServeOptions::new(9600, Parity::None).paced(true);
    let line = VirtualLine::spawn(options, vec![shared]).unwrap();
    let mut master = master_on(&line, Parity::None);
    let read = Request::ReadHoldingRegisters {
        start: 0x1000,
        quantity: 6,
    };
    let started = Instant::now();
    let count = 10;
    for _ in 0..count {
        master
            .transact(1, &read, MASTER_TIMEOUT)
            .await
            .unwrap()
            .unwrap();
    }
    let elapsed = started.elapsed();
    let journal = line.journal();
    assert_eq!(journal.frames(), vec![hex::decode(READ_ALL); count]);
    let min_silence = journal.min_silence().unwrap();
    assert!(
        min_silence >= options.timing.t3_5,
        "silence {min_silence:?} < t3.5 {:?}",
        options.timing.t3_5
    );
    // Wire minimum per transaction: request, t3.5, answer, t3.5.
    let wire = options.timing.frame_time(8 + 17) + options.timing.t3_5 * 2;
    println!(
        "{count} paced transactions in {elapsed:?}: {:?} each, wire minimum {wire:?}, \
         smallest silence before a request {min_silence:?}",
        elapsed / count as u32
    );
}

#[tokio::test]
async fn long_noise_never_stops_the_line() {
    let (line, _, _) = line_a();
    let mut port = open(&line.path());
    // 2 KiB of pseudo-random bytes in one burst (longer than any frame).
    let noise: Vec<u8> = (0u32..2048)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    port.write_all(&noise).await.unwrap();
    let _ = listen(&mut port).await;
    assert!(line.journal().discarded_bytes() > 0);
    assert_eq!(
        exchange(&mut port, &hex::decode(READ_ALL), 17).await,
        hex::decode("01 03 0C 20 40 00 03 00 0A 00 05 00 00 00 18 35 F4")
    );
}

/// A process started while a line is served (a broker, a gateway under test) inherits no end
/// of its pty: an unplugged line must really be gone for the gateway.
#[tokio::test]
async fn a_served_line_is_not_inherited_by_child_processes() {
    let (line, _, _) = line_a();
    let slave = line
        .path()
        .canonicalize()
        .expect("the line's path resolves");
    let listing = std::process::Command::new("sh")
        .args(["-c", "for fd in /proc/self/fd/*; do readlink \"$fd\"; done"])
        .output()
        .expect("sh runs");
    let open_files = String::from_utf8_lossy(&listing.stdout);
    assert!(
        !open_files
            .lines()
            .any(|file| file == "/dev/ptmx" || std::path::Path::new(file) == slave),
        "the child holds an end of the served pty ({}): {open_files}",
        slave.display()
    );
}
