//! The frame log for bug reports: one file shared by every line, one record per frame as the
//! master writes it (`<unix time µs> <tx|rx> <hex>`), prefixed with the line's name so that
//! the lines' records can be told apart. Records of different lines never mix within a line
//! of text: each write goes out under the file's lock.

use std::fmt;
use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};

/// The open frame log, cheap to clone (every line gets a [`LineFrameWriter`] on it).
#[derive(Clone)]
pub struct FrameLog {
    path: PathBuf,
    file: Arc<Mutex<File>>,
}

impl fmt::Debug for FrameLog {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("FrameLog")
            .field("path", &self.path)
            .finish()
    }
}

impl FrameLog {
    /// Opens `path` for appending (created when missing).
    pub fn create(path: &Path) -> io::Result<FrameLog> {
        let file = OpenOptions::new().create(true).append(true).open(path)?;
        Ok(FrameLog {
            path: path.to_path_buf(),
            file: Arc::new(Mutex::new(file)),
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The writer for one line's master (`Master::record_frames_to`).
    pub fn writer(&self, line: &str) -> LineFrameWriter {
        LineFrameWriter {
            log: self.clone(),
            prefix: format!("{line} "),
            at_line_start: true,
        }
    }

    fn lock(&self) -> MutexGuard<'_, File> {
        // A writer that panicked mid-record leaves a plain file behind: keep using it.
        self.file
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

/// Writes one line's records into the shared [`FrameLog`], each text line prefixed with the
/// line's name.
#[derive(Debug)]
pub struct LineFrameWriter {
    log: FrameLog,
    prefix: String,
    at_line_start: bool,
}

impl Write for LineFrameWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let mut file = self.log.lock();
        for piece in buf.split_inclusive(|&b| b == b'\n') {
            if self.at_line_start {
                file.write_all(self.prefix.as_bytes())?;
            }
            file.write_all(piece)?;
            self.at_line_start = piece.ends_with(b"\n");
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        self.log.lock().flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(
            text,
            "line-a 1700000000000001 tx 010310000006C108\n\
             line-b 1700000000000002 tx 01030074\n\
             line-a 1700000000000003 rx 0103\n"
        );
        // Appends on reopen.
        let again = FrameLog::create(&path).unwrap();
        again.writer("line-c").write_all(b"x\n").unwrap();
        assert!(std::fs::read_to_string(&path)
            .unwrap()
            .ends_with("line-c x\n"));
    }
}
