//! Properties of the codec: every request and answer survives encode → decode on both sides,
//! and no byte string makes any decoder panic.

use proptest::prelude::*;
use rtu2mqtt_modbus::codec::{
    decode_answer, decode_request, encode_answer, encode_exception, encode_request,
    request_frame_len, Answer, DecodeError,
};
use rtu2mqtt_modbus::{
    DeviceIdObject, DeviceIdentification, ExceptionCode, ReadDeviceIdCode, Request, Response,
};

/// Any in-spec request.
fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        (any::<u16>(), 1u16..=2000)
            .prop_map(|(start, quantity)| Request::ReadCoils { start, quantity }),
        (any::<u16>(), 1u16..=2000)
            .prop_map(|(start, quantity)| Request::ReadDiscreteInputs { start, quantity }),
        (any::<u16>(), 1u16..=125)
            .prop_map(|(start, quantity)| Request::ReadHoldingRegisters { start, quantity }),
        (any::<u16>(), 1u16..=125)
            .prop_map(|(start, quantity)| Request::ReadInputRegisters { start, quantity }),
        (any::<u16>(), any::<bool>())
            .prop_map(|(address, value)| Request::WriteSingleCoil { address, value }),
        (any::<u16>(), any::<u16>())
            .prop_map(|(address, value)| Request::WriteSingleRegister { address, value }),
        (any::<u16>(), prop::collection::vec(any::<bool>(), 1..=1968))
            .prop_map(|(start, values)| Request::WriteMultipleCoils { start, values }),
        (any::<u16>(), prop::collection::vec(any::<u16>(), 1..=123))
            .prop_map(|(start, values)| Request::WriteMultipleRegisters { start, values }),
        (1u8..=4, any::<u8>()).prop_map(|(code, object_id)| {
            Request::ReadDeviceIdentification {
                code: ReadDeviceIdCode::from_u8(code).unwrap_or(ReadDeviceIdCode::Basic),
                object_id,
            }
        }),
    ]
}

/// A request and a normal answer that fits it.
fn request_and_answer() -> impl Strategy<Value = (Request, Response)> {
    request().prop_flat_map(|request| {
        let answer: BoxedStrategy<Response> = match request.clone() {
            Request::ReadCoils { quantity, .. } => {
                prop::collection::vec(any::<bool>(), usize::from(quantity))
                    .prop_map(Response::Coils)
                    .boxed()
            }
            Request::ReadDiscreteInputs { quantity, .. } => {
                prop::collection::vec(any::<bool>(), usize::from(quantity))
                    .prop_map(Response::DiscreteInputs)
                    .boxed()
            }
            Request::ReadHoldingRegisters { quantity, .. } => {
                prop::collection::vec(any::<u16>(), usize::from(quantity))
                    .prop_map(Response::HoldingRegisters)
                    .boxed()
            }
            Request::ReadInputRegisters { quantity, .. } => {
                prop::collection::vec(any::<u16>(), usize::from(quantity))
                    .prop_map(Response::InputRegisters)
                    .boxed()
            }
            Request::WriteSingleCoil { address, value } => {
                Just(Response::WriteSingleCoil { address, value }).boxed()
            }
            Request::WriteSingleRegister { address, value } => {
                Just(Response::WriteSingleRegister { address, value }).boxed()
            }
            Request::WriteMultipleCoils { start, values } => Just(Response::WriteMultipleCoils {
                start,
                quantity: values.len() as u16,
            })
            .boxed(),
            Request::WriteMultipleRegisters { start, values } => {
                Just(Response::WriteMultipleRegisters {
                    start,
                    quantity: values.len() as u16,
                })
                .boxed()
            }
            // Up to four objects of up to 59 bytes: always within one PDU.
            Request::ReadDeviceIdentification { code, .. } => (
                any::<u8>(),
                any::<bool>(),
                any::<u8>(),
                prop::collection::vec(
                    (any::<u8>(), prop::collection::vec(any::<u8>(), 0..60)),
                    0..=4,
                ),
            )
                .prop_map(
                    move |(conformity_level, more_follows, next_object_id, objects)| {
                        Response::DeviceIdentification(DeviceIdentification {
                            code,
                            conformity_level,
                            more_follows,
                            next_object_id,
                            objects: objects
                                .into_iter()
                                .map(|(id, value)| DeviceIdObject { id, value })
                                .collect(),
                        })
                    },
                )
                .boxed(),
        };
        (Just(request), answer)
    })
}

