//! What the fuzz targets share: how a target's input bytes are read ([`Input`]), the request a
//! frame input starts with ([`request_of`]), the seed profiles, and the checks of a decoded
//! answer against its bytes ([`assert_reencodes`]). The input layouts are written down here so
//! that the seed corpora (`examples/seeds.rs`) and the targets agree on them.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use rtu2mqtt_modbus::codec::{self, Answer};
use rtu2mqtt_modbus::crc::append_crc;
use rtu2mqtt_modbus::{Request, Response, SlaveId};
use rtu2mqtt_profile::{registry, Profile};

/// The profiles of the seed plant's devices and the generic sensor, in `config/profiles/`.
pub const SEED_PROFILES: [&str; 4] = [
    "ruiwan-dust-collector",
    "wuzhou-valve",
    "lixian-air-shower",
    "generic-th-sensor",
];

/// The seed profiles, read from their files and compiled once.
pub fn seed_profiles() -> &'static [(String, Arc<Profile>)] {
    static PROFILES: OnceLock<Vec<(String, Arc<Profile>)>> = OnceLock::new();
    PROFILES.get_or_init(|| {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/profiles");
        SEED_PROFILES
            .iter()
            .map(|name| {
                let profile = registry::load_file(&dir.join(format!("{name}.toml")))
                    .unwrap_or_else(|error| panic!("profile {name}: {error}"));
                (name.to_string(), Arc::new(profile))
            })
            .collect()
    })
}

/// A fuzz input read front to back; reading past its end gives zeros and empty slices, so
/// every byte string is a valid input.
#[derive(Debug, Clone, Copy)]
pub struct Input<'a> {
    bytes: &'a [u8],
}

impl<'a> Input<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        Input { bytes }
    }

    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    pub fn u8(&mut self) -> u8 {
        self.take(1).first().copied().unwrap_or(0)
    }

    /// Big-endian, as Modbus writes its words.
    pub fn u16(&mut self) -> u16 {
        u16::from_be_bytes([self.u8(), self.u8()])
    }

    /// Up to `count` bytes.
    pub fn take(&mut self, count: usize) -> &'a [u8] {
        let (taken, rest) = self.bytes.split_at(count.min(self.bytes.len()));
        self.bytes = rest;
        taken
    }

    /// A part announced by its length byte: `[length u8][bytes]`.
    pub fn part(&mut self) -> &'a [u8] {
        let length = usize::from(self.u8());
        self.take(length)
    }

    pub fn rest(&mut self) -> &'a [u8] {
        self.take(self.bytes.len())
    }
}

/// Writes a part as [`Input::part`] reads it.
pub fn push_part(out: &mut Vec<u8>, part: &[u8]) {
    let length = u8::try_from(part.len()).expect("a part is at most 255 bytes");
    out.push(length);
    out.extend_from_slice(part);
}

/// The request a master would send, from the request frame without its CRC (address and PDU,
/// as `[length][bytes]`): the CRC is appended here so that mutations reach the answer rather
/// than fail at the request's CRC. `None` when it is no request the master can send.
pub fn request_of(input: &mut Input<'_>) -> Option<(SlaveId, Request)> {
    let mut frame = input.part().to_vec();
    append_crc(&mut frame);
    let (slave, request) = codec::decode_request(&frame).ok()?;
    codec::encode_request(slave, &request).ok()?;
    Some((slave, request))
}

/// Writes a request as [`request_of`] reads it.
pub fn push_request(out: &mut Vec<u8>, slave: SlaveId, request: &Request) {
    let frame = codec::encode_request(slave, request).expect("a request the master sends");
    push_part(out, &frame[..frame.len() - 2]);
}

/// The frame the device would have sent for `answer`, CRC included.
pub fn encode(slave: SlaveId, request: &Request, answer: &Answer) -> Vec<u8> {
    match answer {
        Answer::Normal(response) => codec::encode_answer(slave, response),
        Answer::Exception(code) => {
            codec::encode_exception(slave, request.function().value(), *code)
        }
    }
}

/// A decoded answer re-encodes to the very bytes it was decoded from (`frame`: address, PDU
/// and, when `with_crc`, the CRC). The one freedom a decoder takes is allowed: the padding
/// bits after the last coil of the last byte, which carry nothing and are encoded as zeros.
pub fn assert_reencodes(
    slave: SlaveId,
    request: &Request,
    answer: &Answer,
    frame: &[u8],
    with_crc: bool,
) {
    let mut expected = encode(slave, request, answer);
    if !with_crc {
        expected.truncate(expected.len() - 2);
    }
    let mut got = frame.to_vec();
    if let Answer::Normal(Response::Coils(bits) | Response::DiscreteInputs(bits)) = answer {
        let last_data = 2 + bits.len().div_ceil(8);
        let used = bits.len() % 8;
        if used != 0 {
            got[last_data] &= (1u8 << used) - 1;
        }
        if with_crc {
            got.truncate(got.len() - 2);
            append_crc(&mut got);
        }
    }
    assert_eq!(
        codec::hex(&got),
        codec::hex(&expected),
        "{answer:?} decoded from {} does not re-encode to it",
        codec::hex(frame)
    );
}

/// The seed plant of `config/rtu2mqtt.toml` as the bridge sees it, and what its lines would
/// hold of the commands the bridge hands them.
pub mod plant {
    use std::collections::{HashMap, HashSet};
    use std::sync::OnceLock;

