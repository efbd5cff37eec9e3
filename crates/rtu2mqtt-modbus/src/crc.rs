//! CRC-16/MODBUS (init 0xFFFF, reflected polynomial 0xA001), sent low byte first.

use crc::{Crc, CRC_16_MODBUS};

/// Table-driven CRC-16/MODBUS, built at compile time.
const MODBUS: Crc<u16> = Crc::<u16>::new(&CRC_16_MODBUS);

/// The CRC of `bytes`, as a number; on the wire it goes low byte first.
pub fn crc16(bytes: &[u8]) -> u16 {
    MODBUS.checksum(bytes)
}

/// Appends the CRC of everything already in `frame`, low byte first.
pub fn append_crc(frame: &mut Vec<u8>) {
    let crc = crc16(frame);
    frame.extend_from_slice(&crc.to_le_bytes());
}

/// The CRC carried in the last two bytes of `frame` and the CRC computed over the rest
/// (`None` when the frame is shorter than a CRC).
pub fn carried_and_computed(frame: &[u8]) -> Option<(u16, u16)> {
    let body_len = frame.len().checked_sub(2)?;
    let carried = u16::from_le_bytes([frame[body_len], frame[body_len + 1]]);
    Some((carried, crc16(&frame[..body_len])))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value_of_the_catalogue() {
        // The CRC catalogue's check value for "123456789".
        assert_eq!(crc16(b"123456789"), 0x4B37);
    }

    #[test]
    fn appended_low_byte_first() {
        let mut frame = vec![0x01, 0x03, 0x10, 0x00, 0x00, 0x06];
        append_crc(&mut frame);
        assert_eq!(&frame[6..], &[0xC1, 0x08]);
        assert_eq!(carried_and_computed(&frame), Some((0x08C1, 0x08C1)));
    }

    #[test]
    fn short_frame_has_no_crc() {
        assert_eq!(carried_and_computed(&[0x01]), None);
    }
}
