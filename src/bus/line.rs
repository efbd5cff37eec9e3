//! (bus helper)

use super::{LineEvent, LineHandle, LineSpec};
use crate::shutdown::Shutdown;
use tokio::sync::mpsc;

/// Starts the task that owns `spec`'s port.
pub fn spawn_line(
    spec: LineSpec,
    events_tx: mpsc::Sender<LineEvent>,
    shutdown: Shutdown,
) -> (LineHandle, tokio::task::JoinHandle<()>) {
    todo!("bus helper")
}
