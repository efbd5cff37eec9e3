//! A history journal segment as the gateway reads it at start: the file's bytes decoded
//! (`record::decode`), then the same bytes as a segment file in a journal's directory, opened
//! and replayed by the journal. Input: the file's bytes (seeds: segments written by the
//! journal itself).
//!
//! Asserted: every record decoded is stored in the bytes as it would be written, in order and
//! without overlap; the damage count is bounded by the bytes; a foreign file holds no record;
//! the journal replays exactly the records decoded, counts the damage decode found, and goes
//! on working (a record appended after reading the file comes out after them).

#![no_main]

use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use rtu2mqtt::config::HistoryConfig;
use rtu2mqtt::history::record::{self, MAGIC};
use rtu2mqtt::history::{Journal, Record};

fuzz_target!(|data: &[u8]| {
    let decoded = record::decode(data);
    let mut at = 0;
    for record in &decoded.records {
        let stored = record
            .encode()
            .expect("a decoded record can be stored again");
        let found = data[at..]
            .windows(stored.len())
            .position(|window| window == stored.as_slice())
            .unwrap_or_else(|| panic!("{record:?} is not in the bytes after offset {at}"));
        at += found + stored.len();
    }
    assert!(decoded.damaged as usize <= data.len());
    assert_eq!(decoded.first_damage.is_some(), decoded.damaged > 0);
    if decoded.foreign {
        assert!(decoded.records.is_empty());
    }

    // In memory where there is a tmpfs: the journal syncs what it writes.
    let dir = match std::path::Path::new("/dev/shm") {
        shm if shm.is_dir() => tempfile::tempdir_in(shm),
        _ => tempfile::tempdir(),
    }
    .expect("a temporary directory");
    std::fs::write(dir.path().join("00000000000000000007.journal"), data)
        .expect("the segment written");
    let config = HistoryConfig {
        path: dir.path().to_path_buf(),
        max_size: 1 << 30,
        max_age: Duration::from_secs(1 << 40),
    };
    let mut journal = Journal::open(&config);
    assert_eq!(journal.problem(), None);
    let stats = journal.stats();
    if !decoded.foreign {
        assert_eq!(stats.damaged, decoded.damaged);
    }
    assert_eq!(stats.waiting, decoded.records.len() as u64);
    let appended = Record {
        at_ms: 1,
        device: "after".to_string(),
        document: "{\"ts\":1,\"values\":{}}".to_string(),
    };
    journal.append(&appended, 0);
    let replayed = journal.take(usize::MAX, 0);
    let mut expected = decoded.records.clone();
    expected.push(appended);
    assert_eq!(replayed, expected);
    assert!(journal.is_empty());
    // An empty file or a part of the header is no segment: removed, not replayed.
    if MAGIC.starts_with(data) {
        assert!(decoded.records.is_empty() && decoded.damaged == 0);
    }
});
