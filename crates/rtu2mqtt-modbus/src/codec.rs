//! Byte work only: RTU frames (address, PDU, CRC) to and from [`Request`] / [`Response`].
//! Master side (encode a request, know its answer's length, decode the answer) and server side
//! (decode a request, encode an answer) for the simulators.
//!
//! Quantities follow the application protocol specification: reads of registers 1..=125,
//! reads of bits 1..=2000, writes of registers 1..=123, writes of coils 1..=1968. A request
//! outside those limits is refused by [`encode_request`] (it could not be framed, or no
//! conforming device would accept it) and by [`decode_request`].

use super::crc::{append_crc, carried_and_computed};
use super::device_id;
use super::frame::{ExceptionCode, FunctionCode, Request, Response, SlaveId};
pub use crate::decode_error::DecodeError;
pub use crate::frame::MAX_FRAME_LEN;

/// Most registers one read may ask for.
pub(crate) const MAX_READ_REGISTERS: u16 = 125;
/// Most bits (coils or discrete inputs) one read may ask for.
pub(crate) const MAX_READ_BITS: u16 = 2000;
/// Most registers one FC10 write may carry.
pub(crate) const MAX_WRITE_REGISTERS: u16 = 123;
/// Most coils one FC0F write may carry.
pub(crate) const MAX_WRITE_COILS: u16 = 1968;

/// Coil value on the wire for ON in FC05.
const COIL_ON: u16 = 0xFF00;
/// Coil value on the wire for OFF in FC05.
const COIL_OFF: u16 = 0x0000;

/// Why a request cannot be put on the wire.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// The request asks for no item, or for more than one frame of its function may carry
    /// (125 registers or 2000 bits read, 123 registers or 1968 coils written).
    #[error("{function:?}: quantity {quantity} outside 1..={max}")]
    QuantityOutOfRange {
        /// The request's function.
        function: FunctionCode,
        /// Items (coils or registers) the request asks for.
        quantity: usize,
        /// Most items the function allows.
        max: u16,
    },
}

/// A decoded answer: a device's exception is an answer, not a transport error.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Answer {
    /// The normal answer, checked against the request.
    Normal(Response),
    /// The device's exception answer (function | 0x80) with its code.
    Exception(ExceptionCode),
}

/// Length of an exception answer frame: address, function | 0x80, code, CRC.
pub(crate) const EXCEPTION_FRAME_LEN: usize = 5;

/// Bytes needed to carry `bits` bits, eight to a byte.
fn bit_bytes(bits: usize) -> usize {
    bits.div_ceil(8)
}

/// Packs bits eight to a byte, first bit in the least significant position.
fn pack_bits(bits: &[bool]) -> Vec<u8> {
    let mut bytes = vec![0u8; bit_bytes(bits.len())];
    for (index, _) in bits.iter().enumerate().filter(|(_, on)| **on) {
        bytes[index / 8] |= 1 << (index % 8);
    }
    bytes
}

/// Unpacks exactly `count` bits (padding bits of the last byte are dropped).
fn unpack_bits(bytes: &[u8], count: usize) -> Vec<bool> {
    (0..count)
        .map(|index| {
            bytes
                .get(index / 8)
                .is_some_and(|byte| byte & (1 << (index % 8)) != 0)
        })
        .collect()
}

fn words_to_bytes(words: &[u16]) -> Vec<u8> {
    words.iter().flat_map(|word| word.to_be_bytes()).collect()
}

fn bytes_to_words(bytes: &[u8]) -> Vec<u16> {
    bytes
        .chunks_exact(2)
        .map(|pair| u16::from_be_bytes([pair[0], pair[1]]))
        .collect()
}

fn be16(bytes: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([bytes[at], bytes[at + 1]])
}

fn check_quantity(function: FunctionCode, quantity: usize, max: u16) -> Result<(), EncodeError> {
    if quantity == 0 || quantity > usize::from(max) {
        Err(EncodeError::QuantityOutOfRange {
            function,
            quantity,
            max,
        })
    } else {
        Ok(())
    }
}

