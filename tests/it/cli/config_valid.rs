//! The configuration as users meet it: the shipped example is valid, so is the one the Debian
//! package installs (it polls nothing until lines are written), `rtu2mqtt check` prints
//! the poll plan and exits 0; a configuration with many mistakes gets every one of them listed
//! with its place, exit 1, in one run whatever the phase; environment overrides reach the
//! settings; names, prefixes, ports, the CA file and secrets are checked so that nothing
//! accepted breaks the MQTT link or leaks a password.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use rtu2mqtt::config;

fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/rtu2mqtt.toml")
}

fn check(path: &Path) -> (bool, String, String) {
    let output = Command::new(crate::support::child::gateway_binary())
        .arg("check")
        .arg("--config")
        .arg(path)
        .env_remove("RTU2MQTT_CONFIG")
        .output()
        .unwrap();
    (
        output.status.success(),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

#[test]
fn the_example_configuration_is_the_seed_plant() {
    let config = config::load(&example()).unwrap();
    assert_eq!(config.mqtt.client_id, "rtu2mqtt-edge1");
    assert_eq!(config.mqtt.prefix, "plant");
    let lines: Vec<(&str, usize)> = config
        .lines
        .iter()
        .map(|line| (line.name.as_str(), line.devices.len()))
        .collect();
    assert_eq!(lines, [("line-a", 2), ("line-b", 1)]);
    let shower = &config.lines[0].devices[1];
    assert_eq!(shower.name, "air_shower");
    assert_eq!(shower.address, 0x81);
    assert_eq!(shower.profile.name(), "lixian-air-shower");
    assert_eq!(
        config.lines[1].serial.format.parity,
        rtu2mqtt_modbus::timing::Parity::Even
    );
}

#[test]
fn check_prints_the_poll_plan() {
    let (ok, stdout, stderr) = check(&example());
    assert!(ok, "check failed: {stderr}");
    for expected in [
        "valid",
        "line line-a on /dev/ttyUSB0: 9600 baud 8N1",
        "line line-b on /dev/ttyUSB1: 9600 baud 8E1",
        "dust_collector",
        "ruiwan-dust-collector",
        "air_shower",
        "valve",
        "per fast cycle:",
        "bus load",
    ] {
        assert!(
            stdout.contains(expected),
            "{expected:?} missing in:\n{stdout}"
        );
    }
    // The /dev/ttyUSB0 names deserve a warning, not an error.
    assert!(stdout.contains("warning: lines[0].port"), "{stdout}");
}

const MANY_MISTAKES: &str = r##"
[mqtt]
url = "mqtt://127.0.0.1:1883"
client_id = "edge1"
prefix = "#plant"
keep_alive = "500ms"
inflight = 0
colour = "blue"

[[lines]]
name = "line-a"
port = "/dev/ttyS1"
baud = 9601
stop_bits = 3

[[lines.devices]]
name = "dust_collector"
profile = "ruiwan-dust-collector"
address = 254
poll_interval = "200ms"

[[lines.devices]]
name = "gateway"
profile = "lixian-air-shower"
address = 0x81

[[lines.devices]]
name = "second"
profile = "lixian-air-shower"
address = 0x81

[[lines]]
name = "line-b"
port = "/dev/ttyS2"

[[lines.devices]]
name = "dust_collector"
profile = "no-such-profile"
address = 1
"##;

#[test]
fn every_problem_is_listed_with_its_place() {
    // Unknown keys are reported first (with the other problems after them).
    let (ok, _, stderr) = check_text(MANY_MISTAKES, &[]);
    assert!(!ok);
    assert!(stderr.contains("mqtt.colour: unknown key"), "{stderr}");

    let (ok, stdout, stderr) = check_text(&MANY_MISTAKES.replace("colour = \"blue\"\n", ""), &[]);
    assert!(!ok, "accepted: {stdout}");
    for place in [
        "mqtt.prefix:",
        "mqtt.keep_alive:",
        "mqtt.inflight:",
        "lines[0].baud:",
        "lines[0].stop_bits:",
        "lines[0].devices[0].address: 254 is outside 1–247 allowed by profile ruiwan-dust-collector",
        "lines[0].devices[0].poll_interval:",
        "lines[0].devices[1].name: \"gateway\" is reserved",
        "lines[0].devices[2].address: 129 is already used on this line",
        "lines[1].devices[0].name: \"dust_collector\" is already the name of lines[0].devices[0]",
        "lines[1].devices[0].profile:",
    ] {
        assert!(stderr.contains(place), "{place:?} missing in:\n{stderr}");
    }
}

#[test]
fn environment_overrides_reach_the_settings() {
    let output = Command::new(crate::support::child::gateway_binary())
        .arg("check")
        .arg("--config")
        .arg(example())
        .env("RTU2MQTT__MQTT__PREFIX", "site7")
        .env("RTU2MQTT__MQTT__KEEP_ALIVE", "0s")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(stderr.contains("mqtt.keep_alive"), "{stderr}");

    let output = Command::new(crate::support::child::gateway_binary())
        .arg("check")
        .arg("--config")
        .arg(example())
        .env("RTU2MQTT__MQTT__PREFIX", "site7")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success());
    assert!(stdout.contains("prefix \"site7\""), "{stdout}");
}

#[test]
fn a_missing_file_is_a_clear_error() {
    let (ok, _, stderr) = check(Path::new("/nonexistent/rtu2mqtt.toml"));
    assert!(!ok);
    assert!(
        stderr.contains("cannot read the configuration file"),
        "{stderr}"
    );
}

/// `check` on `text` written as config.toml in a fresh directory (with `files` beside it):
/// (accepted, stdout, stderr).
fn check_text(text: &str, files: &[(&str, &str)]) -> (bool, String, String) {
    let dir = tempfile::tempdir().unwrap();
    for (name, content) in files {
        std::fs::write(dir.path().join(name), content).unwrap();
    }
    let text = text.replace("{dir}", &dir.path().to_string_lossy());
    let path = dir.path().join("config.toml");
    std::fs::write(&path, text).unwrap();
    check(&path)
}

/// A valid configuration of one valve on `{port}`; `{mqtt}` and `{device}` take more keys.
const ONE_VALVE: &str = r#"
[mqtt]
url = "mqtt://127.0.0.1:1883"
client_id = "edge1"
{mqtt}

[[lines]]
name = "line-b"
port = "/dev/ttyS2"

[[lines.devices]]
name = "valve"
profile = "wuzhou-valve"
address = 1
{device}
"#;

fn one_valve(mqtt: &str, device: &str) -> String {
    ONE_VALVE
        .replace("{mqtt}", mqtt)
        .replace("{device}", device)
}

#[test]
fn the_base_of_these_checks_is_valid() {
    let (ok, stdout, stderr) = check_text(&one_valve("", ""), &[]);
    assert!(ok, "{stdout}{stderr}");
}

#[test]
fn the_setting_that_paged_start_up_code_out_is_an_unknown_key() {
    let text = one_valve("", "") + "\n[gateway]\nrelease_startup_code_after = \"30s\"\n";
    let (ok, _, stderr) = check_text(&text, &[]);
    assert!(!ok, "the old key passed silently");
    assert!(
        stderr.contains("gateway.release_startup_code_after: unknown key"),
        "{stderr}"
    );
}

#[test]
fn an_unknown_key_or_a_wrong_type_does_not_hide_the_other_problems() {
    let (ok, _, stderr) = check_text(MANY_MISTAKES, &[]);
    assert!(!ok);
    for place in [
        "mqtt.colour: unknown key",
        "mqtt.keep_alive:",
        "lines[0].devices[0].address: 254 is outside 1–247",
        "lines[0].devices[1].name: \"gateway\" is reserved",
        "lines[1].devices[0].profile:",
    ] {
        assert!(stderr.contains(place), "{place:?} missing in:\n{stderr}");
    }
    let text = one_valve("", "").replace("address = 1", "address = 300\npoll_interval = 5");
    let (ok, _, stderr) = check_text(&text, &[]);
    assert!(!ok);
    assert!(
        stderr.contains("lines[0].devices[0].poll_interval: 5 is not a duration"),
        "{stderr}"
    );
    assert!(
        stderr.contains("lines[0].devices[0].address: 300 is outside"),
        "{stderr}"
    );
}

#[test]
fn names_the_contract_uses_as_topic_levels_are_refused() {
    for name in ["availability", "set", "result", "gateway"] {
        let text = one_valve("", "").replace("name = \"valve\"", &format!("name = \"{name}\""));
        let (ok, _, stderr) = check_text(&text, &[]);
        assert!(!ok, "device {name} accepted");
        assert!(
            stderr.contains(&format!("lines[0].devices[0].name: \"{name}\" is reserved")),
            "{stderr}"
        );
    }
    let valve = include_str!("../../../config/profiles/wuzhou-valve.toml");
    for field in ["availability", "set", "result"] {
        let profile = valve.replace("name = \"serial_number\"", &format!("name = \"{field}\""));
        assert_ne!(profile, valve, "the valve profile changed shape");
        let text = one_valve("", "").replace("\"wuzhou-valve\"", "\"valve.toml\"");
        let (ok, _, stderr) = check_text(&text, &[("valve.toml", &profile)]);
        assert!(!ok, "field {field} accepted");
        assert!(
            stderr.contains("lines[0].devices[0].profile:")
                && stderr.contains(&format!("({field}).name: \"{field}\" is reserved")),
            "{stderr}"
        );
    }
}

#[test]
fn names_are_bounded_and_never_echoed_whole() {
    let long = "x".repeat(70_000);
    let valve = include_str!("../../../config/profiles/wuzhou-valve.toml");
    let profile = valve.replace("name = \"serial_number\"", &format!("name = \"{long}\""));
    let text = one_valve("", "").replace("\"wuzhou-valve\"", "\"valve.toml\"");
    let (ok, _, stderr) = check_text(&text, &[("valve.toml", &profile)]);
    assert!(!ok, "a 70,000-character field name was accepted");
    assert!(stderr.contains("at most 64 characters"), "{stderr}");
    assert!(stderr.len() < 2_000, "{} bytes of problems", stderr.len());

    let text = one_valve("", "").replace("name = \"valve\"", &format!("name = \"{long}\""));
    let (ok, _, stderr) = check_text(&text, &[]);
    assert!(!ok);
    assert!(stderr.contains("(70000 bytes)"), "{stderr}");
    assert!(stderr.len() < 2_000, "{} bytes of problems", stderr.len());
}

#[test]
fn one_port_spelled_two_ways_is_one_port() {
    let second_line = |port: &str| {
        format!(
            "\n[[lines]]\nname = \"line-c\"\nport = \"{port}\"\n\n[[lines.devices]]\n\
             name = \"valve2\"\nprofile = \"wuzhou-valve\"\naddress = 2\n"
        )
    };
    // Lexically: the port does not exist here.
    let text = one_valve("", "") + &second_line("/dev/./ttyS2");
    let (ok, _, stderr) = check_text(&text, &[]);
    assert!(!ok, "/dev/./ttyS2 and /dev/ttyS2 accepted as two ports");
    assert!(
        stderr.contains("lines[1].port: /dev/./ttyS2 is already the port of lines[0]"),
        "{stderr}"
    );
    // A link (as /dev/serial/by-id/… is) and its target.
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("ttyA");
    std::fs::write(&target, b"").unwrap();
    let link = dir.path().join("usb-FTDI-if00-port0");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    let text = one_valve("", "").replace("/dev/ttyS2", &target.to_string_lossy())
        + &second_line(&link.to_string_lossy());
    let (ok, _, stderr) = check_text(&text, &[]);
    assert!(!ok, "a link and its target accepted as two ports");
    assert!(
        stderr.contains("is already the port of lines[0]"),
        "{stderr}"
    );
}

#[test]
fn the_prefix_stays_out_of_the_discovery_prefix() {
    for mqtt in [
        "prefix = \"homeassistant\"\ndiscovery = true",
        "prefix = \"homeassistant/plant\"\ndiscovery = true",
        "prefix = \"site\"\ndiscovery_prefix = \"site/ha\"\ndiscovery = true",
    ] {
        let (ok, _, stderr) = check_text(&one_valve(mqtt, ""), &[]);
        assert!(!ok, "{mqtt} accepted");
        assert!(stderr.contains("mqtt.prefix:"), "{stderr}");
    }
}

#[test]
fn a_ca_file_without_a_certificate_is_refused() {
    let mqtt = "url = \"mqtts://127.0.0.1:8883\"\nca_file = \"ca.crt\"";
    let text = one_valve("", "").replace("url = \"mqtt://127.0.0.1:1883\"", mqtt);
    for junk in [
        "not a certificate\n",
        "-----BEGIN CERTIFICATE-----\nMAA=\n-----END CERTIFICATE-----\n",
    ] {
        let (ok, _, stderr) = check_text(&text, &[("ca.crt", junk)]);
        assert!(!ok, "{junk:?} accepted as a CA");
        assert!(stderr.contains("mqtt.ca_file:"), "{stderr}");
    }
}

#[test]
fn secrets_never_appear_in_a_message() {
    let text = one_valve("", "").replace(
        "mqtt://127.0.0.1:1883",
        "mqtt://user:s3cr3t-pw@127.0.0.1:1883",
    );
    let (ok, stdout, stderr) = check_text(&text, &[]);
    assert!(!ok);
    assert!(
        !stderr.contains("s3cr3t") && !stdout.contains("s3cr3t"),
        "{stderr}"
    );
    assert!(
        stderr.contains("mqtt://user:***@127.0.0.1:1883"),
        "{stderr}"
    );

    let text = one_valve("username = \"user\"\npassword = 987654321", "");
    let (ok, _, stderr) = check_text(&text, &[]);
    assert!(!ok);
    assert!(stderr.contains("mqtt.password:"), "{stderr}");
    assert!(!stderr.contains("987654321"), "{stderr}");
}

#[test]
fn check_shows_the_sparkplug_node() {
    let text = std::fs::read_to_string(example()).expect("example configuration")
        + "\n[sparkplug]\ngroup_id = \"plant\"\nprimary_host_id = \"scada\"\n";
    let (valid, stdout, stderr) = check_text(&text, &[]);
    assert!(valid, "{stderr}");
    assert!(
        stdout.lines().any(|line| line
            == "sparkplug: spBv1.0/plant/…/rtu2mqtt-edge1 on mqtt://127.0.0.1:1883 as \
                \"rtu2mqtt-edge1-sparkplug\", births wait for primary host \"scada\""),
        "{stdout}"
    );
}

#[test]
fn check_shows_the_history_journal_and_places_its_problems() {
    let text = one_valve("", "") + "\n[history]\npath = \"{dir}/history\"\nmax_size = \"1MiB\"\n";
    let (ok, stdout, stderr) = check_text(&text, &[]);
    assert!(ok, "{stdout}{stderr}");
    let shown = stdout
        .lines()
        .find(|line| line.starts_with("history: journal in "))
        .unwrap_or_else(|| panic!("no history line:\n{stdout}"));
    assert!(
        shown.ends_with(
            "/history, at most 1048576 bytes, records kept 7days; stream on plant/+/history"
        ),
        "{shown}"
    );
    assert!(stdout.contains("history journal: nothing yet"), "{stdout}");

    let bad = one_valve("", "")
        + "\n[history]\npath = \"{dir}/history\"\nmax_size = \"lots\"\nmax_age = \"soon\"\n";
    let (ok, stdout, stderr) = check_text(&bad, &[]);
    assert!(!ok, "{stdout}");
    assert!(
        stderr.contains("history.max_size: \"lots\" is not a size"),
        "{stderr}"
    );
    assert!(stderr.contains("history.max_age"), "{stderr}");
    let (ok, _, stderr) = check_text(
        &(one_valve("", "") + "\n[history]\nmax_size = \"1MiB\"\n"),
        &[],
    );
    assert!(!ok);
    assert!(stderr.contains("history.path"), "{stderr}");
}

#[test]
fn check_says_where_the_history_journal_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("a-file"), "not a directory").unwrap();
    std::os::unix::fs::symlink(dir.path().join("loop-b"), dir.path().join("loop-a")).unwrap();
    std::os::unix::fs::symlink(dir.path().join("loop-a"), dir.path().join("loop-b")).unwrap();
    let root = dir.path().display().to_string();
    for (path, cause) in [
        (
            format!("{root}/a-file"),
            format!("{root}/a-file: is not a directory"),
        ),
        (
            format!("{root}/a-file/history"),
            format!("{root}/a-file: is not a directory, so {root}/a-file/history cannot be made"),
        ),
        (
            format!("{root}/loop-a"),
            format!("{root}/loop-a: Too many levels of symbolic links"),
        ),
    ] {
        let text = one_valve("", "") + &format!("\n[history]\npath = \"{path}\"\n");
        let (ok, stdout, stderr) = check_text(&text, &[]);
        assert!(!ok, "{stdout}{stderr}");
        let shown = stdout
            .lines()
            .find(|line| line.starts_with("history.path: cannot be written (as uid "))
            .unwrap_or_else(|| panic!("{path}: not said:\n{stdout}"));
        assert!(shown.contains(&cause), "{shown}");
        assert!(
            shown.ends_with("report itself unhealthy until it can"),
            "{shown}"
        );
    }
    let text = one_valve("", "") + &format!("\n[history]\npath = \"{root}/fresh/history\"\n");
    let (ok, stdout, stderr) = check_text(&text, &[]);
    assert!(
        ok,
        "a directory still to be made under a writable one: {stdout}{stderr}"
    );
    assert!(!stdout.contains("cannot be written"), "{stdout}");
}

