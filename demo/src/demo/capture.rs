//! Log capture for the demo's live table: while the table owns the terminal, whatever the
//! process writes to stderr (the gateway's log, the broker's) is diverted into a pipe and
//! handed over line by line, so the table can show the latest lines under itself instead of
//! being scribbled over. Dropping the capture puts stderr back; so does a panic, before its
//! message is printed.

use std::io::{BufRead, BufReader};
use std::os::fd::{AsRawFd, OwnedFd, RawFd};
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::Once;

use tokio::sync::mpsc;

const STDERR: RawFd = 2;

/// The real stderr while a capture runs (-1 otherwise), for the panic hook: a panic message
/// must reach the terminal, not a pipe whose reader may never run again.
static SAVED_STDERR: AtomicI32 = AtomicI32::new(-1);
static PANIC_HOOK: Once = Once::new();

fn restore_stderr() {
    let saved = SAVED_STDERR.swap(-1, Ordering::SeqCst);
    if saved >= 0 {
        let _ = nix::unistd::dup2(saved, STDERR);
    }
}

/// stderr diverted into a pipe; restored on drop.
pub(super) struct StderrCapture {
    saved: OwnedFd,
}

impl StderrCapture {
    /// Diverts stderr; each complete line (ANSI colours removed) is sent on `lines_tx`.
    pub(super) fn start(lines_tx: mpsc::UnboundedSender<String>) -> std::io::Result<Self> {
        let saved = duplicate(STDERR)?;
        let (read_end, write_end) = nix::unistd::pipe().map_err(std::io::Error::from)?;
        PANIC_HOOK.call_once(|| {
            let previous = std::panic::take_hook();
            std::panic::set_hook(Box::new(move |info| {
                restore_stderr();
                previous(info);
            }));
        });
        SAVED_STDERR.store(saved.as_raw_fd(), Ordering::SeqCst);
        nix::unistd::dup2(write_end.as_raw_fd(), STDERR).map_err(std::io::Error::from)?;
        // fd 2 is now the pipe's only write end: once stderr is restored, the reader sees EOF.
        drop(write_end);
        std::thread::Builder::new()
            .name("stderr-capture".to_string())
            .spawn(move || {
                let reader = BufReader::new(std::fs::File::from(read_end));
                for line in reader.split(b'\n') {
                    let Ok(line) = line else { break };
                    let text = strip_ansi(&String::from_utf8_lossy(&line));
                    if lines_tx.send(text).is_err() {
                        break;
                    }
                }
            })?;
        Ok(StderrCapture { saved })
    }
}

impl Drop for StderrCapture {
    fn drop(&mut self) {
        SAVED_STDERR.store(-1, Ordering::SeqCst);
        let _ = nix::unistd::dup2(self.saved.as_raw_fd(), STDERR);
    }
}

fn duplicate(fd: RawFd) -> std::io::Result<OwnedFd> {
    let copy = nix::unistd::dup(fd).map_err(std::io::Error::from)?;
    // SAFETY: `dup` just returned this descriptor; nothing else owns it.
    Ok(unsafe { <OwnedFd as std::os::fd::FromRawFd>::from_raw_fd(copy) })
}

/// Removes ANSI escape sequences (`ESC [ … letter`), which tracing adds for colours.
pub(super) fn strip_ansi(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            if chars.peek() == Some(&'[') {
                chars.next();
                for c in chars.by_ref() {
                    if c.is_ascii_alphabetic() {
                        break;
                    }
                }
            }
            continue;
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours_are_removed() {
        assert_eq!(
            strip_ansi("\u{1b}[2m2026\u{1b}[0m \u{1b}[33m WARN\u{1b}[0m parity"),
            "2026  WARN parity"
        );
        assert_eq!(strip_ansi("plain"), "plain");
        assert_eq!(strip_ansi("cut \u{1b}"), "cut ");
    }
}
