//! The simulators' side of the wire: server-side framing (how long is the request that starts
//! with these bytes, decode it, encode an answer or an exception) and the character timing the
//! simulated line paces itself with.
//!
//! It is written apart from `crate::rtu::codec` on purpose: the simulated devices are test
//! equipment for the gateway, so a framing bug in the gateway's codec must show up as a failed
//! transaction against them, not be mirrored by them.

use std::time::Duration;

use crate::rtu::frame::{ExceptionCode, Request, Response, SlaveId};
use crate::rtu::timing::{CharFormat, Parity};

const MODBUS_CRC: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_MODBUS);

/// CRC-16/MODBUS of `bytes`; on the wire it goes low byte first.
pub fn crc16(bytes: &[u8]) -> u16 {
    MODBUS_CRC.checksum(bytes)
}

/// `body` followed by its CRC, low byte first.
pub fn with_crc(mut body: Vec<u8>) -> Vec<u8> {
    let crc = crc16(&body);
    body.extend_from_slice(&crc.to_le_bytes());
    body
}

/// True when the last two bytes of `frame` are the CRC of the rest.
pub fn crc_ok(frame: &[u8]) -> bool {
    if frame.len() < 4 {
        return false;
    }
    let (body, tail) = frame.split_at(frame.len() - 2);
    crc16(body).to_le_bytes() == [tail[0], tail[1]]
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
    let request = match function {
        0x01..=0x06 => {
            fixed(4)?;
            let (a, b) = (
                word(0).ok_or(RequestError::Malformed)?,
                word(2).ok_or(RequestError::Malformed)?,
            );
            match function {
                0x01 => Request::ReadCoils {
                    start: a,
                    quantity: b,
                },
                0x02 => Request::ReadDiscreteInputs {
                    start: a,
                    quantity: b,
                },
                0x03 => Request::ReadHoldingRegisters {
                    start: a,
                    quantity: b,
                },
                0x04 => Request::ReadInputRegisters {
                    start: a,
                    quantity: b,
                },
                0x05 => match b {
                    0xFF00 => Request::WriteSingleCoil {
                        address: a,
                        value: true,
                    },
                    0x0000 => Request::WriteSingleCoil {
                        address: a,
                        value: false,
                    },
                    _ => return Err(RequestError::Malformed),
                },
                _ => Request::WriteSingleRegister {
                    address: a,
                    value: b,
                },
            }
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
        other => return Err(RequestError::UnknownFunction(other)),
    };
    Ok((address, request))
}

fn pack_bits(bits: &[bool]) -> Vec<u8> {
    let mut bytes = vec![0u8; bits.len().div_ceil(8)];
    for (i, _) in bits.iter().enumerate().filter(|(_, on)| **on) {
        bytes[i / 8] |= 1 << (i % 8);
    }
    bytes
}

/// The frame of a normal answer from `address`.
pub fn encode_answer(address: SlaveId, response: &Response) -> Vec<u8> {
    let mut body = vec![address];
    match response {
        Response::Coils(bits) | Response::DiscreteInputs(bits) => {
            body.push(if matches!(response, Response::Coils(_)) {
                0x01
            } else {
                0x02
            });
            let packed = pack_bits(bits);
            // Quantities are bounded by the devices (≤ 2000 bits), so the count fits a byte.
            body.push(packed.len() as u8);
            body.extend_from_slice(&packed);
        }
        Response::HoldingRegisters(words) | Response::InputRegisters(words) => {
            body.push(if matches!(response, Response::HoldingRegisters(_)) {
                0x03
            } else {
                0x04
            });
            body.push((words.len() * 2) as u8);
            for word in words {
                body.extend_from_slice(&word.to_be_bytes());
            }
        }
        Response::WriteSingleCoil { address, value } => {
            body.push(0x05);
            body.extend_from_slice(&address.to_be_bytes());
            body.extend_from_slice(&(if *value { 0xFF00u16 } else { 0 }).to_be_bytes());
        }
        Response::WriteSingleRegister { address, value } => {
            body.push(0x06);
            body.extend_from_slice(&address.to_be_bytes());
            body.extend_from_slice(&value.to_be_bytes());
        }
        Response::WriteMultipleCoils { start, quantity } => {
            body.push(0x0F);
            body.extend_from_slice(&start.to_be_bytes());
            body.extend_from_slice(&quantity.to_be_bytes());
        }
        Response::WriteMultipleRegisters { start, quantity } => {
            body.push(0x10);
            body.extend_from_slice(&start.to_be_bytes());
            body.extend_from_slice(&quantity.to_be_bytes());
        }
    }
    with_crc(body)
}

/// The frame of an exception answer from `address` to `function`.
pub fn encode_exception(address: SlaveId, function: u8, code: ExceptionCode) -> Vec<u8> {
    with_crc(vec![address, function | 0x80, code.value()])
}

/// The timing of the simulated line: the wire time of frames and the t3.5 silence, from the
/// baud rate and the character format (start bit + data + parity + stop bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WireTiming {
    pub baud: u32,
    pub format: CharFormat,
}

