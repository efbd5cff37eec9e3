//! A Sparkplug host's NCMD or DCMD as the edge node takes it (`Session::on_message`: protobuf
//! decoding, metric lookup by name or alias, datatype and value checks), the commands it hands
//! out then taken by the bridge core as the daemon does (`Core::on_external_command`), for the
//! seed plant of `config/rtu2mqtt.toml` with every device online and born. Input: one byte
//! picking the topic (the NCMD, a device's DCMD or an unknown device's), then the payload
//! (seeds: payloads written by the project's own encoder).
//!
//! Asserted: a payload that decodes encodes to bytes that decode to the same payload again;
//! every metric of a DCMD to a born device is either handed out as a command or refused, once;
//! a command is for that device and a field it may write; what the core then hands to the
//! line keeps the rules of the MQTT commands (`plant::Lines::check`); an NCMD does something
//! only when it asks for a rebirth.

#![no_main]

use std::time::Instant;

use libfuzzer_sys::fuzz_target;
use rand::rngs::StdRng;
use rand::SeedableRng;
use rtu2mqtt::bridge::core::Core;
use rtu2mqtt::sparkplug::core::protobuf::{MetricValue, Payload};
use rtu2mqtt::sparkplug::core::session_interface::{Action, REBIRTH};
use rtu2mqtt_fuzz::plant::{self, Lines};
use rtu2mqtt_fuzz::Input;

fuzz_target!(|data: &[u8]| {
    let mut input = Input::new(data);
    let pick = input.u8();
    let payload = input.rest();

    if let Ok(decoded) = Payload::decode_bytes(payload) {
        let encoded = decoded.encode_to_bytes();
        let again = Payload::decode_bytes(&encoded).expect("our own encoding decodes");
        assert_eq!(
            again.encode_to_bytes(),
            encoded,
            "the encoding is not stable"
        );
    }

    let settings = plant::core_settings();
    let devices = settings.devices.clone();
    let mut lines = Lines::new(devices.clone());
    let now = Instant::now();
    let mut core = Core::new(settings, now, StdRng::seed_from_u64(7));
    lines.check(core.on_connected());
    let mut session = plant::born_session();
    for device in &devices {
        let online = lines.availability(&device.name, true);
        lines.check(core.on_line_event(online, now));
    }

    let topic = match pick % 5 {
        0 => session.node_topic("NCMD"),
        4 => session.device_topic("DCMD", "boiler"),
        n => session.device_topic("DCMD", &devices[usize::from(n - 1) % devices.len()].name),
    };
    let actions = session.on_message(plant::SPARKPLUG_NOW, &topic, payload);
    let Some(device) = topic.rsplit_once("/DCMD/gw/").map(|(_, device)| device) else {
        // The NCMD: births again on a rebirth request, nothing otherwise.
        let rebirth = Payload::decode_bytes(payload).is_ok_and(|p| {
            p.metrics.iter().any(|m| {
                m.value == Some(MetricValue::Boolean(true))
                    && (m.name.as_deref() == Some(REBIRTH) || m.name.is_none())
            })
        });
        assert!(
            rebirth || actions.is_empty(),
            "an NCMD without a rebirth: {actions:?}"
        );
        return;
    };
    let profile = devices
        .iter()
        .find(|d| d.name == device)
        .map(|d| &d.profile);
    let decoded = Payload::decode_bytes(payload);
    let mut answered = 0;
    for action in actions {
        match action {
            Action::Command(command) => {
                answered += 1;
                assert_eq!(command.device, device);
                let profile = profile.expect("a command for a device of ours");
                let field = profile
                    .field(&command.field)
                    .unwrap_or_else(|| panic!("{device}: no field {}", command.field));
                assert!(field.writable, "{device}.{} is read-only", command.field);
                lines.check(core.on_external_command(command, now));
            }
            Action::Refused { reason, .. } => {
                answered += 1;
                assert!(!reason.is_empty());
            }
            Action::Publish { .. } => {}
            other => panic!("a DCMD led to {other:?}"),
        }
    }
    match (profile, decoded) {
        (Some(_), Ok(decoded)) => assert_eq!(answered, decoded.metrics.len()),
        // An unknown device or no payload: one refusal.
        _ => assert_eq!(answered, 1),
    }
});