proptest! {
    #[test]
    fn request_round_trip(slave in any::<u8>(), request in request()) {
        let frame = encode_request(slave, &request).unwrap();
        prop_assert!(frame.len() <= 256);
        // The server frames it from its head alone, then decodes it back.
        prop_assert_eq!(request_frame_len(&frame[..frame.len().min(7)]).unwrap(), Some(frame.len()));
        prop_assert_eq!(decode_request(&frame).unwrap(), (slave, request));
    }

    #[test]
    fn answer_round_trip(slave in any::<u8>(), (request, response) in request_and_answer()) {
        let frame = encode_answer(slave, &response);
        if matches!(request, Request::ReadDeviceIdentification { .. }) {
            // Its length is in its bytes; answer_len is the longest it may be.
            prop_assert!(frame.len() <= request.answer_len());
        } else {
            prop_assert_eq!(frame.len(), request.answer_len());
        }
        prop_assert_eq!(decode_answer(slave, &request, &frame).unwrap(), Answer::Normal(response));
    }

    #[test]
    fn exception_round_trip(slave in any::<u8>(), request in request(), code in any::<u8>()) {
        let frame = encode_exception(slave, request.function().value(), ExceptionCode::from_u8(code));
        prop_assert_eq!(decode_answer(slave, &request, &frame).unwrap(), Answer::Exception(ExceptionCode::from_u8(code)));
    }

    #[test]
    fn any_flipped_bit_is_detected(slave in any::<u8>(), (request, response) in request_and_answer(), bit in any::<prop::sample::Index>()) {
        let mut frame = encode_answer(slave, &response);
        let bit = bit.index(frame.len() * 8);
        frame[bit / 8] ^= 1 << (bit % 8);
        prop_assert!(decode_answer(slave, &request, &frame).is_err());
    }

    #[test]
    fn wrong_address_is_named(slave in any::<u8>(), other in any::<u8>(), (request, response) in request_and_answer()) {
        prop_assume!(slave != other);
        let frame = encode_answer(other, &response);
        prop_assert_eq!(
            decode_answer(slave, &request, &frame),
            Err(DecodeError::WrongAddress { expected: slave, found: other })
        );
    }

    #[test]
    fn answer_decoder_never_panics(slave in any::<u8>(), request in request(), bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        let _ = decode_answer(slave, &request, &bytes);
    }

    #[test]
    fn request_decoders_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        let _ = request_frame_len(&bytes);
        let _ = decode_request(&bytes);
    }

    /// Random bytes that look like a request head: the framing and decoding paths past the
    /// function code are reached far more often than with fully random bytes.
    #[test]
    fn request_decoder_never_panics_on_plausible_heads(
        slave in any::<u8>(),
        function in prop::sample::select(vec![1u8, 2, 3, 4, 5, 6, 0x0F, 0x10, 0x2B]),
        rest in prop::collection::vec(any::<u8>(), 0..300),
    ) {
        let mut bytes = vec![slave, function];
        bytes.extend(rest);
        let _ = request_frame_len(&bytes);
        let _ = decode_request(&bytes);
        if let Ok(Some(len)) = request_frame_len(&bytes) {
            let _ = decode_request(&bytes[..len.min(bytes.len())]);
        }
    }

    #[test]
    fn encoders_never_panic_on_out_of_spec_quantities(
        slave in any::<u8>(),
        quantity in any::<u16>(),
        bits in prop::collection::vec(any::<bool>(), 0..5000),
        words in prop::collection::vec(any::<u16>(), 0..400),
    ) {
        for request in [
            Request::ReadCoils { start: 0, quantity },
            Request::ReadHoldingRegisters { start: 0, quantity },
            Request::WriteMultipleCoils { start: 0, values: bits.clone() },
            Request::WriteMultipleRegisters { start: 0, values: words.clone() },
        ] {
            if let Ok(frame) = encode_request(slave, &request) {
                prop_assert_eq!(decode_request(&frame).unwrap(), (slave, request));
            }
        }
        for response in [Response::Coils(bits), Response::HoldingRegisters(words)] {
            let frame = encode_answer(slave, &response);
            prop_assert!(frame.len() <= 256);
            prop_assert_eq!(usize::from(frame[2]) + 5, frame.len());
        }
    }
}

