//! Process shutdown as a cloneable token: one [`ShutdownTrigger`] fires it (SIGTERM, SIGINT,
//! Ctrl-C in the demo, a fatal watchdog finding); every task holds a [`Shutdown`] and finishes
//! its current work before returning. [`Shutdown::child`] makes a token that can also be fired
//! alone (one line stopped by a configuration reload). [`hangups`] turns SIGHUP into reload
//! requests, so the signal's default action (ending the process) never applies.

use tokio::sync::watch;

/// Fires the shutdown of every [`Shutdown`] made from it.
#[derive(Debug, Clone)]
pub struct ShutdownTrigger {
    tx: watch::Sender<bool>,
}

/// A task's view of the shutdown.
#[derive(Debug, Clone)]
pub struct Shutdown {
    rx: watch::Receiver<bool>,
}

/// A new trigger and its first token.
pub fn channel() -> (ShutdownTrigger, Shutdown) {
    let (tx, rx) = watch::channel(false);
    (ShutdownTrigger { tx }, Shutdown { rx })
}

impl ShutdownTrigger {
    pub fn fire(&self) {
        self.tx.send_replace(true);
    }

    pub fn subscribe(&self) -> Shutdown {
        Shutdown {
            rx: self.tx.subscribe(),
        }
    }
}

impl Shutdown {
    pub fn is_fired(&self) -> bool {
        *self.rx.borrow()
    }

    /// A token that fires with this one, or alone through the returned trigger. Needs a Tokio
    /// runtime (a small task forwards this token's firing).
    pub fn child(&self) -> (ShutdownTrigger, Shutdown) {
        let (trigger, token) = channel();
        let mut parent = self.clone();
        let forward = trigger.clone();
        tokio::spawn(async move {
            tokio::select! {
                () = parent.fired() => forward.fire(),
                // Every token of the child is gone: nothing left to stop.
                () = forward.tx.closed() => {}
            }
        });
        (trigger, token)
    }

    /// Resolves once the shutdown has been fired (at once if it already was, or if the trigger
    /// is gone).
    pub async fn fired(&mut self) {
        // An error means every trigger is gone: nobody can ask for a clean stop any more, so
        // treat it as a shutdown rather than running forever unstoppable.
        let _ = self.rx.wait_for(|fired| *fired).await;
    }
}

/// Installs the SIGHUP handler and returns its requests: one per signal, coalesced while one
/// is waiting. From here on SIGHUP never ends the process.
pub fn hangups() -> std::io::Result<tokio::sync::mpsc::Receiver<()>> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn fired_resolves_for_every_clone() {
        let (trigger, token) = channel();
        let mut a = token.clone();
        let mut b = trigger.subscribe();
        assert!(!a.is_fired());
        trigger.fire();
        a.fired().await;
        b.fired().await;
        assert!(token.is_fired());
    }

    #[tokio::test]
    async fn a_child_fires_alone_or_with_its_parent() {
        let (trigger, token) = channel();
        let (alone, mut first) = token.child();
        let (_other, mut second) = token.child();
        alone.fire();
        first.fired().await;
        assert!(!second.is_fired());
        trigger.fire();
        second.fired().await;
    }
}
