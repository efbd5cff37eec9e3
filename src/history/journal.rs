//! The journal: append-only segment files in the `[history]` directory holding the change
//! sets that could not be published, replayed in order after the reconnect and deleted once
//! handed out. Bounded by size and age (the oldest records go, counted), synced at most once
//! a second (a crash or power cut loses at most the last second and never what came before),
//! read again at start.
//!
//! Nothing on disk stops it: only regular files named `<sequence>.journal` that hold a
//! segment are read (anything else of that name, whatever its number, is skipped with a
//! warning, never opened in a way that blocks or follows a link, never read past the largest
//! segment; an empty one is removed, with a warning too), damage costs only
//! the damaged records ([`record::decode`]), and a sequence number near the top of its range
//! renumbers the segments instead of running out. A journal that cannot be written (a full
//! disk, a path that is no usable directory) is a pause: the newest records wait in memory
//! ([`PENDING_LIMIT`]), the cause is said once and kept as [`Journal::problem`] (the gateway
//! is unhealthy meanwhile), and writing resumes by itself when it can. Records handed out
//! that come back go in front of all that waits ([`front`]).

use std::collections::VecDeque;
use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use nix::unistd::{access, AccessFlags};

use super::record::{self, Record, MAGIC};
pub use super::segment_file::MAX_SEGMENT_FILE;
use super::segment_file::{read_segment_file, segment_names, MAX_SEGMENT, SUFFIX};
use crate::config::HistoryConfig;

/// The longest time written records stay unsynced.
pub const SYNC_INTERVAL: Duration = Duration::from_secs(1);
/// How often a journal that cannot be written is tried again.
pub const RETRY_INTERVAL: Duration = Duration::from_secs(1);
/// Encoded bytes of the newest records kept in memory while the journal cannot be written;
/// past it the oldest of them go, counted as dropped.
pub const PENDING_LIMIT: u64 = 1024 * 1024;
/// Segments are a sixteenth of the bound, so that dropping the oldest frees little at once,
/// within these limits.
const MIN_SEGMENT: u64 = 4 * 1024;
/// How far the segments are numbered up when one has to be put before the first.
const FRONT_ROOM: u64 = 1 << 20;
/// A segment numbered this high makes the journal number its segments from 0 again, in
/// order: a stray name cannot make the numbers run out.
const RENUMBER_FROM: u64 = 1 << 63;

/// The journal's health, for statistics, Prometheus and `check`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct JournalStats {
    /// Bytes on disk.
    pub bytes: u64,
    /// Records waiting to be replayed (on disk and in memory).
    pub waiting: u64,
    /// Records dropped by `max_size` or `max_age`, or from the memory queue when it is full.
    pub dropped: u64,
    /// Damaged parts found and skipped (torn tails, flipped bits, foreign files).
    pub damaged: u64,
    /// Records that could not be written when they came (they wait in memory).
    pub write_failures: u64,
}

/// One segment file.
#[derive(Debug)]
struct Segment {
    sequence: u64,
    bytes: u64,
    records: u64,
    /// Records handed out for replay from its start (they are no longer waiting).
    handed: u64,
    /// Read-at stamp of its newest record (ms since the epoch).
    newest_ms: u64,
}

impl Segment {
    /// A segment just made: its header and no record.
    fn begun(sequence: u64) -> Segment {
        Segment {
            sequence,
            bytes: MAGIC.len() as u64,
            records: 0,
            handed: 0,
            newest_ms: 0,
        }
    }
}

/// A segment being written: the one appended to, or the one in front of all that records
/// coming back are put in.
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
    /// The directory was read: `segments` holds what earlier runs left.
    loaded: bool,
    /// Oldest first; when `writer` is set, the last one is the one written.
    segments: VecDeque<Segment>,
    writer: Option<Writer>,
    /// The first segment, while records handed out come back into it
    /// ([`Journal::put_back`]).
    front_writer: Option<Writer>,
    next_sequence: u64,
    /// The oldest segment's records not handed out yet, once replay has started on it.
    replaying: Option<VecDeque<Record>>,
    /// Records handed out that came back while they could not be written (or while others
    /// that could not waited here), older than every record on disk, oldest first.
    returned: VecDeque<Record>,
    /// Where the next record coming back goes in `returned`: those coming back after one
    /// replay come before whatever that replay left, in the order they come.
    returned_at: usize,
    unsynced_since: Option<Instant>,
    /// Records not written yet, newer than every record on disk, oldest first.
    pending: VecDeque<Record>,
    pending_bytes: u64,
    /// Why the journal cannot be written now (said once), with the place.
    problem: Option<String>,
    retry_at: Option<Instant>,
    stats: JournalStats,
}

