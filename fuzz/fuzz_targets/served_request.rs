//! Modbus requests as a served line (`[lines.serve]`) reads them from a client's connection:
//! framing (Modbus TCP or RTU over TCP), the access policy, the pipeline and the answers'
//! order, with a stand-in for the line that plans client writes through the line's own policy
//! and answers every request. The seed plant's profiles are at addresses 1, 2 and 0x81. Input:
//! a byte of options (framing, access), then the client's bytes (seeds: the golden request
//! frames, as RTU and as ADUs).
//!
//! Asserted: the connection ends; under `read-only` no write reaches the line, and under
//! `profile` and `read-only` only reads inside a device's declared blocks and writes to a
//! device of the line do; a write the policy plans sets only fields the profile lets be
//! written, to values it accepts; in Modbus TCP every request framed is answered by one
//! well-formed ADU.

#![no_main]

use std::cell::RefCell;
use std::sync::Arc;

use libfuzzer_sys::fuzz_target;
use rtu2mqtt::bus::serve::fuzzing::{serve_bytes, Served};
use rtu2mqtt::bus::serve::{Access, ServeFraming};
use rtu2mqtt_fuzz::{seed_profiles, Input};
use rtu2mqtt_modbus::tcp::mbap::{self, Header};
use rtu2mqtt_modbus::SlaveId;
use rtu2mqtt_profile::Profile;

const ADDRESSES: [SlaveId; 3] = [1, 2, 0x81];

thread_local! {
    /// A runtime whose clock runs only when every task waits, so that the server's patience
    /// (a torn frame, an answer not taken) costs no time and gives the same run every time.
    static RUNTIME: RefCell<tokio::runtime::Runtime> = RefCell::new(
        tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .start_paused(true)
            .build()
            .expect("a runtime"),
    );
}

fuzz_target!(|data: &[u8]| {
    let mut input = Input::new(data);
    let options = input.u8();
    let framing = if options & 1 == 0 {
        ServeFraming::ModbusTcp
    } else {
        ServeFraming::RawRtu
    };
    let access = match (options >> 1) % 3 {
        0 => Access::Profile,
        1 => Access::ReadOnly,
        _ => Access::Raw,
    };
    let devices: Vec<(SlaveId, Arc<Profile>)> = ADDRESSES
        .iter()
        .zip(seed_profiles())
        .map(|(&address, (_, profile))| (address, Arc::clone(profile)))
        .collect();
    let client = input.rest();
    let served = RUNTIME.with(|runtime| {
        runtime
            .borrow()
            .block_on(serve_bytes(framing, access, &devices, client))
    });
    check(&served, access, framing, &devices);
});

fn check(
    served: &Served,
    access: Access,
    framing: ServeFraming,
    devices: &[(SlaveId, Arc<Profile>)],
) {
    for on_line in &served.on_line {
        let request = &on_line.request;
        if access == Access::Raw {
            continue;
        }
        let profile = devices
            .iter()
            .find(|(address, _)| *address == on_line.unit)
            .map(|(_, profile)| profile)
            .unwrap_or_else(|| panic!("{request:?} to unit {} reached the line", on_line.unit));
        if request.is_read() {
            assert!(
                profile
                    .read_blocks()
                    .iter()
                    .any(|b| b.request.covers(request)),
                "{request:?} outside the blocks reached the line"
            );
            continue;
        }
        assert_eq!(
            access,
            Access::Profile,
            "{request:?} reached a read-only line"
        );
        let Some(Ok(targets)) = &on_line.planned else {
            continue;
        };
        for (field, text) in targets {
            let info = profile
                .field(field)
                .unwrap_or_else(|| panic!("{request:?} planned for no field {field}"));
            assert!(info.writable, "{request:?} writes read-only {field}");
            assert!(
                profile.parse_value(field, text).is_ok(),
                "{request:?} sets {field} to {text}, refused by its profile"
            );
        }
    }
    if framing == ServeFraming::ModbusTcp {
        let mut rest = served.answers.as_slice();
        let mut answers = 0;
        while !rest.is_empty() {
            let header = Header::decode(rest).expect("an answer's MBAP header");
            let length = header.adu_len();
            assert!(length <= rest.len(), "a torn answer ADU");
            let (adu, after) = rest.split_at(length);
            let (_, rtu) = mbap::adu_to_rtu(adu).expect("a whole answer ADU");
            assert!(rtu.len() >= 5, "an answer without a PDU");
            rest = after;
            answers += 1;
        }
        assert_eq!(
            answers, served.requests,
            "answers for {} requests ({})",
            served.requests, served.end
        );
    }
}
