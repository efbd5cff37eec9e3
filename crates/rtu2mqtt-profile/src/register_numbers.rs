//! How a profile numbers its registers (`register_numbers` in `[device]`), and the bus address
//! each number stands for. Manuals print a register three ways: the address on the bus
//! (0-based, what a frame carries), its 1-based number ("register 3204"), or the Modicon number
//! with the table's digit in front ("43204", "403204"); a profile copies the manual's numbers
//! and says which they are, and everything after compilation sees bus addresses only.

use serde::Deserialize;

/// The numbering convention of a profile's `start`s and `address`es.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RegisterNumbers {
    /// The address on the bus, 0-based: what the request frame carries.
    #[default]
    Bus,
    /// 1-based register numbers: bus address + 1.
    OneBased,
    /// Modicon numbers: the table's digit (0 coils, 1 discrete inputs, 3 input registers,
    /// 4 holding registers), then the 1-based number in four digits (`43204`) or five
    /// (`403204`).
    Modicon,
}

/// The Modicon table digit of the registers or coils a function reads or writes.
fn table_digit(function: u8) -> Option<u32> {
    match function {
        1 | 5 | 15 => Some(0),
        2 => Some(1),
        4 => Some(3),
        3 | 6 | 16 => Some(4),
        _ => None,
    }
}

impl RegisterNumbers {
    /// The bus address of `number` (as the profile writes it) in a request of `function`; why
    /// not, as a sentence, when it is no number of this convention for that function.
    pub fn bus_address(self, number: u32, function: u8) -> Result<u16, String> {
        match self {
            Self::Bus => u16::try_from(number)
                .map_err(|_| format!("{number} is not a bus address (0–65535)")),
            Self::OneBased => number
                .checked_sub(1)
                .and_then(|address| u16::try_from(address).ok())
                .ok_or_else(|| format!("{number} is not a register number (1–65536)")),
            Self::Modicon => {
                let Some(digit) = table_digit(function) else {
                    return Err(format!("function {function} has no Modicon table"));
                };
                let four = digit * 10_000;
                let five = digit * 100_000;
                let address = if (four + 1..=four + 9_999).contains(&number) {
                    number - four - 1
                } else if (five + 1..=five + 65_536).contains(&number) {
                    number - five - 1
                } else {
                    return Err(format!(
                        "{number} is not a Modicon number of function {function}'s table \
                         ({digit}xxxx: {} to {}, or {digit}xxxxx: {} to {})",
                        four + 1,
                        four + 9_999,
                        five + 1,
                        five + 65_536
                    ));
                };
                // Within 0..=65535 by the ranges above.
                u16::try_from(address).map_err(|_| format!("{number} is out of range"))
            }
        }
    }

    /// For a profile numbering by bus address: whether `start` (of a block read with
    /// `function`) looks like a Modicon number of that function's table, with the bus address
    /// it would stand for. Such a start is almost always a number copied from a manual.
    pub fn looks_like_modicon(self, start: u16, function: u8) -> Option<u16> {
        if self != Self::Bus {
            return None;
        }
        let digit = table_digit(function).filter(|digit| *digit >= 3)?;
        let four = digit * 10_000;
        (four + 1..=four + 9_999)
            .contains(&u32::from(start))
            .then(|| start - four as u16 - 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_manuals_three_numbers_of_one_register() {
        // Register 3204 of the holding registers, bus address 3203.
        assert_eq!(RegisterNumbers::Bus.bus_address(3203, 3), Ok(3203));
        assert_eq!(RegisterNumbers::OneBased.bus_address(3204, 3), Ok(3203));
        assert_eq!(RegisterNumbers::Modicon.bus_address(43204, 3), Ok(3203));
        assert_eq!(RegisterNumbers::Modicon.bus_address(403204, 16), Ok(3203));
        assert_eq!(RegisterNumbers::Modicon.bus_address(30001, 4), Ok(0));
        assert_eq!(RegisterNumbers::Modicon.bus_address(465536, 3), Ok(65535));
        assert_eq!(RegisterNumbers::Modicon.bus_address(1, 1), Ok(0));
        assert_eq!(RegisterNumbers::Modicon.bus_address(10010, 2), Ok(9));
    }

    #[test]
    fn numbers_outside_the_convention_or_the_functions_table_are_refused() {
        assert!(RegisterNumbers::Bus.bus_address(65536, 3).is_err());
        assert!(RegisterNumbers::OneBased.bus_address(0, 3).is_err());
        let wrong_table = RegisterNumbers::Modicon.bus_address(43204, 4).unwrap_err();
        assert!(
            wrong_table.contains("3xxxx: 30001 to 39999"),
            "{wrong_table}"
        );
        assert!(RegisterNumbers::Modicon.bus_address(40000, 3).is_err());
        assert!(RegisterNumbers::Modicon.bus_address(3204, 3).is_err());
    }

    #[test]
    fn a_bus_start_in_the_register_tables_looks_like_a_modicon_number() {
        assert_eq!(
            RegisterNumbers::Bus.looks_like_modicon(43204, 3),
            Some(3203)
        );
        assert_eq!(RegisterNumbers::Bus.looks_like_modicon(30001, 4), Some(0));
        assert_eq!(RegisterNumbers::Bus.looks_like_modicon(43204, 4), None);
        assert_eq!(RegisterNumbers::Bus.looks_like_modicon(3204, 3), None);
        // SunSpec's base register is a bus address, not a Modicon number.
        assert_eq!(RegisterNumbers::Bus.looks_like_modicon(40000, 3), None);
        assert_eq!(RegisterNumbers::Modicon.looks_like_modicon(43204, 3), None);
    }
}