/// Checks a request's quantity against the specification's limits.
fn validate_request(request: &Request) -> Result<(), EncodeError> {
    let function = request.function();
    match request {
        Request::ReadCoils { quantity, .. } | Request::ReadDiscreteInputs { quantity, .. } => {
            check_quantity(function, usize::from(*quantity), MAX_READ_BITS)
        }
        Request::ReadHoldingRegisters { quantity, .. }
        | Request::ReadInputRegisters { quantity, .. } => {
            check_quantity(function, usize::from(*quantity), MAX_READ_REGISTERS)
        }
        Request::WriteSingleCoil { .. }
        | Request::WriteSingleRegister { .. }
        | Request::ReadDeviceIdentification { .. } => Ok(()),
        Request::WriteMultipleCoils { values, .. } => {
            check_quantity(function, values.len(), MAX_WRITE_COILS)
        }
        Request::WriteMultipleRegisters { values, .. } => {
            check_quantity(function, values.len(), MAX_WRITE_REGISTERS)
        }
    }
}

fn coil_word(value: bool) -> u16 {
    if value {
        COIL_ON
    } else {
        COIL_OFF
    }
}

/// The RTU frame of `request` to `slave`, CRC included. Refuses quantities outside the
/// specification's limits (see the module documentation) instead of sending a frame no device
/// should accept.
pub fn encode_request(slave: SlaveId, request: &Request) -> Result<Vec<u8>, EncodeError> {
    validate_request(request)?;
    let mut frame = Vec::with_capacity(request.frame_len());
    frame.push(slave);
    frame.push(request.function().value());
    match request {
        Request::ReadCoils { start, quantity }
        | Request::ReadDiscreteInputs { start, quantity }
        | Request::ReadHoldingRegisters { start, quantity }
        | Request::ReadInputRegisters { start, quantity } => {
            frame.extend_from_slice(&start.to_be_bytes());
            frame.extend_from_slice(&quantity.to_be_bytes());
        }
        Request::WriteSingleCoil { address, value } => {
            frame.extend_from_slice(&address.to_be_bytes());
            frame.extend_from_slice(&coil_word(*value).to_be_bytes());
        }
        Request::WriteSingleRegister { address, value } => {
            frame.extend_from_slice(&address.to_be_bytes());
            frame.extend_from_slice(&value.to_be_bytes());
        }
        Request::WriteMultipleCoils { start, values } => {
            let packed = pack_bits(values);
            frame.extend_from_slice(&start.to_be_bytes());
            // Validated above: at most 1968 coils, 246 bytes.
            frame.extend_from_slice(&(values.len() as u16).to_be_bytes());
            frame.push(packed.len() as u8);
            frame.extend_from_slice(&packed);
        }
        Request::WriteMultipleRegisters { start, values } => {
            frame.extend_from_slice(&start.to_be_bytes());
            // Validated above: at most 123 registers, 246 bytes.
            frame.extend_from_slice(&(values.len() as u16).to_be_bytes());
            frame.push((values.len() * 2) as u8);
            frame.extend_from_slice(&words_to_bytes(values));
        }
        Request::ReadDeviceIdentification { code, object_id } => {
            frame.extend_from_slice(&device_id::request_data(*code, *object_id));
        }
    }
    append_crc(&mut frame);
    Ok(frame)
}

/// Decodes a complete answer frame to `request` sent to `slave`.
///
/// Checks in wire order: address, exception flag, length (a read's byte count is checked as
/// soon as it is there), CRC, then the content. A write's answer must echo the request.
pub fn decode_answer(
    slave: SlaveId,
    request: &Request,
    frame: &[u8],
) -> Result<Answer, DecodeError> {
    decode_answer_with(slave, request, frame, Trailer::Crc)
}

/// [`decode_answer`] of an answer without a CRC: the unit id and the PDU of a Modbus TCP ADU,
/// whose integrity TCP has checked. The lengths in its errors count no CRC.
pub(crate) fn decode_unit_answer(
    unit: SlaveId,
    request: &Request,
    frame: &[u8],
) -> Result<Answer, DecodeError> {
    decode_answer_with(unit, request, frame, Trailer::None)
}

/// Bytes of a serial frame's CRC.
const CRC_LEN: usize = 2;

/// What follows an answer's PDU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Trailer {
    /// The CRC of a serial line's frame.
    Crc,
    /// Nothing: the frame came inside an ADU.
    None,
}

impl Trailer {
    /// Bytes the frame carries after its PDU.
    fn len(self) -> usize {
        match self {
            Trailer::Crc => CRC_LEN,
            Trailer::None => 0,
        }
    }

    /// The length of a frame counted with a CRC (as [`Request::answer_len`] counts), counted
    /// with this trailer.
    fn frame_len(self, with_crc: usize) -> usize {
        with_crc - CRC_LEN + self.len()
    }
}

