//! The device library: each library profile decodes its vendor's own worked examples and reads
//! its simulator (built from the same register map, not from the profile); end to end, each
//! profile runs in the gateway against its simulator on a real pty (one over Modbus TCP) and
//! every value the simulator holds reaches a real mosquitto with the text the map gives, while
//! values the device marks "not available" are published as `unavailable`; the Growatt takes a
//! power limit. `rtu2mqtt sunspec` walks the simulated inverter; the profile it writes passes
//! `check` and reads the inverter the same way.

use crate::support;
use crate::support::child;

use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_modbus::Response;
use rtu2mqtt_profile::registry::{built_in, library_names};
use rtu2mqtt_profile::{sunspec, Profile, Value, UNAVAILABLE};
use rtu2mqtt_sim::library::{self, LibraryDevice};
use rtu2mqtt_sim::register_map::Entry;
use rtu2mqtt_sim::{
    lock, share, GenericDevice, Protocol, Reply, ServeOptions, SharedDevice, SimDevice,
    TcpSimulator, VirtualLine,
};
use support::{fast_config, Gateway, Mosquitto, TestClient};

/// Generous for a busy 2-core machine: only runs out when something is broken.
const ANSWER: Duration = Duration::from_secs(20);

/// A decoded value: its text, `None` for a value the device marks unavailable (published as
/// `unavailable`), or the decoding error.
type Reading = Result<Option<String>, String>;

fn published(value: Value) -> Option<String> {
    (value != Value::Unavailable).then(|| value.to_text())
}

/// Decodes every block of `profile` from what `device` answers, field by field.
fn read_all(profile: &Profile, device: &mut dyn SimDevice) -> Vec<(String, Reading)> {
    let mut out = Vec::new();
    for (index, block) in profile.read_blocks().iter().enumerate() {
        let Reply::Normal(answer) = device.handle(&block.request, Instant::now()) else {
            panic!("{}: block {} refused", profile.name(), block.name);
        };
        for reading in profile.decode_block(index, &answer) {
            out.push((
                reading.field,
                reading.value.map(published).map_err(|e| e.to_string()),
            ));
        }
    }
    out
}

/// Asserts that the readings publish every entry's text and nothing for an unavailable one.
fn assert_readings(name: &str, readings: &[(String, Reading)], entries: &[Entry]) {
    for entry in entries {
        let reading = readings
            .iter()
            .find(|(field, _)| *field == entry.field)
            .unwrap_or_else(|| panic!("{name}: no field {}", entry.field));
        assert_eq!(
            reading.1,
            Ok(entry.published.clone()),
            "{name}.{}",
            entry.field
        );
    }
}

#[test]
fn the_library_is_built_in_and_listed() {
    assert_eq!(
        library_names(),
        [
            "eastron-sdm120",
            "eastron-sdm630",
            "abb-a43",
            "sunspec-inverter",
            "growatt-min",
            "schneider-iem3155"
        ]
    );
    let output = Command::new(child::gateway_binary())
        .arg("profiles")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    for name in library_names() {
        assert!(
            stdout.contains(&format!("{name}: ")),
            "{name} not listed:\n{stdout}"
        );
        assert!(
            stdout.contains(&format!("device library: config/profiles/{name}.toml")),
            "{stdout}"
        );
    }
}

#[test]
fn every_library_profile_reads_its_simulator() {
    for LibraryDevice { profile, map, .. } in library::devices() {
        let compiled = built_in(profile).unwrap_or_else(|e| panic!("{profile}: {e}"));
        let mut device = map.device(1);
        let readings = read_all(&compiled, &mut device);
        assert_readings(profile, &readings, &map.entries);
        // Every field of the profile is covered by the simulator's map.
        for field in compiled.fields() {
            assert!(
                map.entry(&field.name).is_some(),
                "{profile}.{} has no value in the simulator",
                field.name
            );
        }
    }
}

/// The words of an answer written as the vendor's hex bytes.
fn words(hex: &str) -> Vec<u16> {
    let bytes: Vec<u8> = hex
        .split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect();
    bytes
        .chunks(2)
        .map(|p| u16::from_be_bytes([p[0], p[1]]))
        .collect()
}

