//! The `enum` codec: a whole register (or a pair) holding a code, each code named by the
//! profile (`values = { 0 = "waiting", 1 = "normal", 3 = "fault" }`), sparse as devices number
//! their states. A code the profile does not name is either "no value" (`unknown = "invalid"`)
//! or published as the number it is (`unknown = "publish_number"`).

use serde::Deserialize;

use crate::registers::RegisterLayout;
use crate::value::Value;

/// What a code the profile does not name becomes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UnknownCode {
    /// The value is unavailable, like an `invalid` mark: published as unavailable.
    #[default]
    Invalid,
    /// The code itself is published, as a number.
    PublishNumber,
}

/// A compiled `enum` codec.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct EnumCodec {
    /// 1 (a u16 code) or 2 (a u32 code).
    pub(crate) registers: u16,
    pub(crate) layout: RegisterLayout,
    /// The named codes, in ascending code order.
    pub(crate) codes: Vec<(u32, String)>,
    pub(crate) unknown: UnknownCode,
}

impl EnumCodec {
    /// The names, in code order (the field's options).
    pub(crate) fn names(&self) -> Vec<String> {
        self.codes.iter().map(|(_, name)| name.clone()).collect()
    }

    /// The value the code in `words` (the field's registers as read) stands for.
    pub(crate) fn decode(&self, words: &[u16]) -> Value {
        let code = self.layout.join(words) as u32;
        match self.codes.iter().find(|(known, _)| *known == code) {
            Some((_, name)) => Value::Enum(name.clone()),
            None => match self.unknown {
                UnknownCode::Invalid => Value::Unavailable,
                UnknownCode::PublishNumber => Value::Int(i128::from(code)),
            },
        }
    }

    /// The registers, in the order written, that hold the code of `value` (a name; a number
    /// only when it is a named code).
    pub(crate) fn encode(&self, value: &Value) -> Result<Vec<u16>, String> {
        let code = match value {
            Value::Enum(word) => self
                .codes
                .iter()
                .find(|(_, name)| name == word)
                .map(|(code, _)| *code)
                .ok_or_else(|| format!("unknown option `{word}`"))?,
            Value::Int(number) => u32::try_from(*number)
                .ok()
                .filter(|code| self.codes.iter().any(|(known, _)| known == code))
                .ok_or_else(|| format!("{number} is not one of the named codes"))?,
            other => return Err(format!("{other:?} is not one of the named codes")),
        };
        Ok(self.layout.split(u64::from(code), self.registers))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registers::{ByteOrder, WordOrder};

    fn codec(registers: u16, unknown: UnknownCode) -> EnumCodec {
        EnumCodec {
            registers,
            layout: RegisterLayout {
                words: WordOrder::HighFirst,
                bytes: ByteOrder::HighFirst,
            },
            codes: vec![
                (0, "waiting".to_string()),
                (1, "normal".to_string()),
                (3, "fault".to_string()),
                (70_000, "far".to_string()),
            ],
            unknown,
        }
    }

    #[test]
    fn sparse_codes_are_named_and_the_others_follow_unknown() {
        let invalid = codec(1, UnknownCode::Invalid);
        assert_eq!(invalid.decode(&[3]), Value::Enum("fault".to_string()));
        assert_eq!(invalid.decode(&[2]), Value::Unavailable);
        let number = codec(1, UnknownCode::PublishNumber);
        assert_eq!(number.decode(&[2]), Value::Int(2));
        assert_eq!(number.decode(&[0]), Value::Enum("waiting".to_string()));
    }

    #[test]
    fn a_u32_code_spans_two_registers_in_the_word_order() {
        let wide = codec(2, UnknownCode::Invalid);
        assert_eq!(
            wide.decode(&[0x0001, 0x1170]),
            Value::Enum("far".to_string())
        );
        assert_eq!(
            wide.encode(&Value::Enum("far".to_string())),
            Ok(vec![0x0001, 0x1170])
        );
        let mut low_first = wide.clone();
        low_first.layout.words = WordOrder::LowFirst;
        assert_eq!(
            low_first.decode(&[0x1170, 0x0001]),
            Value::Enum("far".to_string())
        );
    }

    #[test]
    fn only_named_codes_are_written() {
        let codec = codec(1, UnknownCode::PublishNumber);
        assert_eq!(codec.encode(&Value::Enum("fault".to_string())), Ok(vec![3]));
        assert_eq!(codec.encode(&Value::Int(1)), Ok(vec![1]));
        assert!(codec.encode(&Value::Int(2)).is_err());
        assert!(codec.encode(&Value::Enum("other".to_string())).is_err());
    }
}
