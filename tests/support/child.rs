//! Child processes for async tests without tokio's process driver (the gateway is built
//! without it): a command's output awaited on the blocking pool, and a child killed on drop.

#![allow(dead_code)]

use std::process::{Child, Command, Output};

/// Runs `command` to its end on the blocking pool and returns what it printed.
pub async fn output(mut command: Command) -> std::io::Result<Output> {
    tokio::task::spawn_blocking(move || command.output())
        .await
        .map_err(std::io::Error::other)?
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
