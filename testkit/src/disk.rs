//! A small tmpfs for tests of a full disk: mounted on a fresh directory, filled to the last
//! byte on demand, unmounted when dropped. Mounting needs root; where it is not permitted
//! there is none, and the test says so and leaves that part out.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A mounted tmpfs.
pub struct SmallDisk {
    dir: tempfile::TempDir,
}

impl SmallDisk {
    /// A tmpfs of `size` (as mount takes it: `256k`, `16m`); None where mounting fails.
    pub fn mount(size: &str) -> Option<SmallDisk> {
        let dir = tempfile::tempdir().ok()?;
        let mounted = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(dir.path())
            .status()
            .is_ok_and(|status| status.success());
        mounted.then_some(SmallDisk { dir })
    }

    pub fn path(&self) -> &Path {
        self.dir.path()
    }

    /// Takes all the room left, in a file whose path is returned (remove it for room again).
    pub fn fill(&self) -> PathBuf {
        let path = self.dir.path().join("filler");
        if let Ok(mut file) = std::fs::File::create(&path) {
            while file.write_all(&[0xAA; 65536]).is_ok() {}
            while file.write_all(&[0xAA; 1]).is_ok() {}
        }
        path
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(self.dir.path()).status();
    }
}
