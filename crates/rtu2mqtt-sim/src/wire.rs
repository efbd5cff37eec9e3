//! How a simulated device frames and decodes what it hears: the length of the request that
//! starts with some bytes, and its decoding once its CRC is checked. (Answers are encoded with
//! `rtu2mqtt_modbus::codec`.)
//!
//! This is not `rtu2mqtt_modbus::codec::decode_request` on purpose. That one refuses what a master
//! must never send; a device has to hear it and react as the real ones do: a quantity of 0 or
//! above the specification's limit is a request the device answers with exception 03, a
//! function code it does not know is a frame that ends at the next silence and gets
//! exception 01.
//!
//! Read Device Identification (0x2B, MEI type 0x0E) is decoded for the devices that implement
//! it; another MEI type is a function the devices do not know, and a read device ID code
//! outside 01–04 a frame they ignore. Keeping the device side apart also keeps it an
//! independent check on the gateway's codec.

use rtu2mqtt_modbus::crc::{append_crc, carried_and_computed};
use rtu2mqtt_modbus::device_id::{ReadDeviceIdCode, MEI_READ_DEVICE_ID};
use rtu2mqtt_modbus::frame::{Request, SlaveId};

/// `body` followed by its CRC, low byte first.
pub fn with_crc(mut body: Vec<u8>) -> Vec<u8> {
    append_crc(&mut body);
    body
}

/// True when the last two bytes of `frame` are the CRC of the rest and there is at least an
/// address and a function code before them.
pub fn crc_ok(frame: &[u8]) -> bool {
    frame.len() >= 4
        && carried_and_computed(frame).is_some_and(|(carried, computed)| carried == computed)
}

/// How a request frame's length is known from its first bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameLen {
    /// Not enough bytes yet to tell.
    NeedMore,
    /// The whole frame is this many bytes.
    Known(usize),
    /// A function code this framer does not know: the frame ends at the next silence.
    UntilSilence,
}

/// The length of the request frame starting with `head` (address, function, …).
pub fn request_frame_len(head: &[u8]) -> FrameLen {
    let Some(&function) = head.get(1) else {
        return FrameLen::NeedMore;
    };
    match function {
        // address, function, start, quantity/value, CRC
        0x01..=0x06 => FrameLen::Known(8),
        // address, function, start, quantity, byte count, data, CRC
        0x0F | 0x10 => match head.get(6) {
            Some(&byte_count) => FrameLen::Known(7 + usize::from(byte_count) + 2),
            None => FrameLen::NeedMore,
        },
        // address, function, MEI type, read device ID code, object id, CRC
        0x2B => FrameLen::Known(7),
        _ => FrameLen::UntilSilence,
    }
}

/// Why a CRC-valid frame is not a request the devices can act on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RequestError {
    /// A function code outside the supported set (the device answers exception 01).
    UnknownFunction(u8),
    /// The frame's inner lengths do not add up (a device stays silent on it).
    Malformed,
}

