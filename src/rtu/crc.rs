//! CRC-16/MODBUS (init 0xFFFF, reflected polynomial 0xA001), sent low byte first.

/// The CRC of `bytes`, as a number; on the wire it goes low byte first.
pub fn crc16(bytes: &[u8]) -> u16 {
    todo!("rtu helper")
}
