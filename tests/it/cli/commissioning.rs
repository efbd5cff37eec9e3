//! The commissioning commands against simulated devices on real ptys: `scan` finds each seed
//! device at its address and baud rate (the simulators garble their answers while the master's
//! baud rate on the pty differs from theirs) and asks each one what it is (Read Device
//! Identification, the SunSpec marker), naming the profile that fits and writing the
//! configuration; `read` decodes a known block every way, and neither puts a write on the line
//! (asserted from the simulators' journals).

use crate::support::child;

use std::process::Output;
use std::time::Duration;

use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_sim::{share, AirShower, DustCollector, ServeOptions, Valve, VirtualLine};

/// A pty served at `baud` 8N1 with the devices, answering garbled at any other baud rate.
fn line(baud: u32, devices: Vec<rtu2mqtt_sim::SharedDevice>) -> VirtualLine {
    let options = ServeOptions::new(baud, Parity::None).enforcing_baud(true);
    VirtualLine::spawn(options, devices).unwrap()
}

async fn run(args: &[&str]) -> Output {
    let mut command = std::process::Command::new(child::gateway_binary());
    command.args(args).env("RUST_LOG", "error");
    child::output(command, Duration::from_secs(60))
        .await
        .expect("command finished")
}

/// `subcommand` run on `line`'s port with the further `args`.
async fn run_on(line: &VirtualLine, subcommand: &str, args: &[&str]) -> Output {
    let path = line.path().to_string_lossy().into_owned();
    let mut all = vec![subcommand, "--port", &path];
    all.extend_from_slice(args);
    run(&all).await
}

/// `read` of `count` items from `start` with `function` at `address` on `line`'s port.
async fn read_block(
    line: &VirtualLine,
    address: &str,
    function: &str,
    start: &str,
    count: &str,
) -> Output {
    let args = [
        "--address",
        address,
        "--function",
        function,
        "--start",
        start,
        "--count",
        count,
    ];
    run_on(line, "read", &args).await
}

fn stdout(output: &Output) -> String {
    String::from_utf8_lossy(&output.stdout).into_owned()
}

/// Every frame the devices heard is a read (FC01–FC04, or FC43/14 Read Device
/// Identification).
async fn assert_only_reads(line: &VirtualLine) {
    // The journal records an answer once it is written: the command may have printed first.
    line.journal()
        .wait_for_requests(1, Duration::from_secs(2))
        .await;
    let frames = line.journal().frames();
    assert!(!frames.is_empty());
    for frame in frames {
        let read_device_id = frame.get(1..3) == Some(&[0x2B, 0x0E][..]);
        assert!(
            (0x01..=0x04).contains(&frame[1]) || read_device_id,
            "a non-read frame reached the line: {frame:02X?}"
        );
    }
}

