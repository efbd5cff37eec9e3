//! Built-in profiles (compiled into the binary) and loading a profile by name or by path.
//!
//! The built-ins are the files in `config/profiles/`, included at compile time, so the binary
//! works alone and the files users copy are exactly what runs: the seed plant's devices, then
//! the device library (meters and inverters written from their vendors' public register maps).

use std::path::Path;

use super::codec;
use super::model::Behaviour;
use super::{FieldInfo, FieldKind, Profile, ProfileErrors};

/// (name, TOML text) of every built-in profile: the seed plant first, then [`LIBRARY`].
const SEED: &[(&str, &str)] = &[
    (
        "ruiwan-dust-collector",
        include_str!("../../../config/profiles/ruiwan-dust-collector.toml"),
    ),
    (
        "wuzhou-valve",
        include_str!("../../../config/profiles/wuzhou-valve.toml"),
    ),
    (
        "lixian-air-shower",
        include_str!("../../../config/profiles/lixian-air-shower.toml"),
    ),
];

/// (name, TOML text) of the device library.
const LIBRARY: &[(&str, &str)] = &[
    (
        "eastron-sdm120",
        include_str!("../../../config/profiles/eastron-sdm120.toml"),
    ),
    (
        "eastron-sdm630",
        include_str!("../../../config/profiles/eastron-sdm630.toml"),
    ),
    (
        "abb-a43",
        include_str!("../../../config/profiles/abb-a43.toml"),
    ),
    (
        "sunspec-inverter",
        include_str!("../../../config/profiles/sunspec-inverter.toml"),
    ),
    (
        "growatt-min",
        include_str!("../../../config/profiles/growatt-min.toml"),
    ),
    (
        "schneider-iem3155",
        include_str!("../../../config/profiles/schneider-iem3155.toml"),
    ),
];

fn all_built_in() -> impl Iterator<Item = &'static (&'static str, &'static str)> {
    SEED.iter().chain(LIBRARY)
}

/// Why a profile could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// A name without `/` or `.toml` names no built-in profile.
    #[error(
        "no built-in profile `{name}` (built-in: {known}); a profile file path must end in .toml"
    )]
    UnknownBuiltIn {
        /// The name asked for.
        name: String,
        /// The built-in names, comma-separated, for the message.
        known: String,
    },
    /// A listing argument (`rtu2mqtt profiles NAME`) is no built-in name and no readable file.
    #[error("`{name}` is neither a built-in profile (built-in: {known}) nor a profile file")]
    NeitherBuiltInNorFile {
        /// The argument as given.
        name: String,
        /// The built-in names, comma-separated, for the message.
        known: String,
    },
    /// The profile file could not be read (missing, unreadable, not UTF-8).
    #[error("cannot read profile {path}: {source}")]
    Read {
        /// The path as shown to the user (relative paths already joined to their base).
        path: String,
        /// What the file system said.
        source: std::io::Error,
    },
    /// The text was read but is not a valid profile: every problem with its place.
    #[error("{0}")]
    Invalid(#[from] ProfileErrors),
}

/// Names of the built-in profiles.
pub fn built_in_names() -> Vec<&'static str> {
    all_built_in().map(|(name, _)| *name).collect()
}

/// Names of the device library's profiles (built in too).
pub fn library_names() -> Vec<&'static str> {
    LIBRARY.iter().map(|(name, _)| *name).collect()
}

/// A built-in profile by name; [`LoadError::UnknownBuiltIn`] for a name that is not built in.
pub fn built_in(name: &str) -> Result<Profile, LoadError> {
    let (_, text) = all_built_in()
        .find(|(known, _)| *known == name)
        .ok_or_else(|| LoadError::UnknownBuiltIn {
            name: name.to_string(),
            known: built_in_names().join(", "),
        })?;
    Ok(Profile::from_toml(text, &format!("built-in {name}"))?)
}

/// Every built-in profile (each one is valid: the tests load them all).
pub fn built_in_profiles() -> Vec<Profile> {
    built_in_names()
        .into_iter()
        .filter_map(|name| built_in(name).ok())
        .collect()
}

