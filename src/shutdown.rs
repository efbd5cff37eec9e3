//! Process shutdown as a cloneable token: one [`ShutdownTrigger`] fires it (SIGTERM, SIGINT,
//! Ctrl-C in the demo, a fatal watchdog finding); every task holds a [`Shutdown`] and finishes
//! its current work before returning.

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

    /// Resolves once the shutdown has been fired (at once if it already was, or if the trigger
    /// is gone).
    pub async fn fired(&mut self) {
        // An error means every trigger is gone: nobody can ask for a clean stop any more, so
        // treat it as a shutdown rather than running forever unstoppable.
        let _ = self.rx.wait_for(|fired| *fired).await;
    }
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
}
