//! The task between a line and the gateway's line events when some field of the line has
//! `publish` settings: it passes every event through the line's [`Report`] in order, and
//! sleeps until the next held value or heartbeat is due (a timer, not the next poll). A line
//! without settings has no such task: its events go straight out.

use std::time::{Instant, SystemTime};

use tokio::sync::mpsc;

use super::event::LineEvent;
use super::report::Report;
use tokio_util::sync::CancellationToken;

/// Events a line may be ahead of its reporter by (the reporter hands them on at once).
pub(crate) const REPORTER_QUEUE: usize = 64;

/// Reports what `report` lets through of the events on `from` to `to`, until `from` closes
/// (the line has stopped). Waits for room on `to`, but not past a shutdown.
pub(crate) async fn run(
    mut report: Report,
    mut from: mpsc::Receiver<LineEvent>,
    to: mpsc::Sender<LineEvent>,
    shutdown: CancellationToken,
) {
    loop {
        let wake = report.next_wake();
        let sleep = async {
            match wake {
                Some(at) => tokio::time::sleep_until(tokio::time::Instant::from_std(at)).await,
                None => std::future::pending().await,
            }
        };
        let out = tokio::select! {
            event = from.recv() => match event {
                Some(event) => report.on_event(event, Instant::now()).into_iter().collect(),
                None => return,
            },
            () = sleep => report.due(Instant::now(), SystemTime::now()),
        };
        for event in out {
            tokio::select! {
                biased;
                sent = to.send(event) => if sent.is_err() { return },
                () = shutdown.cancelled() => return,
            }
        }
    }
}
