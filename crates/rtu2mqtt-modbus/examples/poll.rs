//! Polls one holding register of one device on a serial line, once a second.
//!
//! `cargo run -p rtu2mqtt-modbus --example poll -- /dev/ttyUSB0 9600 1 0x0000`
//! (port, baud rate at 8N1, device address, register address).

use std::time::Duration;

use rtu2mqtt_modbus::serial::master::{Master, MasterOptions};
use rtu2mqtt_modbus::serial::transport::{Port, SerialSettings};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_modbus::{Request, Response, Transact};

/// A number written in decimal or as `0x…`.
fn number<T: TryFrom<u32>>(text: &str) -> Result<T, String> {
    let parsed = match text.strip_prefix("0x") {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => text.parse(),
    };
    parsed
        .ok()
        .and_then(|value| T::try_from(value).ok())
        .ok_or_else(|| format!("{text:?} is not a number in range"))
}

#[tokio::main(flavor = "current_thread")]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [path, baud, slave, register] = args.as_slice() else {
        return Err("usage: poll <port> <baud> <device address> <register>".into());
    };
    let format = CharFormat {
        data_bits: 8,
        parity: Parity::None,
        stop_bits: 1,
    };
    let baud: u32 = number(baud)?;
    let port = Port::open(&SerialSettings {
        path: path.clone(),
        baud,
        format,
        rs485: None,
    })?;
    let timing = LineTiming::new(baud, format);
    let mut master = Master::new(port, timing, MasterOptions::default());
    let request = Request::ReadHoldingRegisters {
        start: number(register)?,
        quantity: 1,
    };
    let slave = number(slave)?;
    // The answer's wire time, t3.5 and the host's latency, plus 50 ms for the device to turn.
    let timeout = timing.default_response_timeout(request.answer_len(), Duration::from_millis(50));
    loop {
        match master.transact(slave, &request, timeout).await {
            Ok(Ok(Response::HoldingRegisters(words))) => println!("{register} = {words:?}"),
            Ok(Ok(other)) => println!("unexpected response {other:?}"),
            Ok(Err(exception)) => println!("the device answered with {exception:?}"),
            Err(error) => println!("no answer: {error}"),
        }
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
}
