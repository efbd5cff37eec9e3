//! A configuration to copy, written from what a scan found: a `[[lines]]` table per serial
//! setting the devices answered at, with the line's port or url, and a `[[lines.devices]]`
//! table per device with the profile that fits it, or a comment saying why none is named.
//! The text is what `rtu2mqtt check` reads; a device without a profile is left for the user to
//! complete (its `profile` key is missing on purpose, so `check` points at it).

use std::fmt::Write as _;

use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_profile::identify::{Fit, Identity};
use rtu2mqtt_profile::Profile;

/// Where the line is reached.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkPlace {
    /// A serial port's path.
    Port(String),
    /// A `tcp://` or `modbus-tcp://` url.
    Url(String),
}

/// One line of the configuration.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SuggestedLine {
    pub name: String,
    pub place: LinkPlace,
    /// The serial setting the devices answered at; `None` behind a Modbus TCP gateway, whose
    /// serial setting is its own.
    pub serial: Option<(u32, Parity)>,
    pub devices: Vec<SuggestedDevice>,
}

/// What fits one device found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ProfileChoice {
    /// A built-in profile's name or a profile file's path.
    Named(String),
    /// A SunSpec map no profile names: `rtu2mqtt sunspec` writes one.
    SunSpecChain { base: u16 },
    /// Nothing is known to fit.
    Unknown,
}

/// The profiles a scan may name, each with the reference a configuration gives it (a
/// built-in profile's name, a profile file's path).
#[derive(Debug, Clone)]
pub struct Candidates {
    profiles: Vec<Profile>,
    references: Vec<String>,
}

impl Candidates {
    /// Every built-in profile, by its name.
    pub fn built_in() -> Self {
        let profiles = rtu2mqtt_profile::registry::built_in_profiles();
        let references = profiles.iter().map(|p| p.name().to_string()).collect();
        Self {
            profiles,
            references,
        }
    }

    /// Adds `profile`, referred to as `reference`, unless one with the same reference is
    /// there already.
    pub fn add(&mut self, profile: Profile, reference: String) {
        if !self.references.contains(&reference) {
            self.profiles.push(profile);
            self.references.push(reference);
        }
    }

    /// What fits a device that says it is `identity`.
    pub fn choose(&self, identity: &Identity) -> ProfileChoice {
        match identity.fit(&self.profiles) {
            Fit::Profile(fitting) => self
                .profiles
                .iter()
                .position(|profile| std::ptr::eq(profile, fitting))
                .and_then(|index| self.references.get(index))
                .map_or(ProfileChoice::Unknown, |reference| {
                    ProfileChoice::Named(reference.clone())
                }),
            Fit::SunSpecChain { base } => ProfileChoice::SunSpecChain { base },
            Fit::Unknown => ProfileChoice::Unknown,
        }
    }
}

impl ProfileChoice {
    /// As a scan's table shows it: the profile, `unknown`, or the SunSpec command to run.
    pub fn describe(&self) -> String {
        match self {
            Self::Named(profile) => profile.clone(),
            Self::SunSpecChain { base } => format!("SunSpec map at {base}: `rtu2mqtt sunspec`"),
            Self::Unknown => "unknown".to_string(),
        }
    }
}

/// One device of a line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SuggestedDevice {
    pub address: u8,
    /// Its name in a running configuration, if it is configured already.
    pub name: Option<String>,
    pub profile: ProfileChoice,
}

impl SuggestedDevice {
    /// The configured name, or one made of the profile's name and the address
    /// (`eastron_sdm630_3`), `device_<address>` without a profile.
    pub fn name(&self) -> String {
        if let Some(name) = &self.name {
            return name.clone();
        }
        let stem = match &self.profile {
            ProfileChoice::Named(profile) => name_stem(profile),
            ProfileChoice::SunSpecChain { .. } => "sunspec".to_string(),
            ProfileChoice::Unknown => String::new(),
        };
        if stem.is_empty() {
            format!("device_{}", self.address)
        } else {
            format!("{stem}_{}", self.address)
        }
    }
}

