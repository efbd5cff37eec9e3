//! Why bytes are not the answer a request expects: what the codec and the framers report, and
//! the transactions count and log.

/// Why bytes are not the expected answer. Callers match on it to count and log.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// The frame starts with another device's address: not the answer to our request.
    #[error("answer from address {found}, expected {expected}")]
    WrongAddress {
        /// The address the request went to.
        expected: u8,
        /// The address the frame carries.
        found: u8,
    },
    /// The frame answers another function (or is no exception of ours).
    #[error("answer with function {found:#04x}, expected {expected:#04x}")]
    WrongFunction {
        /// The request's function code.
        expected: u8,
        /// The function byte of the frame.
        found: u8,
    },
    /// A read answer's byte count is not the one the request's quantity calls for.
    #[error("byte count {found}, expected {expected}")]
    WrongByteCount {
        /// Data bytes the request asked for.
        expected: usize,
        /// Data bytes the answer announces.
        found: usize,
    },
    /// The CRC carried in the last two bytes is not the CRC of the bytes before them: a
    /// byte was corrupted on the line.
    #[error("bad CRC {found:#06x}, computed {computed:#06x}")]
    BadCrc {
        /// The CRC of the frame's bytes as received.
        computed: u16,
        /// The CRC the frame carries.
        found: u16,
    },
    /// The frame ended before its expected length.
    #[error("truncated frame: {got} of {needed} bytes")]
    Truncated {
        /// Bytes the frame should have.
        needed: usize,
        /// Bytes there are.
        got: usize,
    },
    /// Anything else that cannot be read as the frame expected, with what was wrong: a
    /// function this codec does not frame, a write's answer that does not echo the request,
    /// a coil value other than 0xFF00 or 0x0000, a quantity outside the specification's
    /// limits in a request.
    #[error("malformed frame: {0}")]
    Malformed(&'static str),
}
