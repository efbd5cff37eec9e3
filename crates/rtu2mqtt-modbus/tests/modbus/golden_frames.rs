//! Every frame printed in docs/devices.md, byte for byte, both ways: the master encodes the
//! request and decodes the answer; the server side (simulators) decodes the request and encodes
//! the answer.

use rtu2mqtt_modbus::codec::{
    decode_answer, decode_request, encode_answer, encode_exception, encode_request,
    request_frame_len, Answer,
};
use rtu2mqtt_modbus::{ExceptionCode, FunctionCode, Request, Response};

/// Master encodes exactly `frame`; the server side frames and decodes it back to `request`.
fn assert_request_golden(slave: u8, request: &Request, frame: &[u8]) {
    assert_eq!(
        encode_request(slave, request).unwrap(),
        frame,
        "encoded {request:?}"
    );
    assert_eq!(request_frame_len(&frame[..7]).unwrap(), Some(frame.len()));
    assert_eq!(decode_request(frame).unwrap(), (slave, request.clone()));
}

/// Server side encodes exactly `frame`; the master decodes it to `response`.
fn assert_answer_golden(slave: u8, request: &Request, response: &Response, frame: &[u8]) {
    assert_eq!(request.answer_len(), frame.len());
    assert_eq!(
        encode_answer(slave, response),
        frame,
        "encoded {response:?}"
    );
    assert_eq!(
        decode_answer(slave, request, frame).unwrap(),
        Answer::Normal(response.clone())
    );
}

/// `body` followed by its CRC, low byte first: for the answers the document does not print.
fn with_crc(mut body: Vec<u8>) -> Vec<u8> {
    let crc = rtu2mqtt_modbus::crc::crc16(&body);
    body.extend(crc.to_le_bytes());
    body
}

// ---- 1. Dust collector (address 1, holding registers at 0x1000) ----

#[test]
fn dust_collector_read_all() {
    let request = Request::ReadHoldingRegisters {
        start: 0x1000,
        quantity: 6,
    };
    #[rustfmt::skip]
    let frame = [
        0x01,       // address 1
        0x03,       // read holding registers
        0x10, 0x00, // start 0x1000
        0x00, 0x06, // 6 registers
        0xC1, 0x08, // CRC, low byte first
    ];
    assert_request_golden(1, &request, &frame);
    // Its answer (not printed in the document): 6 words, 12 data bytes.
    let words = vec![0x0003, 0x0005, 0x0002, 0x000A, 0x05DC, 0x0019];
    let mut body = vec![0x01, 0x03, 12];
    body.extend(words.iter().flat_map(|word: &u16| word.to_be_bytes()));
    let answer = with_crc(body);
    assert_answer_golden(1, &request, &Response::HoldingRegisters(words), &answer);
}

#[test]
fn dust_collector_gear_8() {
    let request = Request::WriteSingleRegister {
        address: 0x1002,
        value: 8,
    };
    #[rustfmt::skip]
    let frame = [
        0x01,       // address 1
        0x06,       // write single register
        0x10, 0x02, // register 0x1002 (gear, table address)
        0x00, 0x08, // gear 8
        0x2D, 0x0C, // CRC
    ];
    assert_request_golden(1, &request, &frame);
    // The answer to FC06 echoes the request.
    assert_answer_golden(
        1,
        &request,
        &Response::WriteSingleRegister {
            address: 0x1002,
            value: 8,
        },
        &frame,
    );
}

#[test]
fn dust_collector_power_on_pulse_gear_pv_sv() {
    let request = Request::WriteMultipleRegisters {
        start: 0x1000,
        values: vec![0x0300, 0x0005, 0x0002, 0x000A],
    };
    #[rustfmt::skip]
    let frame = [
        0x01,       // address 1
        0x10,       // write multiple registers
        0x10, 0x00, // start 0x1000
        0x00, 0x04, // 4 registers
        0x08,       // 8 data bytes
        0x03, 0x00, // status word: power on + pulse cleaning on
        0x00, 0x05, // gear 5
        0x00, 0x02, // PV 2 minutes
        0x00, 0x0A, // SV 10 seconds
        0x25, 0x38, // CRC
    ];
    assert_request_golden(1, &request, &frame);
    let answer = with_crc(vec![0x01, 0x10, 0x10, 0x00, 0x00, 0x04]);
    assert_answer_golden(
        1,
        &request,
        &Response::WriteMultipleRegisters {
            start: 0x1000,
            quantity: 4,
        },
        &answer,
    );
}

// ---- 3. Air shower (address 0x81, coils) ----