#[test]
fn check_shows_a_served_line_and_warns_about_raw_access() {
    let served = ONE_VALVE
        .replace("{mqtt}", "")
        .replace("{device}", "")
        .replace(
            "port = \"/dev/ttyS2\"\n",
            "port = \"/dev/ttyS2\"\n[lines.serve]\nlisten = \"modbus-tcp://0.0.0.0:5020\"\n\
             access = \"raw\"\ncache = \"1s\"\n",
        );
    let (ok, stdout, stderr) = check_text(&served, &[]);
    assert!(ok, "{stdout}{stderr}");
    assert!(
        stdout.lines().any(|line| line
            == "  served on modbus-tcp://0.0.0.0:5020 to at most 8 clients, access raw, cache 1s"),
        "{stdout}"
    );
    assert!(
        stdout
            .lines()
            .any(|line| line.starts_with("warning: lines[0].serve.access: raw:")),
        "{stdout}"
    );
}

/// The cadence meter (one block of each cadence) next to the seed valve.
const MIXED_CONFIG: &str = r#"
[mqtt]
url = "mqtt://127.0.0.1:1883"
client_id = "edge1"

[[lines]]
name = "line-m"
port = "/dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A10KXYZ-if00-port0"
baud = 9600

[[lines.devices]]
name = "meter"
profile = "{dir}/cadence-meter.toml"
address = 3
poll_interval = "1s"

