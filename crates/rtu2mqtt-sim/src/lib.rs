//! Simulated devices built from profiles, with per-device behaviour, wire pacing and fault
//! injection, served on a (pseudo-)serial port.
//!
//! - [`SimDevice`]: one simulated device as a pure request → [`Reply`] function with a clock
//!   passed in. The seed devices ([`DustCollector`], [`Valve`], [`AirShower`]) are written by
//!   hand from docs/devices.md with their quirks, not derived from our profiles: a profile bug is
//!   caught by them rather than copied into them; [`GenericDevice`] is built from a profile's
//!   read blocks for every other profile.
//! - [`server::serve`]: frames requests on a byte stream, hands them to the addressed device,
//!   answers after t3.5 (optionally paced at the wire's character rate), applying the
//!   [`Faults`] of the moment and writing everything into the [`Journal`].
//! - [`VirtualLine`]: a pty pair served in the background, whose slave path the gateway opens
//!   like a real port; [`SeedPlant`] puts the three seed devices on two of them.
//! - [`TcpSimulator`]: the same devices behind a TCP port, as a serial device server (raw RTU
//!   frames) or a Modbus TCP gateway, with network faults of its own ([`TcpFaults`]).
//!
//! Modules: `device` (what a simulated device is), the devices `dust_collector`, `air_shower`, `valve` (written by hand), `generic`
//! (from any profile, optionally with a `command_interface`: a command frame and its result
//! register), `library` (the device library's tables of `register_map` values) and
//! `sunspec` (SunSpec maps); `server` (framing, `pace`, `faults`, `journal`; `drive` runs a
//! device's clock), `wire` (frames on the simulator's side), `virtual_line` (a served pty),
//! `pty_settings` (the baud rate the master set, watched through the pty), `serial_stream` (a
//! mio-serial port as a tokio stream), `tcp` (serving over TCP: raw RTU or Modbus TCP) and
//! `plant` (the seed plant).
//!
//! The daemon does not depend on this crate; it serves tests, the benchmarks and the demo
//! (`rtu2mqtt-demo`, `rtu2mqtt-demo simulate`).
//!
//! ```no_run
//! # async fn example() -> std::io::Result<()> {
//! use rtu2mqtt_modbus::timing::Parity;
//! use rtu2mqtt_sim::{lock, share, AirShower, DustCollector, Occurrence, ServeOptions, VirtualLine};
//!
//! let (dust, dust_shared) = share(DustCollector::new(1));
//! let (_shower, shower_shared) = share(AirShower::new());
//! let options = ServeOptions::new(9600, Parity::None).paced(true);
//! let line = VirtualLine::spawn(options, vec![dust_shared, shower_shared])?;
//! // The gateway opens `line.path()` (/dev/pts/N) like a real port.
//! line.faults().update(|f| f.drop = Occurrence::next(2));
//! lock(&dust).set_power(true);
//! let seen = line.journal().frames();
//! # let _ = seen; Ok(())
//! # }
//! ```

// Kept true on every build, as in the daemon: `pub` is the crate's surface, every public type
// prints with `{:?}`, the 2018 idioms.
#![warn(unreachable_pub, missing_debug_implementations, rust_2018_idioms)]

pub mod air_shower;
pub mod command_interface;
mod device;
#[cfg(test)]
mod drive;
pub mod dust_collector;
pub mod faults;
pub mod generic;
pub mod journal;
pub mod library;
pub mod pace;
pub mod plant;
pub mod pty_settings;
pub mod register_map;
pub mod serial_stream;
pub mod server;
pub mod sunspec;
pub mod tcp;
pub mod valve;
pub mod virtual_line;
pub mod wire;

