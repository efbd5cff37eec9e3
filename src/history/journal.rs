//! The journal: append-only segment files in the `[history]` directory holding the change
//! sets that could not be published, replayed in order after the reconnect and deleted once
//! handed out. Bounded by size and age (the oldest records go, counted), synced at most once
//! a second (a crash or power cut loses at most the last second and never what came before),
//! read again at start. A write that fails (full disk, unwritable directory) is said once and
//! counted; the caller goes on without it.

use std::collections::VecDeque;
use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::record::{self, Record, MAGIC};
use crate::config::HistoryConfig;

/// Segment files are named `<sequence>.journal`, the sequence zero-padded so that names sort.
const SUFFIX: &str = "journal";
/// The longest time written records stay unsynced.
pub const SYNC_INTERVAL: Duration = Duration::from_secs(1);
/// Segments are a sixteenth of the bound, so that dropping the oldest frees little at once,
/// within these limits.
const MIN_SEGMENT: u64 = 4 * 1024;
const MAX_SEGMENT: u64 = 4 * 1024 * 1024;

/// The journal's health, for statistics, Prometheus and `check`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct JournalStats {
    /// Bytes on disk.
    pub bytes: u64,
    /// Records waiting to be replayed.
    pub waiting: u64,
    /// Records dropped by `max_size` or `max_age`.
    pub dropped: u64,
    /// Damaged parts found and skipped (torn tails, flipped bits, foreign files).
    pub damaged: u64,
    /// Records that could not be written (full disk, unwritable directory).
    pub write_failures: u64,
}

/// One segment file.
#[derive(Debug)]
struct Segment {
    sequence: u64,
    bytes: u64,
    records: u64,
    /// Read-at stamp of its newest record (ms since the epoch).
    newest_ms: u64,
}

/// The segment being appended to.
#[derive(Debug)]
struct Writer {
    file: File,
    sequence: u64,
}

/// The journal in one directory.
#[derive(Debug)]
pub struct Journal {
    dir: PathBuf,
    max_size: u64,
    max_age: Duration,
    segment_size: u64,
    /// Oldest first; when `writer` is set, the last one is the one written.
    segments: VecDeque<Segment>,
    writer: Option<Writer>,
    next_sequence: u64,
    /// The oldest segment's records, once replay has started on it, and how many are out.
    replaying: Option<(VecDeque<Record>, u64)>,
    unsynced_since: Option<Instant>,
    /// A write failed and was said; the next success is said too.
    failing: bool,
    stats: JournalStats,
}

impl Journal {
    /// Opens (creating it when missing) the journal of `config`, reading what earlier runs
    /// left. Fails only when the directory cannot be made or listed.
    pub fn open(config: &HistoryConfig) -> io::Result<Journal> {
        fs::create_dir_all(&config.path)?;
        let mut journal = Journal {
            dir: config.path.clone(),
            max_size: config.max_size,
            max_age: config.max_age,
            segment_size: (config.max_size / 16).clamp(MIN_SEGMENT, MAX_SEGMENT),
            segments: VecDeque::new(),
            writer: None,
            next_sequence: 0,
            replaying: None,
            unsynced_since: None,
            failing: false,
            stats: JournalStats::default(),
        };
        let mut sequences: Vec<u64> = fs::read_dir(&config.path)?
            .flatten()
            .filter_map(|entry| sequence_of(&entry.path()))
            .collect();
        sequences.sort_unstable();
        for sequence in sequences {
            journal.next_sequence = sequence + 1;
            let path = journal.path_of(sequence);
            let bytes = match fs::read(&path) {
                Ok(bytes) => bytes,
                Err(error) => {
                    tracing::warn!(path = %path.display(), %error, "history journal segment unreadable: skipped");
                    journal.stats.damaged += 1;
                    continue;
                }
            };
            let decoded = record::decode(&bytes);
            journal.stats.damaged += decoded.damaged;
            if decoded.damaged > 0 {
                tracing::warn!(
                    path = %path.display(),
                    damaged = decoded.damaged,
                    intact = decoded.records.len(),
                    foreign = decoded.foreign,
                    "history journal segment damaged: the damaged parts are skipped"
                );
            }
            if decoded.foreign {
                continue; // not ours: left alone
            }
            if decoded.records.is_empty() {
                let _ = fs::remove_file(&path);
                continue;
            }
            journal.segments.push_back(Segment {
                sequence,
                bytes: bytes.len() as u64,
                records: decoded.records.len() as u64,
                newest_ms: decoded.records.iter().map(|r| r.at_ms).max().unwrap_or(0),
            });
        }
        journal.refresh_stats();
        Ok(journal)
    }

