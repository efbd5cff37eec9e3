//! SunSpec information models as data, and a profile written from a device's model chain.
//!
//! The table (`data/sunspec/models.json`) is generated from the SunSpec Alliance's published
//! model definitions by `scripts/sunspec-models.py`, for the models `rtu2mqtt sunspec` knows.
//! This module reads it, says how a SunSpec point type becomes a codec, and writes the TOML
//! text of a profile for a [`Chain`] found on a device. Pure: the bus walk is `commissioning::sunspec`.

use std::fmt::Write as _;
use std::sync::OnceLock;

use serde::Deserialize;

/// The generated table, embedded.
const TABLE: &str = include_str!("../../../data/sunspec/models.json");

/// The two registers at a SunSpec base: "SunS".
pub const MARKER: [u16; 2] = [0x5375, 0x6E53];

/// Where a SunSpec device may begin its map.
pub const BASES: [u16; 3] = [40000, 0, 50000];

/// The model id that ends the chain.
pub const END_ID: u16 = 0xFFFF;

/// One point of a model (or of its repeating group).
#[derive(Debug, Clone, Deserialize)]
pub struct Point {
    /// The specification's point name (`PhVphA`, `W_SF`), unique within its model or group.
    pub name: String,
    /// The specification's point type (`uint16`, `int32`, `sunssf`, `string`, `pad`, …).
    #[serde(rename = "type")]
    pub kind: String,
    /// Its length in registers.
    pub size: u16,
    /// The scale factor: a point's name, or a fixed exponent.
    #[serde(default)]
    sf: Option<ScaleFactor>,
    #[serde(default)]
    units: Option<String>,
    #[serde(default)]
    label: Option<String>,
}

/// A point's `sf`: the name of a `sunssf` point of the same model, or a fixed exponent.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
enum ScaleFactor {
    Point(String),
    Fixed(i8),
}

/// A repeating group (model 160's modules).
#[derive(Debug, Clone, Deserialize)]
pub struct Group {
    /// The group's name in the specification (`module`).
    pub name: String,
    /// The points of one repeat, in register order.
    pub points: Vec<Point>,
}

/// One SunSpec information model of the table: its points in register order.
#[derive(Debug, Clone, Deserialize)]
pub struct Model {
    /// The model id, the value of its `ID` register (1 common, 103 three-phase inverter).
    pub id: u16,
    /// The specification's model name (`inverter_three_phase`).
    pub name: String,
    /// The name people read (`Inverter (Three Phase)`).
    pub label: String,
    /// The field-name prefix in a written profile (`inverter`, `meter`).
    pub prefix: String,
    /// The fixed part, `ID` and `L` first.
    pub points: Vec<Point>,
    /// The group repeated after the fixed part (model 160's modules), if the model has one.
    #[serde(default)]
    pub repeating: Option<Group>,
}

impl Model {
    /// Registers of the fixed part after `ID` and `L` (what `L` counts, without repeats).
    pub fn fixed_len(&self) -> u16 {
        self.points.iter().map(|p| p.size).sum::<u16>() - 2
    }

    /// Registers of one repeat of the repeating group (0 without one).
    pub fn group_len(&self) -> u16 {
        self.repeating
            .as_ref()
            .map_or(0, |g| g.points.iter().map(|p| p.size).sum())
    }

    /// How many repeats a model of length `length` holds, when `length` fits the model.
    pub fn repeats(&self, length: u16) -> Option<u16> {
        let fixed = self.fixed_len();
        match self.group_len() {
            0 => (length == fixed).then_some(0),
            group => (length >= fixed && (length - fixed) % group == 0)
                .then_some((length - fixed) / group),
        }
    }

    /// Register offset of a fixed point from the model's `ID` register.
    pub fn offset_of(&self, point: &str) -> Option<u16> {
        let mut offset = 0;
        for p in &self.points {
            if p.name == point {
                return Some(offset);
            }
            offset += p.size;
        }
        None
    }
}