/// The part of a profile reference a device name can carry: a file's stem, in lower case,
/// anything but letters and digits as `_`.
fn name_stem(profile: &str) -> String {
    let file = profile.rsplit('/').next().unwrap_or(profile);
    let stem = file.strip_suffix(".toml").unwrap_or(file);
    let mapped: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '_'
            }
        })
        .collect();
    mapped.trim_matches('_').to_string()
}

/// `text` as a TOML string.
fn quoted(text: &str) -> String {
    toml::Value::String(text.to_string()).to_string()
}

/// The configuration text for `lines`.
pub fn configuration(lines: &[SuggestedLine]) -> String {
    let mut out = String::new();
    if lines.len() > 1 {
        let _ = writeln!(
            out,
            "# Devices answered at {} serial settings: a port is one line at one setting; keep \
             the line whose devices you use.",
            lines.len()
        );
    }
    for (index, line) in lines.iter().enumerate() {
        if index > 0 {
            out.push('\n');
        }
        out.push_str("[[lines]]\n");
        let _ = writeln!(out, "name = {}", quoted(&line.name));
        match &line.place {
            LinkPlace::Port(port) => {
                let _ = writeln!(out, "port = {}", quoted(port));
            }
            LinkPlace::Url(url) => {
                let _ = writeln!(out, "url = {}", quoted(url));
            }
        }
        if let Some((baud, parity)) = line.serial {
            let _ = writeln!(out, "baud = {baud}");
            let _ = writeln!(out, "parity = {}", quoted(&parity.to_string()));
        }
        device_tables(&mut out, &line.devices);
    }
    out
}

/// The `[[lines.devices]]` tables of `devices` to add to the configured line `line`, after
/// its `[[lines]]` table.
pub fn devices_to_add(line: &str, devices: &[SuggestedDevice]) -> String {
    let mut out = format!("# under the [[lines]] table of {}:\n", quoted(line));
    device_tables(&mut out, devices);
    out
}