    pub fn stats(&self) -> JournalStats {
        self.stats
    }

    /// What the journal in `dir` holds, read without changing anything (for `check`); None
    /// when there is no such directory yet.
    pub fn inspect(dir: &Path) -> io::Result<Option<JournalStats>> {
        if !dir.exists() {
            return Ok(None);
        }
        let mut stats = JournalStats::default();
        for entry in fs::read_dir(dir)?.flatten() {
            let path = entry.path();
            if sequence_of(&path).is_none() {
                continue;
            }
            let bytes = fs::read(&path)?;
            let decoded = record::decode(&bytes);
            stats.damaged += decoded.damaged;
            if !decoded.foreign {
                stats.bytes += bytes.len() as u64;
                stats.waiting += decoded.records.len() as u64;
            }
        }
        Ok(Some(stats))
    }

    pub fn is_empty(&self) -> bool {
        self.stats.waiting == 0
    }

    /// Appends one record (not yet synced: see [`Journal::sync_due`]), dropping the oldest
    /// records when the bound would be passed and anything older than `max_age` at `now_ms`.
    pub fn append(&mut self, record: &Record, now_ms: u64) {
        let Some(bytes) = record.encode() else {
            self.stats.write_failures += 1;
            tracing::warn!(device = %record.device, "history record too large for the journal: not kept");
            return;
        };
        self.drop_expired(now_ms);
        let length = bytes.len() as u64;
        while self.stats.bytes + length > self.max_size && self.drop_oldest() {}
        match self.write(&bytes) {
            Ok(()) => {
                if self.failing {
                    self.failing = false;
                    tracing::info!(dir = %self.dir.display(), "history journal writable again");
                }
                if let Some(segment) = self.segments.back_mut() {
                    segment.bytes += length;
                    segment.records += 1;
                    segment.newest_ms = segment.newest_ms.max(record.at_ms);
                }
                self.unsynced_since.get_or_insert_with(Instant::now);
            }
            Err(error) => {
                self.stats.write_failures += 1;
                // What was half written is a torn tail: the next record starts a new segment.
                self.writer = None;
                if !self.failing {
                    self.failing = true;
                    tracing::error!(
                        dir = %self.dir.display(),
                        %error,
                        "history journal cannot be written: values measured while the broker \
                         is away are not kept until it can; polling and live publishing go on"
                    );
                }
            }
        }
        self.refresh_stats();
    }

    fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        let full = self
            .segments
            .back()
            .is_some_and(|segment| segment.bytes + bytes.len() as u64 > self.segment_size);
        if self.writer.is_none() || full {
            self.start_segment()?;
        }
        match &mut self.writer {
            Some(writer) => writer.file.write_all(bytes),
            None => Err(io::Error::other("no segment open")),
        }
    }

    /// Closes the segment written (synced) and opens the next.
    fn start_segment(&mut self) -> io::Result<()> {
        if let Some(writer) = self.writer.take() {
            writer.file.sync_data()?;
        }
        let sequence = self.next_sequence;
        let path = self.path_of(sequence);
        let mut file = OpenOptions::new()
            .create_new(true)
            .append(true)
            .open(&path)?;
        file.write_all(MAGIC)?;
        // The new name must survive a power cut as well as the records in it.
        File::open(&self.dir)?.sync_all()?;
        self.next_sequence += 1;
        self.segments.push_back(Segment {
            sequence,
            bytes: MAGIC.len() as u64,
            records: 0,
            newest_ms: 0,
        });
        self.writer = Some(Writer { file, sequence });
        Ok(())
    }

    /// Syncs what was written when it has waited [`SYNC_INTERVAL`] (call every tick).
    pub fn sync_due(&mut self, now: Instant) {
        if self
            .unsynced_since
            .is_some_and(|since| now.saturating_duration_since(since) >= SYNC_INTERVAL)
        {
            self.sync();
        }
    }

    /// Syncs what was written now (on shutdown).
    pub fn sync(&mut self) {
        self.unsynced_since = None;
        if let Some(writer) = &self.writer {
            if let Err(error) = writer.file.sync_data() {
                self.stats.write_failures += 1;
                tracing::error!(dir = %self.dir.display(), %error, "history journal cannot be synced");
            }
        }
    }

    /// Up to `limit` of the oldest records, in order, handed out for replay and deleted from
    /// the journal (a segment file goes when its last record is handed out). Records older
    /// than `max_age` at `now_ms` are dropped, counted, instead.
    pub fn take(&mut self, limit: usize, now_ms: u64) -> Vec<Record> {
        self.drop_expired(now_ms);
        let oldest_kept = now_ms.saturating_sub(self.max_age.as_millis() as u64);
        let mut out = Vec::new();
        while out.len() < limit {
            let Some(sequence) = self.segments.front().map(|segment| segment.sequence) else {
                break;
            };
            if self.replaying.is_none() {
                self.replaying = Some((self.read_segment(sequence), 0));
            }
            let Some((records, handed)) = &mut self.replaying else {
                break;
            };
            match records.pop_front() {
                Some(record) => {
                    *handed += 1;
                    if record.at_ms < oldest_kept {
                        self.stats.dropped += 1;
                    } else {
                        out.push(record);
                    }
                }
                None => {
                    let total = self.segments.front().map_or(0, |s| s.records);
                    let handed = *handed;
                    if handed < total {
                        // Appended since it was read: read again past what was handed out.
                        let mut fresh = self.read_segment(sequence);
                        fresh.drain(..fresh.len().min(handed as usize));
                        if !fresh.is_empty() {
                            self.replaying = Some((fresh, handed));
                            continue;
                        }
                    }
                    self.remove_front();
                }
            }
        }
        self.refresh_stats();
        out
    }

    fn writer_is(&self, sequence: u64) -> bool {
        self.writer.as_ref().is_some_and(|w| w.sequence == sequence)
    }

    /// The oldest segment's records that were not handed out yet. A segment read while it is
    /// still written is read again when it has grown.
    fn read_segment(&mut self, sequence: u64) -> VecDeque<Record> {
        let path = self.path_of(sequence);
        match fs::read(&path) {
            Ok(bytes) => record::decode(&bytes).records.into(),
            Err(error) => {
                tracing::warn!(path = %path.display(), %error, "history journal segment unreadable: skipped");
                self.stats.damaged += 1;
                VecDeque::new()
            }
        }
    }

    /// Deletes the oldest segment; false when there is none to delete.
    fn remove_front(&mut self) -> bool {
        let Some(segment) = self.segments.pop_front() else {
            return false;
        };
        if self.writer_is(segment.sequence) {
            self.writer = None;
            self.unsynced_since = None;
        }
        self.replaying = None;
        if let Err(error) = fs::remove_file(self.path_of(segment.sequence)) {
            if error.kind() != io::ErrorKind::NotFound {
                tracing::warn!(%error, "history journal segment could not be deleted");
            }
        }
        true
    }

    /// Drops the oldest segment to keep the bound, counting its records not yet handed out.
    fn drop_oldest(&mut self) -> bool {
        let handed = self.replaying.as_ref().map_or(0, |(_, handed)| *handed);
        let Some(records) = self.segments.front().map(|s| s.records) else {
            return false;
        };
        self.stats.dropped += records.saturating_sub(handed);
        self.remove_front()
    }

    fn drop_expired(&mut self, now_ms: u64) {
        let oldest_kept = now_ms.saturating_sub(self.max_age.as_millis() as u64);
        while self
            .segments
            .front()
            .is_some_and(|s| s.records > 0 && s.newest_ms < oldest_kept)
        {
            self.drop_oldest();
        }
    }

    fn refresh_stats(&mut self) {
        let handed = self.replaying.as_ref().map_or(0, |(_, handed)| *handed);
        self.stats.bytes = self.segments.iter().map(|s| s.bytes).sum();
        let records: u64 = self.segments.iter().map(|s| s.records).sum();
        self.stats.waiting = records.saturating_sub(handed);
    }

    fn path_of(&self, sequence: u64) -> PathBuf {
        self.dir.join(format!("{sequence:020}.{SUFFIX}"))
    }
}

