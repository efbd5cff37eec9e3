//! The journal's on-disk format, pure: a segment is a magic header followed by records, each
//! `[length u32 LE][CRC-32 of the body u32 LE][body]`, the body being
//! `[read at, ms since the epoch u64 LE][device name length u8][device name][JSON document]`.
//! Decoding never fails: a damaged part (a torn tail, a flipped bit, a foreign file) is
//! skipped and counted, and every intact record around it is kept.

use crc::{Crc, CRC_32_ISO_HDLC};

/// The first bytes of every segment (a foreign file does not start with them).
pub const MAGIC: &[u8; 16] = b"rtu2mqtt-hist-1\n";
/// Length field and checksum in front of each body.
pub const RECORD_HEADER: usize = 8;
/// Longest body accepted; a longer length field is damage, not a record.
pub const MAX_BODY: usize = 64 * 1024;
/// Read-at stamp and device name length.
const BODY_HEADER: usize = 9;

const CHECKSUM: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// One device's change set as published on its history topic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Record {
    /// When the answer was read, in milliseconds since the Unix epoch.
    pub at_ms: u64,
    pub device: String,
    /// The history document (`{"ts":…,"values":{…}}`).
    pub document: String,
}

impl Record {
    /// The record as stored; None when it cannot be (a device name over 255 bytes, a body
    /// over [`MAX_BODY`]).
    pub fn encode(&self) -> Option<Vec<u8>> {
        let device_len = u8::try_from(self.device.len()).ok()?;
        let body_len = BODY_HEADER + self.device.len() + self.document.len();
        if body_len > MAX_BODY {
            return None;
        }
        let mut bytes = Vec::with_capacity(RECORD_HEADER + body_len);
        bytes.extend_from_slice(&u32::try_from(body_len).ok()?.to_le_bytes());
        bytes.extend_from_slice(&[0; 4]);
        bytes.extend_from_slice(&self.at_ms.to_le_bytes());
        bytes.push(device_len);
        bytes.extend_from_slice(self.device.as_bytes());
        bytes.extend_from_slice(self.document.as_bytes());
        let checksum = CHECKSUM.checksum(&bytes[RECORD_HEADER..]);
        bytes[4..RECORD_HEADER].copy_from_slice(&checksum.to_le_bytes());
        Some(bytes)
    }

    fn decode_body(body: &[u8]) -> Option<Record> {
        let at_ms = u64::from_le_bytes(body.get(..8)?.try_into().ok()?);
        let device_len = usize::from(*body.get(8)?);
        let device = body.get(BODY_HEADER..BODY_HEADER + device_len)?;
        let document = body.get(BODY_HEADER + device_len..)?;
        Some(Record {
            at_ms,
            device: String::from_utf8(device.to_vec()).ok()?,
            document: String::from_utf8(document.to_vec()).ok()?,
        })
    }
}

/// What a segment's bytes hold.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Decoded {
    /// The intact records, in order.
    pub records: Vec<Record>,
    /// Damaged parts skipped: a record whose checksum failed, a torn or unreadable tail, a
    /// file that is not a segment at all.
    pub damaged: u64,
    /// The file does not start with [`MAGIC`]: not ours.
    pub foreign: bool,
}

/// Decodes a whole segment file.
pub fn decode(bytes: &[u8]) -> Decoded {
    let mut decoded = Decoded::default();
    if !bytes.starts_with(MAGIC) {
        decoded.foreign = true;
        decoded.damaged = 1;
        return decoded;
    }
    let mut at = MAGIC.len();
    while at < bytes.len() {
        let Some(header) = bytes.get(at..at + RECORD_HEADER) else {
            decoded.damaged += 1; // a torn length field
            break;
        };
        let length = u32::from_le_bytes([header[0], header[1], header[2], header[3]]) as usize;
        let expected = u32::from_le_bytes([header[4], header[5], header[6], header[7]]);
        let body_at = at + RECORD_HEADER;
        let body = bytes.get(body_at..body_at + length);
        let Some(body) = body.filter(|_| (BODY_HEADER..=MAX_BODY).contains(&length)) else {
            // A length that cannot be (a flipped bit or a torn tail): nothing after it can be
            // found again.
            decoded.damaged += 1;
            break;
        };
        at = body_at + length;
        match Record::decode_body(body).filter(|_| CHECKSUM.checksum(body) == expected) {
            Some(record) => decoded.records.push(record),
            None => decoded.damaged += 1,
        }
    }
    decoded
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(n: u64) -> Record {
        Record {
            at_ms: 1_796_223_601_123 + n,
            device: "fan1".to_string(),
            document: format!("{{\"ts\":\"x\",\"values\":{{\"fan_speed\":{n}}}}}"),
        }
    }

    fn segment(count: u64) -> Vec<u8> {
        let mut bytes = MAGIC.to_vec();
        for n in 0..count {
            bytes.extend(record(n).encode().unwrap_or_default());
        }
        bytes
    }

    #[test]
    fn records_come_back_as_written() {
        let decoded = decode(&segment(3));
        assert_eq!(decoded.records, vec![record(0), record(1), record(2)]);
        assert_eq!(decoded.damaged, 0);
        assert!(!decoded.foreign);
    }

    #[test]
    fn a_torn_tail_loses_only_the_torn_record() {
        let whole = segment(3);
        for cut in 1..record(2).encode().map_or(0, |bytes| bytes.len()) {
            let decoded = decode(&whole[..whole.len() - cut]);
            assert_eq!(decoded.records, vec![record(0), record(1)], "cut {cut}");
            assert_eq!(decoded.damaged, 1, "cut {cut}");
        }
    }

    #[test]
    fn a_flipped_bit_in_a_body_loses_that_record_alone() {
        let mut bytes = segment(3);
        let second = MAGIC.len() + record(0).encode().map_or(0, |b| b.len());
        bytes[second + RECORD_HEADER + 3] ^= 0x10;
        let decoded = decode(&bytes);
        assert_eq!(decoded.records, vec![record(0), record(2)]);
        assert_eq!(decoded.damaged, 1);
    }

    #[test]
    fn every_single_bit_flip_is_detected_never_a_wrong_record() {
        let bytes = segment(2);
        for bit in MAGIC.len() * 8..bytes.len() * 8 {
            let mut flipped = bytes.clone();
            flipped[bit / 8] ^= 1 << (bit % 8);
            let decoded = decode(&flipped);
            assert!(decoded.damaged >= 1, "bit {bit} went unnoticed");
            for found in &decoded.records {
                assert!(
                    [record(0), record(1)].contains(found),
                    "bit {bit}: {found:?}"
                );
            }
        }
    }

    #[test]
    fn a_foreign_file_is_not_read_as_records() {
        let decoded = decode(b"[mqtt]\nurl = \"mqtt://x\"\n");
        assert!(decoded.foreign);
        assert!(decoded.records.is_empty());
        assert_eq!(decoded.damaged, 1);
        assert_eq!(
            decode(b""),
            Decoded {
                records: vec![],
                damaged: 1,
                foreign: true
            }
        );
    }

    #[test]
    fn what_cannot_be_stored_is_refused() {
        let long = Record {
            device: "d".repeat(256),
            ..record(0)
        };
        assert_eq!(long.encode(), None);
        let huge = Record {
            document: "x".repeat(MAX_BODY),
            ..record(0)
        };
        assert_eq!(huge.encode(), None);
    }
}
