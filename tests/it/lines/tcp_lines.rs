//! End to end over the network: the gateway (`run_gateway`) with one line on a pty, one line to
//! a simulated serial device server (`tcp://`, raw RTU) and one to a simulated Modbus TCP
//! gateway (`modbus-tcp://`), behind a real mosquitto. Every network fault of the simulators
//! is put on the TCP lines and the line's behaviour is asserted (offline/online, reconnects),
//! as is that no wrong value reaches MQTT and that the pty line never notices. One test talks
//! to a pymodbus Modbus TCP server (an implementation not written here).

use crate::support;
use crate::support::child;

use std::process::Command;
use std::time::Duration;

use crate::cli::commissioning::{cells, identification_rows};
use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_sim::{
    self as sim, share, AirShower, DustCollector, Occurrence, Protocol, ServeOptions, TcpFaults,
    TcpSimulator, Valve, VirtualLine,
};
use support::{Gateway, Mosquitto, TestClient};

/// Generous bounds for a busy 2-core machine: they only fail when something is broken.
const ANSWER: Duration = Duration::from_secs(20);

/// The valve's opening and the Modbus TCP dust collector's gear: constant during a test, so
/// any other value on their topics would be a wrong one.
const VALVE_OPENING: u16 = 40;
const GW_GEAR: u16 = 6;

/// Everything a test needs: the broker, the three lines' simulators and the gateway.
struct Plant {
    broker: Mosquitto,
    client: TestClient,
    /// Subscribed to everything and never waited on: it keeps every message for the audit.
    auditor: TestClient,
    pty: VirtualLine,
    raw: TcpSimulator,
    modbus: TcpSimulator,
    valve: std::sync::Arc<std::sync::Mutex<Valve>>,
    dust_gw: std::sync::Arc<std::sync::Mutex<DustCollector>>,
    raw_devices: Vec<sim::SharedDevice>,
    gateway: Option<Gateway>,
    /// `plant/gateway/<client id>/stats` (each line's document is under it).
    stats_topic: String,
}

async fn bind(
    address: &str,
    protocol: Protocol,
    parity: Parity,
    devices: Vec<sim::SharedDevice>,
) -> TcpSimulator {
    TcpSimulator::bind(address, protocol, ServeOptions::new(9600, parity), devices)
        .await
        .unwrap()
}

impl Plant {
    async fn start(name: &str) -> Plant {
        let broker = Mosquitto::start();
        let (dust, dust_shared) = share(DustCollector::new(1));
        sim::lock(&dust).set_power(true);
        let (_shower, shower_shared) = share(AirShower::new());
        let pty = VirtualLine::spawn(
            ServeOptions::new(9600, Parity::None),
            vec![dust_shared, shower_shared],
        )
        .unwrap();
        let (valve, valve_shared) = share(Valve::new(1));
        sim::lock(&valve).set_opening(VALVE_OPENING);
        let raw_devices = vec![valve_shared];
        let raw = bind(
            "127.0.0.1:0",
            Protocol::RawRtu,
            Parity::Even,
            raw_devices.clone(),
        )
        .await;
        let (dust_gw, dust_gw_shared) = share(DustCollector::new(1));
        sim::lock(&dust_gw).set_power(true);
        let (_shower_gw, shower_gw_shared) = share(AirShower::new());
        let modbus = bind(
            "127.0.0.1:0",
            Protocol::ModbusTcp,
            Parity::None,
            vec![dust_gw_shared, shower_gw_shared],
        )
        .await;
        let mut client = TestClient::connect(broker.port, &format!("{name}-observer")).await;
        client.subscribe("plant/#").await;
        let mut auditor = TestClient::connect(broker.port, &format!("{name}-auditor")).await;
        auditor.subscribe("plant/#").await;
        let mut plant = Plant {
            broker,
            client,
            auditor,
            pty,
            raw,
            modbus,
            valve,
            dust_gw,
            raw_devices,
            gateway: None,
            stats_topic: format!("plant/gateway/{name}-gw/stats"),
        };
        let config = support::fast_config(&plant.config_text(&format!("{name}-gw")));
        plant.gateway = Some(Gateway::start(config).await);
        for device in [
            "dust_collector",
            "air_shower",
            "valve",
            "dust_gw",
            "shower_gw",
        ] {
            plant
                .wait_text(&format!("plant/{device}/availability"), "online")
                .await;
        }
        // A command over Modbus TCP sets the gear the faults must never change.
        let result = plant.command("dust_gw", "gear", GW_GEAR).await;
        assert_eq!(result["outcome"], "applied", "{result}");
        plant
    }