/// The table rows (after the header) of a scan's output.
fn rows(text: &str) -> Vec<String> {
    text.lines()
        .skip_while(|line| !line.starts_with("address"))
        .skip(1)
        .take_while(|line| !line.is_empty())
        .map(str::to_owned)
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scan_finds_each_seed_device_at_its_address_and_baud_rate() {
    let dust = line(9600, vec![share(DustCollector::new(1)).1]);
    let shower = line(19200, vec![share(AirShower::new()).1]);
    let valve = line(4800, vec![share(Valve::new(2)).1]);
    let scan = |line| {
        let args = [
            "--baud",
            "4800,9600,19200",
            "--parity",
            "none",
            "--addresses",
            "1,2,0x81",
            "--timeout",
            "150ms",
        ];
        async move { run_on(line, "scan", &args).await }
    };
    let (dust_out, shower_out, valve_out) = tokio::join!(scan(&dust), scan(&shower), scan(&valve));
    for output in [&dust_out, &shower_out, &valve_out] {
        assert!(
            output.status.success(),
            "{}\n{}",
            stdout(output),
            String::from_utf8_lossy(&output.stderr)
        );
    }

    // The dust collector has no register 0: it answers exception 02, and reads no input
    // registers or coils either.
    assert_eq!(
        rows(&stdout(&dust_out)),
        ["  1 (0x01)    9600  8N1     FC03 exception 02 (illegal data address); FC04 exception 01 (illegal function); FC01 exception 01 (illegal function)"]
    );
    // The air shower serves coils only.
    assert_eq!(
        rows(&stdout(&shower_out)),
        ["129 (0x81)   19200  8N1     FC03 exception 01 (illegal function); FC04 exception 01 (illegal function); FC01 ok"]
    );
    // The valve reads its address register.
    assert_eq!(
        rows(&stdout(&valve_out)),
        ["  2 (0x02)    4800  8N1     FC03 ok"]
    );
    // The valve heard and answered the probe (FC03, one register at 0) at every baud rate,
    // garbled at the wrong ones, and the scan took none of those for a device (it asked what
    // it is only at the right one, with other reads).
    let probe = [2, 0x03, 0x00, 0x00, 0x00, 0x01];
    let answered: Vec<_> = valve
        .journal()
        .requests()
        .into_iter()
        .filter(|record| record.frame.starts_with(&probe) && record.answer.is_some())
        .collect();
    assert_eq!(answered.len(), 3, "one probe per baud rate");
    let garbled = answered
        .iter()
        .filter(|record| !rtu2mqtt_sim::wire::crc_ok(record.answer.as_deref().unwrap_or_default()))
        .count();
    assert_eq!(garbled, 2);

    for line in [&dust, &shower, &valve] {
        assert_only_reads(line).await;
    }
    assert_eq!(dust.journal().writes_to(1), 0);
}

/// The whole address range at one format takes seconds, not the 100 ms timeout per silent
/// address, and still finds every device: one that answers at once, one that starts answering
/// only after the quick wait (heard late, probed again with the full timeout), and one at the
/// last address.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_range_scan_is_quick_and_finds_every_device() {
    // Paced like a wire: each answer comes whole after its wire time.
    let options = ServeOptions::new(9600, Parity::None).paced(true);
    let plant = VirtualLine::spawn(
        options,
        vec![
            share(DustCollector::new(1)).1,
            share(Valve::new(2)).1,
            share(AirShower::new()).1,
            share(Valve::new(247)).1,
        ],
    )
    .unwrap();
    // The air shower (0x81) starts answering 17 ms late, 29 ms after the request: beyond the
    // quick wait (20 ms), so its answer comes while the next address is probed, and within
    // the 100 ms timeout.
    plant.faults().update(|f| {
        f.target = Some(0x81);
        f.delay = Duration::from_millis(17);
    });
    let started = std::time::Instant::now();
    let output = run_on(
        &plant,
        "scan",
        &["--baud", "9600", "--parity", "none", "--timeout", "100ms"],
    )
    .await;
    let took = started.elapsed();
    let text = stdout(&output);
    let errors = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(output.status.success(), "{text}\n{errors}");
    assert_eq!(
        rows(&text),
        [
            "  1 (0x01)    9600  8N1     FC03 exception 02 (illegal data address); FC04 exception 01 (illegal function); FC01 exception 01 (illegal function)",
            "  2 (0x02)    9600  8N1     FC03 ok",
            "129 (0x81)    9600  8N1     FC03 exception 01 (illegal function); FC04 exception 01 (illegal function); FC01 ok",
            "247 (0xf7)    9600  8N1     FC03 ok",
        ],
        "{errors}"
    );
    // The figure the scan prints, and the wall time around it (process start included).
    let seconds: f64 = errors
        .lines()
        .find_map(|line| line.strip_prefix("scanned 247 addresses at 1 serial setting in "))
        .and_then(|rest| rest.strip_suffix(" s"))
        .and_then(|figure| figure.parse().ok())
        .unwrap_or_else(|| panic!("no duration printed: {errors}"));
    println!("247 addresses at 9600 8N1: {seconds} s (wall {took:?})");
    assert!(seconds <= 10.0, "{seconds} s");
    assert!(took <= Duration::from_secs(12), "{took:?}");
    assert_only_reads(&plant).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scan_with_a_profile_shows_the_decoded_fields() {
    let valve = line(9600, vec![share(Valve::new(1)).1]);
    let output = run_on(
        &valve,
        "scan",
        &[
            "--baud",
            "9600",
            "--parity",
            "none",
            "--addresses",
            "1",
            "--profile",
            "wuzhou-valve",
        ],
    )
    .await;
    let text = stdout(&output);
    assert!(output.status.success(), "{text}");
    assert!(
        text.contains("wuzhou-valve at address 1 (9600 8N1):"),
        "{text}"
    );
    assert!(text.contains("software_version"), "{text}");
    assert_only_reads(&valve).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn read_decodes_the_valve_identity_block_every_way() {
    let valve = line(9600, vec![share(Valve::new(1)).1]);
    let output = read_block(&valve, "1", "3", "0x0000", "11").await;
    let text = stdout(&output);
    assert!(
        output.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    // The frames, byte for byte.
    assert!(text.contains("request  01 03 00 00 00 0B 04 0D"), "{text}");
    let answer = valve.journal().requests()[0].answer.clone().unwrap();
    assert!(text.contains(&format!(
        "answer   {}",
        rtu2mqtt_modbus::codec::hex(&answer)
    )));
    // Identity registers: address 1, serial 0x20 0x23 0x11 0x22 0x00 0x4A 0x5B, software 0x13,
    // hardware 0x02, baud code 6. u16, i16, bits, BCD, characters per register.
    for line in [
        "0x0000     0    0x0001        1       1  0000 0000 0000 0001     1  \"..\"",
        "0x0001     1    0x0020       32      32  0000 0000 0010 0000    20  \". \"",
        "0x0006     6    0x004a       74      74  0000 0000 0100 1010     -  \".J\"",
        "0x0007     7    0x005b       91      91  0000 0000 0101 1011     -  \".[\"",
        "0x000a    10    0x0006        6       6  0000 0000 0000 0110     6  \"..\"",
    ] {
        assert!(text.contains(line), "missing `{line}` in\n{text}");
    }
    // Pairs: 0x0001 0x0020 high word first is 0x00010020, low word first 0x00200001; as f32
    // both are tiny (denormal or near it), shown with an exponent.
    let high_first = 0x0001_0020u32;
    let low_first = 0x0020_0001u32;
    let pair = format!(
        "0x0000     0    {high_first:>21}  {:>11}  {:>14}  | {low_first:>20}  {:>11}  {:>14}",
        high_first as i32,
        format!("{:e}", f32::from_bits(high_first)),
        low_first as i32,
        format!("{:e}", f32::from_bits(low_first)),
    );
    assert!(text.contains(&pair), "missing `{pair}` in\n{text}");
    // The block as characters, both byte orders (non-printable bytes as dots).
    assert!(
        text.contains("text (high byte first) \"... .#.......J.[......\""),
        "{text}"
    );
    assert!(
        text.contains("text (low byte first)  \".. .#.......J.[.......\""),
        "{text}"
    );
    assert_only_reads(&valve).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn read_shows_bits_of_a_coil_block() {
    let shower = line(9600, vec![share(AirShower::new()).1]);
    let output = read_block(&shower, "0x81", "1", "0", "22").await;
    let text = stdout(&output);
    assert!(output.status.success(), "{text}");
    assert!(text.contains("request  81 01 00 00 00 16"), "{text}");
    assert!(text.contains("0x0000     0    "), "{text}");
    assert!(text.contains("0x0010    16    "), "{text}");
    assert!(text.contains("on: "), "{text}");
    assert_only_reads(&shower).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_port_held_by_rtu2mqtt_is_refused() {
    let (master, slave) = mio_serial::SerialStream::pair().unwrap();
    let path = mio_serial::SerialPort::name(&slave).unwrap();
    drop(slave);
    // Another rtu2mqtt process holds the port (here a simulator; a gateway holds it the same way).
    let mut command = std::process::Command::new(child::binary("rtu2mqtt-demo"));
    command
        .args(["simulate", "--profile", "wuzhou-valve", "--port", &path])
        .env("RUST_LOG", "error");
    let holder = child::KillOnDrop::spawn(command).unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    for args in [
        vec!["read", "--port", &path, "--address", "1", "--start", "0"],
        vec!["scan", "--port", &path, "--addresses", "1"],
    ] {
        let output = run(&args).await;
        let error = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success());
        assert!(
            error.contains(&format!("{path} is in use by rtu2mqtt pid {}", holder.id())),
            "{error}"
        );
    }
    drop(holder);
    drop(master);
}

#[tokio::test]
async fn write_functions_are_refused_before_the_port_is_opened() {
    let output = run(&[
        "read",
        "--port",
        "/nonexistent",
        "--address",
        "1",
        "--function",
        "6",
        "--start",
        "0",
    ])
    .await;
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("only the read functions"));
}

/// The rows of a scan's identification table after its header, each split at its column
/// gaps.
pub(crate) fn identification_rows(text: &str) -> Vec<Vec<String>> {
    text.lines()
        .skip_while(|line| !line.starts_with("address     FC43"))
        .skip(1)
        .take_while(|line| !line.is_empty())
        .map(|line| {
            line.split("  ")
                .map(str::trim)
                .filter(|w| !w.is_empty())
                .map(str::to_owned)
                .collect()
        })
        .collect()
}

/// One expected row of [`identification_rows`].
pub(crate) fn cells(row: &[&str]) -> Vec<String> {
    row.iter().map(|cell| cell.to_string()).collect()
}

/// A site's own profile for a meter that identifies itself as Sim Metering SM-3P-100.
const SITE_METER: &str = r#"
[device]
name = "sim-meter"
manufacturer = "Sim Metering"
model = "SM-3P"
identification = { vendor = "Sim Metering", product_code = "SM-3P-*" }

[line]
baud = 9600
parity = "none"

[[blocks]]
name = "values"
function = 3
start = 0
count = 2

[[fields]]
name = "voltage"
block = "values"
offset = 0
codec = { type = "u16", scale = 0.1, decimals = 1 }
unit = "V"
"#;

/// `scan` asks each device found what it is: a device with identification objects is named by
/// the profile whose `identification` they match (the library's iEM3155, and a site profile
/// from `--profiles`), a SunSpec inverter by its chain (the built-in sunspec-inverter), a device
/// without FC43 (the dust collector answers exception 01) and one whose identification no
/// profile names are unknown. A stream longer than one answer is followed. The configuration
/// it writes is one `check` reads, wanting only the two missing profiles; and nothing but
/// reads reached the line.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scan_identifies_each_device_and_writes_the_configuration() {
    use rtu2mqtt_modbus::DeviceIdObject;
    use rtu2mqtt_sim::GenericDevice;

    let profiles = tempfile::tempdir().unwrap();
    let profile_path = profiles.path().join("sim-meter.toml");
    std::fs::write(&profile_path, SITE_METER).unwrap();
    let site = rtu2mqtt_profile::Profile::from_toml(SITE_METER, "sim-meter").unwrap();
    let meter = GenericDevice::from_profile(&site, 3).with_identification(vec![
        DeviceIdObject::text(0, "Sim Metering"),
        DeviceIdObject::text(1, "SM-3P-100"),
        DeviceIdObject::text(2, "1.4.2"),
    ]);
    let inverter = rtu2mqtt_sim::library::sunspec_inverter().device(4);
    // A meter of another series (a PM3255) with fixed-length objects padded with NUL bytes,
    // as some meters send them: the vendor's 230 bytes leave no room for the revision, which
    // comes with a second request.
    let mut vendor = b"Schneider Electric".to_vec();
    vendor.resize(230, 0);
    let mut other_meter = GenericDevice::empty(5).with_identification(vec![
        DeviceIdObject {
            id: 0,
            value: vendor,
        },
        DeviceIdObject::text(1, "METSEPM3255"),
        DeviceIdObject::text(2, "1.2.3"),
    ]);
    other_meter.set_holding(0, 7);
    let iem3155 = rtu2mqtt_sim::library::iem3155().device(6);
    let plant = line(
        9600,
        vec![
            share(DustCollector::new(1)).1,
            share(meter).1,
            share(inverter).1,
            share(other_meter).1,
            share(iem3155).1,
        ],
    );
    let directory = profiles.path().to_string_lossy().into_owned();
    let output = run_on(
        &plant,
        "scan",
        &[
            "--baud",
            "9600",
            "--parity",
            "none",
            "--addresses",
            "1-6",
            "--timeout",
            "150ms",
            "--profiles",
            &directory,
        ],
    )
    .await;
    let text = stdout(&output);
    assert!(
        output.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let site_reference = profile_path.to_string_lossy().into_owned();
    assert_eq!(
        identification_rows(&text),
        [
            cells(&[
                "1 (0x01)",
                "exception 01 (illegal function)",
                "-",
                "-",
                "-",
                "-",
                "unknown"
            ]),
            cells(&[
                "3 (0x03)",
                "ok",
                "Sim Metering",
                "SM-3P-100",
                "1.4.2",
                "-",
                &site_reference
            ]),
            cells(&[
                "4 (0x04)",
                "exception 01 (illegal function)",
                "-",
                "-",
                "-",
                "40000: models 1, 103, 160",
                "sunspec-inverter"
            ]),
            cells(&[
                "5 (0x05)",
                "ok",
                "Schneider Electric",
                "METSEPM3255",
                "1.2.3",
                "-",
                "unknown"
            ]),
            cells(&[
                "6 (0x06)",
                "ok",
                "Schneider Electric",
                "A9MEM3155",
                "002.001.004",
                "-",
                "schneider-iem3155"
            ]),
        ],
        "{text}"
    );
    let configuration = text
        .split("a configuration to copy (docs/configuration.md):\n\n")
        .nth(1)
        .unwrap_or_else(|| panic!("no configuration: {text}"));
    let port = plant.path().to_string_lossy().into_owned();
    assert_eq!(
        configuration,
        format!(
            "[[lines]]\nname = \"line1\"\nport = \"{port}\"\nbaud = 9600\nparity = \"none\"\n\n\
             [[lines.devices]]\nname = \"device_1\"\n# profile: unknown — write one, see docs/profiles.md\naddress = 1\n\n\
             [[lines.devices]]\nname = \"sim_meter_3\"\nprofile = \"{site_reference}\"\naddress = 3\n\n\
             [[lines.devices]]\nname = \"sunspec_inverter_4\"\nprofile = \"sunspec-inverter\"\naddress = 4\n\n\
             [[lines.devices]]\nname = \"device_5\"\n# profile: unknown — write one, see docs/profiles.md\naddress = 5\n\n\
             [[lines.devices]]\nname = \"schneider_iem3155_6\"\nprofile = \"schneider-iem3155\"\naddress = 6\n"
        )
    );
    // The configuration as `check` reads it: only the two devices without a profile lack one.
    let config_dir = tempfile::tempdir().unwrap();
    let config_path = config_dir.path().join("config.toml");
    std::fs::write(
        &config_path,
        format!("[mqtt]\nurl = \"mqtt://127.0.0.1:1883\"\nclient_id = \"edge\"\n\n{configuration}"),
    )
    .unwrap();
    let check = run(&["check", "--config", &config_path.to_string_lossy()]).await;
    let said = format!(
        "{}{}",
        stdout(&check),
        String::from_utf8_lossy(&check.stderr)
    );
    assert!(!check.status.success(), "{said}");
    let problems: Vec<&str> = said
        .lines()
        .filter(|line| line.contains("lines[0].devices["))
        .collect();
    assert_eq!(problems.len(), 2, "{said}");
    assert!(
        problems[0].contains("devices[0]") && problems[0].contains("profile"),
        "{said}"
    );
    assert!(
        problems[1].contains("devices[3]") && problems[1].contains("profile"),
        "{said}"
    );

    // The long stream was followed from the object the device named; the seed device was
    // asked once and said exception 01.
    let frames = plant.journal().frames();
    let hex = |frame: &[u8]| rtu2mqtt_modbus::codec::hex(frame);
    let asked: Vec<String> = frames
        .iter()
        .filter(|frame| frame.get(1) == Some(&0x2B))
        .map(|frame| hex(frame))
        .collect();
    let expected = |address: u8, from: u8| {
        hex(&rtu2mqtt_modbus::codec::encode_request(
            address,
            &rtu2mqtt_modbus::Request::ReadDeviceIdentification {
                code: rtu2mqtt_modbus::ReadDeviceIdCode::Basic,
                object_id: from,
            },
        )
        .unwrap())
    };
    assert_eq!(asked[0], "01 2B 0E 01 00 70 77");
    assert_eq!(
        asked,
        [
            expected(1, 0),
            expected(3, 0),
            expected(4, 0),
            expected(5, 0),
            expected(5, 2),
            expected(6, 0)
        ]
    );
    // Nothing was asked at the silent address.
    assert!(frames
        .iter()
        .all(|frame| frame[0] != 2 || frame[1] == 0x03 && frame[2..6] == [0, 0, 0, 1]));
    assert_only_reads(&plant).await;
}
