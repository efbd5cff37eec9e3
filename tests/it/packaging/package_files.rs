//! The Debian package's own files agree with the unit: the executable and the configuration go
//! where the unit's `ExecStart=` looks, and the maintainer scripts make and purge the
//! credential file the unit loads. (The packaged configuration is checked with the others in
//! config_valid.rs; `scripts/package-check` proves the package itself on a fresh Debian.)

const MANIFEST: &str = include_str!("../../../Cargo.toml");
const UNIT: &str = include_str!("../../../systemd/rtu2mqtt.service");
const POSTINST: &str = include_str!("../../../packaging/debian/postinst");
const POSTRM: &str = include_str!("../../../packaging/debian/postrm");

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
