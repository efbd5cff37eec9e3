//! The journal: append-only segment files in the `[history]` directory holding the change
//! sets that could not be published, replayed in order after the reconnect and deleted once
//! handed out. Bounded by size and age (the oldest records go, counted), synced at most once
//! a second (a crash or power cut loses at most the last second and never what came before),
//! read again at start.
//!
//! Nothing on disk stops it: only regular files named `<sequence>.journal` that hold a
//! segment are read (anything else of that name is skipped with a warning, never opened in a
//! way that blocks or follows a link, never read past the largest segment), damage costs only
//! the damaged records ([`record::decode`]), and a sequence number near the top of its range
//! renumbers the segments instead of running out. A journal that cannot be written (a full
//! disk, a path that is no usable directory) is a pause: the newest records wait in memory
//! ([`PENDING_LIMIT`]), the cause is said once and kept as [`Journal::problem`] (the gateway
//! is unhealthy meanwhile), and writing resumes by itself when it can.

use std::collections::VecDeque;
use std::fs::{self, File, OpenOptions};
use std::io::{self, Read, Write};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use nix::unistd::{access, AccessFlags};

use super::record::{self, Record, MAGIC, MAX_RECORD};
use crate::config::HistoryConfig;

/// Segment files are named `<sequence>.journal`, the sequence zero-padded so that names sort.
const SUFFIX: &str = "journal";
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
const MAX_SEGMENT: u64 = 4 * 1024 * 1024;
/// No segment is ever longer: a larger file of that name is not one, and is not read.
pub const MAX_SEGMENT_FILE: u64 = MAX_SEGMENT + MAGIC.len() as u64 + MAX_RECORD as u64;
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
    /// The directory was read: `segments` holds what earlier runs left.
    loaded: bool,
    /// Oldest first; when `writer` is set, the last one is the one written.
    segments: VecDeque<Segment>,
    writer: Option<Writer>,
    next_sequence: u64,
    /// The oldest segment's records, once replay has started on it, and how many are out.
    replaying: Option<(VecDeque<Record>, u64)>,
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
            next_sequence: 0,
            replaying: None,
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
        for (path, _) in segment_names(dir)? {
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
            stats.damaged += decoded.damaged;
            if !decoded.foreign {
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
        if let Some(writer) = &self.writer {
            if let Err(error) = writer.file.sync_data() {
                tracing::error!(dir = %self.dir.display(), %error, "history journal cannot be synced");
            }
        }
    }

    /// Up to `limit` of the oldest records, in order, handed out for replay and deleted from
    /// the journal (a segment file goes when its last record is handed out); those waiting in
    /// memory come after the disk's. Records older than `max_age` at `now_ms` are dropped,
    /// counted, instead.
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
        while out.len() < limit && self.segments.is_empty() {
            let Some(record) = self.pending.pop_front() else {
                break;
            };
            self.pending_bytes = self.pending_bytes.saturating_sub(encoded_len(&record));
            if record.at_ms < oldest_kept {
                self.stats.dropped += 1;
            } else {
                out.push(record);
            }
        }
        self.refresh_stats();
        out
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
            self.stats.damaged += decoded.damaged;
            if decoded.foreign {
                tracing::warn!(path = %path.display(), "not a history journal segment (no header, no record): skipped, left alone");
                continue;
            }
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
                let _ = fs::remove_file(&path);
                continue;
            }
            self.segments.push_back(Segment {
                sequence,
                bytes: bytes.len() as u64,
                records: decoded.records.len() as u64,
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
        let (mut file, sequence) = loop {
            let sequence = self.next_sequence;
            self.next_sequence = sequence
                .checked_add(1)
                .ok_or_else(|| io::Error::other("segment numbers exhausted"))?;
            match OpenOptions::new()
                .create_new(true)
                .append(true)
                .open(self.path_of(sequence))
            {
                Ok(file) => break (file, sequence),
                // Something else has that name: it is left alone, the next one is taken.
                Err(error) if error.kind() == io::ErrorKind::AlreadyExists => continue,
                Err(error) => return Err(error),
            }
        };
        if let Err(error) = file.write_all(MAGIC) {
            let _ = fs::remove_file(self.path_of(sequence));
            return Err(error);
        }
        self.segments.push_back(Segment {
            sequence,
            bytes: MAGIC.len() as u64,
            records: 0,
            newest_ms: 0,
        });
        self.writer = Some(Writer { file, sequence });
        // The new name must survive a power cut as well as the records in it.
        File::open(&self.dir)?.sync_all()
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
                if let Some(writer) = self.writer.as_mut().filter(|w| w.sequence == old) {
                    writer.sequence = next;
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

    fn disk_bytes(&self) -> u64 {
        self.segments.iter().map(|s| s.bytes).sum()
    }

    fn refresh_stats(&mut self) {
        let handed = self.replaying.as_ref().map_or(0, |(_, handed)| *handed);
        self.stats.bytes = self.disk_bytes();
        let records: u64 = self.segments.iter().map(|s| s.records).sum();
        self.stats.waiting = records.saturating_sub(handed) + self.pending.len() as u64;
    }

    fn path_of(&self, sequence: u64) -> PathBuf {
        self.dir.join(format!("{sequence:020}.{SUFFIX}"))
    }
}

fn encoded_len(record: &Record) -> u64 {
    record.encode().map_or(0, |bytes| bytes.len() as u64)
}

/// The files of `dir` named like segments, with their sequence numbers, in order.
fn segment_names(dir: &Path) -> io::Result<Vec<(PathBuf, u64)>> {
    let mut names: Vec<(PathBuf, u64)> = fs::read_dir(dir)?
        .flatten()
        .filter_map(|entry| {
            let path = entry.path();
            sequence_of(&path).map(|sequence| (path, sequence))
        })
        .collect();
    names.sort_unstable_by_key(|(_, sequence)| *sequence);
    Ok(names)
}

/// A segment file's bytes. Only a regular file is one: anything else of that name (a FIFO,
/// a socket, a device, a directory, a symbolic link) is refused before it is opened
/// ([`io::ErrorKind::Unsupported`]), opening never blocks or follows a link, the kind is
/// checked again on what was opened, and a file longer than any segment is not read.
fn read_segment_file(path: &Path) -> io::Result<Vec<u8>> {
    let not_segment = |kind: &str| {
        io::Error::new(
            io::ErrorKind::Unsupported,
            format!("{kind}, not a regular file"),
        )
    };
    let kind = fs::symlink_metadata(path)?.file_type();
    if !kind.is_file() {
        return Err(not_segment(kind_name(kind)));
    }
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOFOLLOW)
        .open(path)?;
    let meta = file.metadata()?;
    if !meta.file_type().is_file() {
        return Err(not_segment(kind_name(meta.file_type())));
    }
    if meta.len() > MAX_SEGMENT_FILE {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "{} bytes, longer than any segment ({MAX_SEGMENT_FILE})",
                meta.len()
            ),
        ));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(MAX_SEGMENT_FILE).read_to_end(&mut bytes)?;
    Ok(bytes)
}