#[test]
fn air_shower_read_22_coils_light_on() {
    let request = Request::ReadCoils {
        start: 0,
        quantity: 22,
    };
    #[rustfmt::skip]
    let frame = [
        0x81,       // address 0x81
        0x01,       // read coils
        0x00, 0x00, // start coil 0
        0x00, 0x16, // 22 coils
        0xA2, 0x04, // CRC
    ];
    assert_request_golden(0x81, &request, &frame);
    #[rustfmt::skip]
    let answer = [
        0x81,             // address 0x81
        0x01,             // read coils
        0x03,             // 3 data bytes for 22 coils
        0x00, 0x01, 0x00, // coils 0-7 off, coil 8 (light) on, coils 16-21 off
        0x22, 0x1E,       // CRC
    ];
    let mut coils = vec![false; 22];
    coils[8] = true;
    assert_answer_golden(0x81, &request, &Response::Coils(coils), &answer);
}

/// The 12 writable coils from the two data bytes of the document's frame.
fn twelve_coils(low: u8, high: u8) -> Vec<bool> {
    (0..12)
        .map(|coil| {
            if coil < 8 {
                low & (1 << coil) != 0
            } else {
                high & (1 << (coil - 8)) != 0
            }
        })
        .collect()
}

#[test]
fn air_shower_all_sixteen_writes_and_their_answer() {
    // (meaning, coils 0-7 byte, coils 8-11 byte, CRC low, CRC high)
    let table: [(&str, u8, u8, u8, u8); 16] = [
        ("all clear", 0x00, 0x00, 0x84, 0x76),
        ("e-stop", 0x01, 0x00, 0x85, 0xE6),
        ("front lock", 0x02, 0x00, 0x85, 0x16),
        ("rear lock", 0x04, 0x00, 0x86, 0xB6),
        ("strong wind", 0x08, 0x00, 0x83, 0xB6),
        ("breeze", 0x10, 0x00, 0x89, 0xB6),
        ("front auto door", 0x20, 0x00, 0x9D, 0xB6),
        ("rear auto door", 0x40, 0x00, 0xB5, 0xB6),
        ("tunnel extension", 0x80, 0x00, 0xE5, 0xB6),
        ("light", 0x00, 0x01, 0x45, 0xB6),
        ("buzzer", 0x00, 0x02, 0x05, 0xB7),
        ("voice start", 0x00, 0x04, 0x85, 0xB5),
        ("voice door", 0x00, 0x08, 0x85, 0xB0),
        ("both locks", 0x06, 0x00, 0x87, 0xD6),
        ("both locks + strong", 0x0E, 0x00, 0x80, 0x16),
        ("light + both locks + strong", 0x0E, 0x01, 0x41, 0xD6),
    ];
    #[rustfmt::skip]
    let answer = [
        0x81,       // address 0x81
        0x0F,       // write multiple coils
        0x00, 0x00, // start coil 0
        0x00, 0x0C, // 12 coils written
        0x4A, 0x0E, // CRC
    ];
    for (meaning, low, high, crc_low, crc_high) in table {
        let request = Request::WriteMultipleCoils {
            start: 0,
            values: twelve_coils(low, high),
        };
        #[rustfmt::skip]
        let frame = [
            0x81,             // address 0x81
            0x0F,             // write multiple coils
            0x00, 0x00,       // start coil 0
            0x00, 0x0C,       // 12 coils
            0x02,             // 2 data bytes
            low, high,        // coils 0-7, coils 8-11 (bits 12-15 zero)
            crc_low, crc_high, // CRC
        ];
        assert_eq!(encode_request(0x81, &request).unwrap(), frame, "{meaning}");
        assert_eq!(
            decode_request(&frame).unwrap(),
            (0x81, request.clone()),
            "{meaning}"
        );
        assert_answer_golden(
            0x81,
            &request,
            &Response::WriteMultipleCoils {
                start: 0,
                quantity: 12,
            },
            &answer,
        );
    }
}

#[test]
fn air_shower_exceptions() {
    let request = Request::WriteMultipleCoils {
        start: 0,
        values: twelve_coils(0x18, 0x00),
    };
    // (code, CRC low, CRC high)
    let table = [
        (ExceptionCode::IllegalFunction, 0x84, 0x18),
        (ExceptionCode::IllegalDataAddress, 0xC4, 0x19),
        (ExceptionCode::IllegalDataValue, 0x05, 0xD9),
    ];
    for (code, crc_low, crc_high) in table {
        #[rustfmt::skip]
        let frame = [
            0x81,              // address 0x81
            0x8F,              // 0x0F | 0x80: exception to write multiple coils
            code.value(),      // exception code
            crc_low, crc_high, // CRC
        ];
        assert_eq!(
            encode_exception(0x81, FunctionCode::WriteMultipleCoils.value(), code),
            frame
        );
        assert_eq!(
            decode_answer(0x81, &request, &frame).unwrap(),
            Answer::Exception(code)
        );
    }
}
