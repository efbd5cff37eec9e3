//! Child processes of the tests: the gateway binary's `run` command line, a command's output
//! awaited on the blocking pool within a time limit (async tests have no tokio process driver:
//! the gateway is built without it), and a child killed and reaped on drop, which every test
//! that starts a process holds.

#![allow(dead_code)]

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

/// The gateway binary under test.
pub const BIN: &str = env!("CARGO_BIN_EXE_rtu2mqtt");

/// `rtu2mqtt run --config <config>` with stdin and stdout closed and stderr discarded; the
/// caller adds its environment and, to read the log, where stderr goes.
pub fn gateway_run(config: &Path) -> Command {
    let mut command = Command::new(BIN);
    command
        .args(["run", "--config"])
        .arg(config)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    command
}

/// Runs `command` to its end and returns what it printed; a child still running after `limit`
/// is killed and the result is a `TimedOut` error (a hung child fails its test, never hangs it).
pub async fn output(mut command: Command, limit: Duration) -> std::io::Result<Output> {
    let child = command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()?;
    let pid = Pid::from_raw(child.id() as i32);
    let mut waiting = tokio::task::spawn_blocking(move || child.wait_with_output());
    let finished = match tokio::time::timeout(limit, &mut waiting).await {
        Ok(finished) => finished,
        Err(_elapsed) => {
            let _ = kill(pid, Signal::SIGKILL);
            let _ = waiting.await;
            return Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                format!("{command:?} still ran after {limit:?}"),
            ));
        }
    };
    finished.map_err(std::io::Error::other)?
}

/// A child process killed (SIGKILL, which also ends a stopped one) and reaped when this is
/// dropped, so a failing test leaves no process behind.
pub struct KillOnDrop(pub Child);

impl KillOnDrop {
    /// Spawns `command`.
    pub fn spawn(mut command: Command) -> std::io::Result<Self> {
        command.spawn().map(KillOnDrop)
    }

    pub fn id(&self) -> u32 {
        self.0.id()
    }

    /// The process id, for signals.
    pub fn pid(&self) -> Pid {
        Pid::from_raw(self.0.id() as i32)
    }

    /// Whether it has not exited yet.
    pub fn is_running(&mut self) -> bool {
        matches!(self.0.try_wait(), Ok(None))
    }
}

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