fn device_tables(out: &mut String, devices: &[SuggestedDevice]) {
    for device in devices {
        out.push_str("\n[[lines.devices]]\n");
        let _ = writeln!(out, "name = {}", quoted(&device.name()));
        match &device.profile {
            ProfileChoice::Named(profile) => {
                let _ = writeln!(out, "profile = {}", quoted(profile));
            }
            ProfileChoice::SunSpecChain { base } => {
                let _ = writeln!(
                    out,
                    "# profile: a SunSpec map at {base}: `rtu2mqtt sunspec --address {}` writes \
                     one",
                    device.address
                );
            }
            ProfileChoice::Unknown => {
                out.push_str("# profile: unknown — write one, see docs/profiles.md\n");
            }
        }
        let _ = writeln!(out, "address = {}", device.address);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_with_a_named_and_an_unknown_device() {
        let line = SuggestedLine {
            name: "line1".into(),
            place: LinkPlace::Port("/dev/serial/by-id/usb-FTDI \"x\"".into()),
            serial: Some((9600, Parity::Even)),
            devices: vec![
                SuggestedDevice {
                    address: 3,
                    name: None,
                    profile: ProfileChoice::Named("eastron-sdm630".into()),
                },
                SuggestedDevice {
                    address: 7,
                    name: None,
                    profile: ProfileChoice::Unknown,
                },
                SuggestedDevice {
                    address: 9,
                    name: None,
                    profile: ProfileChoice::SunSpecChain { base: 50000 },
                },
            ],
        };
        assert_eq!(
            configuration(&[line]),
            "[[lines]]\n\
             name = \"line1\"\n\
             port = '/dev/serial/by-id/usb-FTDI \"x\"'\n\
             baud = 9600\n\
             parity = \"even\"\n\
             \n\
             [[lines.devices]]\n\
             name = \"eastron_sdm630_3\"\n\
             profile = \"eastron-sdm630\"\n\
             address = 3\n\
             \n\
             [[lines.devices]]\n\
             name = \"device_7\"\n\
             # profile: unknown — write one, see docs/profiles.md\n\
             address = 7\n\
             \n\
             [[lines.devices]]\n\
             name = \"sunspec_9\"\n\
             # profile: a SunSpec map at 50000: `rtu2mqtt sunspec --address 9` writes one\n\
             address = 9\n"
        );
    }

    #[test]
    fn the_built_in_profile_that_fits_is_named_and_a_site_profile_by_its_path() {
        use rtu2mqtt_modbus::DeviceIdObject;
        use rtu2mqtt_profile::identify::{DeviceId, SunSpecMap};
        let mut candidates = Candidates::built_in();
        let inverter = Identity {
            device_id: DeviceId::NoAnswer,
            sunspec: Some(SunSpecMap {
                base: 40000,
                models: vec![1, 103],
            }),
        };
        assert_eq!(
            candidates.choose(&inverter),
            ProfileChoice::Named("sunspec-inverter".into())
        );
        let meter = Identity {
            device_id: DeviceId::Objects(vec![
                DeviceIdObject::text(0, "Sim Metering"),
                DeviceIdObject::text(1, "SM-3P-100"),
            ]),
            sunspec: None,
        };
        assert_eq!(candidates.choose(&meter), ProfileChoice::Unknown);
        let site = Profile::from_toml(
            "[device]\nname = \"sm3p\"\nmanufacturer = \"Sim Metering\"\nmodel = \"SM-3P\"\n\
             identification = { vendor = \"Sim Metering\", product_code = \"SM-3P-*\" }\n\
             [line]\n[[blocks]]\nname = \"b\"\nfunction = 3\nstart = 0\ncount = 1\n\
             [[fields]]\nname = \"f\"\nblock = \"b\"\noffset = 0\ncodec = { type = \"u16\" }\n",
            "test",
        )
        .unwrap();
        candidates.add(site, "profiles/sm3p.toml".into());
        assert_eq!(
            candidates.choose(&meter),
            ProfileChoice::Named("profiles/sm3p.toml".into())
        );
        assert_eq!(
            ProfileChoice::SunSpecChain { base: 0 }.describe(),
            "SunSpec map at 0: `rtu2mqtt sunspec`"
        );
    }

    #[test]
    fn behind_a_modbus_tcp_gateway_there_is_no_serial_setting() {
        let line = SuggestedLine {
            name: "gw".into(),
            place: LinkPlace::Url("modbus-tcp://10.0.0.5:502".into()),
            serial: None,
            devices: vec![SuggestedDevice {
                address: 1,
                name: Some("inverter".into()),
                profile: ProfileChoice::Named("profiles/site meter.toml".into()),
            }],
        };
        let text = configuration(&[line]);
        assert!(
            text.contains("url = \"modbus-tcp://10.0.0.5:502\"\n\n"),
            "{text}"
        );
        assert!(!text.contains("baud"), "{text}");
        assert!(text.contains("name = \"inverter\"\n"), "{text}");
        assert_eq!(
            devices_to_add("line-a", &[SuggestedDevice {
                address: 4,
                name: None,
                profile: ProfileChoice::Unknown,
            }]),
            "# under the [[lines]] table of \"line-a\":\n\n[[lines.devices]]\nname = \"device_4\"\n\
             # profile: unknown — write one, see docs/profiles.md\naddress = 4\n"
        );
        // A file's stem makes the name when none is configured.
        let unnamed = SuggestedDevice {
            address: 2,
            name: None,
            profile: ProfileChoice::Named("profiles/Site Meter.toml".into()),
        };
        assert_eq!(unnamed.name(), "site_meter_2");
    }
}
