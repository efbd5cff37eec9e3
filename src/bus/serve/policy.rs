//! What a client's request may do under the line's [`Access`], decided without I/O: forward it
//! to the line, refuse it with an exception before any frame is sent, or (a write under
//! `profile` access) turn it into the profile's command plan, validated on the device's last
//! known state exactly like an MQTT command.

use rtu2mqtt_modbus::{ExceptionCode, Request, SlaveId};

use super::Access;
use crate::bus::device_spec::DeviceSpec;
use rtu2mqtt_profile::Behaviour;
use rtu2mqtt_profile::{CommandPlan, DeviceState, Profile, Value};

/// The server's decision on a request before it reaches the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Verdict {
    /// The line runs the request as it came.
    Forward,
    /// A write the line plans through the device's profile ([`plan_write`]).
    ProfileWrite,
    /// Answered at once with this exception; nothing reaches the line.
    Refuse(ExceptionCode),
}

/// Judges `request` to `unit` on a line with `devices`.
pub(crate) fn judge(
    access: Access,
    devices: &[DeviceSpec],
    unit: SlaveId,
    request: &Request,
) -> Verdict {
    let device = devices.iter().find(|device| device.address == unit);
    if access == Access::Raw {
        return Verdict::Forward;
    }
    let Some(device) = device else {
        return Verdict::Refuse(ExceptionCode::GatewayPathUnavailable);
    };
    if request.is_read() {
        let inside = device
            .profile
            .read_blocks()
            .iter()
            .any(|block| block.request.covers(request));
        return if inside {
            Verdict::Forward
        } else {
            Verdict::Refuse(ExceptionCode::IllegalDataAddress)
        };
    }
    // Read Device Identification asks the device what it is and changes nothing.
    if !request.is_write() {
        return Verdict::Forward;
    }
    match access {
        Access::ReadOnly => Verdict::Refuse(ExceptionCode::IllegalFunction),
        _ => Verdict::ProfileWrite,
    }
}

/// A client's write as the profile reads it.
#[derive(Debug)]
pub(crate) struct PlannedWrite {
    /// Every field the write covers: the write waits for the write interval of each.
    pub covered: Vec<String>,
    /// The command slot that carries it out; `None` when the device would do nothing with it
    /// (zeros on buttons and toggles only).
    pub plan: Option<CommandPlan>,
}

