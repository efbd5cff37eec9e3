//! The files of a journal's directory: which names are segments (`<sequence>.journal`, the
//! sequence zero-padded so that names sort) and reading one safely (only a regular file, never
//! blocking nor following a link, never past the largest segment). File I/O only.

use std::fs::{self, OpenOptions};
use std::io::{self, Read};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::{Path, PathBuf};

use super::record::{MAGIC, MAX_RECORD};

/// Segments are at most this long (a sixteenth of the journal's bound, within a floor).
pub(crate) const MAX_SEGMENT: u64 = 4 * 1024 * 1024;
/// No segment is ever longer: a larger file of that name is not one, and is not read.
pub const MAX_SEGMENT_FILE: u64 = MAX_SEGMENT + MAGIC.len() as u64 + MAX_RECORD as u64;

/// Segment files are named `<sequence>.journal`.
pub(super) const SUFFIX: &str = "journal";

/// The files of `dir` named like segments, with their sequence numbers, in order; a name
/// whose number is beyond any sequence number is one too, with none.
pub(super) fn segment_names(dir: &Path) -> io::Result<Vec<(PathBuf, Option<u64>)>> {
    let mut names: Vec<(PathBuf, Option<u64>)> = fs::read_dir(dir)?
        .flatten()
        .filter_map(|entry| {
            let path = entry.path();
            sequence_of(&path).map(|sequence| (path, sequence))
        })
        .collect();
    names.sort_unstable_by_key(|(_, sequence)| sequence.unwrap_or(u64::MAX));
    Ok(names)
}

/// A segment file's bytes. Only a regular file is one: anything else of that name (a FIFO,
/// a socket, a device, a directory, a symbolic link) is refused before it is opened
/// ([`io::ErrorKind::Unsupported`]), opening never blocks or follows a link, the kind is
/// checked again on what was opened, and a file longer than any segment is not read.
pub(super) fn read_segment_file(path: &Path) -> io::Result<Vec<u8>> {
    let not_segment = |kind: &str| {
        io::Error::new(
            io::ErrorKind::Unsupported,
            format!("{kind}, not a regular file"),
        )
    };
    let kind = fs::symlink_metadata(path)?.file_type();
    if !kind.is_file() {
        return Err(not_segment(kind_name(kind)));
    }
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOFOLLOW)
        .open(path)?;
    let meta = file.metadata()?;
    if !meta.file_type().is_file() {
        return Err(not_segment(kind_name(meta.file_type())));
    }
    if meta.len() > MAX_SEGMENT_FILE {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "{} bytes, longer than any segment ({MAX_SEGMENT_FILE})",
                meta.len()
            ),
        ));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(MAX_SEGMENT_FILE).read_to_end(&mut bytes)?;
    Ok(bytes)
}

fn kind_name(kind: fs::FileType) -> &'static str {
    if kind.is_symlink() {
        "a symbolic link"
    } else if kind.is_dir() {
        "a directory"
    } else if kind.is_fifo() {
        "a FIFO"
    } else if kind.is_socket() {
        "a socket"
    } else if kind.is_block_device() || kind.is_char_device() {
        "a device"
    } else {
        "not a regular file"
    }
}

/// The sequence number of a segment file's path: None for a file not named like a segment,
/// Some(None) for one whose number is beyond the range of sequence numbers (no segment of
/// ours, and said like every other such file).
pub(super) fn sequence_of(path: &Path) -> Option<Option<u64>> {
    if path.extension()? != SUFFIX {
        return None;
    }
    let stem = path.file_stem()?.to_str()?;
    if stem.is_empty() || !stem.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    Some(stem.parse().ok())
}
