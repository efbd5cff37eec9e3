//! Child processes for async tests without tokio's process driver (the gateway is built
//! without it): a command's output awaited on the blocking pool within a time limit, and a
//! child killed on drop.

#![allow(dead_code)]

use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

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

/// A child process killed (and reaped) when this is dropped.
pub struct KillOnDrop(pub Child);

impl KillOnDrop {
    /// Spawns `command`.
    pub fn spawn(mut command: Command) -> std::io::Result<Self> {
        command.spawn().map(KillOnDrop)
    }

    pub fn id(&self) -> u32 {
        self.0.id()
    }
}

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
