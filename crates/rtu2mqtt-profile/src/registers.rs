//! How a multi-byte number lies in 16-bit registers: the order of the registers
//! ([`WordOrder`]) and of the two bytes inside each register ([`ByteOrder`]). Together they
//! express every layout devices use: for 32 bits ABCD, CDAB, BADC and DCBA, and their 64-bit
//! counterparts. Pure bit shuffling: no field, value or profile knowledge here.

use serde::Deserialize;

/// Order of the registers of a multi-register value.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum WordOrder {
    /// The first register holds the highest word (Modbus's own order, most devices).
    #[default]
    HighFirst,
    /// The first register holds the lowest word ("word swapped").
    LowFirst,
}

/// Order of the two bytes inside each register.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum ByteOrder {
    /// The high byte comes first on the wire (Modbus's own order).
    #[default]
    HighFirst,
    /// The bytes of every register are swapped.
    LowFirst,
}

/// The layout of a number over `registers` registers.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct RegisterLayout {
    pub(crate) words: WordOrder,
    pub(crate) bytes: ByteOrder,
}

impl RegisterLayout {
    /// The number's bits from its registers as read (`words.len()` is 1, 2 or 4).
    pub(crate) fn join(self, words: &[u16]) -> u64 {
        let swap = |word: u16| match self.bytes {
            ByteOrder::HighFirst => word,
            ByteOrder::LowFirst => word.swap_bytes(),
        };
        let fold = |acc: u64, word: &u16| (acc << 16) | u64::from(swap(*word));
        match self.words {
            WordOrder::HighFirst => words.iter().fold(0, fold),
            WordOrder::LowFirst => words.iter().rev().fold(0, fold),
        }
    }

    /// The registers, in the order they are read and written, that hold the lowest
    /// `16 × count` bits of `bits`.
    pub(crate) fn split(self, bits: u64, count: u16) -> Vec<u16> {
        let mut words: Vec<u16> = (0..count)
            .rev()
            .map(|i| (bits >> (16 * u32::from(i))) as u16)
            .map(|word| match self.bytes {
                ByteOrder::HighFirst => word,
                ByteOrder::LowFirst => word.swap_bytes(),
            })
            .collect();
        if self.words == WordOrder::LowFirst {
            words.reverse();
        }
        words
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const ABCD: RegisterLayout = RegisterLayout {
        words: WordOrder::HighFirst,
        bytes: ByteOrder::HighFirst,
    };
    const CDAB: RegisterLayout = RegisterLayout {
        words: WordOrder::LowFirst,
        bytes: ByteOrder::HighFirst,
    };
    const BADC: RegisterLayout = RegisterLayout {
        words: WordOrder::HighFirst,
        bytes: ByteOrder::LowFirst,
    };
    const DCBA: RegisterLayout = RegisterLayout {
        words: WordOrder::LowFirst,
        bytes: ByteOrder::LowFirst,
    };

    #[test]
    fn the_four_layouts_of_123456789() {
        // 123456789 = 0x075BCD15: A=07 B=5B C=CD D=15.
        let value = 123_456_789u64;
        assert_eq!(ABCD.split(value, 2), [0x075B, 0xCD15]);
        assert_eq!(CDAB.split(value, 2), [0xCD15, 0x075B]);
        assert_eq!(BADC.split(value, 2), [0x5B07, 0x15CD]);
        assert_eq!(DCBA.split(value, 2), [0x15CD, 0x5B07]);
        for (layout, words) in [
            (ABCD, [0x075B, 0xCD15]),
            (CDAB, [0xCD15, 0x075B]),
            (BADC, [0x5B07, 0x15CD]),
            (DCBA, [0x15CD, 0x5B07]),
        ] {
            assert_eq!(layout.join(&words), value, "{layout:?}");
        }
    }

    #[test]
    fn sixty_four_bit_layouts() {
        let value = 0x0102_0304_0506_0708u64;
        assert_eq!(ABCD.split(value, 4), [0x0102, 0x0304, 0x0506, 0x0708]);
        assert_eq!(CDAB.split(value, 4), [0x0708, 0x0506, 0x0304, 0x0102]);
        assert_eq!(BADC.split(value, 4), [0x0201, 0x0403, 0x0605, 0x0807]);
        assert_eq!(DCBA.split(value, 4), [0x0807, 0x0605, 0x0403, 0x0201]);
    }

    #[test]
    fn one_register_only_swaps_bytes() {
        assert_eq!(ABCD.join(&[0x1234]), 0x1234);
        assert_eq!(CDAB.join(&[0x1234]), 0x1234);
        assert_eq!(BADC.join(&[0x1234]), 0x3412);
        assert_eq!(DCBA.split(0x1234, 1), [0x3412]);
    }

    proptest! {
        #[test]
        fn split_then_join_is_the_identity(bits in any::<u64>(), words in any::<bool>(), bytes in any::<bool>()) {
            let layout = RegisterLayout {
                words: if words { WordOrder::HighFirst } else { WordOrder::LowFirst },
                bytes: if bytes { ByteOrder::HighFirst } else { ByteOrder::LowFirst },
            };
            for count in [1u16, 2, 4] {
                let kept = if count == 4 { bits } else { bits & ((1u64 << (16 * count)) - 1) };
                prop_assert_eq!(layout.join(&layout.split(bits, count)), kept);
            }
        }
    }
}
