//! The master against a device it was not written with: pymodbus's own Modbus RTU server on a
//! pseudo-terminal, behind a pacer that gives every byte its wire time
//! (`tests/interop/paced_rtu_server.py`). Reads and writes come back as pymodbus answers them,
//! the frames it saw are the golden ones, and the silence before every request, measured where
//! pymodbus's line sees its first byte, is never shorter than t3.5.

use std::time::Duration;

use rtu2mqtt_modbus::serial::master::{Master, MasterOptions};
use rtu2mqtt_modbus::serial::transport::{Port, SerialSettings};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_modbus::{Request, Response, Transact};
use rtu2mqtt_testkit::hex;
use rtu2mqtt_testkit::PacedPymodbus;

const BAUD: u32 = 9600;
const UNIT: u8 = 1;
const TIMEOUT: Duration = Duration::from_millis(500);

fn format() -> CharFormat {
    CharFormat {
        data_bits: 8,
        parity: Parity::None,
        stop_bits: 1,
    }
}

#[tokio::test(flavor = "current_thread")]
async fn pymodbus_answers_the_master_and_hears_t3_5_before_every_request() {
    let line = PacedPymodbus::spawn(BAUD, 6).expect("pymodbus's RTU server behind the pacer");
    let port = Port::open(&SerialSettings {
        path: line.path().to_string_lossy().into_owned(),
        baud: BAUD,
        format: format(),
        rs485: None,
    })
    .expect("open the pty");
    let timing = LineTiming::new(BAUD, format());
    let mut master = Master::new(port, timing, MasterOptions::default());
    let read = Request::ReadHoldingRegisters {
        start: 0,
        quantity: 6,
    };
    let write = Request::WriteSingleRegister {
        address: 2,
        value: 0x1234,
    };
    let mut replies = Vec::new();
    for request in [&read, &write, &read, &read, &read] {
        replies.push(master.transact(UNIT, request, TIMEOUT).await);
    }
    assert_eq!(
        replies,
        vec![
            Ok(Ok(Response::HoldingRegisters(vec![0; 6]))),
            Ok(Ok(Response::WriteSingleRegister {
                address: 2,
                value: 0x1234
            })),
            Ok(Ok(Response::HoldingRegisters(vec![0, 0, 0x1234, 0, 0, 0]))),
            Ok(Ok(Response::HoldingRegisters(vec![0, 0, 0x1234, 0, 0, 0]))),
            Ok(Ok(Response::HoldingRegisters(vec![0, 0, 0x1234, 0, 0, 0]))),
        ]
    );
    let records = line.requests().expect("the pacer's journal");
    let frames: Vec<String> = records.iter().map(|r| hex::encode(&r.frame)).collect();
    assert_eq!(
        frames,
        [
            "01 03 00 00 00 06 C5 C8",
            "01 06 00 02 12 34 25 7D",
            "01 03 00 00 00 06 C5 C8",
            "01 03 00 00 00 06 C5 C8",
            "01 03 00 00 00 06 C5 C8",
        ]
    );
    assert!(records.iter().all(|r| r.crc_ok && r.answer.is_some()));
    for (index, record) in records.iter().enumerate().skip(1) {
        let silence = record.silence_before.unwrap_or_default();
        assert!(
            silence >= timing.t3_5,
            "request {index} after {silence:?} of silence at the device (t3.5 is {:?})",
            timing.t3_5
        );
    }
}
