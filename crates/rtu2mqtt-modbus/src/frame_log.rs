//! The frame log for bug reports: one file shared by every line, one record per frame as the
//! link writes it (`<unix time µs> <tx|rx> <hex>`), prefixed with the line's name so that the
//! lines' records can be told apart.
//!
//! The links record from the thread that keeps their line's timing, so a record never waits
//! for the disk there: each whole text line goes into a bounded queue, and a writer thread of
//! its own appends it to the file. When the queue is full (the disk stalls) the record is
//! dropped and counted, and the writer notes how many were lost once it catches up.

use std::fmt;
use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::Arc;

/// Records waiting for the writer at the most: some seconds of several busy lines.
const QUEUE_RECORDS: usize = 4096;

/// What the lines' writers share: the queue into the writer thread and the count of records
/// it had no room for.
#[derive(Debug)]
struct Queue {
    records: SyncSender<String>,
    dropped: Arc<AtomicU64>,
}

/// The open frame log, cheap to clone (every line gets a [`LineFrameWriter`] on it). The
/// writer thread ends when the log and every writer on it are gone, after writing what was
/// queued.
#[derive(Clone)]
pub struct FrameLog {
    path: PathBuf,
    queue: Arc<Queue>,
}

impl fmt::Debug for FrameLog {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("FrameLog")
            .field("path", &self.path)
            .field("dropped", &self.dropped())
            .finish()
    }
}

impl FrameLog {
    /// Opens `path` for appending (created when missing) and starts its writer thread.
    pub fn create(path: &Path) -> io::Result<FrameLog> {
        let file = OpenOptions::new().create(true).append(true).open(path)?;
        let (records, received) = mpsc::sync_channel(QUEUE_RECORDS);
        let dropped = Arc::new(AtomicU64::new(0));
        let writer_dropped = Arc::clone(&dropped);
        std::thread::Builder::new()
            .name("frame-log".into())
            .spawn(move || write_records(file, received, &writer_dropped))?;
        Ok(FrameLog {
            path: path.to_path_buf(),
            queue: Arc::new(Queue { records, dropped }),
        })
    }

    /// Records dropped so far because the writer had fallen behind.
    fn dropped(&self) -> u64 {
        self.queue.dropped.load(Ordering::Relaxed)
    }

    /// The writer for one line's link (`Link::record_frames_to`).
    pub fn writer(&self, line: &str) -> LineFrameWriter {
        LineFrameWriter {
            queue: Arc::clone(&self.queue),
            prefix: format!("{line} "),
            partial: String::new(),
        }
    }
}

/// The writer thread: appends every queued record, flushing whenever the queue is empty, and
/// notes the records dropped meanwhile. A failing disk stops the log with a warning.
fn write_records(file: File, received: Receiver<String>, dropped: &AtomicU64) {
    let mut file = BufWriter::new(file);
    let mut noted = 0;
    let mut write = |file: &mut BufWriter<File>, record: &str| -> io::Result<()> {
        file.write_all(record.as_bytes())?;
        let lost = dropped.load(Ordering::Relaxed);
        if lost > noted {
            writeln!(
                file,
                "frame-log {} records dropped: the disk fell behind",
                lost - noted
            )?;
            noted = lost;
        }
        Ok(())
    };
    while let Ok(record) = received.recv() {
        let mut result = write(&mut file, &record);
        while result.is_ok() {
            match received.try_recv() {
                Ok(record) => result = write(&mut file, &record),
                Err(_) => break,
            }
        }
        if let Err(error) = result.and_then(|()| file.flush()) {
            tracing::warn!(%error, "frame log stopped");
            return;
        }
    }
}

/// Writes one line's records into the shared [`FrameLog`], each text line prefixed with the
/// line's name. Never blocks: a whole text line goes to the writer thread, or is dropped and
/// counted when its queue is full.
#[derive(Debug)]
pub struct LineFrameWriter {
    queue: Arc<Queue>,
    prefix: String,
    /// The text line being written, until its newline.
    partial: String,
}

impl crate::FrameSink for LineFrameWriter {}

impl Write for LineFrameWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        for piece in buf.split_inclusive(|&b| b == b'\n') {
            if self.partial.is_empty() {
                self.partial.push_str(&self.prefix);
            }
            self.partial.push_str(&String::from_utf8_lossy(piece));
            if piece.ends_with(b"\n") {
                let record = std::mem::take(&mut self.partial);
                match self.queue.records.try_send(record) {
                    Ok(()) => {}
                    Err(TrySendError::Full(_)) => {
                        self.queue.dropped.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(TrySendError::Disconnected(_)) => {
                        return Err(io::Error::new(
                            io::ErrorKind::BrokenPipe,
                            "the frame log's writer has stopped",
                        ))
                    }
                }
            }
        }
        Ok(buf.len())
    }

    /// Records go out whole at their newline; the writer thread flushes the file.
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    /// The file's text once it holds `lines` lines (the writer thread appends them shortly).
    fn text_with_lines(path: &Path, lines: usize) -> String {
        let give_up = Instant::now() + Duration::from_secs(5);
        loop {
            let text = std::fs::read_to_string(path).unwrap_or_default();
            if text.lines().count() >= lines || Instant::now() > give_up {
                return text;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn records_of_two_lines_are_prefixed_and_whole() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frames.log");
        let log = FrameLog::create(&path).unwrap();
        let mut a = log.writer("line-a");
        let mut b = log.writer("line-b");
        a.write_all(b"1700000000000001 tx 010310000006C108\n")
            .unwrap();
        b.write_all(b"1700000000000002 tx ").unwrap();
        b.write_all(b"01030074\n").unwrap();
        a.write_all(b"1700000000000003 rx 0103\n").unwrap();
        a.flush().unwrap();
        assert_eq!(
            text_with_lines(&path, 3),
            "line-a 1700000000000001 tx 010310000006C108\n\
             line-b 1700000000000002 tx 01030074\n\
             line-a 1700000000000003 rx 0103\n"
        );
        assert_eq!(log.dropped(), 0);
        // Appends on reopen.
        let again = FrameLog::create(&path).unwrap();
        again.writer("line-c").write_all(b"x\n").unwrap();
        assert!(text_with_lines(&path, 4).ends_with("line-c x\n"));
    }

    #[test]
    fn a_full_queue_drops_and_counts_instead_of_waiting() {
        let (records, received) = mpsc::sync_channel(2);
        let queue = Arc::new(Queue {
            records,
            dropped: Arc::new(AtomicU64::new(0)),
        });
        let mut writer = LineFrameWriter {
            queue: Arc::clone(&queue),
            prefix: "line ".into(),
            partial: String::new(),
        };
        let started = Instant::now();
        for _ in 0..5 {
            writer.write_all(b"1 tx 01\n").unwrap();
        }
        assert!(started.elapsed() < Duration::from_secs(1));
        assert_eq!(queue.dropped.load(Ordering::Relaxed), 3);
        assert_eq!(received.try_iter().count(), 2);
    }

    #[test]
    fn the_writer_notes_how_many_records_were_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frames.log");
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .unwrap();
        let (records, received) = mpsc::sync_channel(4);
        let dropped = AtomicU64::new(2);
        records.send("line 1 tx 01\n".to_string()).unwrap();
        drop(records);
        write_records(file, received, &dropped);
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "line 1 tx 01\nframe-log 2 records dropped: the disk fell behind\n"
        );
    }
}