[[lines.devices]]
name = "valve"
profile = "wuzhou-valve"
address = 1
"#;

#[test]
fn check_shows_each_blocks_cadence_and_the_line_load_of_every_period() {
    let (ok, stdout, stderr) = check_text(
        MIXED_CONFIG,
        &[("cadence-meter.toml", crate::lines::cadence::PROFILE)],
    );
    assert!(ok, "check failed: {stderr}");
    for expected in [
        "FC04 0x0000 (0) ×2   fast every 1s",
        "FC04 0x0010 (16) ×2  every 250ms",
        "FC04 0x0100 (256) ×2 every 15s",
        "FC03 0x0300 (768) ×1 slow every 1m",
        "FC03 0x0200 (512) ×2 once",
        "once: 1 block, 25.00 ms on the wire",
        "no load in steady state",
    ] {
        assert!(
            stdout.contains(expected),
            "{expected:?} missing in:\n{stdout}"
        );
    }

    // The load: each block's wire time over its own period, a once block nothing.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("cadence-meter.toml"),
        crate::lines::cadence::PROFILE,
    )
    .unwrap();
    let text = MIXED_CONFIG.replace("{dir}", &dir.path().to_string_lossy());
    let config = config::from_str(&text, dir.path()).unwrap();
    let plan = rtu2mqtt::config::poll_plan::LinePlan::of(&config.lines[0]);
    let meter = &plan.devices[0];
    let periods: Vec<Option<Duration>> = meter.blocks.iter().map(|b| b.period).collect();
    let ms = Duration::from_millis;
    assert_eq!(
        periods,
        [
            Some(ms(1000)),
            Some(ms(250)),
            Some(ms(15_000)),
            Some(ms(60_000)),
            None
        ]
    );
    for block in &meter.blocks {
        let expected = block.period.map_or(0.0, |period| {
            block.wire_time.as_secs_f64() / period.as_secs_f64()
        });
        assert!((block.load - expected).abs() < 1e-12, "{block:?}");
    }
    let sum: f64 = meter.blocks.iter().map(|b| b.load).sum();
    assert!(
        (meter.bus_load - sum).abs() < 1e-9,
        "{} vs {sum}",
        meter.bus_load
    );
    // The 250 ms block weighs four times its wire time per second on the line.
    let voltage = &meter.blocks[1];
    assert!(voltage.load > 3.9 * voltage.wire_time.as_secs_f64());
    let line_sum: f64 = plan.devices.iter().map(|d| d.bus_load).sum();
    assert!((plan.bus_load - line_sum).abs() < 1e-9);
}

