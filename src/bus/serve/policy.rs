//! What a client's request may do under the line's [`Access`], decided without I/O: forward it
//! to the line, refuse it with an exception before any frame is sent, or (a write under
//! `profile` access) turn it into the profile's command plan, validated on the device's last
//! known state exactly like an MQTT command.

use rtu2mqtt_modbus::{ExceptionCode, Request, Response, SlaveId};

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

/// The read that covers exactly what `write` writes, and the answer it would get once the write
/// is applied: the image the profile decodes the written fields from.
fn written_image(write: &Request) -> Option<(Request, Response)> {
    Some(match write {
        Request::WriteSingleRegister { address, value } => (
            Request::ReadHoldingRegisters {
                start: *address,
                quantity: 1,
            },
            Response::HoldingRegisters(vec![*value]),
        ),
        Request::WriteMultipleRegisters { start, values } => (
            Request::ReadHoldingRegisters {
                start: *start,
                quantity: u16::try_from(values.len()).ok()?,
            },
            Response::HoldingRegisters(values.clone()),
        ),
        Request::WriteSingleCoil { address, value } => (
            Request::ReadCoils {
                start: *address,
                quantity: 1,
            },
            Response::Coils(vec![*value]),
        ),
        Request::WriteMultipleCoils { start, values } => (
            Request::ReadCoils {
                start: *start,
                quantity: u16::try_from(values.len()).ok()?,
            },
            Response::Coils(values.clone()),
        ),
        _ => return None,
    })
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
    let (read, image) = written_image(write).ok_or(ExceptionCode::IllegalFunction)?;
    let readings = profile.decode_read(&read, &image);
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