/// The sequence number of a segment file's path; None for any other file.
fn sequence_of(path: &Path) -> Option<u64> {
    if path.extension()? != SUFFIX {
        return None;
    }
    path.file_stem()?.to_str()?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    const NOW: u64 = 1_796_223_601_123;

    fn config(dir: &Path, max_size: u64) -> HistoryConfig {
        HistoryConfig {
            path: dir.to_path_buf(),
            max_size,
            max_age: Duration::from_secs(3600),
        }
    }

    fn record(n: u64) -> Record {
        Record {
            at_ms: NOW + n,
            device: "fan1".to_string(),
            document: format!("{{\"values\":{{\"fan_speed\":{n}}}}}"),
        }
    }

    fn open(dir: &Path, max_size: u64) -> Journal {
        Journal::open(&config(dir, max_size)).unwrap_or_else(|error| panic!("{error}"))
    }

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("rtu2mqtt-journal-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    fn segment_files(dir: &Path) -> Vec<PathBuf> {
        let mut files: Vec<PathBuf> = fs::read_dir(dir)
            .map(|entries| entries.flatten().map(|e| e.path()).collect())
            .unwrap_or_default();
        files.retain(|path| sequence_of(path).is_some());
        files.sort();
        files
    }

    #[test]
    fn records_come_back_in_order_after_a_restart_and_are_deleted_once_handed_out() {
        let dir = scratch("restart");
        let mut journal = open(&dir, 1 << 20);
        for n in 0..500 {
            journal.append(&record(n), NOW + n);
        }
        // No sync, no clean close: what a SIGKILL leaves (the page cache has it).
        drop(journal);
        let mut journal = open(&dir, 1 << 20);
        assert_eq!(journal.stats().waiting, 500);
        let mut replayed = Vec::new();
        loop {
            let batch = journal.take(64, NOW);
            if batch.is_empty() {
                break;
            }
            assert!(batch.len() <= 64);
            replayed.extend(batch);
        }
        assert_eq!(replayed, (0..500).map(record).collect::<Vec<_>>());
        assert_eq!(journal.stats(), JournalStats::default());
        assert!(segment_files(&dir).is_empty(), "{:?}", segment_files(&dir));
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn appends_during_a_replay_come_after_it() {
        let dir = scratch("interleaved");
        let mut journal = open(&dir, 1 << 20);
        for n in 0..10 {
            journal.append(&record(n), NOW);
        }
        let mut replayed = journal.take(4, NOW);
        for n in 10..20 {
            journal.append(&record(n), NOW);
        }
        loop {
            let batch = journal.take(3, NOW);
            if batch.is_empty() {
                break;
            }
            replayed.extend(batch);
        }
        assert_eq!(replayed, (0..20).map(record).collect::<Vec<_>>());
        assert!(journal.is_empty());
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_bound_holds_during_a_long_outage_and_the_oldest_go_counted() {
        let dir = scratch("bound");
        let max_size = 64 * 1024;
        let mut journal = open(&dir, max_size);
        let total = 20_000;
        for n in 0..total {
            journal.append(&record(n), NOW + n);
            assert!(journal.stats().bytes <= max_size, "{:?}", journal.stats());
        }
        let on_disk: u64 = segment_files(&dir)
            .iter()
            .filter_map(|path| fs::metadata(path).ok())
            .map(|meta| meta.len())
            .sum();
        assert!(on_disk <= max_size, "{on_disk} bytes on disk");
        let stats = journal.stats();
        assert_eq!(stats.waiting + stats.dropped, total);
        assert!(stats.dropped > 0);
        // What is left is the newest records, in order, none missing.
        let mut replayed = Vec::new();
        loop {
            let batch = journal.take(1000, NOW + total);
            if batch.is_empty() {
                break;
            }
            replayed.extend(batch);
        }
        let first = total - replayed.len() as u64;
        assert_eq!(replayed, (first..total).map(record).collect::<Vec<_>>());
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn records_older_than_max_age_go_counted() {
        let dir = scratch("age");
        let mut journal = open(&dir, 1 << 20);
        for n in 0..10 {
            journal.append(&record(n), NOW);
        }
        let hour_later = NOW + 3_600_000 + 5;
        let replayed = journal.take(100, hour_later);
        assert_eq!(replayed, (5..10).map(record).collect::<Vec<_>>());
        assert_eq!(journal.stats().dropped, 5);
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn damaged_segments_are_skipped_counted_and_the_rest_replayed() {
        let dir = scratch("damaged");
        let mut journal = open(&dir, 64 * 1024);
        for n in 0..600 {
            journal.append(&record(n), NOW);
        }
        drop(journal);
        let files = segment_files(&dir);
        assert!(files.len() >= 3, "{files:?}");
        // A flipped bit in the first segment, a torn tail on the last, a foreign file.
        let mut first = fs::read(&files[0]).unwrap_or_default();
        first[MAGIC.len() + 20] ^= 0x04;
        fs::write(&files[0], first).unwrap_or_else(|e| panic!("{e}"));
        let last = files.last().cloned().unwrap_or_default();
        let torn = fs::read(&last).unwrap_or_default();
        fs::write(&last, &torn[..torn.len() - 3]).unwrap_or_else(|e| panic!("{e}"));
        fs::write(dir.join("00000000000000000000.journal.bak"), b"other").unwrap_or_default();
        let foreign = dir.join(format!("{:020}.{SUFFIX}", 99_999));
        fs::write(&foreign, b"#!/bin/sh\necho not a journal\n").unwrap_or_else(|e| panic!("{e}"));

        let inspected = Journal::inspect(&dir).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            inspected.map(|stats| (stats.waiting, stats.damaged)),
            Some((598, 3))
        );
        let mut journal = open(&dir, 64 * 1024);
        assert_eq!(journal.stats().damaged, 3);
        let mut replayed = Vec::new();
        loop {
            let batch = journal.take(100, NOW);
            if batch.is_empty() {
                break;
            }
            replayed.extend(batch);
        }
        let expected: Vec<Record> = (1..599).map(record).collect();
        assert_eq!(replayed, expected);
        assert!(foreign.exists(), "a file that is not ours is left alone");
        // New records go to a new segment, after the foreign one's number.
        journal.append(&record(1000), NOW);
        assert_eq!(journal.take(10, NOW), vec![record(1000)]);
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn an_unwritable_directory_is_counted_and_nothing_panics() {
        let dir = scratch("unwritable");
        let mut journal = open(&dir, 1 << 20);
        fs::remove_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        fs::write(&dir, b"now a file").unwrap_or_else(|e| panic!("{e}"));
        for n in 0..3 {
            journal.append(&record(n), NOW);
        }
        assert_eq!(journal.stats().write_failures, 3);
        assert!(journal.take(10, NOW).is_empty());
        let _ = fs::remove_file(&dir);
    }
}