impl Journal {
    /// Opens (creating it when missing) the journal of `config`, reading what earlier runs
    /// left. Never fails: a directory that cannot be made, read or written is the journal's
    /// [`Journal::problem`] until it can.
    pub fn open(config: &HistoryConfig) -> Journal {
        let mut journal = Journal {
            dir: config.path.clone(),
            max_size: config.max_size,
            max_age: config.max_age,
            segment_size: (config.max_size / 16).clamp(MIN_SEGMENT, MAX_SEGMENT),
            loaded: false,
            segments: VecDeque::new(),
            writer: None,
            front_writer: None,
            next_sequence: 0,
            replaying: None,
            returned: VecDeque::new(),
            returned_at: 0,
            unsynced_since: None,
            pending: VecDeque::new(),
            pending_bytes: 0,
            problem: None,
            retry_at: None,
            stats: JournalStats::default(),
        };
        journal.recover(Instant::now());
        journal.refresh_stats();
        journal
    }

    pub fn stats(&self) -> JournalStats {
        self.stats
    }

    /// Why the journal cannot be written now, with the place; None while it can.
    pub fn problem(&self) -> Option<&str> {
        self.problem.as_deref()
    }

    /// What the journal in `dir` holds, read without changing anything (for `check`); None
    /// when there is no such directory yet.
    pub fn inspect(dir: &Path) -> io::Result<Option<JournalStats>> {
        if !dir.exists() {
            return Ok(None);
        }
        let mut stats = JournalStats::default();
        for (path, sequence) in segment_names(dir)? {
            let bytes = match read_segment_file(&path) {
                Ok(bytes) => bytes,
                // Not a regular file: no segment, and no damage either.
                Err(error) if error.kind() == io::ErrorKind::Unsupported => continue,
                Err(_) => {
                    stats.damaged += 1;
                    continue;
                }
            };
            let decoded = record::decode(&bytes);
            // A file with no header and no record is a stray file, not a damaged segment; nor
            // is one numbered beyond any sequence number.
            if !decoded.foreign && sequence.is_some() {
                stats.damaged += decoded.damaged;
                stats.bytes += bytes.len() as u64;
                stats.waiting += decoded.records.len() as u64;
            }
        }
        Ok(Some(stats))
    }

