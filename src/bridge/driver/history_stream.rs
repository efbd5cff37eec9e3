//! The driver's side of the history stream: the journal in the `[history]` directory, where
//! each change set goes (published at once when the broker is there and nothing older waits,
//! journaled otherwise, so that the stream stays in order), and the paced replay after the
//! reconnect. The core decides what a change set is ([`HistoryEntry`]); this only carries it.
//! What is replayed is also handed on (to the Sparkplug node's store and forward), never
//! faster than it is taken. When a connection is lost, what was handed towards the broker and
//! not acknowledged comes back here and is put back in front of everything the journal still
//! holds (it was read before all of that); what the outbox held is older than nothing the
//! writer still gives back, so it waits until all of that is back, and follows it.

use std::time::{Instant, SystemTime};

use rumqttc::QoS;
use tokio::sync::mpsc;

use crate::bridge::core::action::{HistoryEntry, Publish};
use crate::bridge::observers::statistics::HistoryStats;
use crate::config::HistoryConfig;
use crate::history::document::{epoch_ms, read_at_of};
use crate::history::{Journal, Record};
use crate::topics::{TopicKind, Topics};
use rtu2mqtt_profile::topic_levels::HISTORY;

/// Records replayed per tick at most (with the bridge's 250 ms tick, 4,000 a second). While
/// the journal holds records, what is read meanwhile is journaled behind them: the replay has
/// to outrun a plant whose every device changes every second, or it never ends.
pub(crate) const REPLAY_BATCH: usize = 1000;
/// Replay takes what the outbox holds beyond this as room already taken: live values and
/// results go first.
pub(crate) const REPLAY_ROOM: usize = 1250;

/// The journal and the replay.
#[derive(Debug)]
pub(crate) struct HistoryStream {
    topics: Topics,
    journal: Journal,
    /// Where replayed records are handed on, once [`HistoryStream::forward_replays`] is called.
    forward: Option<mpsc::Sender<Record>>,
    /// What the outbox held when the connection was lost, newer than what the writer still
    /// gives back: put back once that is ([`HistoryStream::release_held`]).
    held: Option<Vec<Record>>,
}

/// A publish of the history stream (`<prefix>/<device>/history`, never retained; `history`
/// is no field name, so no state topic looks like it).
pub(crate) fn is_history(topic: &str, retain: bool) -> bool {
    !retain
        && topic
            .strip_suffix(HISTORY)
            .is_some_and(|rest| rest.ends_with('/'))
}

impl HistoryStream {
    /// Opens the journal of `config`, with what earlier runs left in it. A journal that
    /// cannot be written is no reason not to run: it says why once, keeps the newest records
    /// in memory and is tried again until it can ([`HistoryStream::problem`]).
    pub(crate) fn open(config: &HistoryConfig, topics: Topics) -> Self {
        let journal = Journal::open(config);
        let stats = journal.stats();
        if stats.waiting > 0 {
            tracing::info!(
                records = stats.waiting,
                bytes = stats.bytes,
                "history journal holds records of an earlier run: replayed after the connection"
            );
        }
        HistoryStream {
            topics,
            journal,
            forward: None,
            held: None,
        }
    }

    /// Why the journal cannot be written now (the gateway is unhealthy meanwhile); None
    /// while it can.
    pub(crate) fn problem(&self) -> Option<&str> {
        self.journal.problem()
    }

    /// A history publish that went towards the broker and was not acknowledged, or was not
    /// handed over at all: put back in front of what the journal holds (behind what came back
    /// before it).
    pub(crate) fn take_back(&mut self, topic: &str, document: &[u8]) {
        let document = String::from_utf8_lossy(document).into_owned();
        match self.record_of(topic, document) {
            Some(record) => self.journal.put_back(&record),
            None => {
                tracing::warn!(%topic, "a history publish taken back is not one of this gateway's")
            }
        }
    }

    /// The record a history publish was made from.
    fn record_of(&self, topic: &str, document: String) -> Option<Record> {
        let TopicKind::History { device } = self.topics.classify(topic) else {
            return None;
        };
        Some(Record {
            at_ms: read_at_of(&document)?,
            device: device.to_string(),
            document,
        })
    }

    /// `queued` (what the outbox held) waits in memory until [`HistoryStream::release_held`];
    /// change sets read meanwhile are journaled, behind everything.
    pub(crate) fn hold(&mut self, queued: Vec<Publish>) {
        let records: Vec<Record> = queued
            .into_iter()
            .filter_map(|publish| self.record_of(&publish.topic, publish.payload))
            .collect();
        self.held.get_or_insert_with(Vec::new).extend(records);
    }