/// The values `profile` decodes from `answer` to its block `block`, each as published:
/// `None` for an unavailable value, the error text for invalid data.
fn readings(profile: &Profile, block: &str, answer: Response) -> Vec<(String, Reading)> {
    let index = profile
        .read_blocks()
        .iter()
        .position(|b| b.name == block)
        .unwrap();
    profile
        .decode_block(index, &answer)
        .into_iter()
        .map(|r| (r.field, r.value.map(published).map_err(|e| e.to_string())))
        .collect()
}

/// The field values `profile` decodes from `answer` to its block `block`, without the
/// unavailable ones.
fn decode(profile: &Profile, block: &str, answer: Response) -> Vec<(String, String)> {
    readings(profile, block, answer)
        .into_iter()
        .filter_map(|(field, reading)| reading.ok().flatten().map(|v| (field, v)))
        .collect()
}

fn value<'a>(values: &'a [(String, String)], field: &str) -> &'a str {
    values
        .iter()
        .find(|(f, _)| f == field)
        .map(|(_, v)| v.as_str())
        .unwrap_or_else(|| panic!("no {field} in {values:?}"))
}

#[test]
fn vendor_examples_decode_as_the_maps_say() {
    // Eastron SDM630 manual: 0x4370 0x8000 is the float 240.5.
    let sdm120 = built_in("eastron-sdm120").unwrap();
    let mut answer = vec![0u16; 38];
    answer[0] = 0x4370;
    answer[1] = 0x8000;
    let values = decode(&sdm120, "instant", Response::InputRegisters(answer));
    assert_eq!(value(&values, "voltage"), "240.5");

    // ABB A43/A44 manual, readout of 0x5460: L1 active import 00…03 12 92 = 2013.62 kWh,
    // L2 00…04 98 E1 = 3012.81 kWh, L1 active export 00…92 3A = 374.34 kWh.
    let abb = built_in("abb-a43").unwrap();
    let mut phase = words(
        "00 00 00 00 00 03 12 92 00 00 00 00 00 04 98 E1 00 00 00 00 00 05 66 55 \
         00 00 00 00 00 00 92 3A 00 00 00 00 00 01 1C 9B 00 00 00 00 00 01 63 33",
    );
    assert_eq!(phase.len(), 24);
    let values = decode(
        &abb,
        "phase_energy",
        Response::HoldingRegisters(phase.clone()),
    );
    assert_eq!(value(&values, "active_import_l1"), "2013.62");
    assert_eq!(value(&values, "active_import_l2"), "3012.81");
    assert_eq!(value(&values, "active_import_l3"), "3538.77");
    assert_eq!(value(&values, "active_export_l1"), "374.34");
    assert_eq!(value(&values, "active_export_l3"), "909.31");
    phase.iter_mut().for_each(|w| *w = 0);
    // ABB readout of 0x5B00 (from the L3-L2 voltage on; the manual's voltages before it are
    // left as zero): currents, powers with a negative one, frequency, power factors.
    let mut instant = vec![0u16; 8];
    instant.extend(words(
        "00 00 0F CA 00 00 0F C0 00 00 00 65 00 00 00 C9 00 00 01 2E 00 00 00 86 \
         00 01 E8 E4 00 00 5A E2 00 00 B0 97 00 00 DD 6B 00 00 75 41 00 00 00 1C \
         FF FF D0 4A 00 00 A4 DB 00 02 25 C3 00 00 5A E2 00 00 B6 DF 00 01 14 02 \
         13 83 00 87 00 00 FF 6A 01 6F 00 00 04 AF FB 4E FF FF FF FF FF FF FF F3 \
         04 09 FC AE 03 CC 03 E8 03 C6 00 00",
    ));
    assert_eq!(instant.len(), 62);
    let values = decode(&abb, "instant", Response::HoldingRegisters(instant));
    assert_eq!(value(&values, "voltage_l3_l2"), "404.2");
    assert_eq!(value(&values, "voltage_l1_l3"), "403.2");
    assert_eq!(value(&values, "current_l1"), "1.01");
    assert_eq!(value(&values, "current_n"), "1.34");
    assert_eq!(value(&values, "active_power"), "1251.56");
    assert_eq!(value(&values, "reactive_power_l2"), "-122.14");
    assert_eq!(value(&values, "apparent_power_l3"), "706.58");
    assert_eq!(value(&values, "frequency"), "49.95");
    assert_eq!(value(&values, "power_factor"), "0.972");
    assert_eq!(value(&values, "power_factor_l2"), "0.966");

    // SunSpec: a value of 1234 with a scale factor of -2 is 12.34; 0x8000 in an int16 and
    // 0xFFFF in a uint16 mean "not implemented".
    let inverter = built_in("sunspec-inverter").unwrap();
    let mut model = vec![0xFFFFu16; 52];
    model[0] = 103;
    model[1] = 50;
    model[27] = 1234; // DCA
    model[28] = (-2i16) as u16; // DCA_SF
    model[33] = 0x8000; // TmpCab, not implemented
    model[37] = (-1i16) as u16; // Tmp_SF
    let values = decode(&inverter, "inverter", Response::HoldingRegisters(model));
    assert_eq!(value(&values, "dc_current"), "12.34");
    assert!(
        !values.iter().any(|(f, _)| f == "cabinet_temperature"),
        "{values:?}"
    );
    assert!(!values.iter().any(|(f, _)| f == "ac_current"), "{values:?}");
}