/// A meter whose power exponent sits in a block of its own read every second, while the power
/// is in the fast block (every second at the profile's default).
const SCALED_METER: &str = r#"
[device]
name = "scaled-meter"
manufacturer = "Test"
model = "S1"

[line]
min_poll_interval = "100ms"
poll_interval = "1s"

[[blocks]]
name = "power"
function = 3
start = 0
count = 1

[[blocks]]
name = "factors"
function = 3
start = 0x10
count = 1
poll = "1s"

[[fields]]
name = "power"
block = "power"
offset = 0
codec = { type = "i16", scale_by = "power_sf" }

[[fields]]
name = "power_sf"
block = "factors"
offset = 0
codec = { type = "i16" }
"#;

#[test]
fn a_device_polled_faster_than_its_exponents_are_read_is_refused_with_its_place() {
    let config = |poll: &str| {
        MIXED_CONFIG
            .replace("cadence-meter.toml", "scaled-meter.toml")
            .replace(
                "poll_interval = \"1s\"",
                &format!("poll_interval = \"{poll}\""),
            )
    };
    let files = [("scaled-meter.toml", SCALED_METER)];
    let (ok, stdout, stderr) = check_text(&config("1s"), &files);
    assert!(ok, "{stdout}{stderr}");
    let (ok, _, stderr) = check_text(&config("500ms"), &files);
    assert!(
        !ok,
        "accepted a fast block read twice as often as its exponent"
    );
    assert!(
        stderr.contains("lines[0].devices[0].poll_interval")
            && stderr.contains("the exponent `power_sf` of `power`"),
        "{stderr}"
    );
}