impl WireTiming {
    pub fn new(baud: u32, parity: Parity) -> Self {
        Self {
            baud: baud.max(1),
            format: CharFormat {
                data_bits: 8,
                parity,
                stop_bits: 1,
            },
        }
    }

    /// Bits per character on the wire.
    pub fn bits_per_char(&self) -> u32 {
        let parity = u32::from(self.format.parity != Parity::None);
        1 + u32::from(self.format.data_bits) + parity + u32::from(self.format.stop_bits)
    }

    pub fn char_time(&self) -> Duration {
        Duration::from_nanos(u64::from(self.bits_per_char()) * 1_000_000_000 / u64::from(self.baud))
    }

    /// Wire time of `bytes` characters sent back to back.
    pub fn frame_time(&self, bytes: usize) -> Duration {
        self.char_time() * bytes as u32
    }

    /// The silence that ends a frame: 3.5 characters, fixed at 1.75 ms above 19200 baud as the
    /// serial-line specification recommends.
    pub fn t3_5(&self) -> Duration {
        if self.baud > 19_200 {
            Duration::from_micros(1750)
        } else {
            self.char_time() * 7 / 2
        }
    }
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
    fn golden_answers_encode() {
        assert_eq!(
            encode_answer(
                0x81,
                &Response::WriteMultipleCoils {
                    start: 0,
                    quantity: 12
                }
            ),
            hex("81 0F 00 00 00 0C 4A 0E")
        );
        let mut bits = vec![false; 22];
        bits[8] = true;
        assert_eq!(
            encode_answer(0x81, &Response::Coils(bits)),
            hex("81 01 03 00 01 00 22 1E")
        );
        assert_eq!(
            encode_exception(0x81, 0x0F, ExceptionCode::IllegalFunction),
            hex("81 8F 01 84 18")
        );
        assert_eq!(
            encode_exception(0x81, 0x0F, ExceptionCode::IllegalDataAddress),
            hex("81 8F 02 C4 19")
        );
        assert_eq!(
            encode_exception(0x81, 0x0F, ExceptionCode::IllegalDataValue),
            hex("81 8F 03 05 D9")
        );
    }

    #[test]
    fn timing_of_9600_8n1_and_8e1() {
        let n1 = WireTiming::new(9600, Parity::None);
        assert_eq!(n1.bits_per_char(), 10);
        assert_eq!(n1.frame_time(8), Duration::from_nanos(8 * 1_041_666));
        assert_eq!(n1.t3_5(), Duration::from_nanos(1_041_666 * 7 / 2));
        let e1 = WireTiming::new(9600, Parity::Even);
        assert_eq!(e1.bits_per_char(), 11);
        assert_eq!(
            WireTiming::new(38_400, Parity::None).t3_5(),
            Duration::from_micros(1750)
        );
    }

    #[test]
    fn malformed_and_unknown_requests_are_errors() {
        assert_eq!(
            decode_request(&with_crc(vec![1, 0x2B, 0x0E, 0x01])),
            Err(RequestError::UnknownFunction(0x2B))
        );
        // byte count disagrees with the quantity
        assert_eq!(
            decode_request(&with_crc(vec![1, 0x10, 0, 0, 0, 2, 2, 0, 1])),
            Err(RequestError::Malformed)
        );
        assert_eq!(decode_request(&[1, 3]), Err(RequestError::Malformed));
    }
}