fn reading<'a>(readings: &'a [(String, Reading)], field: &str) -> &'a Reading {
    readings
        .iter()
        .find(|(f, _)| f == field)
        .map(|(_, r)| r)
        .unwrap_or_else(|| panic!("no {field} in {readings:?}"))
}

#[test]
fn growatt_and_schneider_words_decode_as_their_documents_say() {
    // Growatt: a 32-bit value is its "H" register, then its "L" register, in 0.1 W.
    let growatt = built_in("growatt-min").unwrap();
    let mut inverter = vec![0u16; 63];
    inverter[0] = 3; // 3000: fault
    inverter[1] = 0x0001; // 3001 Ppv H
    inverter[2] = 0x2630; // 3002 Ppv L: 0x12630 = 75312
    inverter[51] = 0x0002; // 3051 Eac total H
    inverter[52] = 0xC84B; // 3052 Eac total L: 0x2C84B = 182347
    let values = readings(
        &growatt,
        "inverter",
        Response::InputRegisters(inverter.clone()),
    );
    assert_eq!(
        reading(&values, "inverter_status"),
        &Ok(Some("fault".into()))
    );
    assert_eq!(reading(&values, "pv_power"), &Ok(Some("7531.2".into())));
    assert_eq!(
        reading(&values, "energy_total"),
        &Ok(Some("18234.7".into()))
    );
    // A hybrid model's mode in the high byte is a code the profile does not name: its number.
    inverter[0] = 0x0501;
    let values = readings(&growatt, "inverter", Response::InputRegisters(inverter));
    assert_eq!(
        reading(&values, "inverter_status"),
        &Ok(Some("1281".into()))
    );
    // Temperatures are signed tenths: 0xFFF6 is -1.0 °C.
    let mut diagnostics = vec![0u16; 14];
    diagnostics[0] = 0xFFF6;
    let values = readings(
        &growatt,
        "diagnostics",
        Response::InputRegisters(diagnostics),
    );
    assert_eq!(
        reading(&values, "inverter_temperature"),
        &Ok(Some("-1.0".into()))
    );

    // Schneider: Int64 energies in Wh, high word first, published in kWh.
    let iem = built_in("schneider-iem3155").unwrap();
    let energy = words(
        "00 00 00 00 00 BC 61 4E 00 00 00 00 00 00 04 D2 00 00 00 00 00 00 00 00 \
         00 00 00 00 00 00 00 00 00 00 00 00 00 23 CA CE 00 00 00 00 00 00 00 00",
    );
    let values = readings(&iem, "energy", Response::HoldingRegisters(energy));
    assert_eq!(
        reading(&values, "active_import"),
        &Ok(Some("12345.678".into()))
    );
    assert_eq!(reading(&values, "active_export"), &Ok(Some("1.234".into())));
    assert_eq!(
        reading(&values, "reactive_import"),
        &Ok(Some("2345.678".into()))
    );
    // Float32, high word first: 0x43C8 0x4000 is 400.5 V; a NaN (either sign) is unavailable.
    let mut instant = vec![0u16; 38];
    instant[20] = 0x43C8; // 3020 V L1-L2
    instant[21] = 0x4000;
    instant[28] = 0xFFC0; // 3028 V L1-N
    instant[30] = 0x7FC0; // 3030 V L2-N
    let values = readings(&iem, "instant", Response::HoldingRegisters(instant));
    assert_eq!(reading(&values, "voltage_l1_l2"), &Ok(Some("400.5".into())));
    assert_eq!(reading(&values, "voltage_l1_n"), &Ok(None));
    assert_eq!(reading(&values, "voltage_l2_n"), &Ok(None));
    assert_eq!(reading(&values, "voltage_l3_n"), &Ok(Some("0.0".into())));
    // UTF-8 text, first byte in the high byte, ended by NUL; a broken sequence is invalid data.
    let mut identity = vec![0u16; 60];
    identity[0..2].copy_from_slice(&[0x53C3, 0xBC64]); // "Süd"
    identity[20] = 0x53C3; // "S" and a lone lead byte
    let values = readings(&iem, "identity", Response::HoldingRegisters(identity));
    assert_eq!(reading(&values, "meter_name"), &Ok(Some("Süd".into())));
    assert!(reading(&values, "meter_model").is_err(), "{values:?}");
    assert_eq!(reading(&values, "manufacturer"), &Ok(None));
}

