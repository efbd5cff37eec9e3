//! bdSeq kept across restarts, so that it goes on counting instead of starting at 0 again
//! (hosts that track bdSeq take a repeated one for a stale death). One small file in the
//! gateway's state directory (the `[history]` path, or systemd's `STATE_DIRECTORY`) holds the
//! next connection's bdSeq as decimal text; it is replaced whole (write, sync, rename), so a
//! crash leaves the old number or the new one, never a torn one.

use std::fs;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use crate::config::Config;

/// The file's name in the state directory.
pub const FILE: &str = "sparkplug-bdseq";

/// Where the next bdSeq is kept.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BdSeqStore {
    path: PathBuf,
}

impl BdSeqStore {
    /// The store in `dir`.
    pub fn in_dir(dir: &Path) -> Self {
        BdSeqStore {
            path: dir.join(FILE),
        }
    }

    /// The store of `config`: in the `[history]` path, else in systemd's state directory
    /// (`STATE_DIRECTORY`, the first when it names several); None when there is neither.
    pub fn for_config(config: &Config) -> Option<Self> {
        if let Some(history) = &config.history {
            return Some(Self::in_dir(&history.path));
        }
        let dirs = std::env::var_os("STATE_DIRECTORY")?;
        let first = std::env::split_paths(&dirs).next()?;
        (!first.as_os_str().is_empty()).then(|| Self::in_dir(&first))
    }

    /// Where the number is kept.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The bdSeq the next connection takes: 0 when nothing was kept yet; a file that does not
    /// hold a number is said and counts as nothing.
    pub fn load(&self) -> u8 {
        match fs::read_to_string(&self.path) {
            Ok(text) => text.trim().parse().unwrap_or_else(|_| {
                tracing::warn!(path = %self.path.display(), "Sparkplug bdSeq file unreadable: starting at 0");
                0
            }),
            Err(_) => 0,
        }
    }

    /// Keeps `next` for the next connection (of this run or the next one).
    pub fn store(&self, next: u8) -> io::Result<()> {
        let dir = self.path.parent().unwrap_or_else(|| Path::new("."));
        fs::create_dir_all(dir)?;
        let temporary = self.path.with_extension("new");
        let mut file = fs::File::create(&temporary)?;
        writeln!(file, "{next}")?;
        file.sync_all()?;
        fs::rename(&temporary, &self.path)?;
        fs::File::open(dir)?.sync_all()
    }
}

/// How the fix reads in a warning: the directories where the number can be kept.
const FIX: &str = "give the daemon's user a writable state directory: the [history] path, \
                   or STATE_DIRECTORY (systemd's StateDirectory=; the container image's \
                   /var/lib/rtu2mqtt volume)";

/// Keeps the next bdSeq for the edge node's driver, which keeps it before every connection
/// attempt. That it cannot be kept is said once per run, at start (the first attempt is made
/// at start), naming the fix; later failures of the same run are only debug lines, so an
/// outage's reconnect attempts do not repeat it.
#[derive(Debug)]
pub struct Keeper {
    store: Option<BdSeqStore>,
    warned: bool,
}

impl Keeper {
    /// The keeper of `store`; without one, says at once that bdSeq restarts at 0.
    pub fn new(store: Option<BdSeqStore>) -> Self {
        if store.is_none() {
            tracing::warn!(
                "Sparkplug bdSeq is not kept across restarts (it starts at 0 on every start, \
                 which hosts may take for a stale NDEATH): {FIX}"
            );
        }
        Keeper {
            store,
            warned: false,
        }
    }

    /// Keeps `next`; true when it is kept.
    pub fn keep(&mut self, next: u8) -> bool {
        let Some(store) = &self.store else {
            return false;
        };
        match store.store(next) {
            Ok(()) => true,
            Err(error) if !self.warned => {
                self.warned = true;
                tracing::warn!(
                    path = %store.path.display(),
                    %error,
                    "Sparkplug bdSeq cannot be kept for the next start (it will start at 0 \
                     again): {FIX}"
                );
                false
            }
            Err(error) => {
                tracing::debug!(path = %store.path.display(), %error, "Sparkplug bdSeq not kept");
                false
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_next_bd_seq_survives_a_restart_and_wraps() {
        let dir = std::env::temp_dir().join(format!("rtu2mqtt-bdseq-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        let store = BdSeqStore::in_dir(&dir);
        assert_eq!(store.load(), 0);
        store.store(7).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(BdSeqStore::in_dir(&dir).load(), 7);
        store
            .store(255u8.wrapping_add(1))
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(store.load(), 0);
        fs::write(dir.join(FILE), "garbage").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(store.load(), 0);
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_keeper_reports_whether_the_number_was_kept() {
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let mut keeper = Keeper::new(Some(BdSeqStore::in_dir(dir.path())));
        assert!(keeper.keep(9));
        assert_eq!(BdSeqStore::in_dir(dir.path()).load(), 9);
        // A state "directory" that is a file cannot hold it, however often it is tried.
        let blocked = dir.path().join("not-a-dir");
        fs::write(&blocked, "").unwrap_or_else(|e| panic!("{e}"));
        let mut keeper = Keeper::new(Some(BdSeqStore::in_dir(&blocked)));
        for _ in 0..3 {
            assert!(!keeper.keep(9));
        }
        assert!(!Keeper::new(None).keep(9));
    }
}
