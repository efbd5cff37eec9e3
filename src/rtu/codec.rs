//! Byte work only: RTU frames (address, PDU, CRC) to and from [`Request`] / [`Response`].
//! Master side (encode a request, know its answer's length, decode the answer) and server side
//! (decode a request, encode an answer) for the simulators.

use super::frame::{ExceptionCode, Request, Response, SlaveId};

/// Why bytes are not the expected answer. Callers match on it to count and log.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    #[error("answer from address {found}, expected {expected}")]
    WrongAddress { expected: SlaveId, found: SlaveId },
    #[error("answer with function {found:#04x}, expected {expected:#04x}")]
    WrongFunction { expected: u8, found: u8 },
    #[error("byte count {found}, expected {expected}")]
    WrongByteCount { expected: usize, found: usize },
    #[error("bad CRC {found:#06x}, computed {computed:#06x}")]
    BadCrc { computed: u16, found: u16 },
    #[error("truncated frame: {got} of {needed} bytes")]
    Truncated { needed: usize, got: usize },
    #[error("malformed frame: {0}")]
    Malformed(&'static str),
}

/// A decoded answer: a device's exception is an answer, not a transport error.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Answer {
    Normal(Response),
    Exception(ExceptionCode),
}

/// Length of an exception answer frame: address, function | 0x80, code, CRC.
pub const EXCEPTION_FRAME_LEN: usize = 5;

/// The RTU frame of `request` to `slave`, CRC included.
pub fn encode_request(slave: SlaveId, request: &Request) -> Vec<u8> {
    todo!("rtu helper")
}

/// Length in bytes of the normal answer frame to `request` (address and CRC included).
pub fn expected_answer_len(request: &Request) -> usize {
    todo!("rtu helper")
}

/// Decodes a complete answer frame to `request` sent to `slave`.
pub fn decode_answer(
    slave: SlaveId,
    request: &Request,
    frame: &[u8],
) -> Result<Answer, DecodeError> {
    todo!("rtu helper")
}

/// Server side: the total length of the request frame that starts with `head`, once enough of
/// it has arrived to know (None: need more bytes; Err: not a request this codec can frame).
pub fn request_frame_len(head: &[u8]) -> Result<Option<usize>, DecodeError> {
    todo!("rtu helper")
}

/// Server side: decodes a complete request frame.
pub fn decode_request(frame: &[u8]) -> Result<(SlaveId, Request), DecodeError> {
    todo!("rtu helper")
}

/// Server side: the frame of a normal answer.
pub fn encode_answer(slave: SlaveId, response: &Response) -> Vec<u8> {
    todo!("rtu helper")
}

/// Server side: the frame of an exception answer to `function`.
pub fn encode_exception(slave: SlaveId, function: u8, code: ExceptionCode) -> Vec<u8> {
    todo!("rtu helper")
}