#[derive(Debug, Deserialize)]
struct Table {
    source: String,
    models: Vec<Model>,
}

fn table() -> &'static Table {
    static PARSED: OnceLock<Table> = OnceLock::new();
    // The table is part of the binary and checked by the tests: a parse failure is a build
    // defect, reported as an empty table rather than a crash.
    PARSED.get_or_init(|| {
        serde_json::from_str(TABLE).unwrap_or(Table {
            source: String::new(),
            models: Vec::new(),
        })
    })
}

/// Where the table comes from (repository and commit).
fn source() -> &'static str {
    &table().source
}

/// The table's model with this id; `None` for a model `rtu2mqtt sunspec` does not know.
pub fn model(id: u16) -> Option<&'static Model> {
    table().models.iter().find(|m| m.id == id)
}

/// The codec of a SunSpec point type, as a profile's inline table, with the type's "not
/// implemented" raw value as `invalid`; `None` for types a profile does not read (`pad`).
fn codec_of(point: &Point) -> Option<String> {
    let text = match point.kind.as_str() {
        "uint16" | "enum16" | "bitfield16" | "count" => {
            r#"type = "u16", invalid = [0xFFFF]"#.to_string()
        }
        "acc16" => r#"type = "u16""#.to_string(),
        "int16" | "sunssf" => r#"type = "i16", invalid = [0x8000]"#.to_string(),
        "uint32" | "bitfield32" => {
            r#"type = "u32", word_order = "high_first", invalid = [0xFFFFFFFF]"#.to_string()
        }
        "acc32" => r#"type = "u32", word_order = "high_first""#.to_string(),
        "int32" => r#"type = "i32", word_order = "high_first", invalid = [0x80000000]"#.to_string(),
        "uint64" | "acc64" => r#"type = "u64", word_order = "high_first""#.to_string(),
        "int64" => r#"type = "i64", word_order = "high_first""#.to_string(),
        "float32" => r#"type = "f32", word_order = "high_first", decimals = 3"#.to_string(),
        "string" => format!(r#"type = "string", registers = {}"#, point.size),
        _ => return None,
    };
    Some(text)
}

/// `PhVphA` → `ph_vph_a`, `W_SF` → `w_sf`, `DCWH` → `dcwh`, `VAr` (the unit) → `var`.
pub fn snake(name: &str) -> String {
    let chars: Vec<char> = name.replace("VAr", "Var").chars().collect();
    let mut out = String::new();
    for (i, &c) in chars.iter().enumerate() {
        if c.is_ascii_uppercase() && i > 0 {
            let before = chars[i - 1];
            let after_lower = chars.get(i + 1).is_some_and(|n| n.is_ascii_lowercase());
            if before.is_ascii_lowercase()
                || before.is_ascii_digit()
                || (before.is_ascii_uppercase() && after_lower)
            {
                out.push('_');
            }
        }
        if c.is_ascii_alphanumeric() {
            out.push(c.to_ascii_lowercase());
        } else if !out.ends_with('_') {
            out.push('_');
        }
    }
    out.trim_matches('_').replace("__", "_")
}

/// A SunSpec unit as a profile writes it.
fn unit_of(units: &str) -> &str {
    match units {
        "C" => "°C",
        "Pct" => "%",
        "Secs" => "s",
        "VAr" | "var" => "var",
        "VArh" | "varh" => "varh",
        other => other,
    }
}

/// Home Assistant hints for a unit: (device_class, state_class).
fn ha_of(units: &str, kind: &str) -> Option<(&'static str, &'static str)> {
    Some(match units {
        "W" => ("power", "measurement"),
        "V" => ("voltage", "measurement"),
        "A" => ("current", "measurement"),
        "Hz" => ("frequency", "measurement"),
        "C" => ("temperature", "measurement"),
        "Wh" if kind.starts_with("acc") => ("energy", "total_increasing"),
        _ => return None,
    })
}

/// One model as found on a device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FoundModel {
    /// The value of its `ID` register.
    pub id: u16,
    /// Address of its `ID` register.
    pub address: u16,
    /// Its `L`: registers after `ID` and `L`.
    pub length: u16,
}