pub use air_shower::AirShower;
pub use command_interface::CommandInterface;
pub use device::{lock, share, Addressing, Reply, SharedDevice, SimDevice};
pub use dust_collector::DustCollector;
pub use faults::{FaultHandle, Faults, Occurrence};
pub use generic::GenericDevice;
pub use journal::{AnswerTiming, Journal, RequestRecord};
pub use library::LibraryDevice;
pub use pace::Pace;
pub use plant::SeedPlant;
pub use register_map::{Raw, RegisterMap};
pub use serial_stream::AsyncSerial;
pub use server::{serve, ServeOptions};
pub use tcp::{Protocol, TcpFaultHandle, TcpFaults, TcpSimulator};
pub use valve::Valve;
pub use virtual_line::VirtualLine;

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use rtu2mqtt_modbus::frame::{Request, Response};

    use super::*;
    use proptest::prelude::*;

    fn any_request() -> impl Strategy<Value = Request> {
        let start = prop_oneof![any::<u16>(), 0u16..0x20, 0x70u16..0xF0, 0x0FF0u16..0x1010];
        prop_oneof![
            (start.clone(), any::<u16>())
                .prop_map(|(start, quantity)| Request::ReadCoils { start, quantity }),
            (start.clone(), any::<u16>())
                .prop_map(|(start, quantity)| Request::ReadHoldingRegisters { start, quantity }),
            (start.clone(), any::<u16>())
                .prop_map(|(start, quantity)| Request::ReadInputRegisters { start, quantity }),
            (start.clone(), any::<u16>())
                .prop_map(|(address, value)| Request::WriteSingleRegister { address, value }),
            (start.clone(), any::<bool>())
                .prop_map(|(address, value)| Request::WriteSingleCoil { address, value }),
            (
                start.clone(),
                proptest::collection::vec(any::<bool>(), 0..40)
            )
                .prop_map(|(start, values)| Request::WriteMultipleCoils { start, values }),
            (start, proptest::collection::vec(any::<u16>(), 0..10))
                .prop_map(|(start, values)| Request::WriteMultipleRegisters { start, values }),
            (1u8..=4, any::<u8>()).prop_map(|(code, object_id)| {
                Request::ReadDeviceIdentification {
                    code: rtu2mqtt_modbus::ReadDeviceIdCode::from_u8(code)
                        .unwrap_or(rtu2mqtt_modbus::ReadDeviceIdCode::Basic),
                    object_id,
                }
            }),
        ]
    }

    proptest! {
        #[test]
        fn devices_answer_any_request_without_panicking(
            requests in proptest::collection::vec(any_request(), 1..20),
            step_ms in 0u64..5000,
        ) {
            let mut devices: Vec<Box<dyn SimDevice>> = vec![
                Box::new(DustCollector::new(1)),
                Box::new(Valve::new(1)),
                Box::new(AirShower::new()),
                Box::new(GenericDevice::from_blocks(
                    &[rtu2mqtt_profile::ReadBlock {
                        name: "all".into(),
                        request: Request::ReadHoldingRegisters { start: 0xFFF0, quantity: 16 },
                        class: rtu2mqtt_profile::PollClass::Fast,
                        used_runs: vec![(0, 16)],
                        reads_linearly: true,
                    }],
                    1,
                )
                .with_identification(vec![
                    rtu2mqtt_modbus::DeviceIdObject::text(0, "Sim"),
                    rtu2mqtt_modbus::DeviceIdObject { id: 0x90, value: vec![0xAB; 200] },
                ])),
            ];
            let start = Instant::now();
            for (i, request) in requests.iter().enumerate() {
                let now = start + std::time::Duration::from_millis(step_ms * i as u64);
                for device in &mut devices {
                    let reply = device.handle(request, now);
                    if let Reply::Normal(Response::HoldingRegisters(words)) = &reply {
                        prop_assert!(words.len() <= 125);
                    }
                }
            }
        }

        #[test]
        fn framing_survives_any_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = wire::request_frame_len(&bytes);
            let _ = wire::decode_request(&bytes);
            let _ = wire::crc_ok(&bytes);
        }
    }
}
