//! What a client's request may do under the line's [`Access`], decided without I/O: forward it
//! to the line, refuse it with an exception before any frame is sent, or (a write under
//! `profile` access) turn it into the profile's command plan, validated on the device's last
//! known state exactly like an MQTT command.

use rtu2mqtt_modbus::{ExceptionCode, Request, SlaveId};

use super::Access;
use crate::bus::DeviceSpec;
use crate::profile::{CommandPlan, DeviceState, Profile};

/// The server's decision on a request before it reaches the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// The line runs the request as it came.
    Forward,
    /// A write the line plans through the device's profile ([`plan_write`]).
    ProfileWrite,
    /// Answered at once with this exception; nothing reaches the line.
    Refuse(ExceptionCode),
}

/// Judges `request` to `unit` on a line with `devices`.
pub fn judge(access: Access, devices: &[DeviceSpec], unit: SlaveId, request: &Request) -> Verdict {
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
    match access {
        Access::ReadOnly => Verdict::Refuse(ExceptionCode::IllegalFunction),
        _ => Verdict::ProfileWrite,
    }
}

/// Plans a client's `write` through `profile` on the device's last known `state`: the fields it
/// writes are decoded as the device would hold them, and the command is validated and planned
/// like one from MQTT (range, read-only, forbidden combinations, read-modify-write of shared
/// registers). A write that names no whole writable field is refused with 02, a value the
/// rules refuse with 03.
pub fn plan_write(
    profile: &Profile,
    write: &Request,
    state: &DeviceState,
) -> Result<CommandPlan, ExceptionCode> {
    let readings = profile
        .decode_write(write)
        .ok_or(ExceptionCode::IllegalDataAddress)?;
    if readings.is_empty() {
        return Err(ExceptionCode::IllegalDataAddress);
    }
    let mut targets = Vec::with_capacity(readings.len());
    for reading in readings {
        let writable = profile
            .field(&reading.field)
            .is_some_and(|field| field.writable);
        if !writable {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        let value = reading.value.map_err(|_| ExceptionCode::IllegalDataValue)?;
        targets.push((reading.field, value.to_text()));
    }
    if let [(field, text)] = targets.as_slice() {
        return profile
            .plan_command(field, text, state)
            .map_err(|_| ExceptionCode::IllegalDataValue);
    }
    // Several fields in one frame: the profile's shared frame that writes them together.
    let values: Vec<(&str, &str)> = targets
        .iter()
        .map(|(field, text)| (field.as_str(), text.as_str()))
        .collect();
    profile
        .write_frame_names()
        .into_iter()
        .find_map(|frame| profile.plan_group(frame, &values, state).ok())
        .ok_or(ExceptionCode::IllegalDataValue)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::time::Duration;

    use super::*;
    use crate::profile::registry::built_in;
    use crate::profile::Value;

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
    }

    #[test]
    fn a_profile_write_is_planned_like_an_mqtt_command() {
        let device = dust_collector();
        let state = DeviceState::new();
        let plan = plan_write(&device.profile, &gear(8), &state).unwrap();
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
}
