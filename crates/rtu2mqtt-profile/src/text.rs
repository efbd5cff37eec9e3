//! The `string` codec's text: characters packed two to a register, in ASCII or UTF-8, with the
//! trailing NUL and space padding devices fill a fixed-size field with removed. Bytes that are
//! not valid text are refused, never replaced, so a garbled answer is never published as text.

use serde::Deserialize;

use super::registers::ByteOrder;

/// How the bytes of a `string` field are read as text.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum Encoding {
    /// Seven-bit ASCII; any byte above 0x7F is invalid data.
    #[default]
    Ascii,
    /// UTF-8; an invalid sequence is invalid data.
    Utf8,
}

/// Why registers do not hold text.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum TextError {
    #[error("byte {byte:#04x} at position {position} is not ASCII")]
    NotAscii { byte: u8, position: usize },
    #[error("the bytes are not valid UTF-8 (from position {0})")]
    NotUtf8(usize),
}

/// The text in `words`: the first character in the high byte of the first register
/// (`ByteOrder::HighFirst`) or in its low byte (`ByteOrder::LowFirst`). Trailing NULs and
/// The text ends at the first NUL (a device that writes a shorter text over a longer one
/// leaves the old bytes behind it); trailing spaces are padding and removed.
pub(crate) fn decode(
    words: &[u16],
    order: ByteOrder,
    encoding: Encoding,
) -> Result<String, TextError> {
    let bytes: Vec<u8> = words
        .iter()
        .flat_map(|word| match order {
            ByteOrder::HighFirst => word.to_be_bytes(),
            ByteOrder::LowFirst => word.to_le_bytes(),
        })
        .collect();
    let terminated = bytes.iter().position(|b| *b == 0).unwrap_or(bytes.len());
    let end = bytes[..terminated]
        .iter()
        .rposition(|b| *b != b' ')
        .map_or(0, |last| last + 1);
    let kept = &bytes[..end];
    match encoding {
        Encoding::Ascii => {
            if let Some(position) = kept.iter().position(|b| !b.is_ascii()) {
                return Err(TextError::NotAscii {
                    byte: kept[position],
                    position,
                });
            }
            Ok(kept.iter().map(|b| char::from(*b)).collect())
        }
        Encoding::Utf8 => std::str::from_utf8(kept)
            .map(str::to_string)
            .map_err(|error| TextError::NotUtf8(error.valid_up_to())),
    }
}

/// `text` in `registers` registers, padded with NULs: the device side of [`decode`], for
/// simulators and tests. None when the text does not fit.
pub(crate) fn encode(text: &str, registers: u16, order: ByteOrder) -> Option<Vec<u16>> {
    let capacity = 2 * usize::from(registers);
    let mut bytes = text.as_bytes().to_vec();
    if bytes.len() > capacity {
        return None;
    }
    bytes.resize(capacity, 0);
    Some(
        bytes
            .chunks(2)
            .map(|pair| match order {
                ByteOrder::HighFirst => u16::from_be_bytes([pair[0], pair[1]]),
                ByteOrder::LowFirst => u16::from_le_bytes([pair[0], pair[1]]),
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_sunspec_manufacturer_name() {
        // SunSpec model 1 `Mn`, 16 registers: "Fronius" then NUL padding.
        let mut words = vec![0x4672, 0x6F6E, 0x6975, 0x7300];
        words.resize(16, 0);
        assert_eq!(
            decode(&words, ByteOrder::HighFirst, Encoding::Ascii),
            Ok("Fronius".to_string())
        );
        assert_eq!(encode("Fronius", 16, ByteOrder::HighFirst), Some(words));
    }

    #[test]
    fn swapped_bytes_and_space_padding() {
        // "SDM630" with the low byte first, padded with spaces.
        let words = [0x4453, 0x364D, 0x3033, 0x2020];
        assert_eq!(
            decode(&words, ByteOrder::LowFirst, Encoding::Ascii),
            Ok("SDM630".to_string())
        );
        assert_eq!(
            decode(&words, ByteOrder::HighFirst, Encoding::Ascii),
            Ok("DS6M03".to_string())
        );
    }

    #[test]
    fn empty_registers_are_empty_text() {
        assert_eq!(
            decode(&[0, 0x2020], ByteOrder::HighFirst, Encoding::Ascii),
            Ok(String::new())
        );
    }

    #[test]
    fn bytes_that_are_not_text_are_refused() {
        // "Zähler" in UTF-8 is valid UTF-8 but not ASCII.
        let words = encode("Zähler", 4, ByteOrder::HighFirst).unwrap_or_default();
        assert_eq!(
            decode(&words, ByteOrder::HighFirst, Encoding::Utf8),
            Ok("Zähler".to_string())
        );
        assert_eq!(
            decode(&words, ByteOrder::HighFirst, Encoding::Ascii),
            Err(TextError::NotAscii {
                byte: 0xC3,
                position: 1
            })
        );
        // A lone continuation byte and a truncated sequence.
        assert_eq!(
            decode(&[0x4180, 0x4200], ByteOrder::HighFirst, Encoding::Utf8),
            Err(TextError::NotUtf8(1))
        );
        assert_eq!(
            decode(&[0x41E2, 0x8200], ByteOrder::HighFirst, Encoding::Utf8),
            Err(TextError::NotUtf8(1))
        );
        // The text ends at its first NUL, whatever an older text left behind it.
        assert_eq!(
            decode(&[0x4100, 0x4200], ByteOrder::HighFirst, Encoding::Ascii),
            Ok("A".to_string())
        );
        assert_eq!(
            decode(
                &[0x4142, 0x2000, 0xFFFF],
                ByteOrder::HighFirst,
                Encoding::Ascii
            ),
            Ok("AB".to_string())
        );
    }

    proptest! {
        #[test]
        fn any_registers_decode_or_are_refused_without_panicking(
            words in proptest::collection::vec(any::<u16>(), 1..20),
            low_first in any::<bool>(),
            utf8 in any::<bool>(),
        ) {
            let order = if low_first { ByteOrder::LowFirst } else { ByteOrder::HighFirst };
            let encoding = if utf8 { Encoding::Utf8 } else { Encoding::Ascii };
            if let Ok(text) = decode(&words, order, encoding) {
                prop_assert!(!text.ends_with(['\0', ' ']));
                prop_assert!(encoding == Encoding::Utf8 || text.is_ascii());
            }
        }

        #[test]
        fn text_round_trips(text in "[ -~]{0,12}[!-~]|\\PC{0,5}[^\\s\\x00]", low_first in any::<bool>()) {
            let order = if low_first { ByteOrder::LowFirst } else { ByteOrder::HighFirst };
            let registers = u16::try_from(text.len().div_ceil(2)).unwrap_or(u16::MAX).max(1);
            let words = encode(&text, registers, order);
            prop_assert!(words.is_some());
            let words = words.unwrap_or_default();
            prop_assert_eq!(decode(&words, order, Encoding::Utf8), Ok(text.clone()));
            if text.is_ascii() {
                prop_assert_eq!(decode(&words, order, Encoding::Ascii), Ok(text));
            }
        }
    }
}
