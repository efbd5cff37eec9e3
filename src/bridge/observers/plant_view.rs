//! What the bridge published under its prefix, as a person at the console sees it: the last
//! payload of every device's field, availability and result topic (and the gateway's own
//! topics) with when it was published, and each new one as it goes out to whoever watches
//! (nothing is sent while no one does). Fed by the bridge's driver with every message it hands
//! to the outbox.
//!
//! A plant of a thousand meters has a hundred thousand such topics, so each is kept small: its
//! device and the rest of its topic as numbers (the names are kept once), a short payload
//! inside the entry itself. A device's JSON view and history stream carry nothing the page
//! does not have already and are left out.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use tokio::sync::broadcast;

/// Messages a slow watcher may fall behind by before it must take the whole view again.
const BACKLOG: usize = 4096;

/// A message as its watchers get it: its JSON text (`{"topic","payload","at_ms"}`), made once
/// however many watch.
pub type News = Arc<str>;

/// One topic's last message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Published {
    pub topic: String,
    pub payload: String,
    /// When the bridge handed it to the outbox.
    pub at: SystemTime,
}

/// Names kept once, each with its number.
#[derive(Debug, Default)]
struct Names {
    ids: HashMap<Arc<str>, u32>,
    names: Vec<Arc<str>>,
}

impl Names {
    fn id(&mut self, name: &str) -> u32 {
        if let Some(&id) = self.ids.get(name) {
            return id;
        }
        let id = self.names.len() as u32;
        let name: Arc<str> = Arc::from(name);
        self.names.push(Arc::clone(&name));
        self.ids.insert(name, id);
        id
    }

    fn find(&self, name: &str) -> Option<u32> {
        self.ids.get(name).copied()
    }

    fn name(&self, id: u32) -> &str {
        self.names.get(id as usize).map_or("", |name| name)
    }
}

/// Longest payload kept inside its entry.
const INLINE: usize = 22;

/// A payload: most are a number or a word and are kept inline.
#[derive(Debug, Clone)]
enum Payload {
    Inline { len: u8, bytes: [u8; INLINE] },
    Boxed(Box<str>),
}

impl Payload {
    fn of(text: &str) -> Payload {
        if text.len() <= INLINE {
            let mut bytes = [0u8; INLINE];
            bytes[..text.len()].copy_from_slice(text.as_bytes());
            Payload::Inline {
                len: text.len() as u8,
                bytes,
            }
        } else {
            Payload::Boxed(Box::from(text))
        }
    }

    fn as_str(&self) -> &str {
        match self {
            Payload::Inline { len, bytes } => {
                std::str::from_utf8(&bytes[..usize::from(*len)]).unwrap_or("")
            }
            Payload::Boxed(text) => text,
        }
    }
}

#[derive(Debug, Clone)]
struct Entry {
    payload: Payload,
    /// Milliseconds since the Unix epoch.
    at_ms: u64,
}

/// The topics, by (first level under the prefix, the rest).
#[derive(Debug, Default)]
struct Last {
    firsts: Names,
    rests: Names,
    entries: HashMap<(u32, u32), Entry>,
}

/// The view, cheap to clone.
#[derive(Debug, Clone)]
pub struct PlantView {
    /// `<prefix>/`: only topics under it are kept.
    root: Arc<str>,
    last: Arc<Mutex<Last>>,
    news: broadcast::Sender<News>,
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