    use rtu2mqtt::bridge::core::{Action, BridgeDevice, CoreSettings};
    use rtu2mqtt::bus::{LineEvent, Origin};
    use rtu2mqtt::config::Config;
    use rtu2mqtt::sparkplug::core::session::Session;
    use rtu2mqtt::sparkplug::core::session_interface::SessionSettings;

    /// Sparkplug's clock in the fuzz targets (ms since the epoch).
    pub const SPARKPLUG_NOW: u64 = 1_700_000_000_000;

    /// The Sparkplug edge node `gw` of group `plant` for the seed plant, connected, with every
    /// device online, its values read once (all zero answers) and born.
    pub fn born_session() -> Session {
        let config = config();
        let devices: Vec<_> = config
            .lines
            .iter()
            .flat_map(|line| &line.devices)
            .map(|device| (device.name.clone(), device.profile.clone()))
            .collect();
        let mut session = Session::new(
            SessionSettings {
                group_id: "plant".to_string(),
                edge_node_id: "gw".to_string(),
                primary_host_id: None,
                devices: devices.clone(),
                version: "fuzz".to_string(),
                node_metrics: Vec::new(),
            },
            0,
        );
        session.on_connected(SPARKPLUG_NOW);
        for (name, profile) in &devices {
            let values = (0..profile.read_blocks().len())
                .flat_map(|block| {
                    let answer = profile.read_blocks()[block].request.empty_answer();
                    answer.map(|answer| profile.decode_block(block, &answer))
                })
                .flatten()
                .filter_map(|reading| Some((reading.field, reading.value.ok()?)))
                .collect();
            let event = LineEvent::Values {
                device: name.clone(),
                values,
                read_at: std::time::SystemTime::UNIX_EPOCH,
                origin: Origin::Poll,
            };
            session.on_line_event(SPARKPLUG_NOW, &event);
        }
        session
    }

    /// The seed plant's configuration, read once.
    pub fn config() -> &'static Config {
        static CONFIG: OnceLock<Config> = OnceLock::new();
        CONFIG.get_or_init(|| {
            let text = include_str!("../../config/rtu2mqtt.toml");
            let base = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config"));
            rtu2mqtt::config::from_str(text, base).expect("the seed plant's configuration")
        })
    }

    /// The bridge core's settings for the seed plant, without Home Assistant discovery: its
    /// documents, built again on every connect, would take most of each run's time and have
    /// nothing to do with commands.
    pub fn core_settings() -> CoreSettings {
        let mut settings = CoreSettings::from_config(config());
        settings.discovery = false;
        settings
    }

    /// The lines' side: which devices are online, which commands are on the bus.
    #[derive(Debug)]
    pub struct Lines {
        devices: HashMap<String, BridgeDevice>,
        online: HashSet<String>,
        /// (command id, device, field) in the order they were handed over.
        on_bus: Vec<(u64, String, String)>,
        handed: HashSet<u64>,
    }

    impl Lines {
        pub fn new(devices: Vec<BridgeDevice>) -> Self {
            Lines {
                devices: devices.into_iter().map(|d| (d.name.clone(), d)).collect(),
                online: HashSet::new(),
                on_bus: Vec::new(),
                handed: HashSet::new(),
            }
        }

        /// The event a line sends when `device` comes online or goes offline.
        pub fn availability(&mut self, device: &str, online: bool) -> LineEvent {
            if online {
                self.online.insert(device.to_string());
            } else {
                self.online.remove(device);
            }
            LineEvent::Availability {
                device: device.to_string(),
                online,
            }
        }

        /// The oldest command on the bus, taken off it: (id, device).
        pub fn finish_oldest(&mut self) -> Option<(u64, String)> {
            if self.on_bus.is_empty() {
                return None;
            }
            let (id, device, _) = self.on_bus.remove(0);
            Some((id, device))
        }

        /// Every command handed to a line keeps the rules: for an online device of that
        /// line, on fields its profile lets be written, with values the profile accepts for
        /// them; one command of a field on the bus at a time; no command handed over twice.
        pub fn check(&mut self, actions: Vec<Action>) {
            for action in actions {
                let Action::Send { line, command } = action else {
                    continue;
                };
                let name = command.device.as_str();
                let device = self
                    .devices
                    .get(name)
                    .unwrap_or_else(|| panic!("a command for {name}, no device of ours"));
                assert_eq!(device.line, line, "{name} handed to line {line}");
                assert!(
                    self.online.contains(name),
                    "a command handed over while {name} is offline"
                );
                assert!(
                    self.handed.insert(command.id),
                    "command {} handed over twice",
                    command.id
                );
                for (target, value) in command.plan.targets() {
                    let info = device
                        .profile
                        .field(target)
                        .unwrap_or_else(|| panic!("{name}: no field {target}"));
                    assert!(info.writable, "{name}.{target} is not writable");
                    assert!(
                        device.profile.parse_value(target, &value.to_text()).is_ok(),
                        "{name}.{target} = {value:?}: a value its profile refuses"
                    );
                }
                let field = command.plan.field().to_string();
                assert!(
                    !self.on_bus.iter().any(|(_, d, f)| d == name && *f == field),
                    "two commands of {name}.{field} on the bus"
                );
                self.on_bus.push((command.id, name.to_string(), field));
            }
        }
    }
}