fn decode_answer_with(
    slave: SlaveId,
    request: &Request,
    frame: &[u8],
    trailer: Trailer,
) -> Result<Answer, DecodeError> {
    let function = request.function().value();
    // What the request alone tells of the answer's length, until its head is checked.
    let least_len = normal_answer_len(request, &[], trailer)?;
    let Some(&address) = frame.first() else {
        return Err(DecodeError::Truncated {
            needed: least_len,
            got: 0,
        });
    };
    if address != slave {
        return Err(DecodeError::WrongAddress {
            expected: slave,
            found: address,
        });
    }
    let Some(&found_function) = frame.get(1) else {
        return Err(DecodeError::Truncated {
            needed: least_len,
            got: frame.len(),
        });
    };
    let is_exception = found_function == function | 0x80;
    if !is_exception && found_function != function {
        return Err(DecodeError::WrongFunction {
            expected: function,
            found: found_function,
        });
    }
    if !is_exception {
        if let (Some(expected), Some(&count)) = (request.answer_data_len(), frame.get(2)) {
            if usize::from(count) != expected {
                return Err(DecodeError::WrongByteCount {
                    expected,
                    found: usize::from(count),
                });
            }
        }
    }
    let needed = if is_exception {
        trailer.frame_len(EXCEPTION_FRAME_LEN)
    } else {
        normal_answer_len(request, frame, trailer)?
    };
    if frame.len() < needed {
        return Err(DecodeError::Truncated {
            needed,
            got: frame.len(),
        });
    }
    if frame.len() > needed {
        return Err(DecodeError::Malformed("answer longer than expected"));
    }
    if trailer == Trailer::Crc {
        check_crc(frame)?;
    }
    if is_exception {
        return Ok(Answer::Exception(ExceptionCode::from_u8(frame[2])));
    }
    let data_end = frame.len() - trailer.len();
    decode_answer_pdu(request, &frame[..data_end]).map(Answer::Normal)
}

/// The length of the normal answer to `request`, counted with `trailer`: from the request, or
/// for Read Device Identification from the answer's own bytes in `frame` (as far as they
/// tell: more than `frame` holds while its objects have not all arrived).
fn normal_answer_len(
    request: &Request,
    frame: &[u8],
    trailer: Trailer,
) -> Result<usize, DecodeError> {
    match request {
        Request::ReadDeviceIdentification { .. } => {
            let pdu = frame.get(1..).unwrap_or_default();
            Ok(1 + device_id::answer_pdu_len(pdu)? + trailer.len())
        }
        _ => Ok(trailer.frame_len(request.answer_len())),
    }
}

fn check_crc(frame: &[u8]) -> Result<(), DecodeError> {
    match carried_and_computed(frame) {
        Some((found, computed)) if found == computed => Ok(()),
        Some((found, computed)) => Err(DecodeError::BadCrc { computed, found }),
        None => Err(DecodeError::Truncated {
            needed: 4,
            got: frame.len(),
        }),
    }
}

/// The content of a normal answer of the right length and integrity, `frame` without its CRC.
fn decode_answer_pdu(request: &Request, frame: &[u8]) -> Result<Response, DecodeError> {
    let data_end = frame.len();
    let echo_mismatch = DecodeError::Malformed("write answer does not echo the request");
    Ok(match request {
        Request::ReadCoils { quantity, .. } => {
            Response::Coils(unpack_bits(&frame[3..data_end], usize::from(*quantity)))
        }
        Request::ReadDiscreteInputs { quantity, .. } => {
            Response::DiscreteInputs(unpack_bits(&frame[3..data_end], usize::from(*quantity)))
        }
        Request::ReadHoldingRegisters { .. } => {
            Response::HoldingRegisters(bytes_to_words(&frame[3..data_end]))
        }
        Request::ReadInputRegisters { .. } => {
            Response::InputRegisters(bytes_to_words(&frame[3..data_end]))
        }
        Request::WriteSingleCoil { address, value } => {
            let echoed = Response::WriteSingleCoil {
                address: be16(frame, 2),
                value: parse_coil_word(be16(frame, 4))?,
            };
            if echoed
                != (Response::WriteSingleCoil {
                    address: *address,
                    value: *value,
                })
            {
                return Err(echo_mismatch);
            }
            echoed
        }
        Request::WriteSingleRegister { address, value } => {
            let echoed = Response::WriteSingleRegister {
                address: be16(frame, 2),
                value: be16(frame, 4),
            };
            if echoed
                != (Response::WriteSingleRegister {
                    address: *address,
                    value: *value,
                })
            {
                return Err(echo_mismatch);
            }
            echoed
        }
        Request::WriteMultipleCoils { start, values } => {
            let echoed = Response::WriteMultipleCoils {
                start: be16(frame, 2),
                quantity: be16(frame, 4),
            };
            if echoed
                != (Response::WriteMultipleCoils {
                    start: *start,
                    quantity: values.len() as u16,
                })
            {
                return Err(echo_mismatch);
            }
            echoed
        }
        Request::WriteMultipleRegisters { start, values } => {
            let echoed = Response::WriteMultipleRegisters {
                start: be16(frame, 2),
                quantity: be16(frame, 4),
            };
            if echoed
                != (Response::WriteMultipleRegisters {
                    start: *start,
                    quantity: values.len() as u16,
                })
            {
                return Err(echo_mismatch);
            }
            echoed
        }
        Request::ReadDeviceIdentification { code, .. } => Response::DeviceIdentification(
            device_id::decode_answer_pdu(*code, &frame[1..data_end])?,
        ),
    })
}

