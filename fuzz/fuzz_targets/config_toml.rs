//! The configuration file as the daemon reads it (`config::from_str`: TOML, types, then the
//! validation of every section; profile references by built-in name or path relative to the
//! repository's `config/`). Input: the TOML text (seeds: `config/rtu2mqtt.toml` and the
//! documentation's examples).
//!
//! Asserted: a refusal lists at least one problem, each with a reason; an accepted
//! configuration keeps the rules the validation promises (device names unique in the gateway,
//! addresses unique on a line, line names unique, every line with a device) and builds the
//! bridge's settings.

#![no_main]

use std::collections::HashSet;
use std::path::Path;

use libfuzzer_sys::fuzz_target;
use rtu2mqtt::bridge::core::CoreSettings;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let base = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config"));
    let config = match rtu2mqtt::config::from_str(text, base) {
        Ok(config) => config,
        Err(problems) => {
            assert!(!problems.0.is_empty(), "a refusal without a problem");
            for problem in &problems.0 {
                assert!(
                    !problem.reason.is_empty(),
                    "no reason at {:?}",
                    problem.place
                );
            }
            return;
        }
    };
    let mut devices = HashSet::new();
    let mut lines = HashSet::new();
    for line in &config.lines {
        assert!(lines.insert(line.name.as_str()), "line {} twice", line.name);
        let mut addresses = HashSet::new();
        for device in &line.devices {
            assert!(
                devices.insert(device.name.as_str()),
                "device {} twice",
                device.name
            );
            assert!(
                addresses.insert(device.address),
                "address {} twice on {}",
                device.address,
                line.name
            );
        }
    }
    let settings = CoreSettings::from_config(&config);
    assert_eq!(settings.devices.len(), devices.len());
});