/// Loads a profile file: [`LoadError::Read`] when it cannot be read, [`LoadError::Invalid`]
/// with every problem when it is not a valid profile.
pub fn load_file(path: &Path) -> Result<Profile, LoadError> {
    let text = std::fs::read_to_string(path).map_err(|source| LoadError::Read {
        path: path.display().to_string(),
        source,
    })?;
    Ok(Profile::from_toml(&text, &path.display().to_string())?)
}

/// Loads a profile as a device names it in the configuration: a built-in name, or a path to a
/// file (anything containing `/` or ending in `.toml`). Relative paths are taken relative to
/// `base` (the configuration file's directory) when given.
pub fn load(reference: &str, base: Option<&Path>) -> Result<Profile, LoadError> {
    if reference.contains('/') || reference.ends_with(".toml") {
        let path = Path::new(reference);
        let path = match base {
            Some(base) if path.is_relative() => base.join(path),
            _ => path.to_path_buf(),
        };
        load_file(&path)
    } else {
        built_in(reference)
    }
}

/// The field's values as `rtu2mqtt profiles` lists them, with the extra integers its `also`
/// admits (`integer 0–100 or 255`).
fn describe_values(field: &FieldInfo) -> String {
    // Its places follow the exponent the device reports: the range says nothing useful.
    if let Some(exponent) = &field.scaled_by {
        return format!("number × 10^{exponent}");
    }
    let kind = describe_kind(&field.kind);
    if field.also.is_empty() {
        return kind;
    }
    let also: Vec<String> = field.also.iter().map(ToString::to_string).collect();
    format!("{kind} or {}", also.join(", "))
}

fn describe_kind(kind: &FieldKind) -> String {
    match kind {
        FieldKind::Bool => "ON/OFF".to_string(),
        FieldKind::Momentary => "button (PRESS)".to_string(),
        FieldKind::Integer { min, max } => format!("integer {min}–{max}"),
        FieldKind::Decimal {
            min,
            max,
            precision,
        } => {
            let p = usize::from(*precision);
            if min.abs() > 1e15 || max.abs() > 1e15 {
                format!("decimal, {p} {}", codec::decimals_word(*precision))
            } else {
                format!("decimal {min:.p$}–{max:.p$}")
            }
        }
        FieldKind::Enum { options } => options.join(" | "),
        FieldKind::Text => "text".to_string(),
    }
}

/// A read request as `profiles` and `check` show it, the bus address in hex and decimal:
/// `FC03 0x0C83 (3203) ×11`.
pub fn describe_read(request: &rtu2mqtt_modbus::Request) -> String {
    use rtu2mqtt_modbus::Request;
    match request {
        Request::ReadCoils { start, quantity }
        | Request::ReadDiscreteInputs { start, quantity }
        | Request::ReadHoldingRegisters { start, quantity }
        | Request::ReadInputRegisters { start, quantity } => format!(
            "FC{:02} 0x{start:04X} ({start}) ×{quantity}",
            request.function().value()
        ),
        other => format!("{other:?}"),
    }
}

fn describe_write(profile: &Profile, index: usize) -> String {
    let inner = &profile.inner;
    let def = &inner.defs[index];
    let Some(frame) = &def.write else {
        return String::new();
    };
    let mut text = format!(
        "FC{:02} @0x{:04X} ({})",
        frame.function, frame.address, frame.address
    );
    if frame.count > 1 && frame.function != 6 {
        text.push_str(&format!("×{}", frame.count));
    }
    let own = def.codec.footprint(def.offset);
    let whole = if inner.block_kinds[def.block].is_bits() {
        1
    } else {
        0xFFFF
    };
    let fills = own.len() == usize::from(frame.count) && own.iter().all(|(_, m)| *m == whole);
    let mut notes = Vec::new();
    if !fills {
        notes.push("read-modify-write".to_string());
    }
    match def.behaviour {
        Behaviour::Toggle => notes.push("toggle".to_string()),
        Behaviour::Momentary => notes.push("button".to_string()),
        Behaviour::State => {}
    }
    if let Some(window) = def.settle_window {
        let until: Vec<String> = def
            .settle_until
            .iter()
            .map(|(field, value)| format!(" or {} {}", inner.infos[*field].name, value.to_text()))
            .collect();
        notes.push(format!(
            "settles ≤ {}{}",
            humantime::format_duration(window),
            until.concat()
        ));
    }
    if let Some(interval) = inner.infos[index].min_write_interval {
        notes.push(format!("≥ {} apart", humantime::format_duration(interval)));
    }
    if !notes.is_empty() {
        text.push_str(&format!(" ({})", notes.join(", ")));
    }
    text
}

