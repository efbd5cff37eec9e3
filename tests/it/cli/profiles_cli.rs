//! `rtu2mqtt profiles [NAME|FILE]…`, run as a user runs it: no argument lists every built-in
//! profile; arguments list only the built-ins named and the files given; an argument that is
//! neither is refused on stderr with the built-in names, exit status 1.

use std::process::{Command, Output};

fn profiles(args: &[&str]) -> Output {
    Command::new(crate::support::child::gateway_binary())
        .arg("profiles")
        .args(args)
        .output()
        .expect("the rtu2mqtt binary runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The profile names the listing starts a profile with (`name: manufacturer, model`).
fn listed(stdout: &str) -> Vec<String> {
    stdout
        .lines()
        .filter(|line| !line.starts_with(' ') && line.contains(": "))
        .filter_map(|line| line.split(':').next())
        .map(str::to_string)
        .collect()
}

#[test]
fn without_arguments_every_built_in_is_listed() {
    let output = profiles(&[]);
    assert!(output.status.success(), "{}", text(&output.stderr));
    assert_eq!(
        listed(&text(&output.stdout)),
        [
            "ruiwan-dust-collector",
            "wuzhou-valve",
            "lixian-air-shower",
            "eastron-sdm120",
            "eastron-sdm630",
            "abb-a43",
            "sunspec-inverter",
            "growatt-min",
            "schneider-iem3155"
        ]
    );
    assert!(output.stderr.is_empty(), "{}", text(&output.stderr));
}

#[test]
fn a_name_lists_that_built_in_only() {
    let output = profiles(&["wuzhou-valve"]);
    assert!(output.status.success(), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    assert_eq!(listed(&stdout), ["wuzhou-valve"]);
    assert!(stdout.contains("setpoint"), "{stdout}");
    assert!(output.stderr.is_empty(), "{}", text(&output.stderr));
}

#[test]
fn a_file_lists_that_file_only_and_names_and_files_mix_in_order() {
    let output = profiles(&["config/profiles/generic-th-sensor.toml"]);
    assert!(output.status.success(), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    assert_eq!(listed(&stdout).len(), 1, "{stdout}");
    assert!(
        stdout.contains("file: config/profiles/generic-th-sensor.toml"),
        "{stdout}"
    );
    assert!(!stdout.contains("ruiwan-dust-collector"), "{stdout}");

    let output = profiles(&[
        "lixian-air-shower",
        "config/profiles/generic-th-sensor.toml",
        "ruiwan-dust-collector",
    ]);
    assert!(output.status.success(), "{}", text(&output.stderr));
    let names = listed(&text(&output.stdout));
    assert_eq!(names.len(), 3, "{names:?}");
    assert_eq!(names[0], "lixian-air-shower");
    assert_eq!(names[2], "ruiwan-dust-collector");
}

#[test]
fn an_unknown_name_is_refused_with_the_built_ins() {
    let output = profiles(&["ruiwan-dust-colector"]);
    assert_eq!(output.status.code(), Some(1));
    assert!(output.stdout.is_empty(), "{}", text(&output.stdout));
    assert_eq!(
        text(&output.stderr),
        "`ruiwan-dust-colector` is neither a built-in profile (built-in: \
         ruiwan-dust-collector, wuzhou-valve, lixian-air-shower, eastron-sdm120, eastron-sdm630, \
         abb-a43, sunspec-inverter, growatt-min, schneider-iem3155) nor a profile file\n"
    );

    // The good ones are still listed; the bad one still fails the run.
    let output = profiles(&["wuzhou-valve", "nope.toml"]);
    assert_eq!(output.status.code(), Some(1));
    assert_eq!(listed(&text(&output.stdout)), ["wuzhou-valve"]);
    assert!(text(&output.stderr).contains("`nope.toml` is neither"));
}

#[test]
fn decimal_counts_are_spelled_right() {
    let stdout = text(&profiles(&[]).stdout);
    assert!(!stdout.contains("1 places"), "{stdout}");
    let sensor = text(&profiles(&["config/profiles/generic-th-sensor.toml"]).stdout);
    assert!(!sensor.contains("1 places"), "{sensor}");
    assert!(sensor.contains("decimal, 1 decimal"), "{sensor}");
    assert!(sensor.contains("decimal, 2 decimals"), "{sensor}");
}

#[test]
fn a_number_scaled_by_an_exponent_field_is_listed_with_that_field() {
    let output = profiles(&["sunspec-inverter"]);
    assert!(output.status.success(), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    let line = stdout
        .lines()
        .find(|line| line.trim_start().starts_with("ac_power "))
        .unwrap_or_else(|| panic!("no ac_power in:\n{stdout}"));
    assert!(line.contains("number × 10^ac_power_sf"), "{line}");
    assert!(line.trim_end().ends_with('W'), "{line}");
    // What a scan recognises it by.
    assert!(
        stdout.contains("\n  identified by: SunSpec map at 40000 starting with models 1, 103\n"),
        "{stdout}"
    );
}
