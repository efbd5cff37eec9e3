//! MQTT commands as the bridge core takes them (`Core::on_message`: topic guard, payload
//! rules, the profile's validation, the command book), for the seed plant of
//! `config/rtu2mqtt.toml`, interleaved with what the lines report (availability, values,
//! commands finished) and the clock. Input: a script of steps, each a kind byte and its
//! operands; a message's topic is either a device's field's `…/set` picked by index or raw
//! text, its payload raw bytes.
//!
//! Asserted: a command handed to a line is for a device of that line that is online, on a
//! field the profile lets be written, with values the profile accepts for it; no two commands
//! of one field are on the bus at once; no command id is handed over twice.

#![no_main]

use std::time::{Duration, Instant, SystemTime};

use libfuzzer_sys::fuzz_target;
use rand::rngs::StdRng;
use rand::SeedableRng;
use rtu2mqtt::bridge::core::{Core, Incoming};
use rtu2mqtt::bus::{CommandOutcome, LineEvent, Origin};
use rtu2mqtt_fuzz::plant::{self, Lines};
use rtu2mqtt_fuzz::Input;
use rumqttc::QoS;

fuzz_target!(|data: &[u8]| {
    let settings = plant::core_settings();
    let topics = settings.topics.clone();
    let mut lines = Lines::new(settings.devices.clone());
    let devices = settings.devices.clone();
    let start = Instant::now();
    let mut now = start;
    let mut core = Core::new(settings, now, StdRng::seed_from_u64(7));
    lines.check(core.on_connected());
    let mut input = Input::new(data);
    let mut steps = 0;
    while !input.is_empty() && steps < 64 {
        steps += 1;
        let kind = input.u8();
        let device = &devices[usize::from(input.u8()) % devices.len()];
        let fields = device.profile.fields();
        let field = &fields[usize::from(input.u8()) % fields.len()].name;
        let actions = match kind % 8 {
            0..=2 => {
                let topic = topics.command_topic(&device.name, field);
                let payload = input.part();
                core.on_message(message(&topic, payload, kind), now)
            }
            3 => {
                let topic = String::from_utf8_lossy(input.part()).into_owned();
                let payload = input.part();
                core.on_message(message(&topic, payload, kind), now)
            }
            4 => {
                let event = lines.availability(&device.name, kind & 0x80 == 0);
                core.on_line_event(event, now)
            }
            5 => {
                // The oldest command on the bus ends, with an outcome the input picks.
                let Some((id, device)) = lines.finish_oldest() else {
                    continue;
                };
                let detail = String::from_utf8_lossy(input.part()).into_owned();
                let outcome = match kind >> 6 {
                    0 => CommandOutcome::Applied { detail },
                    1 => CommandOutcome::NotApplied { detail },
                    _ => CommandOutcome::Rejected { detail },
                };
                core.on_line_event(
                    LineEvent::CommandFinished {
                        id,
                        device,
                        outcome,
                    },
                    now,
                )
            }
            6 => {
                now += Duration::from_millis(u64::from(input.u16()) * 16);
                core.on_tick(now, Vec::new)
            }
            _ => {
                // A value read from the device: the state commands are judged on.
                let text = String::from_utf8_lossy(input.part()).into_owned();
                let Ok(value) = device.profile.parse_value(field, &text) else {
                    continue;
                };
                let event = LineEvent::Values {
                    device: device.name.clone(),
                    values: vec![(field.clone(), value)],
                    read_at: SystemTime::UNIX_EPOCH + (now - start),
                    origin: Origin::Poll,
                };
                core.on_line_event(event, now)
            }
        };
        lines.check(actions);
    }
});

fn message<'m>(topic: &'m str, payload: &'m [u8], flags: u8) -> Incoming<'m> {
    Incoming {
        topic,
        payload,
        qos: if flags & 0x10 == 0 {
            QoS::AtLeastOnce
        } else {
            QoS::AtMostOnce
        },
        pkid: u16::from(flags >> 5),
        dup: flags & 0x08 != 0,
        retain: flags & 0x20 != 0,
    }
}
