//! What the bridge takes besides the broker's messages and the lines' events: messages of
//! local clients (the console), as if published on the broker, and commands of an external
//! source (a Sparkplug node's DCMDs); each waited for only while it is accepted.

use tokio::sync::mpsc;

use crate::bridge::core::{CommandReport, ExternalCommand};

/// A message handed to the bridge as if a client had published it on the broker (the console's
/// commands and refreshes on `…/set` and `…/refresh`): the same rules, the same book.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LocalMessage {
    pub topic: String,
    pub payload: String,
}

/// The next local message; never ready when none are accepted.
pub(super) async fn next_local(
    local: &mut Option<mpsc::Receiver<LocalMessage>>,
) -> Option<LocalMessage> {
    match local {
        Some(messages) => messages.recv().await,
        None => std::future::pending().await,
    }
}

/// The next external command; never ready when none are accepted.
pub(super) async fn next_external(
    external: &mut Option<(mpsc::Receiver<ExternalCommand>, mpsc::Sender<CommandReport>)>,
) -> Option<ExternalCommand> {
    match external {
        Some((commands, _)) => commands.recv().await,
        None => std::future::pending().await,
    }
}
