//! A virtual serial line: a pty pair whose master end is served by the simulated devices in a
//! background task, and whose slave path (`/dev/pts/N`) the gateway opens like a real port.
//!
//! The line keeps its own slave fd open so the master end never reads EIO when the gateway
//! closes and reopens the port. [`VirtualLine::unplug`] closes both ends (the gateway then sees
//! the hang-up a pulled USB adapter gives) and [`VirtualLine::replug`] brings a new pty up with
//! the same devices, faults and journal; with [`VirtualLine::with_link`] a symlink keeps one
//! stable path across replugs, like `/dev/serial/by-id`.

use std::fs::File;
use std::path::{Path, PathBuf};

use mio_serial::{SerialPort as _, SerialStream};
use tokio::task::JoinHandle;

use super::device::SharedDevice;
use super::faults::FaultHandle;
use super::journal::Journal;
use super::pty_settings::BaudWatch;
use super::serial_stream::AsyncSerial;
use super::server::{serve_watching, ServeOptions};
use tokio_util::sync::CancellationToken;

/// The serving side of one plugged-in pty.
struct Plugged {
    slave_path: PathBuf,
    /// Held open so the master never sees EIO while the gateway has the port closed.
    _slave: File,
    stop: CancellationToken,
    task: JoinHandle<std::io::Result<()>>,
}

/// A served pty pair.
pub struct VirtualLine {
    options: ServeOptions,
    devices: Vec<SharedDevice>,
    faults: FaultHandle,
    journal: Journal,
    link: Option<PathBuf>,
    plugged: Option<Plugged>,
}

impl std::fmt::Debug for VirtualLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualLine")
            .field("path", &self.path())
            .field("plugged", &self.is_plugged())
            .field("devices", &self.devices.len())
            .finish_non_exhaustive()
    }
}

impl VirtualLine {
    /// Creates a pty pair and serves `devices` on it. Needs a tokio runtime.
    pub fn spawn(options: ServeOptions, devices: Vec<SharedDevice>) -> std::io::Result<Self> {
        let mut line = Self {
            options,
            devices,
            faults: FaultHandle::default(),
            journal: Journal::new(),
            link: None,
            plugged: None,
        };
        line.plug()?;
        Ok(line)
    }

    /// Like [`VirtualLine::spawn`], with a symlink at `link` to the slave (kept pointing at the
    /// current pty across replugs).
    pub fn with_link(
        options: ServeOptions,
        devices: Vec<SharedDevice>,
        link: &Path,
    ) -> std::io::Result<Self> {
        let mut line = Self::spawn(options, devices)?;
        line.link = Some(link.to_path_buf());
        line.update_link()?;
        Ok(line)
    }

    fn plug(&mut self) -> std::io::Result<()> {
        let (master, opened_slave) = SerialStream::pair().map_err(std::io::Error::from)?;
        // serialport opens the pair without close-on-exec: a process started later (a broker,
        // a gateway under test) would inherit the master end and keep an unplugged line open.
        close_on_exec(std::os::fd::AsRawFd::as_raw_fd(&master))?;
        let slave_path = opened_slave
            .name()
            .map(PathBuf::from)
            .ok_or_else(|| std::io::Error::other("pty slave without a path"))?;
        // The slave is held as a plain file (close-on-exec, and a descriptor of its own for
        // the baud watch) before the pair's own handle on it goes.
        let slave = open_slave(&slave_path)?;
        drop(opened_slave);
        let baud_watch = if self.options.enforce_baud {
            let watched = slave.try_clone()?;
            Some(BaudWatch::new(watched.into(), self.options.timing.baud))
        } else {
            None
        };
        let token = CancellationToken::new();
        let stop = token.clone();
        let task = tokio::spawn(serve_watching(
            AsyncSerial::new(master)?,
            self.options,
            baud_watch,
            self.devices.clone(),
            self.faults.clone(),
            self.journal.clone(),
            token,
        ));
        tracing::debug!(path = %slave_path.display(), "virtual line plugged");
        self.plugged = Some(Plugged {
            slave_path,
            _slave: slave,
            stop,
            task,
        });
        Ok(())
    }

    fn update_link(&self) -> std::io::Result<()> {
        let (Some(link), Some(plugged)) = (&self.link, &self.plugged) else {
            return Ok(());
        };
        // Replace atomically: a new symlink beside it, renamed over the old one.
        let temporary = link.with_extension("tmp-link");
        let _ = std::fs::remove_file(&temporary);
        std::os::unix::fs::symlink(&plugged.slave_path, &temporary)?;
        std::fs::rename(&temporary, link)
    }

    /// The path to open: the symlink if there is one, else the pty slave (`/dev/pts/N`).
    /// While unplugged, the last path.
    pub fn path(&self) -> PathBuf {
        match (&self.link, &self.plugged) {
            (Some(link), _) => link.clone(),
            (None, Some(plugged)) => plugged.slave_path.clone(),
            (None, None) => PathBuf::new(),
        }
    }

    /// The pty slave's own path (None while unplugged).
    pub fn slave_path(&self) -> Option<&Path> {
        self.plugged.as_ref().map(|p| p.slave_path.as_path())
    }

    pub fn faults(&self) -> &FaultHandle {
        &self.faults
    }

    pub fn journal(&self) -> &Journal {
        &self.journal
    }

    pub fn devices(&self) -> &[SharedDevice] {
        &self.devices
    }

    pub fn is_plugged(&self) -> bool {
        self.plugged.is_some()
    }

    /// Stops serving, closes both pty ends and removes the link: the gateway's reads end, its
    /// writes fail, its reopens find nothing.
    pub async fn unplug(&mut self) {
        if let Some(plugged) = self.plugged.take() {
            plugged.stop.cancel();
            if let Err(error) = plugged.task.await {
                tracing::warn!(%error, "virtual line task ended abnormally");
            }
            tracing::debug!(path = %plugged.slave_path.display(), "virtual line unplugged");
        }
        // The link goes with the adapter, as udev removes a by-id link: left in place it would
        // name the freed pty number, which the next pty opened on the machine takes at once, and
        // the gateway would reopen a stranger's line.
        if let Some(link) = &self.link {
            let _ = std::fs::remove_file(link);
        }
    }

    /// A new pty with the same devices, faults and journal (the slave path changes; the link,
    /// if any, follows it).
    pub async fn replug(&mut self) -> std::io::Result<()> {
        self.unplug().await;
        self.plug()?;
        self.update_link()
    }
}

impl Drop for VirtualLine {
    fn drop(&mut self) {
        if let Some(plugged) = &self.plugged {
            plugged.stop.cancel();
        }
        if let Some(link) = &self.link {
            let _ = std::fs::remove_file(link);
        }
    }
}

/// Opens a pty slave for reading and writing without making it the process's controlling
/// terminal.
pub(crate) fn open_slave(path: &Path) -> std::io::Result<File> {
    use std::os::unix::fs::OpenOptionsExt;

    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
        .open(path)
}

/// Marks `fd` close-on-exec.
fn close_on_exec(fd: std::os::fd::RawFd) -> std::io::Result<()> {
    use nix::fcntl::{fcntl, FcntlArg, FdFlag};
    let flags = fcntl(fd, FcntlArg::F_GETFD).map_err(std::io::Error::from)?;
    let flags = FdFlag::from_bits_truncate(flags) | FdFlag::FD_CLOEXEC;
    fcntl(fd, FcntlArg::F_SETFD(flags)).map_err(std::io::Error::from)?;
    Ok(())
}
