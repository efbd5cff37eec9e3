//! Every generated file written below a directory, for the package build.

use std::io;
use std::path::{Path, PathBuf};

use crate::completions::completions;
use crate::manual::manual_pages;

/// Every asset, written below `dir` (directories made as needed); returns the paths written.
pub fn write_all(dir: &Path) -> io::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    for asset in manual_pages()?.into_iter().chain(completions()) {
        let path = dir.join(&asset.path);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::write(&path, &asset.contents)?;
        written.push(path);
    }
    Ok(written)
}