impl FoundModel {
    /// Address of the first register after `ID` and `L`.
    pub fn body(&self) -> u16 {
        self.address + 2
    }
}

/// A device's model chain and what its common model says.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Chain {
    /// The base: the address of "SunS".
    pub base: u16,
    /// The models after the marker, in address order, up to the end id.
    pub models: Vec<FoundModel>,
    /// The common model's `Mn` (empty without a common model).
    pub manufacturer: String,
    /// The common model's `Md`.
    pub model: String,
    /// The common model's `SN`.
    pub serial: String,
    /// The common model's `Vr` (the firmware version).
    pub version: String,
}

/// Text of a SunSpec string point: high byte first, trailing NUL and space trimmed.
pub fn text_of(words: &[u16]) -> String {
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_be_bytes()).collect();
    String::from_utf8_lossy(&bytes)
        .trim_end_matches(['\0', ' '])
        .to_string()
}

/// How a written profile talks to the device.
#[derive(Debug, Clone)]
pub struct LineChoice {
    /// The baud rate (bit/s) the device answered at: the profile's `line.baud`.
    pub baud: u32,
    /// `none`, `even` or `odd`: the profile's `line.parity`.
    pub parity: &'static str,
    /// The station address it answered at: the profile's `line.default_address`.
    pub address: u8,
}

/// A device or field name: lower case, digits, `-`, nothing else.
fn name_part(text: &str) -> String {
    let mut out = String::new();
    for c in text.chars() {
        if c.is_ascii_alphanumeric() {
            out.push(c.to_ascii_lowercase());
        } else if !out.ends_with('-') && !out.is_empty() {
            out.push('-');
        }
    }
    out.trim_matches('-').chars().take(40).collect()
}

