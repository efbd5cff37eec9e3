//! An open serial stream and the reactor's watch on its receive side. The watch can be lifted
//! for a stretch in which no received byte is wanted yet (the rest of an answer that cannot be
//! complete before its wire time): the bytes that arrive meanwhile wait in the kernel's buffer
//! and wake nothing, where each would otherwise wake the runtime's thread for nothing. The next
//! read watches again and takes what has arrived at once.

use std::io::{self, Read};
use std::os::fd::{AsRawFd, RawFd};

use mio_serial::SerialStream;
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

/// A serial stream, watched by the reactor for reading unless the watch has been lifted.
pub(crate) struct ReadWatch {
    /// The reactor's registration of the stream's descriptor (by number: the stream below owns
    /// it). Declared first so that it is dropped, and the descriptor deregistered, before the
    /// stream closes it.
    watch: Option<AsyncFd<RawFd>>,
    /// Registered again since the last read: the reactor has not reported the bytes that
    /// arrived while the watch was lifted, so the next read takes them without waiting for it.
    rewatched: bool,
    stream: SerialStream,
}

impl std::fmt::Debug for ReadWatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ReadWatch")
            .field("watched", &self.watch.is_some())
            .finish_non_exhaustive()
    }
}

impl ReadWatch {
    /// Watches `stream` for reading. Needs the runtime's I/O driver.
    pub(crate) fn new(stream: SerialStream) -> io::Result<ReadWatch> {
        let mut read_watch = ReadWatch {
            watch: None,
            rewatched: false,
            stream,
        };
        read_watch.watched()?;
        read_watch.rewatched = false;
        Ok(read_watch)
    }

    pub(crate) fn get_ref(&self) -> &SerialStream {
        &self.stream
    }

    pub(crate) fn get_mut(&mut self) -> &mut SerialStream {
        &mut self.stream
    }

    /// Stops the reactor watching for received bytes until the next read (one system call).
    pub(crate) fn lift(&mut self) {
        self.watch = None;
    }

    /// The registration, made again (one system call) if the watch was lifted.
    fn watched(&mut self) -> io::Result<&AsyncFd<RawFd>> {
        if self.watch.is_none() {
            // SAFETY: the descriptor is the stream's, which `self` owns and drops after the
            // registration (field order), so it stays open and the same file while registered.
            let watch = unsafe {
                AsyncFd::register_with_interest(self.stream.as_raw_fd(), Interest::READABLE)
            }
            .map_err(|error| error.into_parts().1)?;
            self.rewatched = true;
            self.watch = Some(watch);
        }
        self.watch
            .as_ref()
            .ok_or_else(|| io::Error::other("serial port not registered with the reactor"))
    }

    /// Right after the watch was taken up again: reads whatever is waiting (`WouldBlock` when
    /// nothing is), since the reactor reports it only on its next turn.
    fn read_rewatched(&mut self, buf: &mut [u8]) -> Option<io::Result<usize>> {
        if !std::mem::replace(&mut self.rewatched, false) {
            return None;
        }
        loop {
            match (&self.stream).read(buf) {
                Err(error) if error.kind() == io::ErrorKind::Interrupted => continue,
                Err(error) if error.kind() == io::ErrorKind::WouldBlock => return None,
                result => return Some(result),
            }
        }
    }

    /// Waits for received bytes and reads them into `buf`.
    pub(crate) async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.watched()?;
        if let Some(result) = self.read_rewatched(buf) {
            return result;
        }
        let (Some(watch), stream) = (&self.watch, &self.stream) else {
            return Err(io::Error::other(
                "serial port not registered with the reactor",
            ));
        };
        loop {
            let mut ready = watch.readable().await?;
            if let Ok(result) = ready.try_io(|_| (&*stream).read(buf)) {
                return result;
            }
        }
    }

    /// Reads what has arrived without waiting: `WouldBlock` when nothing has (as far as the
    /// reactor knows, or, right after the watch was lifted, the port itself).
    pub(crate) fn try_read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.watched()?;
        if let Some(result) = self.read_rewatched(buf) {
            return result;
        }
        let (Some(watch), stream) = (&self.watch, &self.stream) else {
            return Err(io::ErrorKind::WouldBlock.into());
        };
        watch.try_io(Interest::READABLE, |_| (&*stream).read(buf))
    }
}

impl AsRawFd for ReadWatch {
    fn as_raw_fd(&self) -> RawFd {
        self.stream.as_raw_fd()
    }
}
