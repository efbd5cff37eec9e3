//! Registers shown every way a profile could read them, for the commissioning page: each
//! register as 16 bits (unsigned, signed, hex, bits), each pair and each four as 32 and 64
//! bits in every byte order (with floats), and the block as text both ways. Pure.

use serde::Serialize;

/// The byte orders of a value over several registers, named as the letters of its bytes
/// from most to least significant, as the registers carry them: `ABCD` is big-endian (the
/// first register high), `CDAB` the words swapped, `BADC` the bytes of each word swapped,
/// `DCBA` both.
pub const ORDERS: [&str; 4] = ["ABCD", "CDAB", "BADC", "DCBA"];

/// One register.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Register {
    pub address: u16,
    pub hex: String,
    pub u16: u16,
    pub i16: i16,
    pub bits: String,
    /// Its two bytes as characters (`.` where not printable).
    pub chars: String,
    /// The value of the pair and of the four starting here, in each of [`ORDERS`]; empty past
    /// the block's end.
    pub wide: Vec<Wide>,
}

/// The pair and the four registers from one address, in one byte order.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Wide {
    pub order: &'static str,
    pub u32: Option<u32>,
    pub i32: Option<i32>,
    pub f32: Option<String>,
    /// As text: a JSON number cannot carry every 64-bit value.
    pub u64: Option<String>,
    pub i64: Option<String>,
    pub f64: Option<String>,
}

/// The block read.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Registers {
    pub registers: Vec<Register>,
    /// The block as text, high byte of each register first.
    pub text_high_first: String,
    /// The block as text, low byte first.
    pub text_low_first: String,
}

/// The bytes of `words` (in register order) arranged in `order`, high byte first.
fn arranged(words: &[u16], order: &str) -> Vec<u8> {
    let words: Vec<u16> = match order {
        "CDAB" | "DCBA" => words.iter().rev().copied().collect(),
        _ => words.to_vec(),
    };
    let swap = matches!(order, "BADC" | "DCBA");
    words
        .iter()
        .flat_map(|w| {
            if swap {
                w.to_le_bytes()
            } else {
                w.to_be_bytes()
            }
        })
        .collect()
}

/// A float as a person reads it: plain for ordinary magnitudes, with an exponent for tiny or
/// huge ones (registers that are no float show up as such), non-finite values by name.
pub fn float(value: f64) -> String {
    if !value.is_finite() {
        return format!("{value:?}");
    }
    let magnitude = value.abs();
    if magnitude != 0.0 && !(1e-4..1e12).contains(&magnitude) {
        format!("{value:e}")
    } else {
        format!("{value}")
    }
}

fn printable(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|&b| {
            if (0x20..0x7F).contains(&b) {
                b as char
            } else {
                '.'
            }
        })
        .collect()
}

/// `words` read from `start`, every way.
pub fn registers(start: u16, words: &[u16]) -> Registers {
    let registers = words
        .iter()
        .enumerate()
        .map(|(i, &word)| {
            let wide = ORDERS
                .iter()
                .map(|&order| {
                    let pair = words.get(i..i + 2).map(|w| arranged(w, order));
                    let four = words.get(i..i + 4).map(|w| arranged(w, order));
                    let u32_of = |b: &Vec<u8>| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
                    let u64_of = |b: &Vec<u8>| {
                        u64::from_be_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
                    };
                    Wide {
                        order,
                        u32: pair.as_ref().map(u32_of),
                        i32: pair.as_ref().map(|b| u32_of(b) as i32),
                        f32: pair
                            .as_ref()
                            .map(|b| float(f64::from(f32::from_bits(u32_of(b))))),
                        u64: four.as_ref().map(|b| u64_of(b).to_string()),
                        i64: four.as_ref().map(|b| (u64_of(b) as i64).to_string()),
                        f64: four.as_ref().map(|b| float(f64::from_bits(u64_of(b)))),
                    }
                })
                .collect();
            Register {
                address: start.wrapping_add(i as u16),
                hex: format!("{word:04x}"),
                u16: word,
                i16: word as i16,
                bits: format!(
                    "{:04b} {:04b} {:04b} {:04b}",
                    word >> 12,
                    (word >> 8) & 0xF,
                    (word >> 4) & 0xF,
                    word & 0xF
                ),
                chars: printable(&word.to_be_bytes()),
                wide,
            }
        })
        .collect();
    let high: Vec<u8> = words.iter().flat_map(|w| w.to_be_bytes()).collect();
    let low: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    Registers {
        registers,
        text_high_first: printable(&high),
        text_low_first: printable(&low),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wide<'a>(table: &'a Registers, at: usize, order: &str) -> &'a Wide {
        table.registers[at]
            .wide
            .iter()
            .find(|w| w.order == order)
            .unwrap()
    }

    #[test]
    fn a_float_reads_in_each_order() {
        // 230.5 as f32 is 0x43668000.
        let table = registers(100, &[0x4366, 0x8000]);
        assert_eq!(wide(&table, 0, "ABCD").f32.as_deref(), Some("230.5"));
        let swapped = registers(100, &[0x8000, 0x4366]);
        assert_eq!(wide(&swapped, 0, "CDAB").f32.as_deref(), Some("230.5"));
        let bytes = registers(100, &[0x6643, 0x0080]);
        assert_eq!(wide(&bytes, 0, "BADC").f32.as_deref(), Some("230.5"));
        let both = registers(100, &[0x0080, 0x6643]);
        assert_eq!(wide(&both, 0, "DCBA").f32.as_deref(), Some("230.5"));
        assert_eq!(wide(&table, 1, "ABCD").u32, None, "no pair past the end");
    }

    #[test]
    fn sixty_four_bits_are_exact() {
        let table = registers(0, &[0xFFFF, 0xFFFF, 0xFFFF, 0xFFFE]);
        assert_eq!(
            wide(&table, 0, "ABCD").u64.as_deref(),
            Some("18446744073709551614")
        );
        assert_eq!(wide(&table, 0, "ABCD").i64.as_deref(), Some("-2"));
        let energy = registers(0, &[0x0000, 0x0000, 0x0001, 0x0002]);
        assert_eq!(wide(&energy, 0, "ABCD").u64.as_deref(), Some("65538"));
        assert_eq!(
            wide(&energy, 0, "CDAB").u64.as_deref(),
            Some(((0x0002u64 << 48) | (0x0001 << 32)).to_string().as_str())
        );
    }

    #[test]
    fn sixteen_bits_and_text() {
        let table = registers(7, &[0x4142, 0xFFFF]);
        assert_eq!(table.registers[1].address, 8);
        assert_eq!(table.registers[1].i16, -1);
        assert_eq!(table.registers[0].chars, "AB");
        assert_eq!(table.text_high_first, "AB..");
        assert_eq!(table.text_low_first, "BA..");
    }
}
