//! The journal's on-disk format, pure: a segment is a magic header followed by records, each
//! `[length u32 LE][CRC-32 of the body u32 LE][body]`, the body being
//! `[read at, ms since the epoch u64 LE][device name length u8][device name][JSON document]`.
//! Decoding never fails and damage stays local: a part whose length or checksum does not
//! check (a torn tail, a flipped bit, garbage) is skipped by scanning forward to the next
//! offset where a whole record checks, counted once, and every intact record around it is
//! kept. A damaged magic header costs no record. Nothing is allocated from a length field.

use crc::{Crc, CRC_32_ISO_HDLC};

/// The first bytes of every segment (a foreign file does not start with them).
pub const MAGIC: &[u8; 16] = b"rtu2mqtt-hist-1\n";
/// Length field and checksum in front of each body.
pub const RECORD_HEADER: usize = 8;
/// Longest body accepted; a longer length field is damage, not a record.
pub const MAX_BODY: usize = 64 * 1024;
/// The longest record as stored.
pub const MAX_RECORD: usize = RECORD_HEADER + MAX_BODY;
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
            device: std::str::from_utf8(device).ok()?.to_string(),
            document: std::str::from_utf8(document).ok()?.to_string(),
        })
    }
}

/// The record stored at `at` and the offset after it, when its length and checksum check.
/// Only slices of `bytes` are looked at: a length field never sizes an allocation.
fn record_at(bytes: &[u8], at: usize) -> Option<(Record, usize)> {
    let header = bytes.get(at..at.checked_add(RECORD_HEADER)?)?;
    let length = usize::try_from(u32::from_le_bytes([
        header[0], header[1], header[2], header[3],
    ]))
    .ok()?;
    if !(BODY_HEADER..=MAX_BODY).contains(&length) {
        return None;
    }
    let expected = u32::from_le_bytes([header[4], header[5], header[6], header[7]]);
    let body_at = at + RECORD_HEADER;
    let body = bytes.get(body_at..body_at + length)?;
    if CHECKSUM.checksum(body) != expected {
        return None;
    }
    Some((Record::decode_body(body)?, body_at + length))
}

/// What a segment's bytes hold.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Decoded {
    /// The intact records, in order.
    pub records: Vec<Record>,
    /// Damaged parts skipped, each a run of bytes between intact records (or before the
    /// first, or after the last) that holds no record that checks: a flipped bit, a torn
    /// tail, garbage, a damaged magic header, a file that is not a segment at all.
    pub damaged: u64,
    /// Byte offset of the first damaged part.
    pub first_damage: Option<usize>,
    /// The file is no segment: no magic header and no record that checks.
    pub foreign: bool,
}

/// Decodes a whole segment file. An empty file, or one holding only the beginning of the
/// magic header (a crash right after its creation), is an empty segment, not damage.
pub fn decode(bytes: &[u8]) -> Decoded {
    let mut decoded = Decoded::default();
    if MAGIC.starts_with(bytes) {
        return decoded;
    }
    let mut damage_from = None;
    if !bytes.starts_with(MAGIC) {
        damage_from = Some(0);
    }
    let mut at = MAGIC.len().min(bytes.len());
    while at < bytes.len() {
        match record_at(bytes, at) {
            Some((record, next)) => {
                decoded.close_damage(damage_from.take());
                decoded.records.push(record);
                at = next;
            }
            None => {
                damage_from.get_or_insert(at);
                at += 1;
            }
        }
    }
    decoded.close_damage(damage_from);
    decoded.foreign = !bytes.starts_with(MAGIC) && decoded.records.is_empty();
    decoded
}