/// A readable listing of one profile: line defaults, blocks, and every field with its access,
/// kind and range, unit, and how it is written.
pub fn describe(profile: &Profile) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let limits = profile.limits();
    let _ = writeln!(
        out,
        "{}: {}, {}",
        profile.name(),
        profile.manufacturer(),
        profile.model()
    );
    if !profile.description().is_empty() {
        let _ = writeln!(out, "  {}", profile.description());
    }
    if let Some(identification) = profile.identification() {
        let _ = writeln!(out, "  identified by: {identification}");
    }
    let parity = rtu2mqtt_modbus::timing::CharFormat {
        data_bits: 8,
        parity: limits.default_parity,
        stop_bits: 1,
    };
    let default_address = profile
        .default_address()
        .map(|a| format!(", usually {a}"))
        .unwrap_or_default();
    let _ = writeln!(
        out,
        "  line: {} baud {parity}, addresses {}–{}{default_address}; poll every {} (at least {}), \
         slow blocks every {}, first transaction {} after start",
        limits.default_baud,
        limits.address_range.start(),
        limits.address_range.end(),
        humantime::format_duration(limits.default_poll_interval),
        humantime::format_duration(limits.min_poll_interval),
        humantime::format_duration(limits.slow_interval),
        humantime::format_duration(limits.startup_delay),
    );
    for block in profile.read_blocks() {
        let class = block.class.to_string();
        let _ = writeln!(
            out,
            "  block {:<14} {:<20} {class}",
            block.name,
            describe_read(&block.request)
        );
    }
    for (name, frame) in &profile.inner.named_frames {
        let _ = writeln!(
            out,
            "  frame {:<14} FC{:02} @0x{:04X} ({})×{}",
            name, frame.function, frame.address, frame.address, frame.count
        );
    }
    let width = profile
        .fields()
        .iter()
        .map(|f| f.name.len())
        .max()
        .unwrap_or(0);
    for (index, field) in profile.fields().iter().enumerate() {
        let access = if field.writable { "rw" } else { "ro" };
        let unit = field.unit.as_deref().unwrap_or("");
        let line = format!(
            "  {:<width$}  {access}  {:<26} {unit:<4} {}",
            field.name,
            describe_values(field),
            describe_write(profile, index),
        );
        let _ = writeln!(out, "{}", line.trim_end());
    }
    for def in &profile.inner.actions {
        let _ = writeln!(out, "  action {}", describe_action(def));
    }
    for warning in profile.warnings() {
        let _ = writeln!(out, "  warning: {warning}");
    }
    out
}

/// An action's line of the listing: its frame, its parameters and its result register.
fn describe_action(def: &crate::action::ActionDef) -> String {
    let info = &def.info;
    let count = def.frame(&vec![0; info.params.len()]).len();
    let params: Vec<String> = info
        .params
        .iter()
        .map(|param| format!("{} {}–{}", param.name, param.min, param.max))
        .collect();
    let params = if params.is_empty() {
        "no parameters".to_string()
    } else {
        params.join(", ")
    };
    let result = match &info.result {
        Some(result) => {
            let codes: Vec<String> = result
                .codes
                .iter()
                .map(|(code, name)| format!("{code} {name}"))
                .collect();
            format!(
                "; result FC{:02} @0x{:04X} ({}): {}",
                result.function,
                result.address,
                result.address,
                codes.join(", ")
            )
        }
        None => "; no result register".to_string(),
    };
    format!(
        "{:<14} FC16 @0x{:04X} ({})×{count}  {params}{result}",
        info.name, def.address, def.address
    )
}
