//! Every profile file loads and validates; the built-ins are exactly the files; broken profiles
//! are refused with errors that name the file and the key.

use std::path::Path;

use rtu2mqtt_profile::registry::{built_in, built_in_names, describe, load, load_file, LoadError};
use rtu2mqtt_profile::{Profile, ProfileErrors};

use crate::support::{CONFIG_DIR, PROFILE_DIR};

#[test]
fn every_profile_file_loads() {
    let mut names = Vec::new();
    for entry in std::fs::read_dir(PROFILE_DIR).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let profile = load_file(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert_eq!(
                path.file_stem().unwrap().to_str().unwrap(),
                profile.name(),
                "file name and profile name agree"
            );
            assert!(!profile.fields().is_empty());
            assert!(!profile.read_blocks().is_empty());
            assert!(!describe(&profile).is_empty());
            names.push(profile.name().to_string());
        }
    }
    names.sort();
    assert_eq!(
        names,
        [
            "abb-a43",
            "eastron-sdm120",
            "eastron-sdm630",
            "generic-th-sensor",
            "growatt-min",
            "lixian-air-shower",
            "ruiwan-dust-collector",
            "schneider-iem3155",
            "sunspec-inverter",
            "wuzhou-valve"
        ]
    );
}

#[test]
fn built_ins_are_the_files() {
    assert_eq!(
        built_in_names(),
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
    for name in built_in_names() {
        let compiled_in = built_in(name).unwrap();
        let file = load_file(&Path::new(PROFILE_DIR).join(format!("{name}.toml"))).unwrap();
        assert_eq!(compiled_in.fields(), file.fields(), "{name}");
        assert_eq!(compiled_in.read_blocks(), file.read_blocks(), "{name}");
        assert_eq!(compiled_in.limits(), file.limits(), "{name}");
    }
    // The seed plant's field names are part of the user interface.
    let fields = |name: &str| -> Vec<String> {
        built_in(name)
            .unwrap()
            .fields()
            .iter()
            .map(|f| f.name.clone())
            .collect()
    };
    assert_eq!(
        fields("ruiwan-dust-collector"),
        [
            "power",
            "pulse_cleaning",
            "fan_alarm",
            "filter_alarm",
            "temperature_alarm",
            "gear",
            "pulse_interval",
            "pulse_duration",
            "fan_speed",
            "temperature"
        ]
    );
    let valve = fields("wuzhou-valve");
    for name in [
        "station_address",
        "serial_number",
        "software_version",
        "hardware_version",
        "baud_code",
        "mode",
        "opening",
        "closed_switch_failed",
        "open_switch_failed",
        "motor",
        "fully_open",
        "fully_closed",
        "direction",
        "jammed",
        "pid_invalid_flags",
        "calibration_invalid_flags",
        "alarm_invalid_flags",
        "measured_1",
        "measured_2",
        "setpoint",
        "full_scale_1",
        "full_scale_2",
        "high_alarm_1",
        "high_alarm_2",
        "low_alarm_1",
        "low_alarm_2",
        "high_alarm_opening_1",
        "high_alarm_opening_2",
        "low_alarm_opening_1",
        "low_alarm_opening_2",
        "high_alarm_ratio_1",
        "high_alarm_ratio_2",
        "low_alarm_ratio_1",
        "low_alarm_ratio_2",
        "regulation_ratio",
        "sample_period",
        "integral_time",
        "derivative_time",
    ] {
        assert!(valve.iter().any(|f| f == name), "valve lacks {name}");
    }
    assert_eq!(valve.len(), 38);
    assert_eq!(fields("lixian-air-shower").len(), 19);
}

#[test]
fn loading_by_reference() {
    assert_eq!(load("wuzhou-valve", None).unwrap().name(), "wuzhou-valve");
    let by_relative = load(
        "profiles/generic-th-sensor.toml",
        Some(Path::new(CONFIG_DIR)),
    )
    .unwrap();
    assert_eq!(by_relative.name(), "generic-th-sensor");
    match load("no-such-device", None) {
        Err(LoadError::UnknownBuiltIn { known, .. }) => assert!(known.contains("wuzhou-valve")),
        other => panic!("{other:?}"),
    }
    let missing = load("/nonexistent/x.toml", None).unwrap_err().to_string();
    assert!(missing.contains("/nonexistent/x.toml"), "{missing}");
}

const BASE: &str = r#"
[device]
name = "test-device"
manufacturer = "Test"
model = "T1"

[line]
max_read_registers = 10

[[blocks]]
name = "main"
function = 3
start = 0
count = 4

[[blocks]]
name = "inputs"
function = 4
start = 0x100
count = 2

[[fields]]
name = "running"
block = "main"
offset = 0
codec = { type = "bit", bit = 1 }

[[fields]]
name = "level"
block = "main"
offset = 1
codec = { type = "u16" }
range = [0, 100]
write = { function = 6, address = 1 }

[[fields]]
name = "input"
block = "inputs"
offset = 0
codec = { type = "u16" }
"#;

fn errors(text: &str) -> ProfileErrors {
    match Profile::from_toml(text, "test.toml") {
        Err(errors) => errors,
        Ok(profile) => panic!("accepted: {}", profile.name()),
    }
}

/// Asserts that the profile is refused with one problem whose text contains every fragment.
fn refused(text: &str, fragments: &[&str]) {
    let errors = errors(text);
    let found = errors.0.iter().any(|e| {
        let line = e.to_string();
        line.starts_with("test.toml") && fragments.iter().all(|f| line.contains(f))
    });
    assert!(found, "expected {fragments:?} in:\n{errors}");
}

#[test]
fn the_base_test_profile_is_valid() {
    let profile = Profile::from_toml(BASE, "test.toml").unwrap();
    assert_eq!(profile.fields().len(), 3);
    assert_eq!(profile.read_blocks()[0].used_runs, vec![(0, 2)]);
}

#[test]
fn overlapping_fields_are_refused() {
    let text = format!(
        "{BASE}\n[[fields]]\nname = \"running2\"\nblock = \"main\"\noffset = 0\ncodec = {{ type = \"bits\", bit = 0, width = 2 }}\n"
    );
    refused(&text, &["fields[3] (running2)", "overlaps field `running`"]);
    let text = format!(
        "{BASE}\n[[fields]]\nname = \"wide\"\nblock = \"main\"\noffset = 1\ncodec = {{ type = \"u32\", word_order = \"high_first\" }}\n"
    );
    refused(&text, &["fields[3] (wide)", "overlaps field `level`"]);
    // Other bits of the same word are fine.
    let text = format!(
        "{BASE}\n[[fields]]\nname = \"other_bit\"\nblock = \"main\"\noffset = 0\ncodec = {{ type = \"bit\", bit = 2 }}\n"
    );
    assert!(Profile::from_toml(&text, "test.toml").is_ok());
}

#[test]
fn a_field_outside_its_block_is_refused() {
    let text = BASE.replace(
        "offset = 1\ncodec = { type = \"u16\" }",
        "offset = 3\ncodec = { type = \"f32\", word_order = \"low_first\" }",
    );
    refused(&text, &["fields[1] (level).offset", "outside block `main`"]);
}

#[test]
fn a_write_rule_on_a_read_only_block_is_refused() {
    let text = BASE.replace(
        "offset = 0\ncodec = { type = \"u16\" }",
        "offset = 0\ncodec = { type = \"u16\" }\nrange = [0, 5]\nwrite = { function = 6, address = 0x100 }",
    );
    refused(
        &text,
        &["fields[2] (input).write.function", "read-only block"],
    );
}

#[test]
fn an_unknown_codec_is_refused_with_its_line() {
    let text = BASE.replace("type = \"u16\" }\nrange", "type = \"float64\" }\nrange");
    let errors = errors(&text);
    let message = errors.to_string();
    assert!(message.starts_with("test.toml:"), "{message}");
    assert!(message.contains("float64"), "{message}");
    // The place carries the line of the bad codec.
    let line = BASE
        .lines()
        .position(|l| l.contains("type = \"u16\" }"))
        .unwrap()
        + 1;
    assert!(message.contains(&format!("test.toml:{line}:")), "{message}");
}

#[test]
fn duplicate_names_are_refused() {
    let text = BASE.replace("name = \"input\"", "name = \"level\"");
    refused(&text, &["fields[2] (level).name", "duplicate field name"]);
    let text = BASE.replace("name = \"inputs\"", "name = \"main\"");
    refused(&text, &["blocks[1] (main).name", "duplicate block name"]);
}

#[test]
fn bad_ranges_are_refused() {
    refused(
        &BASE.replace("range = [0, 100]", "range = [100, 0]"),
        &["fields[1] (level).range", "ordered"],
    );
    refused(
        &BASE.replace("range = [0, 100]", "range = [-1, 100]"),
        &["fields[1] (level).range", "0–65535"],
    );
    refused(
        &BASE.replace("range = [0, 100]", "range = [0.5, 100]"),
        &["fields[1] (level).range", "integer range"],
    );
    refused(
        &BASE.replace("range = [0, 100]\n", ""),
        &["fields[1] (level).range", "needs a range"],
    );
}

#[test]
fn other_mistakes_are_refused_with_their_place() {
    let cases: &[(&str, &str, &[&str])] = &[
        (
            "count = 4",
            "count = 11",
            &["blocks[0] (main).count", "read limit"],
        ),
        (
            "function = 3",
            "function = 7",
            &["blocks[0] (main).function", "not a read function"],
        ),
        (
            "block = \"main\"\noffset = 0",
            "block = \"nope\"\noffset = 0",
            &["fields[0] (running).block", "no block named `nope`"],
        ),
        (
            "{ function = 6, address = 1 }",
            "{ function = 5, address = 1 }",
            &["fields[1] (level).write.function", "does not fit"],
        ),
        (
            "bit = 1 }",
            "bit = 16 }",
            &["fields[0] (running).codec.bit", "0–15"],
        ),
        (
            "[line]\n",
            "[line]\nparity = \"mark\"\n",
            &["line.parity", "mark"],
        ),
        (
            "range = [0, 100]",
            "range = [0, 100]\nalso = [70000]",
            &["fields[1] (level).also", "0–65535"],
        ),
        (
            "bit = 1 }",
            "bit = 1 }\nalso = [3]",
            &["fields[0] (running).also", "only integer"],
        ),
        (
            "[line]\n",
            "[line]\naddress_range = [10, 5]\n",
            &["line.address_range"],
        ),
        ("[line]\n", "[line]\nbaud = 9601\n", &["line.baud"]),
        (
            "name = \"running\"",
            "name = \"Status\"",
            &["fields[0] (Status).name", "lower-case"],
        ),
    ];
    for (from, to, fragments) in cases {
        assert!(BASE.contains(from), "{from}");
        refused(&BASE.replacen(from, to, 1), fragments);
    }
}

#[test]
fn reads_linearly_is_a_block_flag_the_valve_has_and_the_dust_collector_not() {
    let profile = Profile::from_toml(BASE, "test.toml").unwrap();
    assert!(profile.read_blocks().iter().all(|b| !b.reads_linearly));
    let text = BASE.replacen("count = 4\n", "count = 4\nreads_linearly = true\n", 1);
    let profile = Profile::from_toml(&text, "test.toml").unwrap();
    let linear: Vec<bool> = profile
        .read_blocks()
        .iter()
        .map(|b| b.reads_linearly)
        .collect();
    assert_eq!(linear, [true, false]);
    let text = BASE.replacen("count = 4\n", "count = 4\nreads_linearly = \"yes\"\n", 1);
    let message = errors(&text).to_string();
    assert!(message.contains("test.toml"), "{message}");
    assert!(message.contains("bool"), "{message}");

    let valve = built_in("wuzhou-valve").unwrap();
    assert!(valve.read_blocks().iter().all(|b| b.reads_linearly));
    for name in ["ruiwan-dust-collector", "lixian-air-shower"] {
        let profile = built_in(name).unwrap();
        assert!(
            profile.read_blocks().iter().all(|b| !b.reads_linearly),
            "{name}"
        );
    }
}

#[test]
fn unknown_keys_are_refused() {
    let text = BASE.replace("[line]\n", "[line]\nbaudrate = 9600\n");
    let message = errors(&text).to_string();
    assert!(message.contains("baudrate"), "{message}");
    let text = BASE.replace("bit = 1 }", "bit = 1, inverted = true }");
    let message = errors(&text).to_string();
    assert!(message.contains("inverted"), "{message}");
}

#[test]
fn behaviour_and_overlay_rules() {
    let text = BASE.replace(
        "write = { function = 6, address = 1 }",
        "write = { function = 6, address = 1 }\nbehaviour = \"toggle\"",
    );
    refused(&text, &["fields[1] (level).behaviour", "single bit"]);
    let text = format!(
        "{BASE}\n[[fields]]\nname = \"view\"\nblock = \"main\"\noffset = 2\noverlay = true\ncodec = {{ type = \"u16\" }}\n"
    );
    refused(&text, &["fields[3] (view).overlay", "other fields own"]);
    let text = format!(
        "{BASE}\n[[fields]]\nname = \"state\"\nblock = \"main\"\noffset = 2\ncodec = {{ type = \"bits\", bit = 0, width = 1, options = [\"a\", \"b\", \"c\"] }}\n"
    );
    refused(
        &text,
        &["fields[3] (state).codec.options", "do not fit 1 bits"],
    );
}

#[test]
fn forbidden_combinations_are_checked() {
    let text = format!(
        "{BASE}\n[[forbidden]]\nwhen = {{ running = \"ON\", ghost = \"ON\" }}\nreason = \"x\"\n"
    );
    refused(
        &text,
        &["forbidden[0].when.ghost", "no field named `ghost`"],
    );
    let text = format!(
        "{BASE}\n[[forbidden]]\nwhen = {{ running = \"maybe\", level = \"3\" }}\nreason = \"x\"\n"
    );
    refused(&text, &["forbidden[0].when.running", "ON or OFF"]);
}

#[test]
fn example_commands_are_checked_and_offered() {
    let with_level = |extra: &str| {
        BASE.replace(
            "write = { function = 6, address = 1 }\n",
            &format!("write = {{ function = 6, address = 1 }}\n{extra}\n"),
        )
    };
    // Without a declared example, the first writable field offers the top of its range.
    let plain = Profile::from_toml(BASE, "test.toml").unwrap();
    assert_eq!(plain.example_commands(), [("level", "100".to_string())]);
    let declared = Profile::from_toml(&with_level("example = \"42\""), "test.toml").unwrap();
    assert_eq!(declared.example_commands(), [("level", "42".to_string())]);
    refused(
        &with_level("example = \"101\""),
        &["fields[1] (level).example", "101"],
    );
    refused(
        &BASE.replace(
            "codec = { type = \"bit\", bit = 1 }\n",
            "codec = { type = \"bit\", bit = 1 }\nexample = \"ON\"\n",
        ),
        &["fields[0] (running).example", "only a writable field"],
    );
    // The seed devices show the commands the demo suggests.
    for (name, expected) in [
        ("ruiwan-dust-collector", ("gear", "8")),
        ("wuzhou-valve", ("opening", "40")),
        ("lixian-air-shower", ("emergency_stop", "ON")),
    ] {
        let profile = built_in(name).unwrap();
        assert_eq!(
            profile.example_commands(),
            [(expected.0, expected.1.to_string())],
            "{name}"
        );
    }
}

#[test]
fn settle_conditions_are_checked() {
    let with_level = |extra: &str| {
        BASE.replace(
            "write = { function = 6, address = 1 }\n",
            &format!("write = {{ function = 6, address = 1 }}\n{extra}\n"),
        )
    };
    let good = with_level("settle_window = \"30s\"\nsettle_until = { running = \"OFF\" }");
    assert!(Profile::from_toml(&good, "test.toml").is_ok());
    refused(
        &with_level("settle_until = { running = \"OFF\" }"),
        &["fields[1] (level).settle_until", "needs a settle_window"],
    );
    refused(
        &with_level("settle_window = \"30s\"\nsettle_until = { ghost = \"OFF\" }"),
        &["settle_until.ghost", "no field named `ghost`"],
    );
    refused(
        &with_level("settle_window = \"30s\"\nsettle_until = { running = \"stopped\" }"),
        &["settle_until.running", "ON or OFF"],
    );
    refused(
        &with_level("settle_window = \"30s\"\nsettle_until = { level = \"3\" }"),
        &["settle_until.level", "its own value"],
    );
}

#[test]
fn several_problems_are_all_listed() {
    let text = BASE
        .replace("count = 4", "count = 11")
        .replace("name = \"input\"", "name = \"level\"");
    assert!(errors(&text).0.len() >= 2);
}

#[test]
fn poll_takes_fast_slow_once_or_a_period_and_refuses_anything_else_with_its_place() {
    use rtu2mqtt_profile::PollClass;
    use std::time::Duration;
    let with_poll = |main: &str, inputs: &str| {
        BASE.replacen("count = 4\n", &format!("count = 4\npoll = {main}\n"), 1)
            .replacen("count = 2\n", &format!("count = 2\npoll = {inputs}\n"), 1)
    };
    for (main, inputs, classes) in [
        ("\"fast\"", "\"slow\"", [PollClass::Fast, PollClass::Slow]),
        (
            "\"250ms\"",
            "\"once\"",
            [
                PollClass::Every(Duration::from_millis(250)),
                PollClass::Once,
            ],
        ),
        (
            "\"15s\"",
            "\"1h\"",
            [
                PollClass::Every(Duration::from_secs(15)),
                PollClass::Every(Duration::from_secs(3600)),
            ],
        ),
    ] {
        let profile = Profile::from_toml(&with_poll(main, inputs), "test.toml").unwrap();
        let found: Vec<PollClass> = profile.read_blocks().iter().map(|b| b.class).collect();
        assert_eq!(found, classes, "{main} {inputs}");
    }
    // The default is fast.
    let profile = Profile::from_toml(BASE, "test.toml").unwrap();
    assert_eq!(profile.read_blocks()[1].class, PollClass::Fast);

    refused(
        &with_poll("\"sometimes\"", "\"slow\""),
        &[
            "blocks[0] (main).poll",
            "`sometimes` is not fast, slow, once or a duration",
        ],
    );
    // Under the profile's min_poll_interval (100 ms unless it says otherwise): refused, not
    // raised.
    refused(
        &with_poll("\"fast\"", "\"50ms\""),
        &[
            "blocks[1] (inputs).poll",
            "50ms is under the profile's min_poll_interval 100ms",
        ],
    );
    let stricter = with_poll("\"fast\"", "\"1s\"").replacen(
        "[line]\n",
        "[line]\nmin_poll_interval = \"2s\"\n",
        1,
    );
    refused(
        &stricter,
        &[
            "blocks[1] (inputs).poll",
            "under the profile's min_poll_interval 2s",
        ],
    );
    refused(
        &with_poll("\"0s\"", "\"slow\""),
        &["blocks[0] (main).poll", "under"],
    );
    refused(
        &with_poll("\"2days\"", "\"slow\""),
        &["blocks[0] (main).poll", "at most 24h"],
    );
    // Not a string at all: serde's error, with its line.
    refused(
        &with_poll("15", "\"slow\""),
        &["test.toml:15:", "expected a string"],
    );
}