    /// Everything taken back is in the journal: what was held follows it there.
    pub(crate) fn release_held(&mut self) {
        for record in self.held.take().unwrap_or_default() {
            self.journal.put_back(&record);
        }
    }

    pub(crate) fn is_holding(&self) -> bool {
        self.held.is_some()
    }

    fn journal(&mut self, record: Record) {
        self.journal.append(&record, epoch_ms(SystemTime::now()));
    }

    /// Hands every replayed record to `forward` as well; the replay waits while it is full.
    pub(crate) fn forward_replays(&mut self, forward: mpsc::Sender<Record>) {
        self.forward = Some(forward);
    }

    /// Where `entry` goes: the publish to make now, or None when it was journaled (the link
    /// is down, or older records still wait for their replay or to come back).
    pub(crate) fn route(&mut self, entry: HistoryEntry, link_up: bool) -> Option<Publish> {
        let waiting = !self.journal.is_empty();
        if link_up && !waiting && self.held.is_none() {
            return Some(publish(entry.topic, entry.document));
        }
        self.journal(Record {
            at_ms: entry.at_ms,
            device: entry.device,
            document: entry.document,
        });
        None
    }

    /// The next records of the replay, oldest first, as publishes: `room` is how many the
    /// outbox can take before live traffic would wait behind them.
    pub(crate) fn replay(&mut self, room: usize) -> Vec<Publish> {
        if self.forward.as_ref().is_some_and(mpsc::Sender::is_closed) {
            self.forward = None;
        }
        let room = match &self.forward {
            Some(forward) => room.min(forward.capacity()),
            None => room,
        };
        if self.journal.is_empty() || room == 0 {
            return Vec::new();
        }
        let records = self
            .journal
            .take(room.min(REPLAY_BATCH), epoch_ms(SystemTime::now()));
        records
            .into_iter()
            .map(|record| {
                if let Some(forward) = &self.forward {
                    // Room was made above: only a receiver gone meanwhile refuses it.
                    let _ = forward.try_send(record.clone());
                }
                publish(self.topics.history_topic(&record.device), record.document)
            })
            .collect()
    }

    /// Every tick: what was written is synced once it has waited a second, and a journal
    /// that could not be written is tried again.
    pub(crate) fn on_tick(&mut self, now: Instant) {
        self.journal.on_tick(now);
    }

    /// On shutdown: everything written is synced.
    pub(crate) fn sync(&mut self) {
        self.journal.sync();
    }

    /// The journal's health; `link_up` makes what waits a replay backlog.
    pub(crate) fn stats(&self, link_up: bool) -> HistoryStats {
        let journal = self.journal.stats();
        HistoryStats {
            replay_backlog: if link_up { journal.waiting } else { 0 },
            journal,
            writable: self.journal.problem().is_none(),
        }
    }
}

