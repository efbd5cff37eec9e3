//! The files a configuration names: a path taken relative to the configuration's folder, and a
//! password file, read only when no one but its owner and group can read it.

use std::path::{Path, PathBuf};

/// Reads a password file that only its owner and group may read (mode 0640 or stricter).
pub(super) fn read_password_file(path: &Path) -> Result<String, String> {
    use std::os::unix::fs::PermissionsExt;
    let meta = std::fs::metadata(path).map_err(|error| format!("{}: {error}", path.display()))?;
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o137 != 0 {
        return Err(format!(
            "{} has mode {mode:04o}: a password file must be 0640 or stricter \
             (no access for others, no write for the group)",
            path.display()
        ));
    }
    let text =
        std::fs::read_to_string(path).map_err(|error| format!("{}: {error}", path.display()))?;
    let password = text.trim_end_matches(['\r', '\n']).to_string();
    if password.is_empty() {
        return Err(format!("{} is empty", path.display()));
    }
    Ok(password)
}

/// `path` as written in the configuration, relative to `base` (the configuration's folder)
/// unless absolute.
pub(super) fn resolve(base: &Path, path: &Path) -> PathBuf {
    if path.is_absolute() {
        path.to_path_buf()
    } else {
        base.join(path)
    }
}