/// The iEM3155's command interface as the manual gives it: one FC16 from register 5250 (bus
/// 5249), the command, a reserved 0, its parameters; the result code read at register 5376.
/// The reset's frame is the one seen going to real meters; the CRCs are computed apart, by
/// the bit-wise CRC-16/MODBUS of the specification.
#[test]
fn the_iem3155_command_interface_writes_the_manuals_frames_and_reads_the_result() {
    let profile = built_in("schneider-iem3155").expect("built in");
    let frame = |action: &str, payload: &str| {
        let plan = profile
            .plan_command(action, payload, &rtu2mqtt_profile::DeviceState::new())
            .unwrap_or_else(|rejection| panic!("{action} {payload}: {rejection}"));
        let writes = plan.writes(&[]).expect("no read before");
        assert_eq!(
            plan.readback(),
            [rtu2mqtt_modbus::Request::ReadHoldingRegisters {
                start: 5375,
                quantity: 1
            }]
        );
        writes
            .iter()
            .map(|write| {
                rtu2mqtt_modbus::codec::hex(
                    &rtu2mqtt_modbus::codec::encode_request(1, write).expect("a frame"),
                )
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(
        frame("reset_partial_energy", "PRESS"),
        ["01 10 14 81 00 02 04 07 E4 00 00 84 40"]
    );
    assert_eq!(
        frame("set_tariff", "{\"tariff\": 2}"),
        ["01 10 14 81 00 03 06 07 D8 00 00 00 02 51 38"]
    );
    assert_eq!(
        frame("set_tariff_mode", "1"),
        ["01 10 14 81 00 03 06 08 0C 00 00 00 01 21 D4"]
    );
    let refused = profile
        .plan_command("set_tariff", "5", &rtu2mqtt_profile::DeviceState::new())
        .expect_err("tariff 5");
    assert!(refused.to_string().contains("1"), "{refused}");
}

/// One library device on one line of the gateway, prefix `lib`, device name `device`.
fn config(broker: &Mosquitto, client_id: &str, line: &str, profile: &str) -> String {
    format!(
        r#"
[mqtt]
url = "{url}"
client_id = "{client_id}"
prefix = "lib"

[[lines]]
name = "line-1"
{line}
response_timeout = "300ms"

[[lines.devices]]
name = "device"
profile = "{profile}"
address = 1
"#,
        url = broker.url()
    )
}

/// Every entry's text on `lib/device/<field>`, `unavailable` for the entries without a value.
async fn assert_published(client: &mut TestClient, name: &str, entries: &[Entry]) {
    for entry in entries {
        let text = entry.published.as_deref().unwrap_or(UNAVAILABLE);
        let topic = format!("lib/device/{}", entry.field);
        let got = client.next_on(&topic, ANSWER).await.text();
        assert_eq!(got, text, "{name}: {topic}");
    }
}

/// A library device on a pseudo-terminal line of a running gateway, with a client that sees
/// `lib/#`.
struct OnPty {
    gateway: Gateway,
    client: TestClient,
    device: Arc<Mutex<GenericDevice>>,
    _line: VirtualLine,
    _broker: Mosquitto,
}

async fn start_on_pty(device: &LibraryDevice) -> OnPty {
    let baud = built_in(device.profile)
        .map(|p| p.limits().default_baud)
        .unwrap_or(9600);
    let (typed, shared) = share(device.map.device(1));
    let line = VirtualLine::spawn(ServeOptions::new(baud, Parity::None), vec![shared]).unwrap();
    let broker = Mosquitto::start();
    let mut client = TestClient::connect(broker.port, &format!("{}-test", device.profile)).await;
    client.subscribe("lib/#").await;
    let text = config(
        &broker,
        device.profile,
        &format!(
            "port = \"{}\"\nbaud = {baud}\nparity = \"none\"",
            line.path().display()
        ),
        device.profile,
    );
    let gateway = Gateway::start(fast_config(&text)).await;
    OnPty {
        gateway,
        client,
        device: typed,
        _line: line,
        _broker: broker,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_library_device_publishes_its_map_over_a_pty() {
    for device in library::devices() {
        let mut run = start_on_pty(&device).await;
        assert_published(&mut run.client, device.profile, &device.map.entries).await;
        run.gateway.stop().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn growatt_min_takes_a_power_limit_over_a_pty() {
    let mut run = start_on_pty(&library::growatt_min()).await;
    let limit = run
        .client
        .next_on("lib/device/active_power_rate", ANSWER)
        .await;
    assert_eq!(limit.text(), "100");

    // Holding register 3 takes 0–100 % or 255 ("not limited"): 101 is refused unwritten.
    let set = "lib/device/active_power_rate/set";
    let result = "lib/device/active_power_rate/result";
    run.client.publish(set, b"101".to_vec(), false).await;
    let refused = run.client.next_on(result, ANSWER).await.json();
    assert_eq!(refused["outcome"], "rejected", "{refused}");
    assert_eq!(lock(&run.device).holding(3), Some(100));
    assert_eq!(lock(&run.device).writes(), 0);

    run.client.publish(set, b"80".to_vec(), false).await;
    let applied = run.client.next_on(result, ANSWER).await.json();
    assert_eq!(applied["outcome"], "applied", "{applied}");
    assert_eq!(lock(&run.device).holding(3), Some(80));
    let read_back = run
        .client
        .next_on("lib/device/active_power_rate", ANSWER)
        .await;
    assert_eq!(read_back.text(), "80");
    run.gateway.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sdm630_publishes_its_map_over_modbus_tcp() {
    let device = library::sdm630();
    let shared: SharedDevice = share(device.map.device(1)).1;
    let sim = TcpSimulator::bind(
        "127.0.0.1:0",
        Protocol::ModbusTcp,
        ServeOptions::new(9600, Parity::None),
        vec![shared],
    )
    .await
    .unwrap();
    assert!(sim.url().starts_with("modbus-tcp://"));
    let broker = Mosquitto::start();
    let mut client = TestClient::connect(broker.port, "sdm630-test").await;
    client.subscribe("lib/#").await;
    let text = config(
        &broker,
        "sdm630",
        &format!("url = \"{}\"\nconnect_timeout = \"1s\"", sim.url()),
        "eastron-sdm630",
    );
    let gateway = Gateway::start(fast_config(&text)).await;
    assert_published(&mut client, device.profile, &device.map.entries).await;
    gateway.stop().await;
}

/// A `sunspec_chain` entry's field in a profile `rtu2mqtt sunspec` writes: `103/W` is
/// `inverter_w`, `160/module2/DCA` is `mppt_module2_dca`.
fn written_field(entry: &str) -> Option<String> {
    let mut parts = entry.split('/');
    let id: u16 = parts.next()?.parse().ok()?;
    let prefix = &sunspec::model(id)?.prefix;
    let rest: Vec<String> = parts.map(sunspec::snake).collect();
    Some(format!("{prefix}_{}", rest.join("_")))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sunspec_walks_the_inverter_and_its_profile_reads_it() {
    let map = library::sunspec_chain();
    let shared: SharedDevice = share(map.device(1)).1;
    let line = VirtualLine::spawn(ServeOptions::new(9600, Parity::None), vec![shared]).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let written = dir.path().join("inverter.toml");
    let port = line.path();
    let output = tokio::task::spawn_blocking({
        let written = written.clone();
        move || {
            Command::new(child::gateway_binary())
                .args(["sunspec", "--address", "1", "--port"])
                .arg(&port)
                .arg("--output")
                .arg(&written)
                .output()
                .unwrap()
        }
    })
    .await
    .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    for expected in [
        "base 40000",
        "manufacturer  Sim Solar",
        "model         SIM-10K-3P",
        "serial        SIM0001234",
        "version       1.4.2",
        "    1  at 40002  length 66",
        "  103  at 40070  length 50",
        "  160  at 40122  length 48   Multiple MPPT Inverter Extension Model, 2 × module",
    ] {
        assert!(stderr.contains(expected), "{expected:?} not in\n{stderr}");
    }

    // The written profile passes `check` in a configuration that uses it.
    let broker = Mosquitto::start();
    let text = config(
        &broker,
        "sunspec-written",
        &format!("port = \"{}\"", line.path().display()),
        &written.display().to_string(),
    );
    let config_path = dir.path().join("config.toml");
    std::fs::write(&config_path, &text).unwrap();
    let check = Command::new(child::gateway_binary())
        .args(["check", "--config"])
        .arg(&config_path)
        .output()
        .unwrap();
    assert!(
        check.status.success(),
        "{}{}",
        String::from_utf8_lossy(&check.stdout),
        String::from_utf8_lossy(&check.stderr)
    );

    // And it reads the inverter: every value the simulator holds, on the broker.
    // The written profile reads an enum16 as its number: the state 4 that `sunspec-inverter`
    // names `mppt`.
    let entries: Vec<Entry> = map
        .entries
        .iter()
        .filter_map(|e| {
            let published = match e.field.as_str() {
                "103/St" => Some("4".to_string()),
                _ => e.published.clone(),
            };
            written_field(&e.field).map(|field| Entry {
                field,
                published,
                ..e.clone()
            })
        })
        .collect();
    assert!(entries.len() > 40, "{}", entries.len());
    let mut client = TestClient::connect(broker.port, "sunspec-written-test").await;
    client.subscribe("lib/#").await;
    let gateway = Gateway::start(fast_config(&text)).await;
    assert_published(&mut client, "written sunspec profile", &entries).await;
    gateway.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sunspec_over_modbus_tcp_writes_the_profile_to_standard_output() {
    let shared: SharedDevice = share(library::sunspec_chain().device(7)).1;
    let sim = TcpSimulator::bind(
        "127.0.0.1:0",
        Protocol::ModbusTcp,
        ServeOptions::new(9600, Parity::None),
        vec![shared],
    )
    .await
    .unwrap();
    let url = sim.url();
    let output = tokio::task::spawn_blocking(move || {
        Command::new(child::gateway_binary())
            .args(["sunspec", "--address", "7", "--url", &url])
            .output()
            .unwrap()
    })
    .await
    .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(
        stderr.contains("SunSpec map at address 7, base 40000"),
        "{stderr}"
    );
    let text = String::from_utf8_lossy(&output.stdout);
    let profile = Profile::from_toml(&text, "stdout").unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert_eq!(profile.default_address(), Some(7));
    let blocks: Vec<&str> = profile
        .read_blocks()
        .iter()
        .map(|b| b.name.as_str())
        .collect();
    assert_eq!(blocks, ["m1_common", "m103_inverter", "m160_mppt"]);
    // Only reads (FC03) went to the device: marker, headers to the end marker, model 1.
    let requests = sim.journal().requests();
    assert!(requests.len() >= 6, "{}", requests.len());
    assert!(requests.iter().all(|r| r.frame.get(1) == Some(&3)));
}
