//! The process signals: SIGTERM and SIGINT cancel the gateway's shutdown token (a second one
//! ends the process at once); SIGHUP becomes a reload request, so the signal's default action
//! (ending the process) never applies.

use tokio_util::sync::CancellationToken;

/// SIGTERM or SIGINT fires the shutdown; a second one ends the process at once.
pub async fn stop_on_signals(trigger: CancellationToken) {
    use tokio::signal::unix::{signal, SignalKind};
    let (Ok(mut terminate), Ok(mut interrupt)) = (
        signal(SignalKind::terminate()),
        signal(SignalKind::interrupt()),
    ) else {
        tracing::error!("cannot install signal handlers: stop with SIGKILL");
        return;
    };
    tokio::select! {
        _ = terminate.recv() => tracing::info!("SIGTERM: stopping"),
        _ = interrupt.recv() => tracing::info!("SIGINT: stopping"),
    }
    trigger.cancel();
    tokio::select! {
        _ = terminate.recv() => {},
        _ = interrupt.recv() => {},
    }
    tracing::warn!("second signal: exiting without a clean stop");
    std::process::exit(130);
}

/// Installs the SIGHUP handler and returns its requests: one per signal, coalesced while one
/// is waiting. From here on SIGHUP never ends the process.
pub(crate) fn hangups() -> std::io::Result<tokio::sync::mpsc::Receiver<()>> {
    use tokio::signal::unix::{signal, SignalKind};
    let mut hangup = signal(SignalKind::hangup())?;
    let (tx, rx) = tokio::sync::mpsc::channel(1);
    tokio::spawn(async move {
        while hangup.recv().await.is_some() {
            tracing::info!("SIGHUP: reloading the configuration");
            if let Err(tokio::sync::mpsc::error::TrySendError::Closed(())) = tx.try_send(()) {
                tracing::warn!("SIGHUP: the gateway does not take reloads now; ignored");
            }
        }
    });
    Ok(rx)
}
