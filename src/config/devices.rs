//! The checks of `[[lines.devices]]`: each device's name (unique in the gateway, not a word
//! the contract reserves), its profile (built in or a file; its field names become topic
//! levels), its address within the profile's range, its `poll_interval` (within the profile's
//! limits, and not faster than the exponents of its `scale_by` numbers are read) and its
//! `publish` table. What comes out is the bus's [`DeviceSpec`].

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use super::names::{invalid_name, is_valid_name, shown, MAX_NAME_LEN};
use super::problem::Problem;
use super::schema::RawDevice;
use crate::bus::DeviceSpec;
use rtu2mqtt_profile::topic_levels::reserved_name_problem;
use rtu2mqtt_profile::{Profile, PublishRule};

pub(super) fn validate_device(
    raw: &RawDevice,
    place: &str,
    base: &Path,
    profiles: &mut HashMap<String, Arc<Profile>>,
    names: &mut HashMap<String, String>,
    problems: &mut Vec<Problem>,
    warnings: &mut Vec<Problem>,
) -> Option<DeviceSpec> {
    let before = problems.len();
    if !is_valid_name(&raw.name) {
        problems.push(invalid_name(place, &raw.name));
    } else if let Some(reason) = reserved_name_problem(&raw.name) {
        problems.push(Problem::new(format!("{place}.name"), reason));
    } else {
        if let Some(first) = names.get(&raw.name) {
            problems.push(Problem::new(
                format!("{place}.name"),
                format!("{:?} is already the name of {first}", raw.name),
            ));
        } else {
            names.insert(raw.name.clone(), place.to_string());
        }
    }

    let profile = match profiles.get(&raw.profile) {
        Some(profile) => Some(profile.clone()),
        None => match resolve_profile(&raw.profile, base) {
            Ok(profile) => {
                // Once per profile: its field names become topic levels.
                for reason in field_name_problems(&profile) {
                    problems.push(Problem::new(format!("{place}.profile"), reason));
                }
                for warning in profile.warnings() {
                    warnings.push(Problem::new(
                        format!("{place}.profile"),
                        warning.to_string(),
                    ));
                }
                let profile = Arc::new(profile);
                profiles.insert(raw.profile.clone(), profile.clone());
                Some(profile)
            }
            Err(reason) => {
                problems.push(Problem::new(format!("{place}.profile"), reason));
                None
            }
        },
    };
    let profile = profile?;
    let limits = profile.limits();
    let range = &limits.address_range;
    let address = match u8::try_from(raw.address) {
        Ok(address) if range.contains(&address) => Some(address),
        _ => {
            problems.push(Problem::new(
                format!("{place}.address"),
                format!(
                    "{} is outside {}–{} allowed by profile {}",
                    raw.address,
                    range.start(),
                    range.end(),
                    profile.name()
                ),
            ));
            None
        }
    };
    let poll_interval = raw.poll_interval.unwrap_or(limits.default_poll_interval);
    // Zero is continuous polling, which keeps the profile's minimum by itself.
    if !poll_interval.is_zero() && poll_interval < limits.min_poll_interval {
        problems.push(Problem::new(
            format!("{place}.poll_interval"),
            format!(
                "{} is under the minimum {} of profile {}",
                humantime::format_duration(poll_interval),
                humantime::format_duration(limits.min_poll_interval),
                profile.name()
            ),
        ));
    }
    if poll_interval > Duration::from_secs(24 * 3600) {
        problems.push(Problem::new(
            format!("{place}.poll_interval"),
            "must be at most 24h".to_string(),
        ));
    }
    for (number, exponent) in profile.exponents_read_too_rarely(poll_interval) {
        problems.push(Problem::new(
            format!("{place}.poll_interval"),
            format!(
                "at {} the exponent `{exponent}` of `{number}` (profile {}) would be read less \
                 often than `{number}` itself; poll the device at most as often as the \
                 exponent's block is read",
                humantime::format_duration(poll_interval),
                profile.name()
            ),
        ));
    }
    let publish = device_publish(raw, place, &profile, problems);
    if problems.len() != before {
        return None;
    }
    Some(DeviceSpec {
        name: raw.name.clone(),
        address: address?,
        profile,
        poll_interval,
        publish,
    })
}

