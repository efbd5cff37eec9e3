//! How a field is named and sorted in Home Assistant: its display name from the field name (or
//! its label), and the entity category a field gets when its profile gives none.

use rtu2mqtt_profile::{FieldInfo, FieldKind};

/// Words of field names that are abbreviations, written in capitals in a display name (also
/// when a number follows them: `pv1` → `PV1`, `l2` → `L2`).
const ACRONYMS: &[&str] = &[
    "ac", "co2", "crc", "ct", "dc", "hepa", "id", "l", "pf", "pid", "pm25", "pt", "pv", "rtu",
    "sv", "thd", "ups",
];

/// `word` is an abbreviation, alone or followed by a number.
fn is_acronym(word: &str) -> bool {
    ACRONYMS.contains(&word)
        || word
            .find(|c: char| c.is_ascii_digit())
            .filter(|&at| at > 0 && word[at..].chars().all(|c| c.is_ascii_digit()))
            .is_some_and(|at| ACRONYMS.contains(&&word[..at]))
}

/// A display name from a field name: `pulse_interval` → `Pulse interval`,
/// `pid_invalid_flags` → `PID invalid flags` (see [`ACRONYMS`]).
pub fn display_name(field: &str) -> String {
    let words: Vec<String> = field
        .split(['_', '-'])
        .filter(|word| !word.is_empty())
        .enumerate()
        .map(|(index, word)| {
            if is_acronym(word) {
                word.to_uppercase()
            } else if index == 0 {
                let mut chars = word.chars();
                chars
                    .next()
                    .map(|first| first.to_uppercase().chain(chars).collect())
                    .unwrap_or_default()
            } else {
                word.to_string()
            }
        })
        .collect();
    words.join(" ")
}

/// The entity's name in Home Assistant: the profile's `label`, else [`display_name`]. Never
/// the device name: Home Assistant puts the device name in front by itself
/// (`has_entity_name`), so the entity list of a device reads `Gear`, not `dust_collector Gear`.
pub fn entity_name(field: &FieldInfo) -> String {
    field
        .label
        .clone()
        .unwrap_or_else(|| display_name(&field.name))
}

/// Words in a field name that mark it as a diagnostic (identity or health bookkeeping, not
/// something an operator watches).
pub(super) const DIAGNOSTIC_WORDS: &[&str] = &[
    "version", "serial", "flags", "firmware", "hardware", "station", "address", "baud",
];

/// Words in a read-only boolean's name that mark it as a problem indicator.
pub(super) const PROBLEM_WORDS: &[&str] = &[
    "alarm", "failed", "failure", "fault", "error", "jammed", "expired", "invalid",
];

pub(super) fn name_has_word(name: &str, words: &[&str]) -> bool {
    name.split(['_', '-']).any(|part| words.contains(&part))
}

/// Words in a writable number's name that mark it as a setting (configured once, not operated).
const SETTING_WORDS: &[&str] = &[
    "alarm",
    "ratio",
    "scale",
    "interval",
    "duration",
    "period",
    "time",
    "limit",
    "threshold",
    "offset",
    "delay",
    "calibration",
];

/// `entity_category` when the profile gives none: identity and health data (versions, serial
/// number, flag words, address and baud code) is `diagnostic` when read-only and `config` when
/// writable; writable numbers named like settings (alarm limits, ratios, full scales, intervals,
/// durations) are `config`. Live values and controls stay primary entities.
pub(super) fn default_entity_category(field: &FieldInfo) -> Option<&'static str> {
    let identity = name_has_word(&field.name, DIAGNOSTIC_WORDS);
    if identity {
        return Some(if field.writable {
            "config"
        } else {
            "diagnostic"
        });
    }
    let setting =
        field.writable && is_numeric(&field.kind) && name_has_word(&field.name, SETTING_WORDS);
    setting.then_some("config")
}

/// True for fields whose values are numbers.
pub(super) fn is_numeric(kind: &FieldKind) -> bool {
    matches!(kind, FieldKind::Integer { .. } | FieldKind::Decimal { .. })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn abbreviations_keep_their_capitals_with_or_without_a_number() {
        assert_eq!(display_name("ac_power"), "AC power");
        assert_eq!(display_name("pv1_voltage"), "PV1 voltage");
        assert_eq!(display_name("pv_power"), "PV power");
        assert_eq!(display_name("voltage_l2"), "Voltage L2");
        assert_eq!(display_name("thd_current_l3"), "THD current L3");
        assert_eq!(display_name("pid_invalid_flags"), "PID invalid flags");
        assert_eq!(display_name("pulse_interval"), "Pulse interval");
        assert_eq!(display_name("level2"), "Level2");
        assert_eq!(display_name("p001"), "P001");
    }
}
