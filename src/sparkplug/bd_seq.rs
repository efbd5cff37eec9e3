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
}
