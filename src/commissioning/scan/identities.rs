//! What each device a scan found says it is: the reads of
//! [`rtu2mqtt_profile::identify::Identifier`] sent to the address (Read Device Identification
//! and FC03 reads of the SunSpec marker; nothing that writes), only where a device answered
//! the probe; the table of what the devices said with the profile that fits each; and the
//! configuration to copy.

use std::fmt::Write as _;
use std::time::Duration;

use anyhow::Context as _;

use super::Found;
use crate::config::suggestion::{
    configuration, Candidates, LinkPlace, SuggestedDevice, SuggestedLine,
};
use rtu2mqtt_modbus::codec::MAX_FRAME_LEN;
use rtu2mqtt_modbus::link::Link;
use rtu2mqtt_modbus::timing::LineTiming;
use rtu2mqtt_modbus::{Error as LinkError, ExceptionCode, SlaveId, Transact};
use rtu2mqtt_profile::identify::{Heard, Identifier, Identity};

/// The response timeout of an identification read: the probe's, plus the wire time of the
/// longest answer (an identification's length is up to the device).
pub(super) fn identification_timeout(timeout: Duration, timing: &LineTiming) -> Duration {
    timeout + timing.frame_time(MAX_FRAME_LEN)
}

/// Asks the device at `address` what it is.
pub(super) async fn identify(
    master: &mut Link,
    address: SlaveId,
    timeout: Duration,
) -> anyhow::Result<Identity> {
    let mut identifier = Identifier::new();
    while let Some(request) = identifier.next_request() {
        let heard = match master.transact(address, &request, timeout).await {
            Ok(Ok(response)) => Heard::Answer(response),
            // A Modbus TCP gateway's answer in the device's place.
            Ok(Err(
                ExceptionCode::GatewayPathUnavailable | ExceptionCode::GatewayTargetFailedToRespond,
            )) => Heard::Nothing,
            Ok(Err(code)) => Heard::Exception(code),
            Err(LinkError::PortGone(fault)) => return Err(fault).context("serial port"),
            Err(_) => Heard::Nothing,
        };
        identifier.hear(heard);
    }
    Ok(identifier.identity())
}

/// The first find at each address (a device found at several settings is identified once).
fn first_finds(found: &[Found]) -> Vec<&Found> {
    let mut first: Vec<&Found> = Vec::new();
    for device in found {
        if !first.iter().any(|seen| seen.address == device.address) {
            first.push(device);
        }
    }
    first
}

/// The table of what each device said and the profile that fits it.
pub(super) fn table(found: &[Found], candidates: &Candidates) -> String {
    let header = [
        "address",
        "FC43",
        "vendor",
        "product code",
        "revision",
        "SunSpec",
        "profile",
    ];
    let dash = || "-".to_string();
    let mut rows: Vec<[String; 7]> = vec![header.map(str::to_string)];
    for device in first_finds(found) {
        let address = format!("{:>3} ({:#04x})", device.address, device.address);
        let Some(identity) = &device.identity else {
            rows.push([address, dash(), dash(), dash(), dash(), dash(), dash()]);
            continue;
        };
        let id = &identity.device_id;
        rows.push([
            address,
            id.status(),
            id.vendor().unwrap_or_else(dash),
            id.product_code().unwrap_or_else(dash),
            id.revision().unwrap_or_else(dash),
            identity
                .sunspec
                .as_ref()
                .map_or_else(dash, ToString::to_string),
            candidates.choose(identity).describe(),
        ]);
    }
    let widths: Vec<usize> = (0..header.len())
        .map(|column| {
            rows.iter()
                .map(|row| row[column].chars().count())
                .max()
                .unwrap_or(0)
        })
        .collect();
    let mut out = String::new();
    for row in &rows {
        let mut line = String::new();
        for (cell, width) in row.iter().zip(&widths) {
            let _ = write!(line, "{cell:<width$}  ");
        }
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out
}

/// The configuration to copy for the devices found on `place`: one line per serial setting
/// (none behind a Modbus TCP gateway), each device at the first setting it answered at.
pub(super) fn suggestion(
    found: &[Found],
    candidates: &Candidates,
    place: &LinkPlace,
    modbus_tcp: bool,
) -> String {
    let mut lines: Vec<SuggestedLine> = Vec::new();
    for device in first_finds(found) {
        let serial = (!modbus_tcp).then_some((device.baud, device.parity));
        let suggested = SuggestedDevice {
            address: device.address,
            name: None,
            profile: device.identity.as_ref().map_or(
                crate::config::suggestion::ProfileChoice::Unknown,
                |identity| candidates.choose(identity),
            ),
        };
        match lines.iter_mut().find(|line| line.serial == serial) {
            Some(line) => line.devices.push(suggested),
            None => lines.push(SuggestedLine {
                name: format!("line{}", lines.len() + 1),
                place: place.clone(),
                serial,
                devices: vec![suggested],
            }),
        }
    }
    configuration(&lines)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtu2mqtt_modbus::timing::Parity;
    use rtu2mqtt_modbus::DeviceIdObject;
    use rtu2mqtt_profile::identify::{DeviceId, SunSpecMap};

    fn found(address: SlaveId, parity: Parity, identity: Option<Identity>) -> Found {
        Found {
            address,
            baud: 9600,
            parity,
            answers: vec!["FC03 ok".into()],
            identity,
        }
    }

    #[test]
    fn each_address_is_shown_once_with_what_it_said_and_the_profile() {
        let meter = Identity {
            device_id: DeviceId::Objects(vec![
                DeviceIdObject::text(0, "Schneider Electric"),
                DeviceIdObject::text(1, "METSEPM3255"),
                DeviceIdObject::text(2, "V2.1.4"),
            ]),
            sunspec: None,
        };
        let inverter = Identity {
            device_id: DeviceId::Refused(ExceptionCode::IllegalFunction),
            sunspec: Some(SunSpecMap {
                base: 40000,
                models: vec![1, 103],
            }),
        };
        let finds = [
            found(1, Parity::None, Some(meter)),
            found(2, Parity::None, Some(inverter)),
            // The meter again at another parity: not shown twice.
            found(1, Parity::Even, None),
        ];
        let candidates = Candidates::built_in();
        assert_eq!(
            table(&finds, &candidates),
            "address     FC43                             vendor              product code  revision  SunSpec               profile\n  \
             1 (0x01)  ok                               Schneider Electric  METSEPM3255   V2.1.4    -                     unknown\n  \
             2 (0x02)  exception 01 (illegal function)  -                   -             -         40000: models 1, 103  sunspec-inverter\n"
        );
        let place = LinkPlace::Port("/dev/ttyUSB0".into());
        let text = suggestion(&finds, &candidates, &place, false);
        assert_eq!(text.matches("[[lines]]").count(), 1, "{text}");
        assert!(
            text.contains("name = \"device_1\"\n# profile: unknown"),
            "{text}"
        );
        assert!(
            text.contains(
                "name = \"sunspec_inverter_2\"\nprofile = \"sunspec-inverter\"\naddress = 2"
            ),
            "{text}"
        );
    }
}
