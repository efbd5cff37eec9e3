//! The configuration as users meet it: the shipped example is valid, `rtu2mqtt check` prints
//! the poll plan and exits 0; a configuration with many mistakes gets every one of them listed
//! with its place, exit 1; environment overrides reach the settings.

use std::path::{Path, PathBuf};
use std::process::Command;

use rtu2mqtt::config;

fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/rtu2mqtt.toml")
}

fn check(path: &Path) -> (bool, String, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_rtu2mqtt"))
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
        rtu2mqtt::rtu::timing::Parity::Even
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
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("config.toml");
    // Unknown keys are reported first, on their own.
    std::fs::write(&path, MANY_MISTAKES).unwrap();
    let (ok, _, stderr) = check(&path);
    assert!(!ok);
    assert!(stderr.contains("mqtt.colour: unknown key"), "{stderr}");

    std::fs::write(&path, MANY_MISTAKES.replace("colour = \"blue\"\n", "")).unwrap();
    let (ok, stdout, stderr) = check(&path);
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
    let output = Command::new(env!("CARGO_BIN_EXE_rtu2mqtt"))
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

    let output = Command::new(env!("CARGO_BIN_EXE_rtu2mqtt"))
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
