//! What the bridge published under its prefix, as a person at the console sees it: the last
//! payload of every state, availability, result and statistics topic with when it was
//! published, and each new one as it goes out to whoever watches (nothing is sent while no one
//! does). Fed by the bridge's driver with every message it hands to the outbox.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::SystemTime;

use tokio::sync::broadcast;

/// Messages a slow watcher may fall behind by before it must take the whole view again.
const BACKLOG: usize = 4096;

/// One topic's last message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Published {
    pub topic: String,
    pub payload: String,
    /// When the bridge handed it to the outbox.
    pub at: SystemTime,
}

/// The view, cheap to clone.
#[derive(Debug, Clone)]
pub struct PlantView {
    /// `<prefix>/`: only topics under it are kept.
    root: Arc<str>,
    last: Arc<Mutex<HashMap<String, Published>>>,
    news: broadcast::Sender<Arc<Published>>,
}

impl PlantView {
    /// An empty view of the topics under `prefix`.
    pub fn new(prefix: &str) -> Self {
        PlantView {
            root: Arc::from(format!("{prefix}/")),
            last: Arc::default(),
            news: broadcast::channel(BACKLOG).0,
        }
    }

    /// Notes a message the bridge is publishing. Commands (`…/set`) and the history stream are
    /// not state and are left out, as is everything outside the prefix (discovery).
    pub fn note(&self, topic: &str, payload: &str) {
        if !topic.starts_with(&*self.root) || topic.ends_with("/set") || topic.ends_with("/history")
        {
            return;
        }
        let published = Published {
            topic: topic.to_string(),
            payload: payload.to_string(),
            at: SystemTime::now(),
        };
        if self.news.receiver_count() > 0 {
            let _ = self.news.send(Arc::new(published.clone()));
        }
        let mut last = self.last.lock().unwrap_or_else(PoisonError::into_inner);
        if payload.is_empty() {
            // An empty retained message clears the topic.
            last.remove(topic);
        } else {
            last.insert(topic.to_string(), published);
        }
    }

    /// Every topic's last message, in topic order.
    pub fn snapshot(&self) -> Vec<Published> {
        let last = self.last.lock().unwrap_or_else(PoisonError::into_inner);
        let mut all: Vec<Published> = last.values().cloned().collect();
        all.sort_by(|a, b| a.topic.cmp(&b.topic));
        all
    }

    /// The last message on `topic`.
    pub fn get(&self, topic: &str) -> Option<Published> {
        let last = self.last.lock().unwrap_or_else(PoisonError::into_inner);
        last.get(topic).cloned()
    }

    /// Every message from now on (subscribe, then take the snapshot, to miss none).
    pub fn subscribe(&self) -> broadcast::Receiver<Arc<Published>> {
        self.news.subscribe()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_state_under_the_prefix_and_tells_watchers() {
        let view = PlantView::new("plant");
        view.note("plant/valve/position", "12");
        let mut watcher = view.subscribe();
        view.note("plant/valve/position", "13");
        view.note("plant/valve/position/set", "");
        view.note("plant/valve/history", "{}");
        view.note("homeassistant/device/x/config", "{}");
        view.note("plantx/valve/a", "1");
        let all = view.snapshot();
        assert_eq!(all.len(), 1);
        assert_eq!(all[0].payload, "13");
        assert_eq!(watcher.try_recv().unwrap().payload, "13");
        assert!(watcher.try_recv().is_err());
        view.note("plant/valve/position", "");
        assert!(view.get("plant/valve/position").is_none());
    }
}