/// Decodes a complete request frame whose CRC has been checked.
pub fn decode_request(frame: &[u8]) -> Result<(SlaveId, Request), RequestError> {
    if frame.len() < 4 {
        return Err(RequestError::Malformed);
    }
    let address = frame[0];
    let function = frame[1];
    let body = &frame[2..frame.len() - 2];
    let word =
        |i: usize| -> Option<u16> { Some(u16::from_be_bytes([*body.get(i)?, *body.get(i + 1)?])) };
    let fixed = |len: usize| {
        if body.len() == len {
            Ok(())
        } else {
            Err(RequestError::Malformed)
        }
    };
    // FC01..FC06 carry exactly two words: a start and a quantity, or an address and a value.
    let two_words = || -> Result<(u16, u16), RequestError> {
        fixed(4)?;
        Ok((
            word(0).ok_or(RequestError::Malformed)?,
            word(2).ok_or(RequestError::Malformed)?,
        ))
    };
    let request = match function {
        0x01..=0x04 => {
            let (start, quantity) = two_words()?;
            match function {
                0x01 => Request::ReadCoils { start, quantity },
                0x02 => Request::ReadDiscreteInputs { start, quantity },
                0x03 => Request::ReadHoldingRegisters { start, quantity },
                _ => Request::ReadInputRegisters { start, quantity },
            }
        }
        0x05 => {
            let (address, value) = two_words()?;
            let value = match value {
                0xFF00 => true,
                0x0000 => false,
                _ => return Err(RequestError::Malformed),
            };
            Request::WriteSingleCoil { address, value }
        }
        0x06 => {
            let (address, value) = two_words()?;
            Request::WriteSingleRegister { address, value }
        }
        0x0F | 0x10 => {
            let start = word(0).ok_or(RequestError::Malformed)?;
            let quantity = word(2).ok_or(RequestError::Malformed)?;
            let byte_count = usize::from(*body.get(4).ok_or(RequestError::Malformed)?);
            let data = body.get(5..).ok_or(RequestError::Malformed)?;
            if data.len() != byte_count {
                return Err(RequestError::Malformed);
            }
            if function == 0x0F {
                if byte_count != usize::from(quantity).div_ceil(8) {
                    return Err(RequestError::Malformed);
                }
                let values = (0..usize::from(quantity))
                    .map(|i| data[i / 8] & (1 << (i % 8)) != 0)
                    .collect();
                Request::WriteMultipleCoils { start, values }
            } else {
                if byte_count != usize::from(quantity) * 2 {
                    return Err(RequestError::Malformed);
                }
                let values = data
                    .chunks_exact(2)
                    .map(|pair| u16::from_be_bytes([pair[0], pair[1]]))
                    .collect();
                Request::WriteMultipleRegisters { start, values }
            }
        }
        0x2B => match *body {
            [MEI_READ_DEVICE_ID, code, object_id] => Request::ReadDeviceIdentification {
                code: ReadDeviceIdCode::from_u8(code).ok_or(RequestError::Malformed)?,
                object_id,
            },
            [_, _, _] => return Err(RequestError::UnknownFunction(function)),
            _ => return Err(RequestError::Malformed),
        },
        other => return Err(RequestError::UnknownFunction(other)),
    };
    Ok((address, request))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(text: &str) -> Vec<u8> {
        text.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    #[test]
    fn golden_requests_frame_and_decode() {
        let read = hex("01 03 10 00 00 06 C1 08");
        assert!(crc_ok(&read));
        assert_eq!(request_frame_len(&read[..2]), FrameLen::Known(8));
        assert_eq!(
            decode_request(&read).unwrap(),
            (
                1,
                Request::ReadHoldingRegisters {
                    start: 0x1000,
                    quantity: 6
                }
            )
        );
        let fc10 = hex("01 10 10 00 00 04 08 03 00 00 05 00 02 00 0A 25 38");
        assert!(crc_ok(&fc10));
        assert_eq!(request_frame_len(&fc10[..6]), FrameLen::NeedMore);
        assert_eq!(request_frame_len(&fc10[..7]), FrameLen::Known(17));
        assert_eq!(
            decode_request(&fc10).unwrap().1,
            Request::WriteMultipleRegisters {
                start: 0x1000,
                values: vec![0x0300, 5, 2, 10]
            }
        );
        let coils = hex("81 0F 00 00 00 0C 02 0E 01 41 D6");
        assert!(crc_ok(&coils));
        let (address, request) = decode_request(&coils).unwrap();
        assert_eq!(address, 0x81);
        let mut expected = vec![false; 12];
        for i in [1, 2, 3, 8] {
            expected[i] = true;
        }
        assert_eq!(
            request,
            Request::WriteMultipleCoils {
                start: 0,
                values: expected
            }
        );
    }

    #[test]
    fn out_of_spec_quantities_still_decode_for_the_device_to_refuse() {
        assert_eq!(
            decode_request(&with_crc(vec![1, 0x03, 0x10, 0x00, 0x00, 0x00]))
                .unwrap()
                .1,
            Request::ReadHoldingRegisters {
                start: 0x1000,
                quantity: 0
            }
        );
        assert_eq!(
            decode_request(&with_crc(vec![1, 0x01, 0x00, 0x00, 0x08, 0x00]))
                .unwrap()
                .1,
            Request::ReadCoils {
                start: 0,
                quantity: 2048
            }
        );
    }

    #[test]
    fn read_device_identification_frames_and_decodes() {
        // The specification's example request, with pymodbus's CRC on it.
        let basic = hex("01 2B 0E 01 00 70 77");
        assert!(crc_ok(&basic));
        assert_eq!(request_frame_len(&basic[..2]), FrameLen::Known(7));
        assert_eq!(
            decode_request(&basic).unwrap(),
            (
                1,
                Request::ReadDeviceIdentification {
                    code: ReadDeviceIdCode::Basic,
                    object_id: 0
                }
            )
        );
        // Another MEI type (CANopen general reference, 0x0D) is a function no device knows.
        assert_eq!(
            decode_request(&with_crc(vec![1, 0x2B, 0x0D, 0x01, 0x00])),
            Err(RequestError::UnknownFunction(0x2B))
        );
        assert_eq!(
            decode_request(&with_crc(vec![1, 0x2B, 0x0E, 0x07, 0x00])),
            Err(RequestError::Malformed)
        );
    }

    #[test]
    fn malformed_and_unknown_requests_are_errors() {
        assert_eq!(
            decode_request(&with_crc(vec![1, 0x2B, 0x0E, 0x01])),
            Err(RequestError::Malformed)
        );
        assert_eq!(
            decode_request(&with_crc(vec![1, 0x2C, 0x0E, 0x01])),
            Err(RequestError::UnknownFunction(0x2C))
        );
        // byte count disagrees with the quantity
        assert_eq!(
            decode_request(&with_crc(vec![1, 0x10, 0, 0, 0, 2, 2, 0, 1])),
            Err(RequestError::Malformed)
        );
        assert_eq!(decode_request(&[1, 3]), Err(RequestError::Malformed));
    }
}