#[test]
fn out_of_spec_quantities_are_refused() {
    for request in [
        Request::ReadCoils {
            start: 0,
            quantity: 0,
        },
        Request::ReadCoils {
            start: 0,
            quantity: 2001,
        },
        Request::ReadHoldingRegisters {
            start: 0,
            quantity: 126,
        },
        Request::ReadInputRegisters {
            start: 0,
            quantity: 0,
        },
        Request::WriteMultipleCoils {
            start: 0,
            values: vec![true; 1969],
        },
        Request::WriteMultipleCoils {
            start: 0,
            values: vec![],
        },
        Request::WriteMultipleRegisters {
            start: 0,
            values: vec![0; 124],
        },
    ] {
        assert!(encode_request(1, &request).is_err(), "{request:?}");
    }
    // Read 126 registers at 0, by hand: the server side refuses it as malformed.
    let mut frame = vec![0x01, 0x03, 0x00, 0x00, 0x00, 126];
    let crc = rtu2mqtt_modbus::crc::crc16(&frame);
    frame.extend(crc.to_le_bytes());
    assert!(matches!(
        decode_request(&frame),
        Err(DecodeError::Malformed(_))
    ));
}

#[test]
fn decode_errors_tell_the_faults_apart() {
    let request = Request::ReadHoldingRegisters {
        start: 0x1000,
        quantity: 2,
    };
    let good = encode_answer(1, &Response::HoldingRegisters(vec![1, 2]));
    assert_eq!(
        decode_answer(1, &request, &good[..5]),
        Err(DecodeError::Truncated { needed: 9, got: 5 })
    );
    let mut bad_crc = good.clone();
    bad_crc[8] ^= 0xFF;
    assert!(matches!(
        decode_answer(1, &request, &bad_crc),
        Err(DecodeError::BadCrc { .. })
    ));
    let wrong_function = encode_answer(1, &Response::InputRegisters(vec![1, 2]));
    assert_eq!(
        decode_answer(1, &request, &wrong_function),
        Err(DecodeError::WrongFunction {
            expected: 0x03,
            found: 0x04
        })
    );
    let wrong_count = encode_answer(1, &Response::HoldingRegisters(vec![1, 2, 3]));
    assert_eq!(
        decode_answer(1, &request, &wrong_count),
        Err(DecodeError::WrongByteCount {
            expected: 4,
            found: 6
        })
    );
    assert_eq!(
        decode_answer(
            1,
            &request,
            &encode_answer(2, &Response::HoldingRegisters(vec![1, 2]))
        ),
        Err(DecodeError::WrongAddress {
            expected: 1,
            found: 2
        })
    );
    let exception = encode_exception(1, 0x03, ExceptionCode::ServerDeviceBusy);
    assert_eq!(
        decode_answer(1, &request, &exception),
        Ok(Answer::Exception(ExceptionCode::ServerDeviceBusy))
    );
    assert_eq!(
        decode_answer(1, &request, &exception[..4]),
        Err(DecodeError::Truncated { needed: 5, got: 4 })
    );
    // A write answer must echo what was written.
    let write = Request::WriteSingleRegister {
        address: 0x1002,
        value: 8,
    };
    let other_value = encode_answer(
        1,
        &Response::WriteSingleRegister {
            address: 0x1002,
            value: 9,
        },
    );
    assert!(matches!(
        decode_answer(1, &write, &other_value),
        Err(DecodeError::Malformed(_))
    ));
}
