//! The Debian package's own files agree with the daemon and the unit: the configuration it
//! installs is valid and polls nothing until lines are written (its commented examples valid
//! once uncommented), the executable goes where the unit's `ExecStart=` looks, and the
//! maintainer scripts make and purge the credential file the unit loads.
//! (`scripts/package-check` proves the package itself on a fresh Debian.)

use std::path::{Path, PathBuf};
use std::process::Command;

const PACKAGED_CONFIG: &str = include_str!("../../packaging/config.toml");
const MANIFEST: &str = include_str!("../../Cargo.toml");
const UNIT: &str = include_str!("../../systemd/rtu2mqtt.service");
const POSTINST: &str = include_str!("../../packaging/debian/postinst");
const POSTRM: &str = include_str!("../../packaging/debian/postrm");

/// `rtu2mqtt check --config <path>`: success, stdout, stderr.
fn check(path: &Path) -> (bool, String, String) {
    let output = Command::new(crate::support::child::gateway_binary())
        .arg("check")
        .arg("--config")
        .arg(path)
        .env_remove("RTU2MQTT_CONFIG")
        .output()
        .expect("the gateway binary runs");
    (
        output.status.success(),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
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
    assert!(UNIT.contains("\nStateDirectory=rtu2mqtt\n"));
}

#[test]
fn the_packaged_configurations_examples_are_valid_once_uncommented() {
    // Everything after the first commented `[[lines]]` is the example: settings commented as
    // `# key = value`, with their own comments trailing.
    let start = PACKAGED_CONFIG
        .find("\n# [[lines]]\n")
        .expect("an example line");
    let (head, examples) = PACKAGED_CONFIG.split_at(start + 1);
    let uncommented: Vec<&str> = examples
        .lines()
        .map(|line| {
            line.strip_prefix("# ")
                .or_else(|| (line == "#").then_some(""))
                .unwrap_or_else(|| panic!("not a commented setting in the example: {line:?}"))
        })
        .collect();
    let dir = tempfile::tempdir().expect("a temporary directory");
    let path = dir.path().join("config.toml");
    std::fs::write(&path, format!("{head}{}\n", uncommented.join("\n"))).expect("written");
    let (ok, stdout, stderr) = check(&path);
    assert!(ok, "the uncommented example fails:\n{stdout}\n{stderr}");
    let config = rtu2mqtt::config::load(&path).expect("valid");
    let lines: Vec<(&str, usize)> = config
        .lines
        .iter()
        .map(|line| (line.name.as_str(), line.devices.len()))
        .collect();
    assert_eq!(lines, [("line-a", 1), ("line-b", 1)]);
}

/// The `[source, destination, mode]` rows of `[package.metadata.deb] assets`.
fn package_assets() -> Vec<[String; 3]> {
    let manifest: toml::Value = toml::from_str(MANIFEST).expect("Cargo.toml parses");
    let assets = manifest["package"]["metadata"]["deb"]["assets"]
        .as_array()
        .expect("assets")
        .iter()
        .map(|row| {
            let row: Vec<String> = row
                .as_array()
                .expect("an asset row")
                .iter()
                .map(|cell| cell.as_str().expect("a string").to_string())
                .collect();
            [row[0].clone(), row[1].clone(), row[2].clone()]
        })
        .collect();
    assets
}

#[test]
fn the_package_puts_the_executable_and_configuration_where_the_unit_looks() {
    let assets = package_assets();
    let has = |source: &str, destination: &str| {
        assets
            .iter()
            .any(|row| row[0] == source && row[1] == destination)
    };
    let exec_start = UNIT
        .lines()
        .find_map(|line| line.strip_prefix("ExecStart="))
        .expect("ExecStart=");
    assert!(exec_start.starts_with("/usr/bin/rtu2mqtt run --config /etc/rtu2mqtt/config.toml"));
    assert!(has("target/release/rtu2mqtt", "usr/bin/"), "{assets:?}");
    assert!(
        has("packaging/config.toml", "etc/rtu2mqtt/config.toml"),
        "{assets:?}"
    );
    assert!(has("target/deb-assets/man/*.1", "usr/share/man/man1/"));
}

#[test]
fn the_maintainer_scripts_make_and_purge_the_credential_the_unit_loads() {
    let credential = UNIT
        .lines()
        .find_map(|line| line.strip_prefix("LoadCredential=mqtt-password:"))
        .expect("LoadCredential=");
    assert!(
        POSTINST.contains(&format!(
            "install -m 0600 -o root -g root /dev/null {credential}"
        )),
        "postinst does not make {credential}"
    );
    // Made before debhelper's part starts the service, removed on purge only.
    assert!(POSTINST.find(credential) < POSTINST.find("#DEBHELPER#"));
    let purge = &POSTRM[POSTRM.find("\"purge\"").expect("a purge branch")..];
    assert!(purge.contains(&format!("rm -f {credential}")), "{POSTRM}");
    assert!(purge.contains("/var/lib/private/rtu2mqtt"), "{POSTRM}");
    assert!(POSTRM.contains("#DEBHELPER#"));
}
