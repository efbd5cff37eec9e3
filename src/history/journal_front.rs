//! Records that come back: handed out by a replay (or published live) and not acknowledged
//! by the broker, they were read before everything the journal still holds, so they go in
//! front of it: into a segment numbered before the first, in the order they come back, and
//! before what a replay left when they come back after it. While the journal cannot be
//! written they wait in memory, ahead of every record on disk.

use std::fs::{self, File};
use std::io::{self, Write};
use std::time::Instant;

use super::{Journal, Segment, Writer, FRONT_ROOM};
use crate::history::record::Record;

impl Journal {
    /// A record handed out by [`Journal::take`] (or published live) that did not reach the
    /// broker: it goes back in front of every record still waiting, behind those that came
    /// back before it since the last replay, so that the replay keeps the order values were
    /// read in. Written into a segment numbered before the others; kept in memory while the
    /// journal cannot be written (and while others kept there wait).
    pub fn put_back(&mut self, record: &Record) {
        let Some(bytes) = record.encode() else {
            self.stats.write_failures += 1;
            tracing::warn!(device = %record.device, "history record too large for the journal: not kept");
            return;
        };
        if self.problem.is_none() && self.returned.is_empty() {
            match self.store_in_front(&bytes, record.at_ms) {
                Ok(()) => {
                    self.refresh_stats();
                    return;
                }
                Err(error) => {
                    self.fail(&error);
                    // What came back before it waits in memory with it, in order.
                    self.front_to_memory();
                }
            }
        }
        self.stats.write_failures += 1;
        let at = self.returned_at.min(self.returned.len());
        self.returned.insert(at, record.clone());
        self.returned_at = at + 1;
        self.refresh_stats();
    }

    /// Writes one encoded record into the first segment, begun (numbered before every other)
    /// when records come back after a replay.
    fn store_in_front(&mut self, bytes: &[u8], at_ms: u64) -> io::Result<()> {
        if self.front_writer.is_none() {
            self.start_front_segment()?;
        }
        let (Some(writer), Some(segment)) = (&mut self.front_writer, self.segments.front_mut())
        else {
            return Err(io::Error::other("no segment open in front"));
        };
        if let Err(error) = writer.file.write_all(bytes) {
            if writer.file.set_len(segment.bytes).is_err() {
                self.front_writer = None;
            }
            return Err(error);
        }
        segment.bytes += bytes.len() as u64;
        segment.records += 1;
        segment.newest_ms = segment.newest_ms.max(at_ms);
        self.replaying = None;
        self.unsynced_since.get_or_insert_with(Instant::now);
        Ok(())
    }

    /// Opens a segment numbered before every other (the others are numbered up first when
    /// the first is 0 or the number before it is taken).
    fn start_front_segment(&mut self) -> io::Result<()> {
        let sequence = match self.segments.front().map(|s| s.sequence) {
            None => {
                let sequence = self.next_sequence;
                self.next_sequence = sequence.saturating_add(1);
                sequence
            }
            Some(first) => match first.checked_sub(1) {
                Some(before) if fs::symlink_metadata(self.path_of(before)).is_err() => before,
                _ => {
                    self.number_up()?;
                    self.segments.front().map_or(0, |s| s.sequence) - 1
                }
            },
        };
        let file = self.create_segment(sequence)?;
        self.segments.push_front(Segment::begun(sequence));
        // The replay's place in the segment that was first is kept in its `handed`.
        self.replaying = None;
        self.front_writer = Some(Writer { file, sequence });
        File::open(&self.dir)?.sync_all()
    }

    /// Renames every segment to a number [`FRONT_ROOM`] higher (the last first), so that
    /// segments can be put before the first.
    fn number_up(&mut self) -> io::Result<()> {
        for index in (0..self.segments.len()).rev() {
            let old = self.segments[index].sequence;
            let new = old
                .checked_add(FRONT_ROOM)
                .filter(|new| fs::symlink_metadata(self.path_of(*new)).is_err())
                .ok_or_else(|| io::Error::other("no segment number free before the first"))?;
            fs::rename(self.path_of(old), self.path_of(new))?;
            self.segments[index].sequence = new;
            for writer in [&mut self.writer, &mut self.front_writer]
                .into_iter()
                .flatten()
            {
                if writer.sequence == old {
                    writer.sequence = new;
                }
            }
        }
        self.next_sequence = self.next_sequence.saturating_add(FRONT_ROOM);
        Ok(())
    }

    /// The segment records came back into is done with: synced and closed.
    pub(super) fn close_front(&mut self) {
        if let Some(writer) = self.front_writer.take() {
            if let Err(error) = writer.file.sync_data() {
                tracing::error!(dir = %self.dir.display(), %error, "history journal cannot be synced");
            }
        }
    }

    /// The journal cannot be written: what came back into the first segment since the last
    /// replay moves to memory, where the rest of it will wait.
    fn front_to_memory(&mut self) {
        let Some(writer) = self.front_writer.take() else {
            return;
        };
        if self.segments.front().map(|s| s.sequence) != Some(writer.sequence) {
            return;
        }
        let records = self.read_segment(writer.sequence);
        self.returned_at = records.len();
        for record in records.into_iter().rev() {
            self.returned.push_front(record);
        }
        self.remove_front();
    }
}