    fn config_text(&self, client_id: &str) -> String {
        format!(
            r#"
[mqtt]
url = "{broker}"
client_id = "{client_id}"
prefix = "plant"

[gateway]
stats_interval = "1s"

[[lines]]
name = "line-pty"
port = "{pty}"
baud = 9600
parity = "none"
response_timeout = "150ms"
retries = 1
offline_after = 2

[[lines.devices]]
name = "dust_collector"
profile = "ruiwan-dust-collector"
address = 1

[[lines.devices]]
name = "air_shower"
profile = "lixian-air-shower"
address = 0x81

[[lines]]
name = "line-raw"
url = "{raw}"
parity = "even"
network_allowance = "100ms"
connect_timeout = "1s"
retries = 1
offline_after = 2

[[lines.devices]]
name = "valve"
profile = "wuzhou-valve"
address = 1

[[lines]]
name = "line-modbus"
url = "{modbus}"
response_timeout = "300ms"
connect_timeout = "1s"
retries = 1
offline_after = 2

[[lines.devices]]
name = "dust_gw"
profile = "ruiwan-dust-collector"
address = 1

[[lines.devices]]
name = "shower_gw"
profile = "lixian-air-shower"
address = 0x81
"#,
            broker = self.broker.url(),
            pty = self.pty.path().display(),
            raw = self.raw.url(),
            modbus = self.modbus.url(),
        )
    }

    async fn wait_text(&mut self, topic: &str, text: &str) {
        let text = text.to_string();
        self.client
            .wait_for(topic, ANSWER, move |m| m.text() == text)
            .await;
    }

    /// Publishes a command and returns its result JSON.
    async fn command(
        &mut self,
        device: &str,
        field: &str,
        value: impl ToString,
    ) -> serde_json::Value {
        self.client
            .publish(
                &format!("plant/{device}/{field}/set"),
                value.to_string().into_bytes(),
                false,
            )
            .await;
        self.client
            .next_on(&format!("plant/{device}/{field}/result"), ANSWER)
            .await
            .json()
    }

    /// Starts watching for availability changes from now on.
    async fn watch_from_now(&mut self) {
        self.client.settle(Duration::from_millis(200)).await;
        self.client.forget();
    }

    /// Waits for each device's availability to become `text` (after [`Self::watch_from_now`]).
    async fn wait_all(&mut self, devices: &[&str], text: &str) {
        for device in devices {
            self.wait_text(&format!("plant/{device}/availability"), text)
                .await;
        }
    }

    /// No value but the simulators' own was ever published for the fields a fault could
    /// corrupt, the pty line's devices never went offline once online, and neither did
    /// `steady` devices.
    async fn assert_no_wrong_value(&mut self, steady: &[&str]) {
        self.auditor.settle(Duration::from_millis(500)).await;
        let values = |topic: &str| -> Vec<String> {
            self.auditor.on(topic).iter().map(|m| m.text()).collect()
        };
        let opening = VALVE_OPENING.to_string();
        let openings = values("plant/valve/opening");
        assert!(!openings.is_empty());
        assert!(
            openings.iter().all(|v| *v == opening),
            "valve opening: {openings:?}"
        );
        let gear = GW_GEAR.to_string();
        let gears = values("plant/dust_gw/gear");
        assert!(gears.contains(&gear), "dust_gw gear: {gears:?}");
        assert!(
            gears.iter().skip_while(|v| **v != gear).all(|v| *v == gear),
            "dust_gw gear: {gears:?}"
        );
        for device in ["dust_collector", "air_shower"].iter().chain(steady) {
            let availability = values(&format!("plant/{device}/availability"));
            assert!(
                availability
                    .iter()
                    .skip_while(|v| *v != "online")
                    .all(|v| v == "online"),
                "{device}: {availability:?}"
            );
        }
    }