fn kind_name(kind: fs::FileType) -> &'static str {
    if kind.is_symlink() {
        "a symbolic link"
    } else if kind.is_dir() {
        "a directory"
    } else if kind.is_fifo() {
        "a FIFO"
    } else if kind.is_socket() {
        "a socket"
    } else if kind.is_block_device() || kind.is_char_device() {
        "a device"
    } else {
        "not a regular file"
    }
}

/// The sequence number of a segment file's path; None for any other file.
fn sequence_of(path: &Path) -> Option<u64> {
    if path.extension()? != SUFFIX {
        return None;
    }
    let stem = path.file_stem()?.to_str()?;
    if stem.is_empty() || !stem.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    stem.parse().ok()
}

#[cfg(test)]
mod tests {
    use std::process::Command;

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
        Journal::open(&config(dir, max_size))
    }

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("rtu2mqtt-journal-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    /// `scratch(name)`, made.
    fn made(name: &str) -> PathBuf {
        let dir = scratch(name);
        fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        dir
    }

    fn fifo(path: &Path) {
        nix::unistd::mkfifo(path, nix::sys::stat::Mode::S_IRWXU).unwrap_or_else(|e| panic!("{e}"));
    }

    fn segment_files(dir: &Path) -> Vec<PathBuf> {
        let mut files: Vec<PathBuf> = fs::read_dir(dir)
            .map(|entries| entries.flatten().map(|e| e.path()).collect())
            .unwrap_or_default();
        files.retain(|path| sequence_of(path).is_some());
        files.sort();
        files
    }

    fn take_all(journal: &mut Journal, now_ms: u64) -> Vec<Record> {
        let mut replayed = Vec::new();
        loop {
            let batch = journal.take(100, now_ms);
            if batch.is_empty() {
                return replayed;
            }
            replayed.extend(batch);
        }
    }

    /// Writes a segment holding `records` under `name` in `dir`.
    fn write_segment(dir: &Path, name: &str, records: impl IntoIterator<Item = u64>) -> PathBuf {
        let mut bytes = MAGIC.to_vec();
        for n in records {
            bytes.extend(record(n).encode().unwrap_or_default());
        }
        let path = dir.join(name);
        fs::write(&path, bytes).unwrap_or_else(|e| panic!("{e}"));
        path
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
        assert_eq!(journal.problem(), None);
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
        let replayed = take_all(&mut journal, NOW + total);
        let first = total - replayed.len() as u64;
        assert_eq!(replayed, (first..total).map(record).collect::<Vec<_>>());
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_bound_drops_only_records_older_than_every_one_kept() {
        let dir = scratch("oldest-only");
        let max_size = 64 * 1024;
        let mut journal = open(&dir, max_size);
        let mut earlier = 0;
        while journal.stats().dropped == 0 {
            journal.append(&record(earlier), NOW);
            earlier += 1;
        }
        drop(journal);
        // The next run: the journal is at its bound, then an outage adds 60 records.
        let mut journal = open(&dir, max_size);
        let before = journal.stats().waiting;
        for n in 0..200 {
            journal.append(&record(1_000_000 + n), NOW);
        }
        let stats = journal.stats();
        let replayed = take_all(&mut journal, NOW);
        let (older, newer): (Vec<Record>, Vec<Record>) = replayed
            .into_iter()
            .partition(|r| r.at_ms < NOW + 1_000_000);
        assert_eq!(
            newer,
            (0..200).map(|n| record(1_000_000 + n)).collect::<Vec<_>>()
        );
        let first_older = older.first().map_or(earlier, |r| r.at_ms - NOW);
        assert_eq!(
            older,
            (first_older..earlier).map(record).collect::<Vec<_>>()
        );
        assert_eq!(stats.dropped, before - older.len() as u64, "{stats:?}");
        assert!(stats.dropped > 0);
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
    fn damaged_segments_lose_only_their_damaged_records() {
        let dir = scratch("damaged");
        let mut journal = open(&dir, 64 * 1024);
        for n in 0..600 {
            journal.append(&record(n), NOW);
        }
        drop(journal);
        let files = segment_files(&dir);
        assert!(files.len() >= 3, "{files:?}");
        // A flipped bit in the first record, a flipped length byte in the second segment's
        // first record, a damaged header in the third, a torn tail on the last, a foreign
        // file of a segment's name.
        let flip = |path: &Path, at: usize, mask: u8| {
            let mut bytes = fs::read(path).unwrap_or_default();
            bytes[at] ^= mask;
            fs::write(path, bytes).unwrap_or_else(|e| panic!("{e}"));
        };
        flip(&files[0], MAGIC.len() + 20, 0x04);
        flip(&files[1], MAGIC.len() + 1, 0x80);
        flip(&files[2], 3, 0x01);
        let first_records = record::decode(&fs::read(&files[0]).unwrap_or_default()).records;
        let last = files.last().cloned().unwrap_or_default();
        let torn = fs::read(&last).unwrap_or_default();
        fs::write(&last, &torn[..torn.len() - 3]).unwrap_or_else(|e| panic!("{e}"));
        fs::write(dir.join("00000000000000000000.journal.bak"), b"other").unwrap_or_default();
        let foreign = dir.join(format!("{:020}.{SUFFIX}", 99_999));
        fs::write(&foreign, b"#!/bin/sh\necho not a journal\n").unwrap_or_else(|e| panic!("{e}"));

        let inspected = Journal::inspect(&dir).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            inspected.map(|stats| (stats.waiting, stats.damaged)),
            Some((597, 5))
        );
        let mut journal = open(&dir, 64 * 1024);
        assert_eq!(journal.stats().damaged, 5);
        let replayed = take_all(&mut journal, NOW);
        let second_first = first_records.len() as u64 + 1;
        let expected: Vec<Record> = (1..599)
            .filter(|&n| n != second_first)
            .map(record)
            .collect();
        assert_eq!(replayed, expected);
        assert!(foreign.exists(), "a file that is not ours is left alone");
        // A foreign name sets no number: new records go right after the last segment.
        journal.append(&record(1000), NOW);
        let numbers: Vec<u64> = segment_files(&dir)
            .iter()
            .filter_map(|p| sequence_of(p))
            .collect();
        assert_eq!(numbers, [files.len() as u64, 99_999]);
        assert_eq!(journal.take(10, NOW), vec![record(1000)]);
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn only_regular_files_are_segments_and_nothing_blocks_the_start() {
        let dir = made("kinds");
        write_segment(&dir, "00000000000000000001.journal", 0..3);
        fifo(&dir.join("00000000000000000002.journal"));
        let _socket = std::os::unix::net::UnixListener::bind(dir.join("3.journal"))
            .unwrap_or_else(|e| panic!("{e}"));
        fs::create_dir(dir.join("00000000000000000004.journal")).unwrap_or_else(|e| panic!("{e}"));
        let elsewhere = scratch("kinds-target");
        fs::create_dir_all(&elsewhere).unwrap_or_else(|e| panic!("{e}"));
        let target = write_segment(&elsewhere, "x", 100..103);
        std::os::unix::fs::symlink(&target, dir.join("00000000000000000005.journal"))
            .unwrap_or_else(|e| panic!("{e}"));
        std::os::unix::fs::symlink("/dev/zero", dir.join("6.journal"))
            .unwrap_or_else(|e| panic!("{e}"));
        // Longer than any segment (sparse: it takes no room), never read.
        let huge = File::create(dir.join("00000000000000000007.journal"))
            .and_then(|file| file.set_len(8 << 30));
        huge.unwrap_or_else(|e| panic!("{e}"));

        let (opened_tx, opened_rx) = std::sync::mpsc::channel();
        let config = config(&dir, 1 << 20);
        std::thread::spawn(move || {
            let mut journal = Journal::open(&config);
            journal.append(&record(50), NOW);
            let _ = opened_tx.send((journal.stats(), take_all(&mut journal, NOW)));
        });
        let (stats, replayed) = opened_rx
            .recv_timeout(Duration::from_secs(10))
            .unwrap_or_else(|_| panic!("opening the journal blocked"));
        assert_eq!(replayed, [0, 1, 2, 50].map(record));
        assert_eq!(stats.damaged, 1, "the oversized file: {stats:?}");
        assert_eq!(
            fs::read(&target).map(|b| b.len()).ok(),
            Some(MAGIC.len() + 3 * record(100).encode().map_or(0, |b| b.len()))
        );
        for name in [
            "00000000000000000002.journal",
            "3.journal",
            "00000000000000000004.journal",
            "00000000000000000005.journal",
            "6.journal",
            "00000000000000000007.journal",
        ] {
            assert!(
                fs::symlink_metadata(dir.join(name)).is_ok(),
                "{name} left alone"
            );
        }
        let _ = fs::remove_dir_all(&dir);
        let _ = fs::remove_dir_all(&elsewhere);
    }

    #[test]
    fn the_largest_sequence_number_does_not_stop_the_journal() {
        // A foreign file of the largest number: it sets nothing.
        let dir = made("largest-foreign");
        fs::write(dir.join("18446744073709551615.journal"), b"stray").unwrap_or_default();
        let mut journal = open(&dir, 1 << 20);
        for n in 0..5 {
            journal.append(&record(n), NOW);
        }
        assert_eq!(journal.problem(), None);
        assert_eq!(journal.stats().write_failures, 0);
        assert_eq!(
            take_all(&mut journal, NOW),
            (0..5).map(record).collect::<Vec<_>>()
        );
        let _ = fs::remove_dir_all(&dir);

        // A real segment of the largest number: the segments are numbered from 0 again, in
        // order.
        let dir = made("largest-segment");
        write_segment(&dir, "00000000000000000007.journal", 0..2);
        write_segment(&dir, "18446744073709551615.journal", 2..4);
        let mut journal = open(&dir, 1 << 20);
        for n in 4..6 {
            journal.append(&record(n), NOW);
        }
        let numbers: Vec<u64> = segment_files(&dir)
            .iter()
            .filter_map(|p| sequence_of(p))
            .collect();
        assert_eq!(numbers, [0, 1, 2]);
        assert_eq!(journal.stats().write_failures, 0);
        assert_eq!(
            take_all(&mut journal, NOW),
            (0..6).map(record).collect::<Vec<_>>()
        );
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn after_a_replay_new_records_go_past_what_holds_the_next_names() {
        let dir = made("past-names");
        write_segment(&dir, "00000000000000000001.journal", 0..31);
        fifo(&dir.join("00000000000000000002.journal"));
        fs::write(dir.join("18446744073709551615.journal"), b"stray").unwrap_or_default();
        let mut journal = open(&dir, 1 << 20);
        assert_eq!(
            take_all(&mut journal, NOW),
            (0..31).map(record).collect::<Vec<_>>()
        );
        for n in 31..36 {
            journal.append(&record(n), NOW);
        }
        assert_eq!(journal.problem(), None);
        assert_eq!(
            take_all(&mut journal, NOW),
            (31..36).map(record).collect::<Vec<_>>()
        );
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn empty_segments_are_removed_and_are_no_damage() {
        let dir = made("empty");
        fs::write(dir.join("00000000000000000001.journal"), b"").unwrap_or_default();
        fs::write(dir.join("00000000000000000002.journal"), &MAGIC[..7]).unwrap_or_default();
        write_segment(&dir, "00000000000000000003.journal", 0..0);
        let journal = open(&dir, 1 << 20);
        assert_eq!(journal.stats(), JournalStats::default());
        assert!(segment_files(&dir).is_empty(), "{:?}", segment_files(&dir));
        drop(journal);
        assert_eq!(open(&dir, 1 << 20).stats(), JournalStats::default());
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_path_that_is_a_file_is_a_problem_until_it_is_a_directory() {
        let dir = scratch("file-path");
        fs::write(&dir, b"not a directory").unwrap_or_else(|e| panic!("{e}"));
        let mut journal = open(&dir, 1 << 20);
        let problem = journal.problem().map(str::to_string).unwrap_or_default();
        assert_eq!(
            problem,
            format!(
                "{}: is not a directory (the journal needs one)",
                dir.display()
            )
        );
        assert_eq!(Journal::unusable(&dir), Some(problem));
        for n in 0..3 {
            journal.append(&record(n), NOW);
        }
        assert_eq!(journal.stats().write_failures, 3);
        assert_eq!(journal.stats().waiting, 3);
        fs::remove_file(&dir).unwrap_or_else(|e| panic!("{e}"));
        journal.on_tick(Instant::now() + RETRY_INTERVAL);
        assert_eq!(journal.problem(), None);
        assert_eq!(segment_files(&dir).len(), 1, "what waited is on disk");
        journal.append(&record(3), NOW);
        assert_eq!(
            take_all(&mut journal, NOW),
            (0..4).map(record).collect::<Vec<_>>()
        );
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_path_that_loops_or_is_read_only_is_a_problem_with_its_cause() {
        let dir = made("loop");
        std::os::unix::fs::symlink(dir.join("b"), dir.join("a")).unwrap_or_else(|e| panic!("{e}"));
        std::os::unix::fs::symlink(dir.join("a"), dir.join("b")).unwrap_or_else(|e| panic!("{e}"));
        let mut journal = open(&dir.join("a"), 1 << 20);
        assert_eq!(
            journal.problem(),
            Some(
                format!(
                    "{}: Too many levels of symbolic links (os error 40)",
                    dir.join("a").display()
                )
                .as_str()
            )
        );
        journal.append(&record(0), NOW);
        assert_eq!(journal.take(10, NOW), vec![record(0)]);
        let _ = fs::remove_dir_all(&dir);

        let Some(disk) = SmallDisk::mount("read-only", "64k") else {
            eprintln!("a read-only journal is tested on a tmpfs: mounting one needs root");
            return;
        };
        let remounted = Command::new("mount")
            .args(["-o", "remount,ro"])
            .arg(&disk.0)
            .status()
            .is_ok_and(|status| status.success());
        assert!(remounted);
        let journal = open(&disk.0, 1 << 20);
        assert_eq!(
            journal.problem(),
            Some(format!("{}: Read-only file system (os error 30)", disk.0.display()).as_str())
        );
    }

    #[test]
    fn a_directory_gone_under_a_running_journal_keeps_the_records_in_memory() {
        let dir = scratch("unwritable");
        let mut journal = open(&dir, 1 << 20);
        fs::remove_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        fs::write(&dir, b"now a file").unwrap_or_else(|e| panic!("{e}"));
        for n in 0..3 {
            journal.append(&record(n), NOW);
        }
        assert_eq!(journal.stats().write_failures, 3);
        assert!(journal.problem().is_some());
        // The broker is back before the disk: what waited in memory is replayed from there.
        assert_eq!(
            journal.take(10, NOW),
            (0..3).map(record).collect::<Vec<_>>()
        );
        let _ = fs::remove_file(&dir);
    }

    #[test]
    fn the_memory_queue_keeps_the_newest_within_its_limit() {
        let dir = scratch("queue");
        fs::write(&dir, b"not a directory").unwrap_or_else(|e| panic!("{e}"));
        let mut journal = open(&dir, 1 << 20);
        let each = record(0).encode().map_or(1, |b| b.len() as u64);
        let total = 2 * PENDING_LIMIT / each;
        for n in 0..total {
            journal.append(&record(n), NOW);
        }
        let stats = journal.stats();
        assert_eq!(stats.dropped + stats.waiting, total);
        let replayed = take_all(&mut journal, NOW);
        let first = total - stats.waiting;
        assert_eq!(replayed, (first..total).map(record).collect::<Vec<_>>());
        // As many of the newest as fit, not one more.
        let kept: u64 = replayed.iter().map(encoded_len).sum();
        assert!(kept <= PENDING_LIMIT && kept + encoded_len(&record(first - 1)) > PENDING_LIMIT);
        let _ = fs::remove_file(&dir);
    }

    /// Replays what `dir` holds in a fresh journal: the records that come out.
    fn replay_of(dir: &Path, max_size: u64) -> (Vec<Record>, JournalStats) {
        let mut journal = open(dir, max_size);
        let stats = journal.stats();
        (take_all(&mut journal, NOW), stats)
    }

    /// How many of `expected` are missing from `replayed`.
    fn lost(expected: impl IntoIterator<Item = u64>, replayed: &[Record]) -> usize {
        expected
            .into_iter()
            .filter(|&n| !replayed.contains(&record(n)))
            .count()
    }

    /// Every kind of damage of the journal's known failure table, reproduced one after the
    /// other, with the records it costs printed (`--nocapture`) and asserted.
    #[test]
    fn the_damage_table_row_by_row() {
        let mut rows: Vec<(&str, String)> = Vec::new();
        let spans = {
            let mut at = MAGIC.len();
            (0..31u64)
                .map(|n| {
                    let start = at;
                    at += record(n).encode().map_or(0, |b| b.len());
                    start
                })
                .collect::<Vec<_>>()
        };
        let damaged_segment = |name: &str, damage: &dyn Fn(&mut Vec<u8>)| {
            let dir = made(name);
            let path = write_segment(&dir, "00000000000000000001.journal", 0..31);
            let mut bytes = fs::read(&path).unwrap_or_default();
            damage(&mut bytes);
            fs::write(&path, bytes).unwrap_or_else(|e| panic!("{e}"));
            let (replayed, _) = replay_of(&dir, 1 << 20);
            let _ = fs::remove_dir_all(&dir);
            lost(0..31, &replayed)
        };
        let first_low = damaged_segment("row-first-low", &|b| b[spans[0]] ^= 0x01);
        let first_high = damaged_segment("row-first-high", &|b| b[spans[0] + 3] ^= 0x80);
        assert_eq!((first_low, first_high), (1, 1));
        rows.push((
            "one bit flipped in the first record's length field (low, high byte)",
            format!("{first_low}, {first_high} of 31"),
        ));
        let middle = damaged_segment("row-middle", &|b| b[spans[15] + 1] ^= 0x04);
        let huge = damaged_segment("row-huge", &|b| {
            b[spans[15]..spans[15] + 4].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        });
        assert_eq!((middle, huge), (1, 1));
        rows.push((
            "one bit flipped in the middle record's length field; a length of 0xFFFFFFF0",
            format!("{middle}; {huge} of 31"),
        ));
        let magic = damaged_segment("row-magic", &|b| b[4] ^= 0x20);
        assert_eq!(magic, 0);
        rows.push((
            "one bit flipped in the MAGIC header",
            format!("{magic} of 31"),
        ));

        // The largest number, as a stray file and as a real segment.
        for (name, content) in [
            ("row-largest-stray", b"stray".to_vec()),
            ("row-largest-segment", Vec::new()),
        ] {
            let dir = made(name);
            if content.is_empty() {
                write_segment(&dir, "18446744073709551615.journal", 100..102);
            } else {
                fs::write(dir.join("18446744073709551615.journal"), content).unwrap_or_default();
            }
            let mut journal = open(&dir, 1 << 20);
            for n in 0..5 {
                journal.append(&record(n), NOW);
            }
            let failures = journal.stats().write_failures;
            drop(journal);
            let (replayed, _) = replay_of(&dir, 1 << 20);
            let lost = lost(0..5, &replayed);
            assert_eq!((lost, failures), (0, 0));
            rows.push((
                if name.ends_with("stray") {
                    "a stray 18446744073709551615.journal"
                } else {
                    "a real segment named 18446744073709551615.journal"
                },
                format!("{lost} of 5 in the next outage, {failures} write failures"),
            ));
            let _ = fs::remove_dir_all(&dir);
        }

        // A FIFO named like a segment: the start does not wait for it.
        let dir = made("row-fifo");
        write_segment(&dir, "00000000000000000001.journal", 0..5);
        fifo(&dir.join("00000000000000000000.journal"));
        let (done_tx, done_rx) = std::sync::mpsc::channel();
        let fifo_dir = dir.clone();
        std::thread::spawn(move || {
            let _ = done_tx.send(replay_of(&fifo_dir, 1 << 20));
        });
        let (replayed, _) = done_rx
            .recv_timeout(Duration::from_secs(10))
            .unwrap_or_else(|_| panic!("the journal's start waited for a FIFO"));
        let fifo_lost = lost(0..5, &replayed);
        assert_eq!(fifo_lost, 0);
        rows.push((
            "a FIFO named like a segment",
            format!("starts at once, {fifo_lost} of 5 lost"),
        ));
        let _ = fs::remove_dir_all(&dir);

        // An empty segment: no damage, removed.
        let dir = made("row-empty");
        fs::write(dir.join("00000000000000000001.journal"), b"").unwrap_or_default();
        let first = open(&dir, 1 << 20).stats().damaged;
        let second = open(&dir, 1 << 20).stats().damaged;
        assert_eq!((first, second), (0, 0));
        rows.push((
            "an empty segment",
            format!("damaged {first} at the first start, {second} at the next"),
        ));
        let _ = fs::remove_dir_all(&dir);

        // max_size reached by older records, then an outage of about 6 KB of new records.
        let dir = scratch("row-bound");
        let max_size = 64 * 1024;
        let mut journal = open(&dir, max_size);
        let mut older = 0;
        while journal.stats().bytes + 200 < max_size {
            journal.append(&record(older), NOW);
            older += 1;
        }
        drop(journal);
        let mut journal = open(&dir, max_size);
        let newer = 1_000_000..1_000_000 + 6 * 1024 / 50;
        for n in newer.clone() {
            journal.append(&record(n), NOW);
        }
        let dropped = journal.stats().dropped;
        let replayed = take_all(&mut journal, NOW);
        let older_dropped = lost(0..older, &replayed);
        let newer_lost = lost(newer.clone(), &replayed);
        assert_eq!((older_dropped as u64, newer_lost), (dropped, 0));
        rows.push((
            "max_size = 64KiB reached by older records, then about 6 KB of new records",
            format!(
                "{dropped} dropped: {older_dropped} of {older} older, {newer_lost} of {} new",
                newer.end - newer.start
            ),
        ));
        let _ = fs::remove_dir_all(&dir);

        // A path that is a regular file: the records wait in memory, nothing is lost.
        let dir = scratch("row-file");
        fs::write(&dir, b"a file").unwrap_or_else(|e| panic!("{e}"));
        let mut journal = open(&dir, 1 << 20);
        for n in 0..5 {
            journal.append(&record(n), NOW);
        }
        let unusable = journal.problem().is_some();
        let file_lost = lost(0..5, &take_all(&mut journal, NOW));
        assert!(unusable);
        assert_eq!(file_lost, 0);
        rows.push((
            "path names a regular file",
            format!("unhealthy, {file_lost} of 5 lost"),
        ));
        let _ = fs::remove_file(&dir);

        // The disk full, then room again.
        if let Some(disk) = SmallDisk::mount("row-full", "128k") {
            let dir = disk.0.join("history");
            let mut journal = open(&dir, 1 << 20);
            let filler = disk.fill();
            for n in 0..5 {
                journal.append(&record(n), NOW);
            }
            fs::remove_file(filler).unwrap_or_else(|e| panic!("{e}"));
            journal.on_tick(Instant::now() + RETRY_INTERVAL);
            let resumed = journal.problem().is_none();
            for n in 5..10 {
                journal.append(&record(n), NOW);
            }
            drop(journal);
            let (replayed, _) = replay_of(&dir, 1 << 20);
            let full_lost = lost(0..5, &replayed);
            let next_lost = lost(5..10, &replayed);
            assert!(resumed);
            assert_eq!((full_lost, next_lost), (0, 0));
            rows.push((
                "the disk full, then room again",
                format!("resumed; {full_lost} of 5 lost while full, {next_lost} of 5 in the next outage"),
            ));
        }
        for (damage, lost) in rows {
            println!("| {damage} | {lost} |");
        }
    }

    /// A tmpfs of `size` mounted on a fresh directory, unmounted when dropped (needs root).
    struct SmallDisk(PathBuf);

    impl SmallDisk {
        fn mount(name: &str, size: &str) -> Option<SmallDisk> {
            let dir = scratch(name);
            fs::create_dir_all(&dir).ok()?;
            let mounted = Command::new("mount")
                .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
                .arg(&dir)
                .status()
                .is_ok_and(|status| status.success());
            if !mounted {
                let _ = fs::remove_dir(&dir);
                return None;
            }
            Some(SmallDisk(dir))
        }

        /// Takes all the room left (a file of that name).
        fn fill(&self) -> PathBuf {
            let path = self.0.join("filler");
            let mut file = File::create(&path).unwrap_or_else(|e| panic!("{e}"));
            while file.write_all(&[0xAA; 4096]).is_ok() {}
            while file.write_all(&[0xAA; 1]).is_ok() {}
            path
        }
    }

    impl Drop for SmallDisk {
        fn drop(&mut self) {
            let _ = Command::new("umount").arg(&self.0).status();
            let _ = fs::remove_dir(&self.0);
        }
    }

    #[test]
    fn a_full_disk_is_a_pause_and_writing_resumes_by_itself() {
        let Some(disk) = SmallDisk::mount("full", "256k") else {
            eprintln!("a full disk is tested on a tmpfs: mounting one needs root");
            return;
        };
        let dir = disk.0.join("history");
        let mut journal = open(&dir, 1 << 20);
        for n in 0..10 {
            journal.append(&record(n), NOW);
        }
        disk.fill();
        for n in 10..500 {
            journal.append(&record(n), NOW);
        }
        let problem = journal.problem().map(str::to_string).unwrap_or_default();
        assert!(problem.contains("No space left on device"), "{problem}");
        assert_eq!(journal.stats().waiting, 500);
        // Still full: tried again, still a pause.
        journal.on_tick(Instant::now() + RETRY_INTERVAL);
        assert!(journal.problem().is_some());
        // The broker comes back first: what waited in memory is replayed from there, and the
        // disk, still full, is still said to be.
        let early = journal.take(100, NOW);
        assert_eq!(early, (0..100).map(record).collect::<Vec<_>>());
        let memory: Vec<Record> = std::iter::from_fn(|| {
            let batch = journal.take(100, NOW);
            (!batch.is_empty()).then_some(batch)
        })
        .flatten()
        .collect();
        assert_eq!(memory, (100..500).map(record).collect::<Vec<_>>());
        // (The replayed segment's deletion made room: taken again.)
        let filler = disk.fill();
        journal.on_tick(Instant::now() + 2 * RETRY_INTERVAL);
        assert!(journal.problem().is_some(), "the disk is still full");
        for n in 0..500 {
            journal.append(&record(n), NOW);
        }
        fs::remove_file(filler).unwrap_or_else(|e| panic!("{e}"));
        journal.on_tick(Instant::now() + 3 * RETRY_INTERVAL);
        assert_eq!(journal.problem(), None);
        for n in 500..510 {
            journal.append(&record(n), NOW);
        }
        assert_eq!(journal.stats().waiting, 510);
        drop(journal);
        // Nothing half written: read again, every record is there and nothing is damaged.
        let mut journal = open(&dir, 1 << 20);
        assert_eq!(journal.stats().damaged, 0);
        assert_eq!(
            take_all(&mut journal, NOW),
            (0..510).map(record).collect::<Vec<_>>()
        );
        drop(journal);
        drop(disk);
    }
}
