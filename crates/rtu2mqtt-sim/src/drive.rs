//! Test helpers that drive one [`SimDevice`] with single Modbus requests, shared by the seed
//! devices' unit tests so each test module states only what its device does differently.

use std::time::Instant;

use rtu2mqtt_modbus::frame::{ExceptionCode, Request, Response};

use super::device::{Reply, SimDevice};

/// An FC03 read of `quantity` holding registers from `start`.
pub(crate) fn read(device: &mut impl SimDevice, start: u16, quantity: u16, now: Instant) -> Reply {
    device.handle(&Request::ReadHoldingRegisters { start, quantity }, now)
}

/// An FC06 write of `value` to the holding register at `address`.
pub(crate) fn write(device: &mut impl SimDevice, address: u16, value: u16, now: Instant) -> Reply {
    device.handle(&Request::WriteSingleRegister { address, value }, now)
}

/// The words of a normal FC03 answer; any other reply fails the test.
pub(crate) fn words(reply: Reply) -> Vec<u16> {
    match reply {
        Reply::Normal(Response::HoldingRegisters(words)) => words,
        other => panic!("unexpected {other:?}"),
    }
}

/// Asserts that a device without coils refuses an FC01 read as an illegal function.
pub(crate) fn assert_refuses_coils(device: &mut impl SimDevice, now: Instant) {
    assert_eq!(
        device.handle(
            &Request::ReadCoils {
                start: 0,
                quantity: 1
            },
            now
        ),
        Reply::Exception(ExceptionCode::IllegalFunction)
    );
}
