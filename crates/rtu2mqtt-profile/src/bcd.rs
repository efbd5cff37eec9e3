//! Packed BCD words, the one implementation the profile codecs, the commissioning read and the
//! simulators share: four decimal digits in a 16-bit register, one per nibble, the lowest digit
//! in the lowest nibble (`0x1234` is 1234).

/// Digits one word holds.
pub const WORD_DIGITS: u8 = 4;

/// Why a word is not a BCD number of the expected width.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BcdError {
    /// A nibble above 9.
    NotDecimal,
    /// A non-zero digit above the expected ones.
    TooManyDigits,
}

/// The number in the lowest `digits` digits of `word`; every digit above them must be zero.
/// Nibbles are judged from the highest down, so the first fault found is the one reported.
pub fn decode(word: u16, digits: u8) -> Result<u16, BcdError> {
    let mut value = 0u16;
    for position in (0..WORD_DIGITS).rev() {
        let nibble = (word >> (4 * position)) & 0xF;
        if nibble > 9 {
            return Err(BcdError::NotDecimal);
        }
        if position >= digits && nibble != 0 {
            return Err(BcdError::TooManyDigits);
        }
        value = value * 10 + nibble;
    }
    Ok(value)
}

/// `value` in `digits` BCD digits, or `None` when it needs more of them (or more than a word
/// holds).
pub fn encode(value: u16, digits: u8) -> Option<u16> {
    if digits > WORD_DIGITS || u32::from(value) >= 10u32.pow(u32::from(digits)) {
        return None;
    }
    let mut word = 0u16;
    let mut rest = value;
    for position in 0..digits {
        word |= (rest % 10) << (4 * position);
        rest /= 10;
    }
    Some(word)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn known_words() {
        assert_eq!(encode(1234, 4), Some(0x1234));
        assert_eq!(encode(34, 2), Some(0x0034));
        assert_eq!(encode(0, 0), Some(0));
        assert_eq!(encode(100, 2), None);
        assert_eq!(encode(1, 5), None);
        assert_eq!(decode(0x0012, 4), Ok(12));
        assert_eq!(decode(0x9999, 4), Ok(9999));
        assert_eq!(decode(0x001A, 4), Err(BcdError::NotDecimal));
        assert_eq!(decode(0x0123, 2), Err(BcdError::TooManyDigits));
        // The highest fault wins: a non-decimal nibble above the width is not "too many digits".
        assert_eq!(decode(0xA012, 2), Err(BcdError::NotDecimal));
        assert_eq!(decode(0x100A, 2), Err(BcdError::TooManyDigits));
    }

    proptest! {
        #[test]
        fn every_number_of_up_to_four_digits_round_trips(value in 0u16..10_000, extra in 0u8..=4) {
            let digits = (1..=WORD_DIGITS)
                .find(|&d| u32::from(value) < 10u32.pow(u32::from(d)))
                .unwrap_or(WORD_DIGITS)
                .max(extra);
            let word = encode(value, digits);
            prop_assert!(word.is_some());
            prop_assert_eq!(word.map(|word| decode(word, digits)), Some(Ok(value)));
        }

        #[test]
        fn a_word_decodes_only_when_every_nibble_is_a_digit(word in any::<u16>()) {
            let decimal = (0..4).all(|position| (word >> (4 * position)) & 0xF <= 9);
            prop_assert_eq!(decode(word, WORD_DIGITS).is_ok(), decimal);
        }
    }
}