/// TOML string literal.
fn quoted(text: &str) -> String {
    let mut out = String::from("\"");
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if c.is_control() => {}
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// The registers one block of a written profile may read.
const MAX_BLOCK: u16 = 125;

/// The TOML text of a profile reading every known model of `chain` (unknown models are listed
/// in a comment and skipped). Nameplate models (1, 120) are read once (at start, after an
/// outage, on refresh), the rest fast.
pub fn write_profile(chain: &Chain, line: &LineChoice) -> String {
    let mut out = String::new();
    let known: Vec<&FoundModel> = chain
        .models
        .iter()
        .filter(|found| model(found.id).is_some_and(|m| m.repeats(found.length).is_some()))
        .collect();
    let skipped: Vec<String> = chain
        .models
        .iter()
        .filter(|found| !known.contains(found))
        .map(|found| {
            format!(
                "{} (length {}) at {}",
                found.id, found.length, found.address
            )
        })
        .collect();
    let ids: Vec<String> = known.iter().map(|f| f.id.to_string()).collect();
    let _ = writeln!(
        out,
        "# Written by `rtu2mqtt sunspec` from the device at address {}: SunSpec base {}, models {}.",
        line.address,
        chain.base,
        ids.join(", ")
    );
    let _ = writeln!(
        out,
        "# Model definitions: {} (SunSpec Alliance, sunspec/models).",
        source()
    );
    if !skipped.is_empty() {
        let _ = writeln!(
            out,
            "# Not read (unknown model or length): {}.",
            skipped.join(", ")
        );
    }
    let _ = writeln!(
        out,
        "# Values with a `scale_by` are raw × 10^(their *_sf field), read in the same poll;"
    );
    let _ = writeln!(
        out,
        "# SunSpec's \"not implemented\" values are `invalid`.\n"
    );
    let mut device_name = format!(
        "sunspec-{}-{}",
        name_part(&chain.manufacturer),
        name_part(&chain.model)
    );
    device_name = device_name.trim_end_matches('-').replace("--", "-");
    if device_name == "sunspec" {
        device_name = "sunspec-device".into();
    }
    let _ = writeln!(out, "[device]");
    let _ = writeln!(out, "name = {}", quoted(&device_name));
    let manufacturer = if chain.manufacturer.is_empty() {
        "unknown"
    } else {
        &chain.manufacturer
    };
    let model_name = if chain.model.is_empty() {
        "SunSpec device"
    } else {
        &chain.model
    };
    let _ = writeln!(out, "manufacturer = {}", quoted(manufacturer));
    let _ = writeln!(out, "model = {}", quoted(model_name));
    let _ = writeln!(
        out,
        "description = {}",
        quoted(&format!(
            "SunSpec models {} at base {}",
            ids.join(", "),
            chain.base
        ))
    );
    let _ = writeln!(
        out,
        "register_numbers = \"bus\"   # SunSpec's base is a bus address, not a Modicon number\n"
    );
    let _ = writeln!(out, "[line]");
    let _ = writeln!(out, "baud = {}", line.baud);
    let _ = writeln!(out, "parity = {}", quoted(line.parity));
    let _ = writeln!(out, "default_address = {}", line.address);
    let _ = writeln!(out, "min_poll_interval = \"1s\"");
    let _ = writeln!(out, "poll_interval = \"5s\"");
    let _ = writeln!(out, "slow_interval = \"5min\"");
    let _ = writeln!(out, "max_read_registers = {MAX_BLOCK}\n");

    let mut fields = String::new();
    let mut used_prefixes: Vec<String> = Vec::new();
    for found in known {
        let Some(def) = model(found.id) else { continue };
        let repeats = def.repeats(found.length).unwrap_or(0);
        let mut prefix = def.prefix.clone();
        let mut n = 2;
        while used_prefixes.contains(&prefix) {
            prefix = format!("{}{n}", def.prefix);
            n += 1;
        }
        used_prefixes.push(prefix.clone());
        // Every point after ID and L with its address and field name; a repeat's names carry
        // the group's name and number.
        let model_prefix = prefix.as_str();
        let fixed = def
            .points
            .iter()
            .skip(2)
            .map(|point| (prefix.clone(), point));
        let repeated = def.repeating.iter().flat_map(|group| {
            (1..=repeats).flat_map(move |index| {
                let group_prefix = format!("{model_prefix}_{}{index}", snake(&group.name));
                group
                    .points
                    .iter()
                    .map(move |point| (group_prefix.clone(), point))
            })
        });
        let mut points: Vec<(u16, String, &Point)> = Vec::new();
        let mut address = found.body();
        for (name_prefix, point) in fixed.chain(repeated) {
            points.push((
                address,
                format!("{name_prefix}_{}", snake(&point.name)),
                point,
            ));
            address += point.size;
        }
        // Blocks of at most MAX_BLOCK registers, never splitting a point.
        let poll = if matches!(found.id, 1 | 120) {
            "once"
        } else {
            "fast"
        };
        let mut blocks: Vec<(u16, u16)> = Vec::new();
        for (address, _, point) in &points {
            match blocks.last_mut() {
                Some((start, count)) if address + point.size - *start <= MAX_BLOCK => {
                    *count = address + point.size - *start;
                }
                _ => blocks.push((*address, point.size)),
            }
        }
        for (index, (start, count)) in blocks.iter().enumerate() {
            let name = if blocks.len() == 1 {
                format!("m{}_{prefix}", found.id)
            } else {
                format!("m{}_{prefix}_{}", found.id, index + 1)
            };
            let _ = writeln!(out, "[[blocks]]");
            let _ = writeln!(out, "name = {}", quoted(&name));
            let _ = writeln!(out, "function = 3");
            let _ = writeln!(out, "start = {start}");
            let _ = writeln!(out, "count = {count}");
            let _ = writeln!(out, "poll = \"{poll}\"\n");
            for (address, field, point) in &points {
                if address < start || *address >= start + count {
                    continue;
                }
                let Some(mut codec) = codec_of(point) else {
                    continue;
                };
                match &point.sf {
                    Some(ScaleFactor::Point(sf)) => {
                        let _ = write!(codec, r#", scale_by = "{prefix}_{}""#, snake(sf));
                    }
                    Some(ScaleFactor::Fixed(exponent)) if *exponent != 0 => {
                        let _ = write!(codec, ", scale = 1e{exponent}");
                    }
                    _ => {}
                }
                let _ = writeln!(fields, "[[fields]]");
                let _ = writeln!(fields, "name = {}", quoted(field));
                let _ = writeln!(fields, "block = {}", quoted(&name));
                let _ = writeln!(fields, "offset = {}", address - start);
                let _ = writeln!(fields, "codec = {{ {codec} }}");
                if let Some(label) = &point.label {
                    let _ = writeln!(fields, "description = {}", quoted(label));
                }
                let units = point.units.as_deref().unwrap_or("");
                if !units.is_empty() {
                    let _ = writeln!(fields, "unit = {}", quoted(unit_of(units)));
                }
                if let Some((class, state)) = ha_of(units, &point.kind) {
                    let _ = writeln!(
                        fields,
                        "ha = {{ device_class = \"{class}\", state_class = \"{state}\" }}"
                    );
                } else if point.kind == "sunssf" {
                    let _ = writeln!(fields, "ha = {{ entity_category = \"diagnostic\" }}");
                }
                if found.id == 1 {
                    match point.name.as_str() {
                        "SN" => {
                            let _ = writeln!(fields, "identity = \"serial_number\"");
                        }
                        "Vr" => {
                            let _ = writeln!(fields, "identity = \"sw_version\"");
                        }
                        _ => {}
                    }
                }
                fields.push('\n');
            }
        }
    }
    out.push_str(&fields);
    out.trim_end().to_string() + "\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_matches_the_published_lengths() {
        // Lengths (`L`) as the SunSpec specifications give them.
        let lengths = [
            (1, 66),
            (101, 50),
            (102, 50),
            (103, 50),
            (111, 60),
            (112, 60),
            (113, 60),
            (120, 26),
            (121, 30),
            (122, 44),
            (123, 24),
            (124, 24),
            (201, 105),
            (202, 105),
            (203, 105),
            (204, 105),
        ];
        for (id, length) in lengths {
            let def = model(id).unwrap_or_else(|| panic!("model {id} missing"));
            assert_eq!(def.fixed_len(), length, "model {id}");
            assert_eq!(def.repeats(length), Some(0), "model {id}");
            assert_eq!(def.points[0].name, "ID");
            assert_eq!(def.points[1].name, "L");
        }
        let mppt = model(160).unwrap();
        assert_eq!((mppt.fixed_len(), mppt.group_len()), (8, 20));
        assert_eq!(mppt.repeats(48), Some(2));
        assert_eq!(mppt.repeats(49), None);
        assert_eq!(table().models.len(), 17);
        assert!(source().contains("sunspec/models"), "{}", source());
    }

    #[test]
    fn every_point_type_has_a_codec_and_every_scale_factor_exists() {
        for def in &table().models {
            let id = def.id;
            let group = def.repeating.iter().flat_map(|g| g.points.iter());
            for point in def.points.iter().chain(group) {
                assert!(
                    codec_of(point).is_some() || point.kind == "pad",
                    "model {id} {}: {}",
                    point.name,
                    point.kind
                );
                if let Some(ScaleFactor::Point(sf)) = &point.sf {
                    let sf_point = def.points.iter().find(|p| &p.name == sf);
                    assert_eq!(
                        sf_point.map(|p| p.kind.as_str()),
                        Some("sunssf"),
                        "model {id} {} → {sf}",
                        point.name
                    );
                }
            }
        }
    }

    #[test]
    fn model_1_places_its_strings_as_the_specification_does() {
        let common = model(1).unwrap();
        // SunSpec common model: Mn at 40004, Md at 40020, Opt 40036, Vr 40044, SN 40052,
        // DA 40068 for a base of 40000 (ID at 40002).
        assert_eq!(common.offset_of("Mn"), Some(2));
        assert_eq!(common.offset_of("Md"), Some(18));
        assert_eq!(common.offset_of("Vr"), Some(42));
        assert_eq!(common.offset_of("SN"), Some(50));
        assert_eq!(common.offset_of("DA"), Some(66));
    }

    fn found(id: u16, address: u16, length: u16) -> FoundModel {
        FoundModel {
            id,
            address,
            length,
        }
    }

    #[test]
    fn a_written_profile_compiles_splits_long_models_and_skips_unknown_ones() {
        // Model 160 with six modules is 8 + 6 × 20 = 128 registers: two blocks.
        let chain = Chain {
            base: 40000,
            models: vec![
                found(1, 40002, 66),
                found(103, 40070, 50),
                found(160, 40122, 128),
                found(203, 40252, 105),
                found(203, 40359, 105),
                found(64999, 40466, 10),
                found(101, 40478, 49),
            ],
            manufacturer: "Sim \"Solar\"".into(),
            model: "X/1 ".into(),
            serial: "1".into(),
            version: "2".into(),
        };
        let line = LineChoice {
            baud: 19200,
            parity: "even",
            address: 3,
        };
        let text = write_profile(&chain, &line);
        let profile =
            crate::Profile::from_toml(&text, "written").unwrap_or_else(|e| panic!("{e}\n{text}"));
        assert_eq!(profile.name(), "sunspec-sim-solar-x-1");
        assert_eq!(profile.manufacturer(), "Sim \"Solar\"");
        assert_eq!(profile.limits().default_baud, 19200);
        assert_eq!(profile.default_address(), Some(3));
        let blocks: Vec<(&str, String)> = profile
            .read_blocks()
            .iter()
            .map(|b| (b.name.as_str(), format!("{:?}", b.request)))
            .collect();
        let names: Vec<&str> = blocks.iter().map(|(n, _)| *n).collect();
        assert_eq!(
            names,
            [
                "m1_common",
                "m103_inverter",
                "m160_mppt_1",
                "m160_mppt_2",
                "m203_meter",
                "m203_meter2"
            ]
        );
        assert!(profile.field("mppt_module6_dcw").is_some());
        assert!(profile.field("mppt_dca_sf").is_some());
        assert!(profile.field("meter2_tot_wh_imp").is_some());
        assert!(profile.field("inverter_w").is_some());
        // The unknown model and the model whose length does not fit are named, not read.
        assert!(text.contains("Not read (unknown model or length): 64999 (length 10) at 40466, 101 (length 49) at 40478."), "{text}");
        assert!(profile.fields().iter().all(|f| !f.writable));
    }

    #[test]
    fn names_become_snake_case() {
        assert_eq!(snake("PhVphA"), "ph_vph_a");
        assert_eq!(snake("W_SF"), "w_sf");
        assert_eq!(snake("DCWH"), "dcwh");
        assert_eq!(snake("TmpCab"), "tmp_cab");
        assert_eq!(snake("WMaxLimPct_RvrtTms"), "w_max_lim_pct_rvrt_tms");
        assert_eq!(snake("TotWhImpPhA"), "tot_wh_imp_ph_a");
        assert_eq!(snake("VAr_SF"), "var_sf");
        assert_eq!(snake("VArMaxQ1"), "var_max_q1");
        assert_eq!(snake("VA"), "va");
    }

    #[test]
    fn strings_are_high_byte_first_and_trimmed() {
        assert_eq!(text_of(&[0x5375, 0x6E53]), "SunS");
        assert_eq!(text_of(&[0x4142, 0x4300, 0x0000]), "ABC");
    }
}