/// The device's `publish` table, checked, and with it each field's own keys: together they
/// must still hold (a field's `min_interval` over the device's `max_interval` is refused).
fn device_publish(
    raw: &RawDevice,
    place: &str,
    profile: &Profile,
    problems: &mut Vec<Problem>,
) -> PublishRule {
    let Some(table) = &raw.publish else {
        return PublishRule::default();
    };
    let rule = match PublishRule::from_raw(table) {
        Ok(rule) => rule,
        Err(found) => {
            for (key, reason) in found {
                problems.push(Problem::new(format!("{place}.publish.{key}"), reason));
            }
            return PublishRule::default();
        }
    };
    for field in profile.fields() {
        if let Some(reason) = field.publish.or(rule).interval_problem() {
            problems.push(Problem::new(
                format!("{place}.publish"),
                format!(
                    "field `{}` of profile {}: {reason}",
                    field.name,
                    profile.name()
                ),
            ));
        }
    }
    rule
}

/// Field names of `profile` the contract cannot carry: reserved words, or longer than a topic
/// level may be.
fn field_name_problems(profile: &Profile) -> Vec<String> {
    let mut reasons = Vec::new();
    for field in profile.fields() {
        let name = &field.name;
        if name.len() > MAX_NAME_LEN {
            reasons.push(format!(
                "profile {}: field {} is a topic level and must be at most {MAX_NAME_LEN} \
                 characters",
                shown(profile.name()),
                shown(name)
            ));
        } else if let Some(reason) = reserved_name_problem(name) {
            reasons.push(format!("profile {}: field {reason}", shown(profile.name())));
        }
    }
    reasons
}

/// A built-in profile by name, else a profile file (relative to the config file).
fn resolve_profile(spec: &str, base: &Path) -> Result<Profile, String> {
    rtu2mqtt_profile::registry::load(spec, Some(base)).map_err(|error| error.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The problems of one device given by its keys, placed at `lines[0].devices[0]`.
    fn device_problems(keys: &str) -> Vec<String> {
        let text = format!("name = \"valve\"\n{keys}\n");
        let raw: RawDevice = toml::from_str(&text).unwrap_or_else(|error| panic!("{error}"));
        let mut problems = Vec::new();
        let spec = validate_device(
            &raw,
            "lines[0].devices[0]",
            Path::new("."),
            &mut HashMap::new(),
            &mut HashMap::new(),
            &mut problems,
            &mut Vec::new(),
        );
        assert_eq!(spec.is_none(), !problems.is_empty());
        problems.iter().map(ToString::to_string).collect()
    }

    #[test]
    fn a_good_device_passes_with_the_profile_s_default_poll_interval() {
        assert_eq!(
            device_problems("profile = \"wuzhou-valve\"\naddress = 1"),
            Vec::<String>::new()
        );
    }

    #[test]
    fn each_broken_key_is_refused_at_its_place() {
        for (keys, expected) in [
            (
                "profile = \"no-such-profile\"\naddress = 1",
                "lines[0].devices[0].profile: ",
            ),
            (
                "profile = \"wuzhou-valve\"\naddress = 300",
                "lines[0].devices[0].address: 300 is outside ",
            ),
            (
                "profile = \"wuzhou-valve\"\naddress = 1\npoll_interval = \"2d\"",
                "lines[0].devices[0].poll_interval: must be at most 24h",
            ),
            (
                "profile = \"wuzhou-valve\"\naddress = 1\npoll_interval = \"1ms\"",
                "lines[0].devices[0].poll_interval: 1ms is under the minimum ",
            ),
        ] {
            let problems = device_problems(keys);
            assert!(
                problems.iter().any(|problem| problem.starts_with(expected)),
                "{keys}: {problems:?}"
            );
        }
    }

    #[test]
    fn a_reserved_or_repeated_name_is_refused_at_the_name() {
        let raw: RawDevice =
            toml::from_str("name = \"valve\"\nprofile = \"wuzhou-valve\"\naddress = 1")
                .unwrap_or_else(|error| panic!("{error}"));
        let mut names = HashMap::new();
        let mut profiles = HashMap::new();
        let mut problems = Vec::new();
        for place in ["lines[0].devices[0]", "lines[1].devices[0]"] {
            validate_device(
                &raw,
                place,
                Path::new("."),
                &mut profiles,
                &mut names,
                &mut problems,
                &mut Vec::new(),
            );
        }
        let shown: Vec<String> = problems.iter().map(ToString::to_string).collect();
        assert_eq!(
            shown,
            ["lines[1].devices[0].name: \"valve\" is already the name of lines[0].devices[0]"]
        );
        assert_eq!(profiles.len(), 1, "a profile is loaded once");
    }
}