/// The history stream's publication: QoS 1, not retained, kept over a short outage.
fn publish(topic: String, document: String) -> Publish {
    Publish {
        topic,
        payload: document,
        qos: QoS::AtLeastOnce,
        retain: false,
        keep: true,
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, UNIX_EPOCH};

    use super::*;
    use crate::history::document::document;
    use rtu2mqtt_profile::Value;

    fn stream(dir: &std::path::Path) -> HistoryStream {
        let config = HistoryConfig {
            path: dir.to_path_buf(),
            max_size: 1 << 20,
            max_age: Duration::from_secs(7 * 24 * 3600),
        };
        HistoryStream::open(&config, Topics::new("gw", "plant"))
    }

    /// The change set of `gear` read at second `n` (recent, so that `max_age` keeps it).
    fn entry(n: u64) -> HistoryEntry {
        let at_ms = epoch_ms(SystemTime::now()) - 100_000 + n * 1000;
        let gear = Value::Int(i128::from(n));
        HistoryEntry {
            device: "dust".to_string(),
            topic: "plant/dust/history".to_string(),
            at_ms,
            document: document(UNIX_EPOCH + Duration::from_millis(at_ms), [("gear", &gear)]),
        }
    }

    fn replayed_gears(stream: &mut HistoryStream) -> Vec<String> {
        stream
            .replay(100)
            .into_iter()
            .map(|publish| {
                let values = crate::history::document::values_of(&publish.payload);
                values.map_or(String::new(), |v| v[0].1.to_string())
            })
            .collect()
    }

    #[test]
    fn what_comes_back_is_journaled_before_what_was_queued_behind_it() {
        let dir = tempfile::tempdir().expect("dir");
        let mut stream = stream(dir.path());
        // 1 and 2 went to the client, 3 was still in the outbox, when the link went down.
        let handed: Vec<Publish> = [1, 2]
            .iter()
            .filter_map(|&n| stream.route(entry(n), true))
            .collect();
        let queued = stream.route(entry(3), true).into_iter().collect();
        // The client gives back 1; the outbox's 3 is held; 4 is read meanwhile.
        stream.take_back(&handed[0].topic, handed[0].payload.as_bytes());
        stream.hold(queued);
        assert_eq!(stream.route(entry(4), false), None);
        // The writer gives back 2 later.
        stream.take_back(&handed[1].topic, handed[1].payload.as_bytes());
        stream.release_held();
        assert_eq!(replayed_gears(&mut stream), ["1", "2", "3", "4"]);
    }

    #[test]
    fn what_a_replay_handed_out_and_gets_back_comes_before_what_it_left() {
        let dir = tempfile::tempdir().expect("dir");
        let mut stream = stream(dir.path());
        for n in 0..10 {
            assert_eq!(stream.route(entry(n), false), None);
        }
        // The broker is back: the replay hands out 0 to 3; the link is lost again with 0 and 1
        // unacknowledged, 2 with the writer and 3 still in the outbox.
        let handed = stream.replay(4);
        assert_eq!(replay_all_of(handed.clone()), gears(0..4));
        for publish in &handed[..2] {
            stream.take_back(&publish.topic, publish.payload.as_bytes());
        }
        stream.hold(vec![handed[3].clone()]);
        assert_eq!(stream.route(entry(10), false), None, "read meanwhile");
        stream.take_back(&handed[2].topic, handed[2].payload.as_bytes());
        stream.release_held();
        // Back again: the replay hands out 0 and 1 and loses them once more.
        let handed = stream.replay(2);
        assert_eq!(replay_all_of(handed.clone()), gears(0..2));
        for publish in &handed {
            stream.take_back(&publish.topic, publish.payload.as_bytes());
        }
        assert_eq!(stream.route(entry(11), false), None);
        assert_eq!(replay_all(&mut stream, 3), gears(0..12));
        // Nothing is left behind on disk.
        let files = std::fs::read_dir(dir.path()).map_or(0, Iterator::count);
        assert_eq!(files, 0, "every segment is removed once replayed");
    }

    #[test]
    fn what_is_not_a_history_publish_of_this_gateway_is_not_journaled() {
        let dir = tempfile::tempdir().expect("dir");
        let mut stream = stream(dir.path());
        stream.take_back(
            "other/dust/history",
            b"{\"ts\":\"2026-12-02T15:00:01.123Z\",\"values\":{}}",
        );
        stream.take_back("plant/dust/history", b"not a document");
        assert!(stream.replay(100).is_empty());
    }

    #[test]
    fn only_the_history_stream_is_history() {
        assert!(is_history("plant/dust_collector/history", false));
        assert!(!is_history("plant/dust_collector/history", true));
        assert!(!is_history("plant/dust_collector/gear", false));
        assert!(!is_history("plant/dust_collector/prehistory", false));
        assert!(!is_history("history", false));
    }

    /// A tmpfs of `size` on a fresh directory, unmounted when dropped; None where mounting is
    /// not permitted.
    struct SmallDisk(tempfile::TempDir);

    impl SmallDisk {
        fn mount(size: &str) -> Option<SmallDisk> {
            let dir = tempfile::tempdir().ok()?;
            let mounted = std::process::Command::new("mount")
                .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
                .arg(dir.path())
                .status()
                .is_ok_and(|status| status.success());
            mounted.then_some(SmallDisk(dir))
        }

        /// Takes all the room left.
        fn fill(&self) -> std::path::PathBuf {
            use std::io::Write;
            let path = self.0.path().join("filler");
            if let Ok(mut file) = std::fs::File::create(&path) {
                while file.write_all(&[0xAA; 4096]).is_ok() {}
                while file.write_all(&[0xAA; 1]).is_ok() {}
            }
            path
        }
    }

    impl Drop for SmallDisk {
        fn drop(&mut self) {
            let _ = std::process::Command::new("umount")
                .arg(self.0.path())
                .status();
        }
    }

    /// The gears of what `replay(room)` hands out, until it hands out nothing.
    fn replay_all(stream: &mut HistoryStream, room: usize) -> Vec<String> {
        let mut gears = Vec::new();
        loop {
            let batch: Vec<String> = stream
                .replay(room)
                .into_iter()
                .map(|publish| {
                    let values = crate::history::document::values_of(&publish.payload);
                    values.map_or(String::new(), |v| v[0].1.to_string())
                })
                .collect();
            if batch.is_empty() {
                return gears;
            }
            gears.extend(batch);
        }
    }

    fn gears(range: std::ops::Range<u64>) -> Vec<String> {
        range.map(|n| n.to_string()).collect()
    }

    #[test]
    fn after_a_full_disk_a_later_outage_loses_nothing_whatever_waits_in_memory() {
        let Some(disk) = SmallDisk::mount("64k") else {
            eprintln!("a full disk is tested on a tmpfs: mounting one needs root");
            return;
        };
        let mut stream = stream(&disk.0.path().join("history"));
        let mut now = Instant::now();
        let mut tick = |stream: &mut HistoryStream| {
            now += Duration::from_secs(1);
            stream.on_tick(now);
        };
        // An outage on a full disk: what is read waits in memory; room again, the journal
        // is writable again and the broker's return replays it all.
        let filler = disk.fill();
        for n in 0..5 {
            assert_eq!(stream.route(entry(n), false), None);
        }
        tick(&mut stream);
        assert!(stream.problem().is_some());
        std::fs::remove_file(&filler).expect("room again");
        tick(&mut stream);
        assert_eq!(stream.problem(), None);
        assert_eq!(replay_all(&mut stream, 100), gears(0..5));

        // The next outage: the first values go to disk until it is full again (what the
        // segment's last page holds), then 16 wait in memory.
        let failures = stream.stats(false).journal.write_failures;
        let filler = disk.fill();
        let mut n = 5;
        while stream.problem().is_none() {
            assert_eq!(stream.route(entry(n), false), None);
            n += 1;
            assert!(n < 1000, "the disk never filled");
        }
        let on_disk = n - 1 - 5;
        for _ in 0..15 {
            assert_eq!(stream.route(entry(n), false), None);
            n += 1;
        }
        // The one that found the disk full and 15 behind it: 16 in memory.
        assert_eq!(stream.stats(false).journal.write_failures - failures, 16);
        // The broker comes back with those in memory: a little replayed (from disk), then
        // room again and the journal written, then the rest; what is read meanwhile follows.
        let mut replayed = replay_all_of(stream.replay(4));
        std::fs::remove_file(&filler).expect("room again");
        tick(&mut stream);
        assert_eq!(stream.problem(), None);
        assert_eq!(stream.route(entry(n), true), None, "behind the replay");
        replayed.extend(replay_all(&mut stream, 3));
        assert_eq!(replayed, gears(5..n + 1), "{on_disk} were on disk");
        assert_eq!(stream.stats(true).journal.waiting, 0);
        assert!(stream.route(entry(n + 1), true).is_some(), "live again");
    }

    #[test]
    fn what_comes_back_while_the_disk_is_full_waits_in_memory_in_front() {
        let Some(disk) = SmallDisk::mount("64k") else {
            eprintln!("a full disk is tested on a tmpfs: mounting one needs root");
            return;
        };
        let mut stream = stream(&disk.0.path().join("history"));
        for n in 0..6 {
            assert_eq!(stream.route(entry(n), false), None);
        }
        let handed = stream.replay(3);
        assert_eq!(replay_all_of(handed.clone()), gears(0..3));
        // The link is lost with 0 to 2 in flight, on a full disk: 0 is written in front, then
        // the disk is full; all three wait in memory, in order, ahead of 3 to 5.
        let filler = disk.fill();
        for publish in &handed {
            stream.take_back(&publish.topic, publish.payload.as_bytes());
        }
        assert!(stream.problem().is_some());
        assert_eq!(stream.route(entry(6), false), None);
        std::fs::remove_file(&filler).expect("room again");
        stream.on_tick(Instant::now() + Duration::from_secs(2));
        assert_eq!(stream.problem(), None);
        assert_eq!(replay_all(&mut stream, 2), gears(0..7));
    }

    fn replay_all_of(publishes: Vec<Publish>) -> Vec<String> {
        publishes
            .into_iter()
            .map(|publish| {
                let values = crate::history::document::values_of(&publish.payload);
                values.map_or(String::new(), |v| v[0].1.to_string())
            })
            .collect()
    }
}