fn parse_coil_word(word: u16) -> Result<bool, DecodeError> {
    match word {
        COIL_ON => Ok(true),
        COIL_OFF => Ok(false),
        _ => Err(DecodeError::Malformed("coil value neither FF00 nor 0000")),
    }
}

/// Server side: the total length in bytes of the request frame that starts with `head`, once
/// enough of it has arrived to know (`Ok(None)`: need more bytes; `Err`: an unsupported
/// function code, not a request this codec can frame).
pub fn request_frame_len(head: &[u8]) -> Result<Option<usize>, DecodeError> {
    let Some(&code) = head.get(1) else {
        return Ok(None);
    };
    match FunctionCode::from_u8(code) {
        None => Err(DecodeError::Malformed("unsupported function code")),
        Some(FunctionCode::WriteMultipleCoils | FunctionCode::WriteMultipleRegisters) => {
            // Address, function, start, quantity, byte count, data, CRC.
            Ok(head.get(6).map(|&count| 9 + usize::from(count)))
        }
        // Address, function, MEI type, code, object id, CRC.
        Some(FunctionCode::EncapsulatedInterface) => Ok(Some(7)),
        Some(_) => Ok(Some(8)),
    }
}

/// Server side: decodes a complete request frame into the address it was sent to and the
/// request. An error says why the bytes are no request a device should carry out: too short
/// ([`DecodeError::Truncated`]), a bad CRC, or a malformed or unsupported PDU.
pub fn decode_request(frame: &[u8]) -> Result<(SlaveId, Request), DecodeError> {
    let needed = match request_frame_len(frame)? {
        Some(needed) => needed,
        None => {
            return Err(DecodeError::Truncated {
                needed: 8,
                got: frame.len(),
            })
        }
    };
    if frame.len() < needed {
        return Err(DecodeError::Truncated {
            needed,
            got: frame.len(),
        });
    }
    if frame.len() > needed {
        return Err(DecodeError::Malformed(
            "request longer than its function's frame",
        ));
    }
    check_crc(frame)?;
    let slave = frame[0];
    if frame[1] == FunctionCode::EncapsulatedInterface.value() {
        let (code, object_id) = device_id::parse_request_data(&frame[2..needed - 2])?;
        return Ok((slave, Request::ReadDeviceIdentification { code, object_id }));
    }
    let first = be16(frame, 2);
    let second = be16(frame, 4);
    let bad_quantity = DecodeError::Malformed("quantity outside the specification's range");
    let in_range = |quantity: u16, max: u16| (1..=max).contains(&quantity);
    let request = match FunctionCode::from_u8(frame[1]) {
        Some(FunctionCode::ReadCoils) if in_range(second, MAX_READ_BITS) => Request::ReadCoils {
            start: first,
            quantity: second,
        },
        Some(FunctionCode::ReadDiscreteInputs) if in_range(second, MAX_READ_BITS) => {
            Request::ReadDiscreteInputs {
                start: first,
                quantity: second,
            }
        }
        Some(FunctionCode::ReadHoldingRegisters) if in_range(second, MAX_READ_REGISTERS) => {
            Request::ReadHoldingRegisters {
                start: first,
                quantity: second,
            }
        }
        Some(FunctionCode::ReadInputRegisters) if in_range(second, MAX_READ_REGISTERS) => {
            Request::ReadInputRegisters {
                start: first,
                quantity: second,
            }
        }
        Some(FunctionCode::WriteSingleCoil) => Request::WriteSingleCoil {
            address: first,
            value: parse_coil_word(second)?,
        },
        Some(FunctionCode::WriteSingleRegister) => Request::WriteSingleRegister {
            address: first,
            value: second,
        },
        Some(FunctionCode::WriteMultipleCoils) if in_range(second, MAX_WRITE_COILS) => {
            let count = usize::from(frame[6]);
            if count != bit_bytes(usize::from(second)) {
                return Err(DecodeError::WrongByteCount {
                    expected: bit_bytes(usize::from(second)),
                    found: count,
                });
            }
            Request::WriteMultipleCoils {
                start: first,
                values: unpack_bits(&frame[7..7 + count], usize::from(second)),
            }
        }
        Some(FunctionCode::WriteMultipleRegisters) if in_range(second, MAX_WRITE_REGISTERS) => {
            let count = usize::from(frame[6]);
            if count != 2 * usize::from(second) {
                return Err(DecodeError::WrongByteCount {
                    expected: 2 * usize::from(second),
                    found: count,
                });
            }
            Request::WriteMultipleRegisters {
                start: first,
                values: bytes_to_words(&frame[7..7 + count]),
            }
        }
        Some(_) => return Err(bad_quantity),
        None => return Err(DecodeError::Malformed("unsupported function code")),
    };
    Ok((slave, request))
}

