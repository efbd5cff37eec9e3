//! What a number is in command text, the same for every numeric field: plain decimal notation,
//! read exactly (a decimal string becomes a scaled integer; no binary floating point on the
//! way), so that whether a value is accepted never depends on its magnitude.
//!
//! The grammar, after blanks around the text are removed: an optional `-`, one or more ASCII
//! digits, and optionally a `.` followed by one or more ASCII digits. Nothing else: no `+`, no
//! exponent (`1e1`), no hex, no `inf`/`nan`, no digit group separators, no `.5` or `5.`.
//! `-0` is zero. This module only reads numbers; the ranges and wording of refusals belong to
//! the codec.

/// A number as written: its sign and its digits, not yet scaled to any precision.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DecimalText<'a> {
    negative: bool,
    whole: &'a str,
    fraction: &'a str,
}

/// Why a number cannot be taken at a given precision.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScaleError {
    /// More decimals than the precision allows (digits other than trailing zeros).
    TooPrecise,
    /// Too large for any field (beyond ±2^127 scaled units).
    TooLarge,
}

impl<'a> DecimalText<'a> {
    /// Reads `text` (blanks around it ignored); None when it is not a number by the grammar.
    pub fn parse(text: &'a str) -> Option<Self> {
        let text = text.trim();
        let (negative, unsigned) = match text.strip_prefix('-') {
            Some(rest) => (true, rest),
            None => (false, text),
        };
        let (whole, fraction) = match unsigned.split_once('.') {
            Some((whole, fraction)) => (whole, Some(fraction)),
            None => (unsigned, None),
        };
        let digits = |part: &str| !part.is_empty() && part.bytes().all(|b| b.is_ascii_digit());
        if !digits(whole) || fraction.is_some_and(|f| !digits(f)) {
            return None;
        }
        Some(DecimalText {
            negative,
            whole,
            fraction: fraction.unwrap_or(""),
        })
    }

    /// How many decimals the number is written with (`12.340` → 3), at most 255.
    pub fn places(&self) -> u8 {
        u8::try_from(self.fraction.len()).unwrap_or(u8::MAX)
    }

    /// The number in units of 10^-`precision` (`12.34` at 2 → 1234), exactly. Trailing zeros
    /// beyond the precision are fine (`12.340`); any other extra digit is refused, whatever the
    /// magnitude.
    pub fn scaled(&self, precision: u8) -> Result<i128, ScaleError> {
        let places = usize::from(precision);
        let (kept, extra) = if self.fraction.len() > places {
            self.fraction.split_at(places)
        } else {
            (self.fraction, "")
        };
        if extra.bytes().any(|b| b != b'0') {
            return Err(ScaleError::TooPrecise);
        }
        let mut scaled: i128 = 0;
        let padding = places - kept.len();
        let digits = self
            .whole
            .bytes()
            .chain(kept.bytes())
            .chain(std::iter::repeat(b'0').take(padding));
        for digit in digits {
            scaled = scaled
                .checked_mul(10)
                .and_then(|s| s.checked_add(i128::from(digit - b'0')))
                .ok_or(ScaleError::TooLarge)?;
        }
        Ok(if self.negative { -scaled } else { scaled })
    }
}

/// Whether `text` is a number by the grammar.
pub fn is_number(text: &str) -> bool {
    DecimalText::parse(text).is_some()
}

/// `text` as an integer of any register width (a u64 counter, an i64): a number whose
/// decimals, if any, are all zeros. None for anything else.
pub fn wide_integer(text: &str) -> Option<i128> {
    DecimalText::parse(text)?.scaled(0).ok()
}

/// `text` as an integer: a number whose decimals, if any, are all zeros (`8`, `8.0`, `-0`).
/// None for anything else (`8.5`, `1e1`, `+8`, an integer beyond i64).
pub fn integer(text: &str) -> Option<i64> {
    let scaled = DecimalText::parse(text)?.scaled(0).ok()?;
    i64::try_from(scaled).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scaled(text: &str, precision: u8) -> Option<Result<i128, ScaleError>> {
        DecimalText::parse(text).map(|number| number.scaled(precision))
    }

    #[test]
    fn the_grammar() {
        for good in [
            "0", "-0", "10", "007", "12.34", "-3.5", " 8 ", "8\n", "9999.994",
        ] {
            assert!(is_number(good), "{good:?}");
        }
        for bad in [
            "", "-", "+8", "1e1", "1E1", "0x10", "inf", "-inf", "NaN", ".5", "5.", "1_000", "1,5",
            "1.2.3", "--1", "٣", "1 000", "8 .5",
        ] {
            assert!(!is_number(bad), "{bad:?}");
        }
    }

    #[test]
    fn scaling_is_exact_at_every_magnitude() {
        assert_eq!(scaled("9999.99", 2), Some(Ok(999_999)));
        assert_eq!(scaled("9999.994", 2), Some(Err(ScaleError::TooPrecise)));
        assert_eq!(scaled("5000.004", 2), Some(Err(ScaleError::TooPrecise)));
        assert_eq!(scaled("12.345", 2), Some(Err(ScaleError::TooPrecise)));
        assert_eq!(scaled("12.340", 2), Some(Ok(1234)));
        assert_eq!(scaled("12.3", 2), Some(Ok(1230)));
        assert_eq!(scaled("-0.01", 2), Some(Ok(-1)));
        assert_eq!(scaled("-0", 0), Some(Ok(0)));
        assert_eq!(scaled("0.1", 1), Some(Ok(1)));
        let huge = "9".repeat(60);
        assert_eq!(scaled(&huge, 0), Some(Err(ScaleError::TooLarge)));
    }

    #[test]
    fn integers_take_no_fraction() {
        assert_eq!(integer("10"), Some(10));
        assert_eq!(integer("8.0"), Some(8));
        assert_eq!(integer("-0"), Some(0));
        assert_eq!(integer("8.5"), None);
        assert_eq!(integer("1e1"), None);
        assert_eq!(integer("+8"), None);
        assert_eq!(integer("99999999999999999999"), None);
    }
}