/// The cadence meter with its power block copied from a manual as "43204": `check` loads it
/// and warns; said in Modicon numbers, the same text reads bus address 3203 silently.
#[test]
fn check_warns_about_a_start_that_looks_like_a_modicon_number_and_reads_the_convention() {
    let copied = crate::lines::cadence::PROFILE.replacen(
        "function = 4\nstart = 0x0000",
        "function = 3\nstart = 43204",
        1,
    );
    let (ok, stdout, stderr) = check_text(MIXED_CONFIG, &[("cadence-meter.toml", &copied)]);
    assert!(ok, "check failed: {stderr}");
    let warning = stdout
        .lines()
        .find(|line| line.starts_with("warning: lines[0].devices[0].profile: "))
        .unwrap_or_else(|| panic!("no warning in:\n{stdout}"));
    assert!(
        warning.ends_with(
            "cadence-meter.toml: blocks[0] (power).start: 43204 looks like a Modicon number \
             (register 3204 of its table, bus address 3203); a manual's numbers are copied with \
             `register_numbers = \"modicon\"` in [device], and `register_numbers = \"bus\"` says \
             that 43204 is meant"
        ),
        "{warning}"
    );
    assert!(stdout.contains("FC03 0xA8C4 (43204) ×2"), "{stdout}");

    // The manual's numbers said to be Modicon numbers: register 43204 is bus address 3203, and
    // a write to "40101" goes to bus address 100.
    let modicon = r#"
[device]
name = "cadence-meter"
manufacturer = "Test"
model = "M1"
register_numbers = "modicon"

[line]

[[blocks]]
name = "power"
function = 3
start = 43204
count = 2

[[fields]]
name = "power"
block = "power"
offset = 0
codec = { type = "u16" }
range = [0, 100]
write = { function = 6, address = 43204 }
"#;
    let (ok, stdout, stderr) = check_text(MIXED_CONFIG, &[("cadence-meter.toml", modicon)]);
    assert!(ok, "check failed: {stderr}");
    assert!(!stdout.contains("Modicon"), "{stdout}");
    assert!(stdout.contains("FC03 0x0C83 (3203) ×2"), "{stdout}");
    let profile = rtu2mqtt_profile::Profile::from_toml(modicon, "m.toml").unwrap();
    let listing = rtu2mqtt_profile::registry::describe(&profile);
    assert!(listing.contains("FC06 @0x0C83 (3203)"), "{listing}");
}

