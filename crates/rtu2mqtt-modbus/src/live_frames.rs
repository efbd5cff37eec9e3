//! The frames of every line as they happen, for whoever watches them live (the console's frame
//! view): each record of the frame log's format (`<line> <unix time µs> <tx|rx> <hex>`) goes
//! to a broadcast channel while anyone listens, and nowhere while no one does. Never blocks
//! the link: a watcher that falls behind loses the oldest records and is told how many.

use std::io::{self, Write};
use std::sync::Arc;

use tokio::sync::broadcast;

use crate::FrameSink;

/// Records a slow watcher may fall behind by before it loses the oldest.
const BACKLOG: usize = 1024;

/// The live frames of every line, cheap to clone (every line gets a [`LiveFrameWriter`]).
#[derive(Debug, Clone)]
pub struct LiveFrames {
    records: broadcast::Sender<Arc<str>>,
}

impl Default for LiveFrames {
    fn default() -> Self {
        LiveFrames {
            records: broadcast::channel(BACKLOG).0,
        }
    }
}

impl LiveFrames {
    /// The writer for one line's link (`Link::record_frames_to`).
    pub fn writer(&self, line: &str) -> LiveFrameWriter {
        LiveFrameWriter {
            records: self.records.clone(),
            prefix: format!("{line} "),
            partial: String::new(),
        }
    }

    /// Every record from now on, each a text line without its newline.
    pub fn subscribe(&self) -> broadcast::Receiver<Arc<str>> {
        self.records.subscribe()
    }

    /// Someone watches now.
    pub fn watched(&self) -> bool {
        self.records.receiver_count() > 0
    }
}

/// One line's records into [`LiveFrames`], prefixed with the line's name.
#[derive(Debug)]
pub struct LiveFrameWriter {
    records: broadcast::Sender<Arc<str>>,
    prefix: String,
    /// The text line being written, until its newline.
    partial: String,
}

impl FrameSink for LiveFrameWriter {
    fn listening(&self) -> bool {
        self.records.receiver_count() > 0
    }
}

impl Write for LiveFrameWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if self.records.receiver_count() == 0 {
            self.partial.clear();
            return Ok(buf.len());
        }
        for piece in buf.split_inclusive(|&b| b == b'\n') {
            if self.partial.is_empty() {
                self.partial.push_str(&self.prefix);
            }
            self.partial.push_str(&String::from_utf8_lossy(piece));
            if self.partial.ends_with('\n') {
                let record = std::mem::take(&mut self.partial);
                // No receiver left since the check: the record is simply not watched.
                let _ = self.records.send(Arc::from(record.trim_end()));
            }
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// Every frame record to each of several writers (the frame log and the live view); a writer
/// that fails is left out from then on, the others go on.
#[derive(Default)]
pub struct Tee {
    writers: Vec<Box<dyn FrameSink>>,
}

impl std::fmt::Debug for Tee {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tee")
            .field("writers", &self.writers.len())
            .finish()
    }
}

impl Tee {
    /// Adds a writer.
    pub fn push(&mut self, writer: Box<dyn FrameSink>) {
        self.writers.push(writer);
    }

    /// The one writer as itself, several behind the tee, none as None.
    pub fn into_writer(mut self) -> Option<Box<dyn FrameSink>> {
        match self.writers.len() {
            0 => None,
            1 => self.writers.pop(),
            _ => Some(Box::new(self)),
        }
    }
}

impl FrameSink for Tee {
    fn listening(&self) -> bool {
        self.writers.iter().any(|writer| writer.listening())
    }
}

impl Write for Tee {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.writers
            .retain_mut(|writer| writer.write_all(buf).is_ok());
        if self.writers.is_empty() {
            return Err(io::Error::new(
                io::ErrorKind::BrokenPipe,
                "every frame recorder has stopped",
            ));
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        self.writers.retain_mut(|writer| writer.flush().is_ok());
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_reach_a_watcher_whole_and_prefixed() {
        let live = LiveFrames::default();
        let mut writer = live.writer("line-a");
        writer.write_all(b"1 tx 0103\n").unwrap();
        let mut watcher = live.subscribe();
        assert!(live.watched());
        writer.write_all(b"2 tx 01").unwrap();
        writer.write_all(b"03\n3 rx 0183\n").unwrap();
        assert_eq!(&*watcher.try_recv().unwrap(), "line-a 2 tx 0103");
        assert_eq!(&*watcher.try_recv().unwrap(), "line-a 3 rx 0183");
        assert!(
            watcher.try_recv().is_err(),
            "nothing from before the watcher came"
        );
    }

    #[test]
    fn a_tee_writes_to_each_and_drops_a_failing_one() {
        struct Failing;
        impl FrameSink for Failing {}
        impl Write for Failing {
            fn write(&mut self, _: &[u8]) -> io::Result<usize> {
                Err(io::Error::other("disk gone"))
            }
            fn flush(&mut self) -> io::Result<()> {
                Ok(())
            }
        }
        let live = LiveFrames::default();
        let mut watcher = live.subscribe();
        let mut tee = Tee::default();
        tee.push(Box::new(Failing));
        tee.push(Box::new(live.writer("l")));
        let mut writer = tee.into_writer().unwrap();
        writer.write_all(b"1 tx 01\n").unwrap();
        writer.write_all(b"2 tx 02\n").unwrap();
        assert_eq!(&*watcher.try_recv().unwrap(), "l 1 tx 01");
        assert_eq!(&*watcher.try_recv().unwrap(), "l 2 tx 02");
    }
}