/// Server side: the frame of a normal answer.
///
/// Read answers longer than one frame can carry (more than 250 data bytes: over 125 registers
/// or 2000 bits) are cut to that limit so the byte count stays true; a simulator answers only
/// requests [`decode_request`] accepted, which never ask for more.
pub fn encode_answer(slave: SlaveId, response: &Response) -> Vec<u8> {
    let mut frame = vec![slave];
    let push_data = |frame: &mut Vec<u8>, function: FunctionCode, mut data: Vec<u8>| {
        data.truncate(250);
        frame.push(function.value());
        frame.push(data.len() as u8);
        frame.extend_from_slice(&data);
    };
    match response {
        Response::Coils(bits) => push_data(&mut frame, FunctionCode::ReadCoils, pack_bits(bits)),
        Response::DiscreteInputs(bits) => push_data(
            &mut frame,
            FunctionCode::ReadDiscreteInputs,
            pack_bits(bits),
        ),
        Response::HoldingRegisters(words) => push_data(
            &mut frame,
            FunctionCode::ReadHoldingRegisters,
            words_to_bytes(words),
        ),
        Response::InputRegisters(words) => push_data(
            &mut frame,
            FunctionCode::ReadInputRegisters,
            words_to_bytes(words),
        ),
        Response::WriteSingleCoil { address, value } => {
            frame.push(FunctionCode::WriteSingleCoil.value());
            frame.extend_from_slice(&address.to_be_bytes());
            frame.extend_from_slice(&coil_word(*value).to_be_bytes());
        }
        Response::WriteSingleRegister { address, value } => {
            frame.push(FunctionCode::WriteSingleRegister.value());
            frame.extend_from_slice(&address.to_be_bytes());
            frame.extend_from_slice(&value.to_be_bytes());
        }
        Response::WriteMultipleCoils { start, quantity } => {
            frame.push(FunctionCode::WriteMultipleCoils.value());
            frame.extend_from_slice(&start.to_be_bytes());
            frame.extend_from_slice(&quantity.to_be_bytes());
        }
        Response::WriteMultipleRegisters { start, quantity } => {
            frame.push(FunctionCode::WriteMultipleRegisters.value());
            frame.extend_from_slice(&start.to_be_bytes());
            frame.extend_from_slice(&quantity.to_be_bytes());
        }
        Response::DeviceIdentification(answer) => {
            frame.push(FunctionCode::EncapsulatedInterface.value());
            frame.extend_from_slice(&device_id::answer_data(answer));
        }
    }
    append_crc(&mut frame);
    frame
}

/// Server side: the frame of an exception answer to `function`.
pub fn encode_exception(slave: SlaveId, function: u8, code: ExceptionCode) -> Vec<u8> {
    let mut frame = vec![slave, function | 0x80, code.value()];
    append_crc(&mut frame);
    frame
}

/// The bytes of `frame` as spaced upper-case hex, as the documents and logs write frames.
pub fn hex(frame: &[u8]) -> String {
    let mut text = String::with_capacity(frame.len() * 3);
    for (index, byte) in frame.iter().enumerate() {
        if index > 0 {
            text.push(' ');
        }
        text.push_str(&format!("{byte:02X}"));
    }
    text
}