    /// `topic` as (its first level under the prefix, the rest), when the view keeps it:
    /// commands (`…/set`), refreshes, history streams, JSON views (one level) and statistics
    /// documents are not kept, nor is anything outside the prefix (discovery).
    fn place<'t>(&self, topic: &'t str) -> Option<(&'t str, &'t str)> {
        let under = topic.strip_prefix(&*self.root)?;
        let (first, rest) = under.split_once('/')?;
        let kept = !first.is_empty()
            && !rest.is_empty()
            && rest != "history"
            && rest != "refresh"
            && !rest.ends_with("/set")
            && rest != "set"
            // The statistics documents: the console asks the lines for their figures.
            && !(first == "gateway" && rest.contains("/stats"));
        kept.then_some((first, rest))
    }

    /// Notes a message the bridge is publishing (an empty one clears its topic).
    pub fn note(&self, topic: &str, payload: &str) {
        let Some((first, rest)) = self.place(topic) else {
            return;
        };
        let at_ms = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |since| since.as_millis() as u64);
        if self.news.receiver_count() > 0 {
            let _ = self.news.send(Arc::from(news_json(topic, payload, at_ms)));
        }
        let mut last = self.last.lock().unwrap_or_else(PoisonError::into_inner);
        if payload.is_empty() {
            if let (Some(first), Some(rest)) = (last.firsts.find(first), last.rests.find(rest)) {
                last.entries.remove(&(first, rest));
            }
            return;
        }
        let key = (last.firsts.id(first), last.rests.id(rest));
        let entry = Entry {
            payload: Payload::of(payload),
            at_ms,
        };
        last.entries.insert(key, entry);
    }

    fn published(&self, last: &Last, (first, rest): (u32, u32), entry: &Entry) -> Published {
        Published {
            topic: format!(
                "{}{}/{}",
                self.root,
                last.firsts.name(first),
                last.rests.name(rest)
            ),
            payload: entry.payload.as_str().to_string(),
            at: UNIX_EPOCH + Duration::from_millis(entry.at_ms),
        }
    }

    /// Every topic's last message, in topic order.
    pub fn snapshot(&self) -> Vec<Published> {
        let last = self.last.lock().unwrap_or_else(PoisonError::into_inner);
        let mut all: Vec<Published> = last
            .entries
            .iter()
            .map(|(&key, entry)| self.published(&last, key, entry))
            .collect();
        all.sort_by(|a, b| a.topic.cmp(&b.topic));
        all
    }

    /// The last message on `topic`.
    pub fn get(&self, topic: &str) -> Option<Published> {
        let (first, rest) = self.place(topic)?;
        let last = self.last.lock().unwrap_or_else(PoisonError::into_inner);
        let key = (last.firsts.find(first)?, last.rests.find(rest)?);
        let entry = last.entries.get(&key)?;
        Some(self.published(&last, key, entry))
    }

    /// Every message from now on (subscribe, then take the snapshot, to miss none).
    pub fn subscribe(&self) -> broadcast::Receiver<News> {
        self.news.subscribe()
    }
}

/// `{"topic":…,"payload":…,"at_ms":…}`.
pub fn news_json(topic: &str, payload: &str, at_ms: u64) -> String {
    serde_json::json!({ "topic": topic, "payload": payload, "at_ms": at_ms }).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_state_under_the_prefix_and_tells_watchers() {
        let view = PlantView::new("plant");
        view.note("plant/valve/opening", "12");
        let mut watcher = view.subscribe();
        view.note("plant/valve/opening", "13");
        view.note("plant/valve/opening/set", "");
        view.note("plant/valve/history", "{}");
        view.note("plant/valve", "{\"opening\":13}");
        view.note("homeassistant/device/x/config", "{}");
        view.note("plantx/valve/a", "1");
        let all = view.snapshot();
        assert_eq!(all.len(), 1);
        assert_eq!(all[0].topic, "plant/valve/opening");
        assert_eq!(all[0].payload, "13");
        let news: serde_json::Value = serde_json::from_str(&watcher.try_recv().unwrap()).unwrap();
        assert_eq!(news["topic"], "plant/valve/opening");
        assert_eq!(news["payload"], "13");
        assert!(watcher.try_recv().is_err());
        view.note("plant/valve/opening", "");
        assert!(view.get("plant/valve/opening").is_none());
    }

    #[test]
    fn results_availability_and_long_payloads_come_back_whole() {
        let view = PlantView::new("plant");
        let result = "{\"value\":\"8\",\"outcome\":\"applied\",\"detail\":\"read-back confirms\"}";
        view.note("plant/dust_collector/gear/result", result);
        view.note("plant/dust_collector/availability", "online");
        view.note("plant/gateway/edge1/status", "online");
        view.note("plant/gateway/edge1/stats/line-a", "{}");
        view.note("plant/valve/serial_number", "20231122004A5B");
        assert_eq!(
            view.get("plant/dust_collector/gear/result")
                .unwrap()
                .payload,
            result
        );
        assert_eq!(
            view.get("plant/gateway/edge1/status").unwrap().payload,
            "online"
        );
        let topics: Vec<String> = view.snapshot().into_iter().map(|p| p.topic).collect();
        assert_eq!(
            topics,
            [
                "plant/dust_collector/availability",
                "plant/dust_collector/gear/result",
                "plant/gateway/edge1/status",
                "plant/valve/serial_number"
            ]
        );
    }
}
