//! The version `rtu2mqtt --version` shows: the package's own, followed by the commit it was built
//! from when it is built from a git checkout of this repository (`0.1.0 (abc1234)`), so that a
//! report from the field names its exact source. Built without git, or from a copy of the
//! sources outside a checkout, it is the package's version alone.

use std::path::Path;
use std::process::Command;

/// `git <args>` run in this package's directory: its trimmed output, `None` when git is missing,
/// fails or says nothing.
fn git(args: &[&str]) -> Option<String> {
    let output = Command::new("git").args(args).output().ok()?;
    if !output.status.success() {
        return None;
    }
    let text = String::from_utf8(output.stdout).ok()?;
    let text = text.trim();
    (!text.is_empty()).then(|| text.to_string())
}

/// The files whose change means another commit is checked out: `HEAD`, and the branch it names
/// (a loose ref, or `packed-refs` where the branch is packed).
fn files_naming_the_commit() -> Vec<String> {
    let mut files = Vec::new();
    let git_path = |name: &str| git(&["rev-parse", "--path-format=absolute", "--git-path", name]);
    files.extend(git_path("HEAD"));
    if let Some(branch) = git(&["symbolic-ref", "-q", "HEAD"]) {
        match git_path(&branch) {
            Some(loose) if Path::new(&loose).exists() => files.push(loose),
            _ => files.extend(git_path("packed-refs")),
        }
    }
    files
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let package_version = std::env::var("CARGO_PKG_VERSION").unwrap_or_default();
    let manifest_dir = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default();
    // Only this repository's own checkout: sources unpacked inside some other repository
    // must not be labelled with that repository's commit.
    let in_own_checkout = git(&["rev-parse", "--show-toplevel"])
        .and_then(|top| Path::new(&top).canonicalize().ok())
        .zip(Path::new(&manifest_dir).canonicalize().ok())
        .is_some_and(|(top, manifest)| top == manifest);
    let commit = in_own_checkout
        .then(|| git(&["rev-parse", "--short", "HEAD"]))
        .flatten();
    let version = match commit {
        Some(commit) => {
            for file in files_naming_the_commit() {
                println!("cargo:rerun-if-changed={file}");
            }
            format!("{package_version} ({commit})")
        }
        None => package_version,
    };
    println!("cargo:rustc-env=RTU2MQTT_VERSION={version}");
}
