//! The closed set of field codecs: bits, bit groups with enumerations, inverted bits, words,
//! scaled numbers, packed BCD integer + fraction pairs, low-byte chars, byte strings, coils.

/// Why a field has no value in a block answer.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FieldError {
    #[error("invalid BCD digit in {0:#06x}")]
    InvalidBcd(u16),
    #[error("{0}")]
    Invalid(String),
}