    async fn stop(mut self) {
        if let Some(gateway) = self.gateway.take() {
            gateway.stop().await;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_field_is_published_and_commands_apply_on_every_transport() {
    let mut plant = Plant::start("mixed").await;
    plant
        .wait_text("plant/dust_gw/gear", &GW_GEAR.to_string())
        .await;
    plant.auditor.settle(Duration::from_secs(2)).await;
    let config = support::fast_config(&plant.config_text("x"));
    for line in &config.lines {
        for device in &line.devices {
            for field in device.profile.fields() {
                let topic = format!("plant/{}/{}", device.name, field.name);
                assert!(
                    !plant.auditor.on(&topic).is_empty(),
                    "{topic} not published"
                );
            }
        }
    }
    let last = |topic: &str| {
        plant
            .auditor
            .on(topic)
            .last()
            .map(|m| m.text())
            .unwrap_or_default()
    };
    assert_eq!(last("plant/valve/opening"), VALVE_OPENING.to_string());
    assert_eq!(last("plant/valve/mode"), "manual");
    assert_eq!(last("plant/dust_gw/power"), "ON");
    assert_eq!(last("plant/dust_collector/power"), "ON");
    let pulse = sim::lock(&plant.dust_gw).pulse_interval();
    assert_eq!(last("plant/dust_gw/pulse_interval"), pulse.to_string());

    // A command on each TCP kind and on the pty.
    let result = plant.command("valve", "setpoint", "45.67").await;
    assert_eq!(result["outcome"], "applied", "{result}");
    assert_eq!(sim::lock(&plant.valve).register(0xB2), Some(0x0045));
    plant.wait_text("plant/valve/setpoint", "45.67").await;
    let result = plant.command("shower_gw", "light", "ON").await;
    assert_eq!(result["outcome"], "applied", "{result}");
    plant.wait_text("plant/shower_gw/light", "ON").await;
    let result = plant.command("air_shower", "light", "ON").await;
    assert_eq!(result["outcome"], "applied", "{result}");
    // The frames went out as RTU on the raw stream and as MBAP-wrapped RTU to the gateway.
    assert!(plant
        .raw
        .journal()
        .frames()
        .iter()
        .any(|f| f.len() > 2 && f[0] == 0x01 && matches!(f[1], 0x06 | 0x10)));
    assert!(plant
        .modbus
        .journal()
        .frames()
        .iter()
        .any(|f| f.starts_with(&[0x81, 0x0F])));
    // Statistics and availability work the same on every transport.
    for line in ["line-pty", "line-raw", "line-modbus"] {
        let topic = format!("plant/gateway/mixed-gw/stats/{line}");
        plant
            .client
            .wait_for(&topic, ANSWER, |m| {
                m.json()["transactions"].as_u64().unwrap_or(0) > 0
            })
            .await;
    }
    let stats = plant
        .client
        .next_on("plant/gateway/mixed-gw/stats", ANSWER)
        .await
        .json();
    assert_eq!(stats["devices_total"], 5, "{stats}");
    plant.assert_no_wrong_value(&[]).await;
    plant.stop().await;
}

/// The TCP lines' devices under `fault` on both servers go offline; without it they come
/// back. Returns the TCP lines' statistics seen once they are back, by line name.
async fn offline_under_and_back(plant: &mut Plant, fault: fn(&mut TcpFaults)) -> serde_json::Value {
    const TCP_DEVICES: [&str; 3] = ["valve", "dust_gw", "shower_gw"];
    plant.watch_from_now().await;
    for sim in [&plant.raw, &plant.modbus] {
        sim.tcp_faults().update(fault);
    }
    plant.wait_all(&TCP_DEVICES, "offline").await;
    plant.watch_from_now().await;
    for sim in [&plant.raw, &plant.modbus] {
        sim.tcp_faults().clear();
    }
    plant.wait_all(&TCP_DEVICES, "online").await;
    let mut lines = serde_json::Map::new();
    for line in ["line-raw", "line-modbus"] {
        let topic = format!("{}/{line}", plant.stats_topic);
        let document = plant.client.next_on(&topic, ANSWER).await.json();
        lines.insert(line.to_string(), document);
    }
    serde_json::Value::Object(lines)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_closing_mid_answer_fails_transactions_and_the_line_reconnects() {
    let mut plant = Plant::start("close").await;
    let stats =
        offline_under_and_back(&mut plant, |f| f.close_mid_answer = Occurrence::ALWAYS).await;
    // Each drop failed its transaction (counted with the truncated answers); the next one
    // reconnected, so the server kept hearing requests and the devices came back.
    for line in ["line-raw", "line-modbus"] {
        assert!(
            stats[line]["truncated"].as_u64().unwrap_or(0) > 0,
            "{stats}"
        );
        assert_eq!(stats[line]["port_open"], true, "{stats}");
    }
    plant.assert_no_wrong_value(&[]).await;
    plant.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_that_accepts_but_never_answers_takes_the_devices_offline() {
    let mut plant = Plant::start("silent").await;
    let stats = offline_under_and_back(&mut plant, |f| f.never_answer = Occurrence::ALWAYS).await;
    for line in ["line-raw", "line-modbus"] {
        assert!(stats[line]["timeouts"].as_u64().unwrap_or(0) > 0, "{stats}");
    }
    plant.assert_no_wrong_value(&[]).await;
    plant.stop().await;
}

/// Answers split across segments, two answers in one segment (the first held back and so
/// late), garbage before raw answers: every device stays online and every value stays right.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn split_coalesced_and_garbled_streams_never_publish_a_wrong_value() {
    let mut plant = Plant::start("stream").await;
    for sim in [&plant.raw, &plant.modbus] {
        sim.tcp_faults().update(|f| {
            f.split_answer = Occurrence::probability(0.5);
            f.split_gap = Duration::from_millis(30);
        });
    }
    // Garbage on a raw stream is skipped by framing. (On Modbus TCP it would put the stream
    // out of step: the connection is dropped and reopened, see the close test.)
    plant.raw.tcp_faults().update(|f| {
        f.garbage_before = Occurrence::probability(0.3);
        f.garbage_bytes = 4;
    });
    for _ in 0..4 {
        for sim in [&plant.raw, &plant.modbus] {
            sim.tcp_faults()
                .update(|f| f.hold_for_next = Occurrence::next(1));
        }
        plant.client.settle(Duration::from_millis(1500)).await;
    }
    // The held answers came late, with the next ones: dropped and counted on both kinds; the
    // garbage on the raw stream was skipped and counted.
    for (line, counters) in [
        ("line-modbus", &["late_answers"][..]),
        ("line-raw", &["late_answers", "stray_bytes"][..]),
    ] {
        let topic = format!("plant/gateway/stream-gw/stats/{line}");
        plant
            .client
            .wait_for(&topic, ANSWER, |m| {
                let document = m.json();
                counters
                    .iter()
                    .all(|counter| document[*counter].as_u64().unwrap_or(0) > 0)
            })
            .await;
    }
    plant
        .assert_no_wrong_value(&["valve", "dust_gw", "shower_gw"])
        .await;
    plant.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_server_is_reconnected_with_back_off() {
    let mut plant = Plant::start("restart").await;
    let address = plant.raw.local_addr().to_string();
    plant.watch_from_now().await;
    plant.raw.stop().await;
    plant.wait_all(&["valve"], "offline").await;
    // Down for a while: the line keeps trying without giving up.
    tokio::time::sleep(Duration::from_secs(2)).await;
    plant.raw = bind(
        &address,
        Protocol::RawRtu,
        Parity::Even,
        plant.raw_devices.clone(),
    )
    .await;
    plant.wait_all(&["valve"], "online").await;
    assert!(!plant.raw.journal().requests().is_empty());
    plant.assert_no_wrong_value(&["dust_gw", "shower_gw"]).await;
    plant.stop().await;
}

/// The pymodbus Modbus TCP server of `tests/interop/modbus_tcp_server.py` on a free loopback
/// port (killed when dropped), once it listens.
async fn pymodbus_server() -> (child::KillOnDrop, u16) {
    support::pymodbus::server("modbus_tcp_server.py").await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pymodbus_server_is_read_over_modbus_tcp() {
    let (server, port) = pymodbus_server().await;

    let broker = Mosquitto::start();
    let mut client = TestClient::connect(broker.port, "pymodbus-observer").await;
    client.subscribe("plant/#").await;
    let text = format!(
        r#"
[mqtt]
url = "{broker}"
client_id = "pymodbus-gw"
prefix = "plant"

[[lines]]
name = "line-gw"
url = "modbus-tcp://127.0.0.1:{port}"
response_timeout = "1s"

[[lines.devices]]
name = "dust_collector"
profile = "ruiwan-dust-collector"
address = 1
"#,
        broker = broker.url()
    );
    let gateway = Gateway::start(support::fast_config(&text)).await;
    for (field, value) in [
        ("power", "ON"),
        ("gear", "7"),
        ("pulse_interval", "12"),
        ("pulse_duration", "3"),
        ("fan_speed", "1450"),
        ("temperature", "31"),
    ] {
        let value = value.to_string();
        client
            .wait_for(&format!("plant/dust_collector/{field}"), ANSWER, move |m| {
                m.text() == value
            })
            .await;
    }
    client
        .wait_for("plant/dust_collector/availability", ANSWER, |m| {
            m.text() == "online"
        })
        .await;
    gateway.stop().await;
    drop(server);
}

/// Runs `rtu2mqtt args…` and returns its exit success and standard output.
async fn run_cli(args: &[&str]) -> (bool, String) {
    let mut command = Command::new(child::gateway_binary());
    command.args(args);
    let output = child::output(command, Duration::from_secs(60))
        .await
        .expect("rtu2mqtt runs and ends");
    (
        output.status.success(),
        String::from_utf8_lossy(&output.stdout).into_owned(),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scan_and_read_take_a_url_and_never_write() {
    let raw = bind(
        "127.0.0.1:0",
        Protocol::RawRtu,
        Parity::None,
        vec![share(DustCollector::new(1)).1],
    )
    .await;
    let modbus = bind(
        "127.0.0.1:0",
        Protocol::ModbusTcp,
        Parity::None,
        vec![share(DustCollector::new(1)).1, share(AirShower::new()).1],
    )
    .await;
    let (ok, out) = run_cli(&[
        "read",
        "--url",
        &raw.url(),
        "--address",
        "1",
        "--start",
        "0x1000",
        "--count",
        "6",
    ])
    .await;
    assert!(ok, "{out}");
    assert!(out.contains("request  01 03 10 00 00 06 C1 08"), "{out}");
    let (ok, out) = run_cli(&[
        "scan",
        "--url",
        &modbus.url(),
        "--addresses",
        "1-3,0x81",
        "--timeout",
        "300ms",
    ])
    .await;
    assert!(ok, "{out}");
    assert!(out.contains("  1 (0x01)"), "{out}");
    assert!(out.contains("129 (0x81)"), "{out}");
    assert!(!out.contains("  2 (0x02)"), "{out}");
    for frames in [raw.journal().frames(), modbus.journal().frames()] {
        assert!(!frames.is_empty());
        assert!(
            frames
                .iter()
                .all(|f| (1..=4).contains(&f[1]) || f.get(1..3) == Some(&[0x2B, 0x0E][..])),
            "a frame other than a read: {frames:?}"
        );
    }
}

/// Through a Modbus TCP gateway, `scan` asks each unit what it is as on a serial port: the
/// simulated gateway's SunSpec inverter is named by its chain and its meter by its
/// identification (a library profile does not name it), and pymodbus's own Read Device
/// Identification answer (an implementation not written here) is read as pymodbus built it.
/// The configuration has the gateway's url and no serial setting.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scan_through_a_modbus_tcp_gateway_identifies_each_unit() {
    use rtu2mqtt_modbus::DeviceIdObject;
    let meter = sim::GenericDevice::empty(3).with_identification(vec![
        DeviceIdObject::text(0, "Sim Metering"),
        DeviceIdObject::text(1, "SM-3P-100"),
        DeviceIdObject::text(2, "1.4.2"),
    ]);
    let mut meter = meter;
    meter.set_holding(0, 1);
    let inverter = sim::library::sunspec_inverter().device(2);
    let modbus = bind(
        "127.0.0.1:0",
        Protocol::ModbusTcp,
        Parity::None,
        vec![share(inverter).1, share(meter).1],
    )
    .await;
    let (ok, out) = run_cli(&[
        "scan",
        "--url",
        &modbus.url(),
        "--addresses",
        "1-3",
        "--timeout",
        "300ms",
    ])
    .await;
    assert!(ok, "{out}");
    assert_eq!(
        identification_rows(&out),
        [
            cells(&[
                "2 (0x02)",
                "exception 01 (illegal function)",
                "-",
                "-",
                "-",
                "40000: models 1, 103, 160",
                "sunspec-inverter"
            ]),
            cells(&[
                "3 (0x03)",
                "ok",
                "Sim Metering",
                "SM-3P-100",
                "1.4.2",
                "-",
                "unknown"
            ]),
        ],
        "{out}"
    );
    assert!(
        out.ends_with(&format!(
            "[[lines]]\nname = \"line1\"\nurl = \"{}\"\n\n[[lines.devices]]\n\
             name = \"sunspec_inverter_2\"\nprofile = \"sunspec-inverter\"\naddress = 2\n\n\
             [[lines.devices]]\nname = \"device_3\"\n\
             # profile: unknown — write one, see docs/profiles.md\naddress = 3\n",
            modbus.url()
        )),
        "{out}"
    );
    let frames = modbus.journal().frames();
    // Unit 3 was asked for its basic identification from object 0.
    assert!(
        frames
            .iter()
            .any(|f| f.get(..5) == Some(&[3, 0x2B, 0x0E, 0x01, 0x00][..])),
        "{frames:02X?}"
    );

    let (server, port) = pymodbus_server().await;
    let (ok, out) = run_cli(&[
        "scan",
        "--url",
        &format!("modbus-tcp://127.0.0.1:{port}"),
        "--addresses",
        "1",
        "--timeout",
        "500ms",
    ])
    .await;
    assert!(ok, "{out}");
    assert_eq!(
        identification_rows(&out),
        [cells(&[
            "1 (0x01)",
            "ok",
            "pymodbus interop",
            "PM-DUST-1",
            "3.16",
            "-",
            "unknown"
        ])],
        "{out}"
    );
    drop(server);
}

/// A Modbus TCP gateway in front of one device at unit 1: every other unit is answered with
/// exception 0B (its target failed to respond), as real gateways do.
async fn gateway_with_one_device() -> std::net::SocketAddr {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap();
    tokio::spawn(async move {
        while let Ok((mut stream, _)) = listener.accept().await {
            tokio::spawn(async move {
                let mut head = [0u8; 7];
                while stream.read_exact(&mut head).await.is_ok() {
                    let length = usize::from(u16::from_be_bytes([head[4], head[5]]));
                    let mut pdu = vec![0u8; length.saturating_sub(1)];
                    if stream.read_exact(&mut pdu).await.is_err() {
                        return;
                    }
                    let (unit, function) = (head[6], pdu.first().copied().unwrap_or(0));
                    let answer: Vec<u8> = if unit == 1 && function == 3 {
                        vec![3, 2, 0x12, 0x34]
                    } else {
                        vec![function | 0x80, 0x0B]
                    };
                    let mut adu = vec![head[0], head[1], 0, 0];
                    adu.extend_from_slice(&(answer.len() as u16 + 1).to_be_bytes());
                    adu.push(unit);
                    adu.extend_from_slice(&answer);
                    if stream.write_all(&adu).await.is_err() {
                        return;
                    }
                }
            });
        }
    });
    address
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scan_behind_a_gateway_counts_only_real_answers_and_says_what_it_scanned() {
    let gateway = gateway_with_one_device().await;
    let url = format!("modbus-tcp://{gateway}");
    let mut command = Command::new(child::gateway_binary());
    command.args([
        "scan",
        "--url",
        &url,
        "--addresses",
        "1-5",
        "--timeout",
        "300ms",
    ]);
    let output = child::output(command, Duration::from_secs(60))
        .await
        .expect("rtu2mqtt runs and ends");
    let (out, err) = (
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr),
    );
    assert!(output.status.success(), "{out}{err}");
    assert!(out.contains("  1 (0x01)  FC03 ok"), "{out}");
    for absent in ["  2 (0x02)", "  3 (0x03)", "  5 (0x05)"] {
        assert!(
            !out.contains(absent),
            "exception 0B counted as a device: {out}"
        );
    }
    assert!(!out.contains("9600") && !out.contains("8N1"), "{out}");
    assert!(
        err.contains(&format!(
            "scanned 5 addresses through the Modbus TCP gateway {url}"
        )),
        "{err}"
    );
}

/// A Modbus TCP line's bus load is the serial wire time of the frames its gateway carries, the
/// model of `check`'s estimate: five dust collectors behind a simulated Modbus TCP gateway,
/// each polled once a second, publish a figure within 20 % of the estimate once the line has
/// run a whole load window (10 s after the first polls), and never a start-up burst above it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_modbus_tcp_lines_bus_load_is_checks_estimate() {
    let devices: Vec<sim::SharedDevice> = (1..=5)
        .map(|address| {
            let (dust, shared) = share(DustCollector::new(address));
            sim::lock(&dust).set_power(true);
            shared
        })
        .collect();
    let modbus = bind("127.0.0.1:0", Protocol::ModbusTcp, Parity::None, devices).await;
    let broker = Mosquitto::start();
    let mut client = TestClient::connect(broker.port, "load-observer").await;
    client.subscribe("plant/gateway/#").await;
    let mut text = format!(
        "[mqtt]\nurl = \"{}\"\nclient_id = \"load-gw\"\nprefix = \"plant\"\n\n[gateway]\n\
         stats_interval = \"1s\"\n\n[[lines]]\nname = \"gw\"\nurl = \"{}\"\n",
        broker.url(),
        modbus.url()
    );
    for address in 1..=5 {
        text.push_str(&format!(
            "\n[[lines.devices]]\nname = \"dust_{address}\"\nprofile = \"ruiwan-dust-collector\"\n\
             address = {address}\npoll_interval = \"1s\"\n"
        ));
    }
    let config = rtu2mqtt::config::from_str(&text, std::path::Path::new(".")).unwrap();
    let estimate = rtu2mqtt::config::poll_plan::LinePlan::of(&config.lines[0]).bus_load * 100.0;
    let started = std::time::Instant::now();
    let gateway = Gateway::start(config).await;
    let topic = "plant/gateway/load-gw/stats/gw";
    let mut figures: Vec<(Duration, f64)> = Vec::new();
    while started.elapsed() < Duration::from_secs(17) {
        let document = client.next_on(topic, ANSWER).await.json();
        let figure = document["bus_load_percent"]
            .as_f64()
            .unwrap_or_else(|| panic!("no bus_load_percent: {document}"));
        figures.push((started.elapsed(), figure));
    }
    gateway.stop().await;
    println!("check's estimate {estimate:.1} %; published: {figures:?}");
    // 5 × (8 + 17 bytes of 10 bits at 9600 baud + 2 × t3.5) a second.
    assert!((estimate - 16.7).abs() < 0.1, "{estimate}");
    for (at, figure) in &figures {
        assert!(
            *figure <= estimate * 1.2,
            "{figure} % at {at:?} (estimate {estimate:.1} %)"
        );
    }
    // The dust collectors' start-up delay is 3 s: the window is full from 13 s on.
    let settled: Vec<f64> = figures
        .iter()
        .filter(|(at, _)| *at >= Duration::from_secs(14))
        .map(|(_, figure)| *figure)
        .collect();
    assert!(!settled.is_empty(), "{figures:?}");
    for figure in settled {
        assert!(
            (figure - estimate).abs() <= estimate * 0.2,
            "{figure} % against check's {estimate:.1} %"
        );
    }
}
