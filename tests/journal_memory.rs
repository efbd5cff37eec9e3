//! What reading the history journal allocates, measured by a counting allocator: no length
//! field and no file in the directory makes it allocate more than a bound. Its own test binary,
//! since the allocator counts for the whole process it is in.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use proptest::prelude::*;
use rtu2mqtt::config::HistoryConfig;
use rtu2mqtt::history::journal::MAX_SEGMENT_FILE;
use rtu2mqtt::history::record::{self, Record, MAGIC};
use rtu2mqtt::history::Journal;

/// The system allocator, keeping the bytes in use and their peak.
struct Counting;

static IN_USE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let now = IN_USE.fetch_add(layout.size(), Ordering::SeqCst) + layout.size();
        PEAK.fetch_max(now, Ordering::SeqCst);
        // SAFETY: the caller's layout is passed on unchanged.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        IN_USE.fetch_sub(layout.size(), Ordering::SeqCst);
        // SAFETY: `ptr` was allocated by `alloc` above with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// The most `work` allocated on top of what was in use before it.
fn peak_of<T>(work: impl FnOnce() -> T) -> (T, usize) {
    let before = IN_USE.load(Ordering::SeqCst);
    PEAK.store(before, Ordering::SeqCst);
    let out = work();
    (out, PEAK.load(Ordering::SeqCst).saturating_sub(before))
}

fn record(n: u64) -> Record {
    Record {
        at_ms: 1_796_223_601_123 + n,
        device: "fan1".to_string(),
        document: format!("{{\"ts\":\"x\",\"values\":{{\"fan_speed\":{n}}}}}"),
    }
}

/// One test: the counter is the process's, so nothing else may run beside it.
#[test]
fn reading_the_journal_allocates_within_a_bound_whatever_lies_on_disk() {
    // A length prefix of 0xFFFFFFF0: nothing is allocated for it.
    let mut bytes = MAGIC.to_vec();
    for n in 0..31 {
        bytes.extend(record(n).encode().unwrap_or_default());
    }
    bytes[MAGIC.len()..MAGIC.len() + 4].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    let (decoded, peak) = peak_of(|| record::decode(&bytes));
    assert_eq!(decoded.records.len(), 30);
    assert!(peak < 64 * 1024, "{peak} bytes for {} bytes", bytes.len());

    // Any bytes: at most a few times what was read.
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig::with_cases(256));
    runner
        .run(
            &(
                any::<bool>(),
                proptest::collection::vec(any::<u8>(), 0..8192),
            ),
            |(magic, tail)| {
                let mut bytes = if magic { MAGIC.to_vec() } else { Vec::new() };
                bytes.extend(tail);
                let (_, peak) = peak_of(|| record::decode(&bytes));
                prop_assert!(
                    peak <= 8 * bytes.len() + 4096,
                    "{} bytes for {}",
                    peak,
                    bytes.len()
                );
                Ok(())
            },
        )
        .unwrap_or_else(|error| panic!("{error}"));

    // A directory holding a file far larger than any segment (sparse: it takes no room), a
    // segment whose every length field says 0xFFFFFFF0, and a real one: opening the journal
    // stays within two of the largest segments.
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    std::fs::File::create(dir.path().join("00000000000000000001.journal"))
        .and_then(|file| file.set_len(64 << 30))
        .unwrap_or_else(|e| panic!("{e}"));
    let lies: Vec<u8> = MAGIC
        .iter()
        .copied()
        .chain((0..100_000).flat_map(|_| 0xFFFF_FFF0u32.to_le_bytes()))
        .collect();
    std::fs::write(dir.path().join("00000000000000000002.journal"), lies)
        .unwrap_or_else(|e| panic!("{e}"));
    std::fs::write(dir.path().join("00000000000000000003.journal"), &bytes[..])
        .unwrap_or_else(|e| panic!("{e}"));
    let config = HistoryConfig {
        path: dir.path().to_path_buf(),
        max_size: 64 << 20,
        max_age: Duration::from_secs(3600 * 24 * 365 * 100),
    };
    let (journal, peak) = peak_of(|| Journal::open(&config));
    assert_eq!(journal.stats().waiting, 30);
    assert!(
        peak as u64 <= 2 * MAX_SEGMENT_FILE,
        "{peak} bytes to open the journal"
    );
}
