//! The data of the device library's simulators: typed values at register addresses, as a
//! vendor's register map lists them, encoded into words the way Modbus devices send them
//! (high word first, high byte first, IEEE-754 for floats). A [`RegisterMap`] becomes a
//! [`GenericDevice`] holding exactly those registers, so one simulator serves every library
//! device and each device is a table, not code.

use super::generic::GenericDevice;
use rtu2mqtt_modbus::frame::SlaveId;

/// The register table a value lives in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Table {
    /// Read with FC03, written with FC06/FC16.
    Holding,
    /// Read with FC04.
    Input,
}

/// A value as the register map types it.
#[derive(Debug, Clone, PartialEq)]
pub enum Raw {
    U16(u16),
    I16(i16),
    U32(u32),
    I32(i32),
    U64(u64),
    I64(i64),
    F32(f32),
    /// Text (its UTF-8 bytes; ASCII is the same) padded with NUL to this many registers, the
    /// first byte in the high byte.
    Text(&'static str, u16),
}

impl Raw {
    /// The registers, in the order they are sent.
    pub fn words(&self) -> Vec<u16> {
        let split = |bytes: &[u8]| -> Vec<u16> {
            bytes
                .chunks(2)
                .map(|pair| u16::from_be_bytes([pair[0], pair.get(1).copied().unwrap_or(0)]))
                .collect()
        };
        match self {
            Raw::U16(v) => vec![*v],
            Raw::I16(v) => vec![*v as u16],
            Raw::U32(v) => split(&v.to_be_bytes()),
            Raw::I32(v) => split(&v.to_be_bytes()),
            Raw::U64(v) => split(&v.to_be_bytes()),
            Raw::I64(v) => split(&v.to_be_bytes()),
            Raw::F32(v) => split(&v.to_bits().to_be_bytes()),
            Raw::Text(text, registers) => {
                let mut bytes = text.as_bytes().to_vec();
                bytes.resize(usize::from(*registers) * 2, 0);
                split(&bytes)
            }
        }
    }
}

/// One entry of a register map: the profile field that reads it, where it is, its value, and
/// the text the gateway publishes for it (`None`: a "not available" mark, never published).
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    pub field: String,
    pub table: Table,
    pub address: u16,
    pub raw: Raw,
    pub published: Option<String>,
}

impl Entry {
    pub fn new(field: &str, table: Table, address: u16, raw: Raw, published: &str) -> Self {
        Self {
            field: field.to_string(),
            table,
            address,
            raw,
            published: Some(published.to_string()),
        }
    }

    /// A value the device marks as not available: its field is never published.
    pub fn unavailable(field: &str, table: Table, address: u16, raw: Raw) -> Self {
        Self {
            field: field.to_string(),
            table,
            address,
            raw,
            published: None,
        }
    }
}

/// A device's registers: every entry, plus filler words that no field reads (other points of
/// the map, markers, the rest of a block).
#[derive(Debug, Clone, Default)]
pub struct RegisterMap {
    pub entries: Vec<Entry>,
    pub filler: Vec<(Table, u16, u16)>,
}

impl RegisterMap {
    /// A simulated device at `address` holding exactly these registers (anything else answers
    /// exception 02, as a meter does outside its map).
    pub fn device(&self, address: SlaveId) -> GenericDevice {
        let mut device = GenericDevice::empty(address);
        let mut put = |table: Table, at: u16, word: u16| match table {
            Table::Holding => device.set_holding(at, word),
            Table::Input => device.set_input_register(at, word),
        };
        for (table, at, word) in &self.filler {
            put(*table, *at, *word);
        }
        for entry in &self.entries {
            for (i, word) in entry.raw.words().into_iter().enumerate() {
                put(entry.table, entry.address.wrapping_add(i as u16), word);
            }
        }
        device
    }

    /// A map of `entries` over zero-filled blocks `(table, start, count)`: the registers of
    /// each block that no entry holds read as zero.
    pub fn over_zeros(entries: Vec<Entry>, blocks: &[(Table, u16, u16)]) -> Self {
        let map = Self {
            entries,
            filler: vec![],
        };
        blocks.iter().fold(map, |map, &(table, start, count)| {
            map.zeros(table, start, count)
        })
    }

    /// Zero-filled registers `start..start + count` of `table` under the entries.
    pub fn zeros(mut self, table: Table, start: u16, count: u16) -> Self {
        self.filler
            .extend((0..count).map(|i| (table, start.wrapping_add(i), 0)));
        self
    }

    /// The entry of `field`.
    pub fn entry(&self, field: &str) -> Option<&Entry> {
        self.entries.iter().find(|e| e.field == field)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_are_sent_high_word_and_high_byte_first() {
        assert_eq!(Raw::F32(240.5).words(), vec![0x4370, 0x8000]);
        assert_eq!(Raw::I32(-12214).words(), vec![0xFFFF, 0xD04A]);
        assert_eq!(
            Raw::U64(0x0003_1292).words(),
            vec![0x0000, 0x0000, 0x0003, 0x1292]
        );
        assert_eq!(Raw::Text("SunS", 2).words(), vec![0x5375, 0x6E53]);
        assert_eq!(Raw::Text("ABC", 3).words(), vec![0x4142, 0x4300, 0x0000]);
        assert_eq!(Raw::Text("Süd", 3).words(), vec![0x53C3, 0xBC64, 0x0000]);
        assert_eq!(
            Raw::F32(f32::from_bits(0xFFC0_0000)).words(),
            vec![0xFFC0, 0x0000]
        );
        assert_eq!(Raw::I16(-1).words(), vec![0xFFFF]);
    }

    #[test]
    fn a_map_becomes_a_device_holding_exactly_its_registers() {
        let map = RegisterMap {
            entries: vec![Entry::new("v", Table::Input, 0, Raw::F32(230.0), "230")],
            filler: vec![],
        }
        .zeros(Table::Input, 0, 4);
        let device = map.device(7);
        assert_eq!(device.input_register(0), Some(0x4366));
        assert_eq!(device.input_register(3), Some(0));
        assert_eq!(device.input_register(4), None);
        assert_eq!(device.holding(0), None);
    }
}