    /// Why the journal could not be kept in `dir`, with the place (the directory itself, or
    /// the nearest existing parent when it is still to be made); None when it can be. Makes
    /// nothing: the answer is the running user's.
    pub fn unusable(dir: &Path) -> Option<String> {
        let writable = AccessFlags::R_OK | AccessFlags::W_OK | AccessFlags::X_OK;
        match fs::metadata(dir) {
            Ok(meta) if !meta.is_dir() => Some(format!(
                "{}: is not a directory (the journal needs one)",
                dir.display()
            )),
            Ok(_) => access(dir, writable)
                .err()
                .map(|errno| format!("{}: {}", dir.display(), io::Error::from(errno))),
            Err(error)
                if error.kind() == io::ErrorKind::NotFound
                    || error.raw_os_error() == Some(libc::ENOTDIR) =>
            {
                let parent = dir.ancestors().skip(1).find(|p| p.exists())?;
                let cannot = match fs::metadata(parent) {
                    Ok(meta) if !meta.is_dir() => "is not a directory".to_string(),
                    Ok(_) => match access(parent, AccessFlags::W_OK | AccessFlags::X_OK) {
                        Ok(()) => return None,
                        Err(errno) => io::Error::from(errno).to_string(),
                    },
                    Err(error) => error.to_string(),
                };
                Some(format!(
                    "{}: {cannot}, so {} cannot be made",
                    parent.display(),
                    dir.display()
                ))
            }
            Err(error) => Some(format!("{}: {error}", dir.display())),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.stats.waiting == 0
    }

    /// Appends one record (not yet synced: see [`Journal::on_tick`]), dropping the oldest
    /// records when the bound would be passed and anything older than `max_age` at `now_ms`.
    /// While the journal cannot be written the record waits in memory behind the others.
    pub fn append(&mut self, record: &Record, now_ms: u64) {
        let Some(bytes) = record.encode() else {
            self.stats.write_failures += 1;
            tracing::warn!(device = %record.device, "history record too large for the journal: not kept");
            return;
        };
        self.drop_expired(now_ms);
        if self.problem.is_some() || !self.pending.is_empty() {
            self.stats.write_failures += 1;
            self.queue(record.clone(), bytes.len() as u64);
        } else if let Err(error) = self.store(&bytes, record.at_ms) {
            self.stats.write_failures += 1;
            self.fail(&error);
            self.queue(record.clone(), bytes.len() as u64);
        }
        self.refresh_stats();
    }

    /// Every tick: tries a journal that could not be written again (once a
    /// [`RETRY_INTERVAL`]), and syncs what was written once it has waited [`SYNC_INTERVAL`].
    pub fn on_tick(&mut self, now: Instant) {
        if self.problem.is_some() && !matches!(self.retry_at, Some(at) if now < at) {
            self.recover(now);
            self.refresh_stats();
        }
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
        for writer in [&self.writer, &self.front_writer].into_iter().flatten() {
            if let Err(error) = writer.file.sync_data() {
                tracing::error!(dir = %self.dir.display(), %error, "history journal cannot be synced");
            }
        }
    }

    /// Up to `limit` of the oldest records, in order, handed out for replay and deleted from
    /// the journal (a segment file goes when its last record is handed out); those that came
    /// back without being written come first, those waiting in memory after the disk's.
    /// Records older than `max_age` at `now_ms` are dropped, counted, instead.
    pub fn take(&mut self, limit: usize, now_ms: u64) -> Vec<Record> {
        self.drop_expired(now_ms);
        let oldest_kept = now_ms.saturating_sub(self.max_age.as_millis() as u64);
        let mut taken = Vec::new();
        while taken.len() < limit {
            if let Some(record) = self.returned.pop_front() {
                taken.push(record);
                continue;
            }
            let Some(front) = self.segments.front() else {
                break;
            };
            let (sequence, handed, total) = (front.sequence, front.handed, front.records);
            if self.replaying.is_none() {
                let mut records = self.read_segment(sequence);
                records.drain(..records.len().min(handed as usize));
                self.replaying = Some(records);
            }
            match self.replaying.as_mut().and_then(VecDeque::pop_front) {
                Some(record) => {
                    if let Some(front) = self.segments.front_mut() {
                        front.handed += 1;
                    }
                    taken.push(record);
                }
                None => {
                    if handed < total {
                        // Appended since it was read: read again past what was handed out.
                        let mut fresh = self.read_segment(sequence);
                        fresh.drain(..fresh.len().min(handed as usize));
                        if !fresh.is_empty() {
                            self.replaying = Some(fresh);
                            continue;
                        }
                    }
                    self.remove_front();
                }
            }
        }
        // A segment whose every record is out goes now, not at the next replay: a start in
        // between would replay it again.
        while self.segments.front().is_some_and(|s| s.handed >= s.records) {
            self.remove_front();
        }
        while taken.len() < limit && self.segments.is_empty() {
            let Some(record) = self.pending.pop_front() else {
                break;
            };
            self.pending_bytes = self.pending_bytes.saturating_sub(encoded_len(&record));
            taken.push(record);
        }
        if !taken.is_empty() {
            // What comes back from now on was handed out by this replay: it goes before
            // everything the replay left.
            self.close_front();
            self.returned_at = 0;
        }
        let (kept, expired): (Vec<Record>, Vec<Record>) = taken
            .into_iter()
            .partition(|record| record.at_ms >= oldest_kept);
        self.stats.dropped += expired.len() as u64;
        self.refresh_stats();
        kept
    }

    /// Reads the directory when it was not read yet, checks that it can be written, and
    /// writes what waits in memory; the problem is cleared (and that said) once all of it is.
    fn recover(&mut self, now: Instant) {
        self.retry_at = Some(now + RETRY_INTERVAL);
        let ready = if self.loaded { Ok(()) } else { self.load() };
        let ready = ready.and_then(|()| match Journal::unusable(&self.dir) {
            Some(problem) => Err(problem),
            None => Ok(()),
        });
        if let Err(problem) = ready {
            self.fail_with(problem);
            return;
        }
        let mut written = false;
        while let Some(record) = self.pending.front() {
            let Some(bytes) = record.encode() else {
                self.pending.pop_front();
                continue;
            };
            let at_ms = record.at_ms;
            if let Err(error) = self.store(&bytes, at_ms) {
                self.fail(&error);
                return;
            }
            written = true;
            self.pending_bytes = self.pending_bytes.saturating_sub(bytes.len() as u64);
            self.pending.pop_front();
        }
        // Nothing waited (the replay took it from memory): a full disk shows only when
        // something is written, so the next segment is begun to find out.
        if self.problem.is_some() && !written {
            if let Err(error) = self.start_segment() {
                self.fail(&error);
                return;
            }
        }
        if self.problem.take().is_some() {
            tracing::info!(dir = %self.dir.display(), "history journal writable again: what waited in memory is written");
        }
    }

    /// Makes the directory and reads the segments earlier runs left in it.
    fn load(&mut self) -> Result<(), String> {
        // The clearest cause the directory's state gives, else the error itself.
        let place = |error: io::Error| {
            Journal::unusable(&self.dir)
                .unwrap_or_else(|| format!("{}: {error}", self.dir.display()))
        };
        if fs::metadata(&self.dir).is_ok_and(|meta| !meta.is_dir()) {
            return Err(format!(
                "{}: is not a directory (the journal needs one)",
                self.dir.display()
            ));
        }
        fs::create_dir_all(&self.dir).map_err(place)?;
        let names = segment_names(&self.dir).map_err(place)?;
        for (path, sequence) in names {
            let bytes = match read_segment_file(&path) {
                Ok(bytes) => bytes,
                Err(error) => {
                    tracing::warn!(path = %path.display(), %error, "not a history journal segment: skipped, left alone");
                    if error.kind() != io::ErrorKind::Unsupported {
                        self.stats.damaged += 1;
                    }
                    continue;
                }
            };
            let decoded = record::decode(&bytes);
            if decoded.foreign {
                // A stray file, not a damaged segment: said once per start, never counted.
                tracing::warn!(path = %path.display(), "not a history journal segment (no header, no record): skipped, left alone");
                continue;
            }
            self.stats.damaged += decoded.damaged;
            if let Some(offset) = decoded.first_damage {
                tracing::warn!(
                    path = %path.display(),
                    offset,
                    damaged = decoded.damaged,
                    intact = decoded.records.len(),
                    "history journal segment damaged: the damaged records are skipped, the intact ones replayed"
                );
            }
            if decoded.records.is_empty() {
                // Nothing to replay. A whole header is a segment of ours begun and left empty;
                // anything shorter (an empty file, a part of the header) may be a crash right
                // after the file was made, or anybody's empty file: said, like every other
                // file of that name that is no segment, whatever its number.
                if bytes.len() < MAGIC.len() {
                    tracing::warn!(path = %path.display(), bytes = bytes.len(),
                        "history journal file without a header (an empty file, or a crash right \
                         after it was made): no segment, removed");
                }
                let _ = fs::remove_file(&path);
                continue;
            }
            let Some(sequence) = sequence else {
                // Records under a number no segment of ours can have: not replayed, since
                // they cannot be put in order.
                tracing::warn!(path = %path.display(), records = decoded.records.len(),
                    "not a history journal segment (its number is beyond any sequence number): \
                     skipped, left alone");
                continue;
            };
            self.segments.push_back(Segment {
                sequence,
                bytes: bytes.len() as u64,
                records: decoded.records.len() as u64,
                handed: 0,
                newest_ms: decoded.records.iter().map(|r| r.at_ms).max().unwrap_or(0),
            });
        }
        self.loaded = true;
        self.next_sequence = self
            .segments
            .back()
            .map_or(0, |s| s.sequence.saturating_add(1));
        if self.next_sequence >= RENUMBER_FROM {
            self.renumber();
        }
        Ok(())
    }

    /// Writes one encoded record, making room for it first; what a failed write left is
    /// taken back, so that a full disk leaves no torn record behind.
    fn store(&mut self, bytes: &[u8], at_ms: u64) -> io::Result<()> {
        let length = bytes.len() as u64;
        while self.disk_bytes() + length > self.max_size && self.drop_oldest() {}
        let full = self
            .segments
            .back()
            .is_some_and(|segment| segment.bytes + length > self.segment_size);
        if self.writer.is_none() || full {
            self.start_segment()?;
        }
        let (Some(writer), Some(segment)) = (&mut self.writer, self.segments.back_mut()) else {
            return Err(io::Error::other("no segment open"));
        };
        if let Err(error) = writer.file.write_all(bytes) {
            if writer.file.set_len(segment.bytes).is_err() {
                // The torn tail stays: it is damage the reader skips; the next record
                // starts a new segment.
                self.writer = None;
            }
            return Err(error);
        }
        segment.bytes += length;
        segment.records += 1;
        segment.newest_ms = segment.newest_ms.max(at_ms);
        self.unsynced_since.get_or_insert_with(Instant::now);
        Ok(())
    }

    /// Closes the segment written (synced) and opens the next, under a free name.
    fn start_segment(&mut self) -> io::Result<()> {
        if let Some(writer) = self.writer.take() {
            writer.file.sync_data()?;
        }
        if self.next_sequence >= RENUMBER_FROM {
            self.renumber();
        }
        let (file, sequence) = loop {
            let sequence = self.next_sequence;
            self.next_sequence = sequence
                .checked_add(1)
                .ok_or_else(|| io::Error::other("segment numbers exhausted"))?;
            match self.create_segment(sequence) {
                Ok(file) => break (file, sequence),
                // Something else has that name: it is left alone, the next one is taken.
                Err(error) if error.kind() == io::ErrorKind::AlreadyExists => continue,
                Err(error) => return Err(error),
            }
        };
        self.segments.push_back(Segment::begun(sequence));
        self.writer = Some(Writer { file, sequence });
        // The new name must survive a power cut as well as the records in it.
        File::open(&self.dir)?.sync_all()
    }

    /// Makes segment file `sequence` (never over another file) with its header.
    fn create_segment(&self, sequence: u64) -> io::Result<File> {
        let mut file = OpenOptions::new()
            .create_new(true)
            .append(true)
            .open(self.path_of(sequence))?;
        if let Err(error) = file.write_all(MAGIC) {
            let _ = fs::remove_file(self.path_of(sequence));
            return Err(error);
        }
        Ok(file)
    }

    /// Numbers the segments from 0 again, in order, past names something else holds.
    fn renumber(&mut self) {
        let mut next = 0u64;
        for index in 0..self.segments.len() {
            let old = self.segments[index].sequence;
            while next != old && fs::symlink_metadata(self.path_of(next)).is_ok() {
                next += 1;
            }
            if next != old {
                if let Err(error) = fs::rename(self.path_of(old), self.path_of(next)) {
                    tracing::warn!(%error, "history journal segment could not be renumbered");
                    return;
                }
                self.segments[index].sequence = next;
                for writer in [&mut self.writer, &mut self.front_writer]
                    .into_iter()
                    .flatten()
                {
                    if writer.sequence == old {
                        writer.sequence = next;
                    }
                }
            }
            next += 1;
        }
        self.next_sequence = next;
        tracing::info!(dir = %self.dir.display(), segments = self.segments.len(), "history journal segments renumbered from 0");
    }

    /// Keeps `record` in memory until it can be written, the newest first when there is no
    /// room for all.
    fn queue(&mut self, record: Record, length: u64) {
        self.pending.push_back(record);
        self.pending_bytes += length;
        while self.pending_bytes > PENDING_LIMIT {
            let Some(oldest) = self.pending.pop_front() else {
                break;
            };
            self.pending_bytes = self.pending_bytes.saturating_sub(encoded_len(&oldest));
            self.stats.dropped += 1;
        }
    }

    fn fail(&mut self, error: &io::Error) {
        self.fail_with(format!("{}: {error}", self.dir.display()));
    }

    /// Says the first cause once; the journal is tried again every [`RETRY_INTERVAL`].
    fn fail_with(&mut self, problem: String) {
        if self.problem.is_none() {
            tracing::error!(
                %problem,
                "history journal cannot be written: the newest values measured while the \
                 broker is away wait in memory (at most 1 MiB) until it can; polling and live \
                 publishing go on; the gateway reports itself unhealthy meanwhile"
            );
        }
        self.problem = Some(problem);
    }

    fn writer_is(&self, sequence: u64) -> bool {
        self.writer.as_ref().is_some_and(|w| w.sequence == sequence)
    }

    /// The oldest segment's records that were not handed out yet. A segment read while it is
    /// still written is read again when it has grown.
    fn read_segment(&mut self, sequence: u64) -> VecDeque<Record> {
        let path = self.path_of(sequence);
        match read_segment_file(&path) {
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
        if self
            .front_writer
            .as_ref()
            .is_some_and(|w| w.sequence == segment.sequence)
        {
            self.front_writer = None;
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
        let Some(waiting) = self
            .segments
            .front()
            .map(|s| s.records.saturating_sub(s.handed))
        else {
            return false;
        };
        self.stats.dropped += waiting;
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

    fn disk_bytes(&self) -> u64 {
        self.segments.iter().map(|s| s.bytes).sum()
    }

    fn refresh_stats(&mut self) {
        self.stats.bytes = self.disk_bytes();
        let on_disk: u64 = self
            .segments
            .iter()
            .map(|s| s.records.saturating_sub(s.handed))
            .sum();
        self.stats.waiting = on_disk + (self.pending.len() + self.returned.len()) as u64;
    }

    fn path_of(&self, sequence: u64) -> PathBuf {
        self.dir.join(format!("{sequence:020}.{SUFFIX}"))
    }
}

fn encoded_len(record: &Record) -> u64 {
    record.encode().map_or(0, |bytes| bytes.len() as u64)
}

#[path = "journal_front.rs"]
mod front;

#[cfg(test)]
#[path = "journal_tests.rs"]
mod tests;