fn packaged_config_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("packaging/config.toml")
}

#[test]
fn the_packaged_configuration_is_valid_and_polls_nothing() {
    let (ok, stdout, stderr) = check(&packaged_config_path());
    assert!(ok, "check failed:\n{stdout}\n{stderr}");
    assert!(stdout.contains("valid"), "{stdout}");
    assert!(
        format!("{stdout}{stderr}").contains("no [[lines]] configured"),
        "the idle installation is not pointed out:\n{stdout}\n{stderr}"
    );
    let config = rtu2mqtt::config::load(&packaged_config_path()).expect("valid");
    assert!(config.lines.is_empty(), "the package would poll a port");
    // The journal and bdSeq go to the unit's state directory.
    assert_eq!(
        config.history.as_ref().map(|history| history.path.clone()),
        Some(PathBuf::from("/var/lib/rtu2mqtt/history"))
    );
    assert!(
        include_str!("../../../systemd/rtu2mqtt.service").contains("\nStateDirectory=rtu2mqtt\n")
    );
}

#[test]
fn the_packaged_configurations_examples_are_valid_once_uncommented() {
    // Everything after the first commented `[[lines]]` is the example: settings commented as
    // `# key = value`, with their own comments trailing.
    let start = include_str!("../../../packaging/config.toml")
        .find("\n# [[lines]]\n")
        .expect("an example line");
    let (head, examples) = include_str!("../../../packaging/config.toml").split_at(start + 1);
    let uncommented: Vec<&str> = examples
        .lines()
        .map(|line| {
            line.strip_prefix("# ")
                .or_else(|| (line == "#").then_some(""))
                .unwrap_or_else(|| panic!("not a commented setting in the example: {line:?}"))
        })
        .collect();
    let uncommented = format!("{head}{}\n", uncommented.join("\n"));
    let (ok, stdout, stderr) = check_text(&uncommented, &[]);
    assert!(ok, "the uncommented example fails:\n{stdout}\n{stderr}");
    let config = rtu2mqtt::config::from_str(&uncommented, Path::new("/etc/rtu2mqtt"))
        .unwrap_or_else(|problems| panic!("{problems:?}"));
    let lines: Vec<(&str, usize)> = config
        .lines
        .iter()
        .map(|line| (line.name.as_str(), line.devices.len()))
        .collect();
    assert_eq!(lines, [("line-a", 1), ("line-b", 1)]);
}
