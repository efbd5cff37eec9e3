//! The TCP simulator as peers see it: pymodbus, a Modbus TCP client not written here, reads
//! the seed devices from it, and the demo's `simulate` command serves a seed line over Modbus
//! TCP. (The simulator's own frames and faults are tested in crates/rtu2mqtt-sim.)

use crate::support::{child, pymodbus};

use std::time::Duration;

use rtu2mqtt_modbus::codec::{decode_answer, Answer};
use rtu2mqtt_modbus::tcp::mbap;
use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_modbus::{Request, Response};
use rtu2mqtt_sim::{share, AirShower, DustCollector, Protocol, ServeOptions, TcpSimulator, Valve};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// pymodbus (installed with `pip install pymodbus==3.16.1`) reads every seed block from the
/// Modbus TCP simulator. Skipped with a note when python3 or pymodbus is missing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pymodbus_client_reads_the_seed_devices() {
    if !pymodbus::available() {
        return;
    }
    let devices = vec![
        share(DustCollector::new(1)).1,
        share(AirShower::new()).1,
        share(Valve::new(2)).1,
    ];
    let sim = TcpSimulator::bind(
        "127.0.0.1:0",
        Protocol::ModbusTcp,
        ServeOptions::new(9600, Parity::None),
        devices,
    )
    .await
    .unwrap();
    let port = sim.local_addr().port().to_string();
    let stdout = pymodbus::run_client(
        "modbus_tcp_client.py",
        &["127.0.0.1", &port],
        Duration::from_secs(60),
    )
    .await;
    // Every line the client printed is what the devices answered, word for word.
    let requests = sim.journal().requests();
    let mut lines = stdout.lines();
    for record in &requests {
        let line = lines.next().unwrap_or_default();
        let answer = record.answer.clone().unwrap_or_default();
        let (slave, request) = rtu2mqtt_modbus::codec::decode_request(&record.frame).unwrap();
        let expected = match decode_answer(slave, &request, &answer).unwrap() {
            Answer::Normal(Response::HoldingRegisters(words)) => format!("{words:?}"),
            Answer::Normal(Response::Coils(bits)) => {
                format!(
                    "{:?}",
                    bits.iter().map(|b| u8::from(*b)).collect::<Vec<_>>()
                )
            }
            other => panic!("unexpected {other:?}"),
        };
        let prefix = format!("unit={slave} fc={:02} ", request.function().value());
        assert_eq!(line, format!("{prefix}{expected}"));
    }
    assert_eq!(requests.len(), 4);
    assert!(requests
        .iter()
        .all(|r| r.frame[1] == 0x03 || r.frame[1] == 0x01));
}

/// `rtu2mqtt-demo simulate --seed-line a --listen modbus-tcp://…` serves the line to a client.
#[tokio::test]
async fn simulate_command_listens_on_tcp() {
    let port = crate::support::free_port();
    let url = format!("modbus-tcp://127.0.0.1:{port}");
    let mut command = std::process::Command::new(child::binary("rtu2mqtt-demo"));
    command
        .args(["simulate", "--seed-line", "a", "--listen", &url])
        .env("RUST_LOG", "error");
    let simulator = child::KillOnDrop::spawn(command).unwrap();
    let mut stream = None;
    for _ in 0..50 {
        if let Ok(connected) = TcpStream::connect(("127.0.0.1", port)).await {
            stream = Some(connected);
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let mut stream = stream.expect("the simulator listens");
    // The air shower's coil read, as the device documentation prints it, over Modbus TCP.
    let coils = Request::ReadCoils {
        start: 0,
        quantity: 22,
    };
    let request = mbap::encode_request(5, 0x81, &coils).unwrap();
    assert_eq!(
        request,
        [0, 5, 0, 0, 0, 6, 0x81, 0x01, 0x00, 0x00, 0x00, 0x16]
    );
    stream.write_all(&request).await.unwrap();
    let mut answer = [0u8; 7 + 2 + 3];
    tokio::time::timeout(Duration::from_secs(3), stream.read_exact(&mut answer))
        .await
        .expect("the answer within 3 s")
        .unwrap();
    assert_eq!(&answer[..9], &[0, 5, 0, 0, 0, 6, 0x81, 0x01, 3]);
    assert!(matches!(
        mbap::decode_answer(5, 0x81, &coils, &answer).unwrap(),
        mbap::Matched::Current(Answer::Normal(Response::Coils(bits))) if bits.len() == 22
    ));
    drop(simulator);
}