impl Decoded {
    fn close_damage(&mut self, from: Option<usize>) {
        if let Some(from) = from {
            self.damaged += 1;
            self.first_damage.get_or_insert(from);
        }
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    fn record(n: u64) -> Record {
        Record {
            at_ms: 1_796_223_601_123 + n,
            device: "fan1".to_string(),
            document: format!("{{\"ts\":\"x\",\"values\":{{\"fan_speed\":{n}}}}}"),
        }
    }

    fn encoded(record: &Record) -> Vec<u8> {
        record.encode().unwrap_or_default()
    }

    fn segment_of(records: &[Record]) -> Vec<u8> {
        let mut bytes = MAGIC.to_vec();
        for record in records {
            bytes.extend(encoded(record));
        }
        bytes
    }

    fn segment(count: u64) -> Vec<u8> {
        segment_of(&(0..count).map(record).collect::<Vec<_>>())
    }

    /// Where each record starts and ends in `segment_of(records)`.
    fn spans(records: &[Record]) -> Vec<(usize, usize)> {
        let mut at = MAGIC.len();
        records
            .iter()
            .map(|record| {
                let end = at + encoded(record).len();
                let span = (at, end);
                at = end;
                span
            })
            .collect()
    }

    #[test]
    fn records_come_back_as_written() {
        let decoded = decode(&segment(3));
        assert_eq!(decoded.records, vec![record(0), record(1), record(2)]);
        assert_eq!(decoded.damaged, 0);
        assert_eq!(decoded.first_damage, None);
        assert!(!decoded.foreign);
    }

    #[test]
    fn a_torn_tail_loses_only_the_torn_record() {
        let whole = segment(3);
        for cut in 1..encoded(&record(2)).len() {
            let decoded = decode(&whole[..whole.len() - cut]);
            assert_eq!(decoded.records, vec![record(0), record(1)], "cut {cut}");
            assert_eq!(decoded.damaged, 1, "cut {cut}");
        }
    }

    #[test]
    fn a_flipped_bit_in_a_body_loses_that_record_alone() {
        let mut bytes = segment(3);
        let second = MAGIC.len() + encoded(&record(0)).len();
        bytes[second + RECORD_HEADER + 3] ^= 0x10;
        let decoded = decode(&bytes);
        assert_eq!(decoded.records, vec![record(0), record(2)]);
        assert_eq!(decoded.damaged, 1);
        assert_eq!(decoded.first_damage, Some(second));
    }

    #[test]
    fn a_flipped_length_byte_loses_that_record_alone() {
        let records: Vec<Record> = (0..31).map(record).collect();
        let spans = spans(&records);
        for (index, bit) in [(0, 0), (0, 7), (0, 24), (0, 31), (15, 3), (15, 30), (30, 1)] {
            let mut bytes = segment_of(&records);
            let at = spans[index].0 + bit / 8;
            bytes[at] ^= 1 << (bit % 8);
            let decoded = decode(&bytes);
            let mut expected = records.clone();
            expected.remove(index);
            assert_eq!(decoded.records, expected, "record {index}, bit {bit}");
            assert_eq!(decoded.damaged, 1);
            assert_eq!(decoded.first_damage, Some(spans[index].0));
        }
    }

    #[test]
    fn a_huge_length_prefix_is_skipped_without_allocating_for_it() {
        let records: Vec<Record> = (0..31).map(record).collect();
        let spans = spans(&records);
        let mut bytes = segment_of(&records);
        bytes[spans[15].0..spans[15].0 + 4].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        let decoded = decode(&bytes);
        assert_eq!(decoded.records.len(), 30);
        assert!(!decoded.records.contains(&record(15)));
        assert_eq!(decoded.damaged, 1);
    }

    #[test]
    fn a_damaged_magic_costs_no_record() {
        for bit in 0..MAGIC.len() * 8 {
            let mut bytes = segment(31);
            bytes[bit / 8] ^= 1 << (bit % 8);
            let decoded = decode(&bytes);
            assert_eq!(decoded.records, (0..31).map(record).collect::<Vec<_>>());
            assert_eq!((decoded.damaged, decoded.first_damage), (1, Some(0)));
            assert!(!decoded.foreign);
        }
    }

    #[test]
    fn every_single_bit_flip_is_detected_never_a_wrong_record() {
        let bytes = segment(2);
        for bit in 0..bytes.len() * 8 {
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
    fn an_empty_segment_is_no_damage_and_a_foreign_file_no_records() {
        for empty in [&b""[..], &MAGIC[..5], &MAGIC[..]] {
            assert_eq!(decode(empty), Decoded::default(), "{empty:?}");
        }
        let decoded = decode(b"[mqtt]\nurl = \"mqtt://x\"\n");
        assert!(decoded.foreign);
        assert!(decoded.records.is_empty());
        assert_eq!((decoded.damaged, decoded.first_damage), (1, Some(0)));
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

    /// Records as the gateway writes them: a device name, a JSON document (no control
    /// characters: JSON escapes them), any read-at stamp.
    fn records() -> impl Strategy<Value = Vec<Record>> {
        let one = (any::<u64>(), "[a-z_0-9]{1,24}", "[ -~é°µ]{0,120}").prop_map(
            |(at_ms, device, text)| Record {
                at_ms,
                device,
                document: format!("{{\"ts\":{at_ms},\"values\":{{\"x\":{text:?}}}}}"),
            },
        );
        proptest::collection::vec(one, 1..12)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        /// A single flipped bit loses at most the record it falls in (none in the header).
        #[test]
        fn a_single_bit_flip_loses_at_most_its_record(records in records(), pick in any::<usize>()) {
            let bytes = segment_of(&records);
            let bit = pick % (bytes.len() * 8);
            let mut flipped = bytes.clone();
            flipped[bit / 8] ^= 1 << (bit % 8);
            let decoded = decode(&flipped);
            let hit = spans(&records).iter().position(|&(from, to)| (from..to).contains(&(bit / 8)));
            let mut expected = records.clone();
            if let Some(index) = hit {
                expected.remove(index);
            }
            prop_assert_eq!(decoded.records, expected);
            prop_assert_eq!(decoded.damaged, 1);
        }

        /// A journal cut anywhere keeps every record wholly before the cut.
        #[test]
        fn a_truncation_loses_only_what_was_cut(records in records(), pick in any::<usize>()) {
            let bytes = segment_of(&records);
            let cut = pick % (bytes.len() + 1);
            let decoded = decode(&bytes[..cut]);
            let spans = spans(&records);
            let kept = spans.iter().filter(|&&(_, to)| to <= cut).count();
            prop_assert_eq!(&decoded.records[..], &records[..kept]);
            let torn = cut > MAGIC.len() && !spans.iter().any(|&(_, to)| to == cut);
            prop_assert_eq!(decoded.damaged, u64::from(torn));
        }

        /// Garbage between records (a torn write followed by later ones, foreign bytes) is
        /// skipped and every record around it is kept.
        #[test]
        fn garbage_between_records_is_skipped(
            records in records(),
            garbage in proptest::collection::vec((any::<usize>(), proptest::collection::vec(any::<u8>(), 1..64)), 1..4),
        ) {
            let spans = spans(&records);
            let mut bytes = segment_of(&records);
            let mut places: Vec<(usize, Vec<u8>)> = garbage
                .into_iter()
                .map(|(pick, junk)| (spans[pick % spans.len()].1, junk))
                .collect();
            places.sort_by_key(|(at, _)| std::cmp::Reverse(*at));
            for (at, junk) in places {
                bytes.splice(at..at, junk);
            }
            let decoded = decode(&bytes);
            prop_assert_eq!(decoded.records, records);
            prop_assert!(decoded.damaged >= 1);
        }

        /// Whatever the bytes, decoding ends, never panics and holds no more than it read.
        #[test]
        fn no_input_panics_or_outgrows_itself(
            magic in any::<bool>(),
            tail in proptest::collection::vec(any::<u8>(), 0..2048),
        ) {
            let mut bytes = if magic { MAGIC.to_vec() } else { Vec::new() };
            bytes.extend(tail);
            let decoded = decode(&bytes);
            let held: usize = decoded
                .records
                .iter()
                .map(|r| RECORD_HEADER + BODY_HEADER + r.device.len() + r.document.len())
                .sum();
            prop_assert!(held <= bytes.len());
        }
    }
}