/// Plans a client's `write` through `profile` on the device's last known `state`, reading the
/// frame as the device does: the fields it covers are decoded; a button at 0 is not pressed
/// and at 1 pressed; a toggle at 0 is left alone and at 1 toggled (the state opposite to the
/// one last read, so a fresh read that already shows it writes nothing); read-only fields and
/// reserved bits inside the frame are written back as the device holds them, whatever the
/// client put there (the vendor's own example frames carry zeros there). The
/// command is validated and planned like one from MQTT (range, forbidden combinations judged
/// on the resulting state, read-modify-write of shared registers): one field as that field
/// (the dust collector's gear written at 0x1001, its place in the settings frame, goes out as
/// the gear's own FC06), several through the very frame the client wrote. A write that lands on no write frame is refused with 02, a
/// value the rules refuse with 03.
pub(crate) fn plan_write(
    profile: &Profile,
    write: &Request,
    state: &DeviceState,
) -> Result<PlannedWrite, ExceptionCode> {
    let readings = profile
        .decode_write(write)
        .ok_or(ExceptionCode::IllegalDataAddress)?;
    if readings.is_empty() {
        return Err(ExceptionCode::IllegalDataAddress);
    }
    let covered: Vec<String> = readings.iter().map(|r| r.field.clone()).collect();
    let mut targets: Vec<(String, String)> = Vec::with_capacity(readings.len());
    for reading in readings {
        let field = reading.field;
        let (Some(info), Some((behaviour, overlay))) =
            (profile.field(&field), profile.write_behaviour(&field))
        else {
            return Err(ExceptionCode::IllegalDataAddress);
        };
        if overlay {
            // A view over bits the frame also gives their own fields.
            continue;
        }
        if !info.writable {
            // Nobody writes it: the frame carries it back as the device holds it.
            continue;
        }
        let value = reading.value.map_err(|_| ExceptionCode::IllegalDataValue)?;
        let text = match (behaviour, &value) {
            (Behaviour::Momentary | Behaviour::Toggle, Value::Bool(false)) => continue,
            (Behaviour::Toggle, Value::Bool(true)) => match state.get(&field) {
                Some(Value::Bool(now)) => Value::Bool(!now).to_text(),
                _ => return Err(ExceptionCode::IllegalDataValue),
            },
            _ => value.to_text(),
        };
        targets.push((field, text));
    }
    if targets.is_empty() {
        return Ok(PlannedWrite {
            covered,
            plan: None,
        });
    }
    let values: Vec<(&str, &str)> = targets
        .iter()
        .map(|(field, text)| (field.as_str(), text.as_str()))
        .collect();
    // One field is written as that field (through its own frame, as an MQTT command would);
    // several through the frame the client wrote.
    let plan = match values.as_slice() {
        [(field, text)] => profile.plan_command(field, text, state),
        _ => profile.plan_foreign_write(write, &values, state),
    }
    .map_err(|_| ExceptionCode::IllegalDataValue)?;
    Ok(PlannedWrite {
        covered,
        plan: Some(plan),
    })
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::time::Duration;

    use super::*;
    use rtu2mqtt_modbus::Response;
    use rtu2mqtt_profile::registry::built_in;

    fn dust_collector() -> DeviceSpec {
        DeviceSpec {
            name: "dust_collector".into(),
            address: 1,
            profile: Arc::new(built_in("ruiwan-dust-collector").unwrap()),
            poll_interval: Duration::from_secs(1),
            publish: Default::default(),
        }
    }

    fn gear(value: u16) -> Request {
        Request::WriteSingleRegister {
            address: 0x1002,
            value,
        }
    }

    #[test]
    fn units_reads_and_writes_are_judged_by_access() {
        let devices = [dust_collector()];
        let block = Request::ReadHoldingRegisters {
            start: 0x1000,
            quantity: 6,
        };
        let part = Request::ReadHoldingRegisters {
            start: 0x1001,
            quantity: 2,
        };
        let outside = Request::ReadHoldingRegisters {
            start: 0x2000,
            quantity: 1,
        };
        let refuse = Verdict::Refuse;
        for access in [Access::Profile, Access::ReadOnly] {
            assert_eq!(judge(access, &devices, 1, &block), Verdict::Forward);
            assert_eq!(judge(access, &devices, 1, &part), Verdict::Forward);
            assert_eq!(
                judge(access, &devices, 1, &outside),
                refuse(ExceptionCode::IllegalDataAddress)
            );
            assert_eq!(
                judge(access, &devices, 9, &block),
                refuse(ExceptionCode::GatewayPathUnavailable)
            );
        }
        assert_eq!(
            judge(Access::ReadOnly, &devices, 1, &gear(8)),
            refuse(ExceptionCode::IllegalFunction)
        );
        assert_eq!(
            judge(Access::Profile, &devices, 1, &gear(8)),
            Verdict::ProfileWrite
        );
        for request in [&outside, &gear(8)] {
            assert_eq!(judge(Access::Raw, &devices, 9, request), Verdict::Forward);
        }
        // Read Device Identification changes nothing: it passes to a configured device.
        let identification = Request::ReadDeviceIdentification {
            code: rtu2mqtt_modbus::ReadDeviceIdCode::Basic,
            object_id: 0,
        };
        for access in [Access::Profile, Access::ReadOnly, Access::Raw] {
            assert_eq!(
                judge(access, &devices, 1, &identification),
                Verdict::Forward
            );
        }
        assert_eq!(
            judge(Access::ReadOnly, &devices, 9, &identification),
            refuse(ExceptionCode::GatewayPathUnavailable)
        );
    }

    #[test]
    fn a_profile_write_is_planned_like_an_mqtt_command() {
        let device = dust_collector();
        let state = DeviceState::new();
        let plan = plan_write(&device.profile, &gear(8), &state)
            .unwrap()
            .plan
            .unwrap();
        assert_eq!(plan.field(), "gear");
        assert_eq!(plan.target(), &Value::Int(8));
        assert_eq!(
            plan.writes(&[]).unwrap(),
            vec![gear(8)],
            "the frame the profile writes is the client's"
        );
        assert_eq!(
            plan_write(&device.profile, &gear(11), &state).unwrap_err(),
            ExceptionCode::IllegalDataValue
        );
        let fan_speed = Request::WriteSingleRegister {
            address: 0x1008,
            value: 100,
        };
        assert_eq!(
            plan_write(&device.profile, &fan_speed, &state).unwrap_err(),
            ExceptionCode::IllegalDataAddress
        );
    }

    fn air_shower() -> Arc<Profile> {
        Arc::new(built_in("lixian-air-shower").unwrap())
    }

    /// The air shower's writable coils as the device reports them, all off but `on`.
    fn shower_state(on: &[&str]) -> DeviceState {
        let profile = air_shower();
        profile
            .fields()
            .iter()
            .filter(|field| field.writable)
            .map(|field| {
                let value = Value::Bool(on.contains(&field.name.as_str()));
                (field.name.clone(), value)
            })
            .collect()
    }

    /// The vendor document's frame `81 0F 00 00 00 0C 02 <b0> <b1>` as a request.
    fn coils_frame(b0: u8, b1: u8) -> Request {
        let bits = (0..12)
            .map(|coil| {
                let byte = if coil < 8 { b0 } else { b1 };
                byte >> (coil % 8) & 1 == 1
            })
            .collect();
        Request::WriteMultipleCoils {
            start: 0,
            values: bits,
        }
    }

    /// The frames `write` puts on the wire when the device's fresh read is `fresh`.
    fn on_the_wire(planned: &PlannedWrite, fresh: Response) -> Vec<Request> {
        let plan = planned.plan.as_ref().expect("a plan");
        let answers: Vec<Response> = plan.reads_before().iter().map(|_| fresh.clone()).collect();
        plan.writes(&answers).unwrap()
    }

    #[test]
    fn the_air_showers_vendor_frames_do_what_the_vendor_document_says() {
        let profile = air_shower();
        let idle = Response::Coils(vec![false; 22]);
        // Light and buzzer on, the rest 0: 0 on the e-stop and the voice buttons is "leave
        // them", and the frame goes out as the client sent it.
        for (b0, b1) in [
            (0x00, 0x03),
            (0x00, 0x01),
            (0x02, 0x00),
            (0x0E, 0x01),
            (0x00, 0x04),
            (0x00, 0x00),
        ] {
            let frame = coils_frame(b0, b1);
            let planned = plan_write(&profile, &frame, &shower_state(&[])).unwrap();
            assert!(planned.covered.iter().any(|f| f == "emergency_stop"));
            assert_eq!(
                on_the_wire(&planned, idle.clone()),
                vec![frame],
                "{b0:02X} {b1:02X}"
            );
        }
        // 1 on the e-stop toggles it: written 1 while the device shows it off...
        let estop = coils_frame(0x01, 0x00);
        let planned = plan_write(&profile, &estop, &shower_state(&[])).unwrap();
        assert_eq!(on_the_wire(&planned, idle.clone()), vec![estop.clone()]);
        // ...and again 1 while it shows it on (it clears it); 0 leaves an active e-stop alone.
        let mut active = vec![false; 22];
        active[0] = true;
        let planned = plan_write(&profile, &estop, &shower_state(&["emergency_stop"])).unwrap();
        assert_eq!(
            on_the_wire(&planned, Response::Coils(active.clone())),
            vec![estop]
        );
        let light = coils_frame(0x00, 0x01);
        let planned = plan_write(&profile, &light, &shower_state(&["emergency_stop"])).unwrap();
        assert_eq!(on_the_wire(&planned, Response::Coils(active)), vec![light]);
        // Zeros on the e-stop alone: the device would do nothing, nothing is planned.
        let untouched = Request::WriteSingleCoil {
            address: 0,
            value: false,
        };
        let planned = plan_write(&profile, &untouched, &shower_state(&[])).unwrap();
        assert!(planned.plan.is_none());
        assert_eq!(planned.covered, ["emergency_stop"]);
        // Strong wind and breeze together stay refused.
        assert_eq!(
            plan_write(&profile, &coils_frame(0x18, 0x00), &shower_state(&[])).unwrap_err(),
            ExceptionCode::IllegalDataValue
        );
    }

    #[test]
    fn the_dust_collectors_vendor_frames_do_what_the_vendor_document_says() {
        let device = dust_collector();
        let profile = &device.profile;
        let state: DeviceState = [
            ("power", Value::Bool(false)),
            ("pulse_cleaning", Value::Bool(false)),
            ("fan_alarm", Value::Bool(false)),
            ("filter_alarm", Value::Bool(false)),
            ("temperature_alarm", Value::Bool(false)),
        ]
        .into_iter()
        .map(|(field, value)| (field.to_string(), value))
        .collect();
        let fresh = Response::HoldingRegisters(vec![0, 3, 0, 0, 0, 0]);
        // `01 10 10 00 00 04 08 03 00 00 05 00 02 00 0A`: power on, pulse cleaning on, gear
        // 5, PV 2, SV 10, in one frame.
        let settings = Request::WriteMultipleRegisters {
            start: 0x1000,
            values: vec![0x0300, 5, 2, 10],
        };
        let planned = plan_write(profile, &settings, &state).unwrap();
        assert!(planned.covered.iter().any(|f| f == "gear"));
        assert_eq!(on_the_wire(&planned, fresh.clone()), vec![settings.clone()]);
        // `01 06 10 02 00 08`: gear 8.
        let planned = plan_write(profile, &gear(8), &state).unwrap();
        assert_eq!(planned.plan.unwrap().writes(&[]).unwrap(), vec![gear(8)]);
        // The gear at its place in the settings frame (0x1001) is written as the gear.
        let at_frame_place = Request::WriteSingleRegister {
            address: 0x1001,
            value: 6,
        };
        let planned = plan_write(profile, &at_frame_place, &state).unwrap();
        assert_eq!(planned.covered, ["gear"]);
        assert_eq!(planned.plan.unwrap().writes(&[]).unwrap(), vec![gear(6)]);
        // Alarm and internal bits are written back as the device holds them, whatever the
        // client sent there.
        let alarm = Request::WriteMultipleRegisters {
            start: 0x1000,
            values: vec![0x0304, 5, 2, 10],
        };
        let planned = plan_write(profile, &alarm, &state).unwrap();
        let held = Response::HoldingRegisters(vec![0x2041, 3, 0, 0, 0, 0]);
        assert_eq!(
            on_the_wire(&planned, held),
            vec![Request::WriteMultipleRegisters {
                start: 0x1000,
                values: vec![0x2341, 5, 2, 10],
            }]
        );
    }
}
