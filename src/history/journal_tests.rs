//! Tests of the journal: segments on disk, damage, sequence numbers, the size bound, a full
//! disk and unusable paths, each on a directory of its own.

use std::process::Command;

use super::*;
use crate::history::segment_file::sequence_of;

const NOW: u64 = 1_796_223_601_123;

fn config(dir: &Path, max_size: u64) -> HistoryConfig {
    HistoryConfig {
        path: dir.to_path_buf(),
        max_size,
        max_age: Duration::from_secs(3600),
    }
}

fn record(n: u64) -> Record {
    Record {
        at_ms: NOW + n,
        device: "fan1".to_string(),
        document: format!("{{\"values\":{{\"fan_speed\":{n}}}}}"),
    }
}

fn open(dir: &Path, max_size: u64) -> Journal {
    Journal::open(&config(dir, max_size))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("rtu2mqtt-journal-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    dir
}

/// `scratch(name)`, made.
fn made(name: &str) -> PathBuf {
    let dir = scratch(name);
    fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
    dir
}

fn fifo(path: &Path) {
    nix::unistd::mkfifo(path, nix::sys::stat::Mode::S_IRWXU).unwrap_or_else(|e| panic!("{e}"));
}

fn segment_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = fs::read_dir(dir)
        .map(|entries| entries.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    files.retain(|path| sequence_of(path).is_some());
    files.sort();
    files
}

fn take_all(journal: &mut Journal, now_ms: u64) -> Vec<Record> {
    let mut replayed = Vec::new();
    loop {
        let batch = journal.take(100, now_ms);
        if batch.is_empty() {
            return replayed;
        }
        replayed.extend(batch);
    }
}

/// Writes a segment holding `records` under `name` in `dir`.
fn write_segment(dir: &Path, name: &str, records: impl IntoIterator<Item = u64>) -> PathBuf {
    let mut bytes = MAGIC.to_vec();
    for n in records {
        bytes.extend(record(n).encode().unwrap_or_default());
    }
    let path = dir.join(name);
    fs::write(&path, bytes).unwrap_or_else(|e| panic!("{e}"));
    path
}

#[test]
fn records_come_back_in_order_after_a_restart_and_are_deleted_once_handed_out() {
    let dir = scratch("restart");
    let mut journal = open(&dir, 1 << 20);
    for n in 0..500 {
        journal.append(&record(n), NOW + n);
    }
    // No sync, no clean close: what a SIGKILL leaves (the page cache has it).
    drop(journal);
    let mut journal = open(&dir, 1 << 20);
    assert_eq!(journal.stats().waiting, 500);
    let mut replayed = Vec::new();
    loop {
        let batch = journal.take(64, NOW);
        if batch.is_empty() {
            break;
        }
        assert!(batch.len() <= 64);
        replayed.extend(batch);
    }
    assert_eq!(replayed, (0..500).map(record).collect::<Vec<_>>());
    assert_eq!(journal.stats(), JournalStats::default());
    assert!(segment_files(&dir).is_empty(), "{:?}", segment_files(&dir));
    assert_eq!(journal.problem(), None);
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn appends_during_a_replay_come_after_it() {
    let dir = scratch("interleaved");
    let mut journal = open(&dir, 1 << 20);
    for n in 0..10 {
        journal.append(&record(n), NOW);
    }
    let mut replayed = journal.take(4, NOW);
    for n in 10..20 {
        journal.append(&record(n), NOW);
    }
    loop {
        let batch = journal.take(3, NOW);
        if batch.is_empty() {
            break;
        }
        replayed.extend(batch);
    }
    assert_eq!(replayed, (0..20).map(record).collect::<Vec<_>>());
    assert!(journal.is_empty());
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn the_bound_holds_during_a_long_outage_and_the_oldest_go_counted() {
    let dir = scratch("bound");
    let max_size = 64 * 1024;
    let mut journal = open(&dir, max_size);
    let total = 20_000;
    for n in 0..total {
        journal.append(&record(n), NOW + n);
        assert!(journal.stats().bytes <= max_size, "{:?}", journal.stats());
    }
    let on_disk: u64 = segment_files(&dir)
        .iter()
        .filter_map(|path| fs::metadata(path).ok())
        .map(|meta| meta.len())
        .sum();
    assert!(on_disk <= max_size, "{on_disk} bytes on disk");
    let stats = journal.stats();
    assert_eq!(stats.waiting + stats.dropped, total);
    assert!(stats.dropped > 0);
    // What is left is the newest records, in order, none missing.
    let replayed = take_all(&mut journal, NOW + total);
    let first = total - replayed.len() as u64;
    assert_eq!(replayed, (first..total).map(record).collect::<Vec<_>>());
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn the_bound_drops_only_records_older_than_every_one_kept() {
    let dir = scratch("oldest-only");
    let max_size = 64 * 1024;
    let mut journal = open(&dir, max_size);
    let mut earlier = 0;
    while journal.stats().dropped == 0 {
        journal.append(&record(earlier), NOW);
        earlier += 1;
    }
    drop(journal);
    // The next run: the journal is at its bound, then an outage adds 60 records.
    let mut journal = open(&dir, max_size);
    let before = journal.stats().waiting;
    for n in 0..200 {
        journal.append(&record(1_000_000 + n), NOW);
    }
    let stats = journal.stats();
    let replayed = take_all(&mut journal, NOW);
    let (older, newer): (Vec<Record>, Vec<Record>) = replayed
        .into_iter()
        .partition(|r| r.at_ms < NOW + 1_000_000);
    assert_eq!(
        newer,
        (0..200).map(|n| record(1_000_000 + n)).collect::<Vec<_>>()
    );
    let first_older = older.first().map_or(earlier, |r| r.at_ms - NOW);
    assert_eq!(
        older,
        (first_older..earlier).map(record).collect::<Vec<_>>()
    );
    assert_eq!(stats.dropped, before - older.len() as u64, "{stats:?}");
    assert!(stats.dropped > 0);
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn records_older_than_max_age_go_counted() {
    let dir = scratch("age");
    let mut journal = open(&dir, 1 << 20);
    for n in 0..10 {
        journal.append(&record(n), NOW);
    }
    let hour_later = NOW + 3_600_000 + 5;
    let replayed = journal.take(100, hour_later);
    assert_eq!(replayed, (5..10).map(record).collect::<Vec<_>>());
    assert_eq!(journal.stats().dropped, 5);
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn damaged_segments_lose_only_their_damaged_records() {
    let dir = scratch("damaged");
    let mut journal = open(&dir, 64 * 1024);
    for n in 0..600 {
        journal.append(&record(n), NOW);
    }
    drop(journal);
    let files = segment_files(&dir);
    assert!(files.len() >= 3, "{files:?}");
    // A flipped bit in the first record, a flipped length byte in the second segment's
    // first record, a damaged header in the third, a torn tail on the last, a foreign
    // file of a segment's name.
    let flip = |path: &Path, at: usize, mask: u8| {
        let mut bytes = fs::read(path).unwrap_or_default();
        bytes[at] ^= mask;
        fs::write(path, bytes).unwrap_or_else(|e| panic!("{e}"));
    };
    flip(&files[0], MAGIC.len() + 20, 0x04);
    flip(&files[1], MAGIC.len() + 1, 0x80);
    flip(&files[2], 3, 0x01);
    let first_records = record::decode(&fs::read(&files[0]).unwrap_or_default()).records;
    let last = files.last().cloned().unwrap_or_default();
    let torn = fs::read(&last).unwrap_or_default();
    fs::write(&last, &torn[..torn.len() - 3]).unwrap_or_else(|e| panic!("{e}"));
    fs::write(dir.join("00000000000000000000.journal.bak"), b"other").unwrap_or_default();
    let foreign = dir.join(format!("{:020}.{SUFFIX}", 99_999));
    fs::write(&foreign, b"#!/bin/sh\necho not a journal\n").unwrap_or_else(|e| panic!("{e}"));

    // Four damaged places; the foreign file is skipped and left alone, not counted as damage
    // (it would be counted again at every start).
    let inspected = Journal::inspect(&dir).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        inspected.map(|stats| (stats.waiting, stats.damaged)),
        Some((597, 4))
    );
    let mut journal = open(&dir, 64 * 1024);
    assert_eq!(journal.stats().damaged, 4);
    let replayed = take_all(&mut journal, NOW);
    let second_first = first_records.len() as u64 + 1;
    let expected: Vec<Record> = (1..599)
        .filter(|&n| n != second_first)
        .map(record)
        .collect();
    assert_eq!(replayed, expected);
    assert!(foreign.exists(), "a file that is not ours is left alone");
    // A foreign name sets no number: new records go right after the last segment.
    journal.append(&record(1000), NOW);
    let numbers: Vec<u64> = segment_files(&dir)
        .iter()
        .filter_map(|p| sequence_of(p).flatten())
        .collect();
    assert_eq!(numbers, [files.len() as u64, 99_999]);
    assert_eq!(journal.take(10, NOW), vec![record(1000)]);
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn only_regular_files_are_segments_and_nothing_blocks_the_start() {
    let dir = made("kinds");
    write_segment(&dir, "00000000000000000001.journal", 0..3);
    fifo(&dir.join("00000000000000000002.journal"));
    let _socket = std::os::unix::net::UnixListener::bind(dir.join("3.journal"))
        .unwrap_or_else(|e| panic!("{e}"));
    fs::create_dir(dir.join("00000000000000000004.journal")).unwrap_or_else(|e| panic!("{e}"));
    let elsewhere = scratch("kinds-target");
    fs::create_dir_all(&elsewhere).unwrap_or_else(|e| panic!("{e}"));
    let target = write_segment(&elsewhere, "x", 100..103);
    std::os::unix::fs::symlink(&target, dir.join("00000000000000000005.journal"))
        .unwrap_or_else(|e| panic!("{e}"));
    std::os::unix::fs::symlink("/dev/zero", dir.join("6.journal"))
        .unwrap_or_else(|e| panic!("{e}"));
    // Longer than any segment (sparse: it takes no room), never read.
    let huge = File::create(dir.join("00000000000000000007.journal"))
        .and_then(|file| file.set_len(8 << 30));
    huge.unwrap_or_else(|e| panic!("{e}"));

    let (opened_tx, opened_rx) = std::sync::mpsc::channel();
    let config = config(&dir, 1 << 20);
    std::thread::spawn(move || {
        let mut journal = Journal::open(&config);
        journal.append(&record(50), NOW);
        let _ = opened_tx.send((journal.stats(), take_all(&mut journal, NOW)));
    });
    let (stats, replayed) = opened_rx
        .recv_timeout(Duration::from_secs(10))
        .unwrap_or_else(|_| panic!("opening the journal blocked"));
    assert_eq!(replayed, [0, 1, 2, 50].map(record));
    assert_eq!(stats.damaged, 1, "the oversized file: {stats:?}");
    assert_eq!(
        fs::read(&target).map(|b| b.len()).ok(),
        Some(MAGIC.len() + 3 * record(100).encode().map_or(0, |b| b.len()))
    );
    for name in [
        "00000000000000000002.journal",
        "3.journal",
        "00000000000000000004.journal",
        "00000000000000000005.journal",
        "6.journal",
        "00000000000000000007.journal",
    ] {
        assert!(
            fs::symlink_metadata(dir.join(name)).is_ok(),
            "{name} left alone"
        );
    }
    let _ = fs::remove_dir_all(&dir);
    let _ = fs::remove_dir_all(&elsewhere);
}

#[test]
fn the_largest_sequence_number_does_not_stop_the_journal() {
    // A foreign file of the largest number: it sets nothing.
    let dir = made("largest-foreign");
    fs::write(dir.join("18446744073709551615.journal"), b"stray").unwrap_or_default();
    let mut journal = open(&dir, 1 << 20);
    for n in 0..5 {
        journal.append(&record(n), NOW);
    }
    assert_eq!(journal.problem(), None);
    assert_eq!(journal.stats().write_failures, 0);
    assert_eq!(
        take_all(&mut journal, NOW),
        (0..5).map(record).collect::<Vec<_>>()
    );
    let _ = fs::remove_dir_all(&dir);

    // A real segment of the largest number: the segments are numbered from 0 again, in
    // order.
    let dir = made("largest-segment");
    write_segment(&dir, "00000000000000000007.journal", 0..2);
    write_segment(&dir, "18446744073709551615.journal", 2..4);
    let mut journal = open(&dir, 1 << 20);
    for n in 4..6 {
        journal.append(&record(n), NOW);
    }
    let numbers: Vec<u64> = segment_files(&dir)
        .iter()
        .filter_map(|p| sequence_of(p).flatten())
        .collect();
    assert_eq!(numbers, [0, 1, 2]);
    assert_eq!(journal.stats().write_failures, 0);
    assert_eq!(
        take_all(&mut journal, NOW),
        (0..6).map(record).collect::<Vec<_>>()
    );
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn after_a_replay_new_records_go_past_what_holds_the_next_names() {
    let dir = made("past-names");
    write_segment(&dir, "00000000000000000001.journal", 0..31);
    fifo(&dir.join("00000000000000000002.journal"));
    fs::write(dir.join("18446744073709551615.journal"), b"stray").unwrap_or_default();
    let mut journal = open(&dir, 1 << 20);
    assert_eq!(
        take_all(&mut journal, NOW),
        (0..31).map(record).collect::<Vec<_>>()
    );
    for n in 31..36 {
        journal.append(&record(n), NOW);
    }
    assert_eq!(journal.problem(), None);
    assert_eq!(
        take_all(&mut journal, NOW),
        (31..36).map(record).collect::<Vec<_>>()
    );
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn empty_segments_are_removed_and_are_no_damage() {
    let dir = made("empty");
    fs::write(dir.join("00000000000000000001.journal"), b"").unwrap_or_default();
    fs::write(dir.join("00000000000000000002.journal"), &MAGIC[..7]).unwrap_or_default();
    write_segment(&dir, "00000000000000000003.journal", 0..0);
    let journal = open(&dir, 1 << 20);
    assert_eq!(journal.stats(), JournalStats::default());
    assert!(segment_files(&dir).is_empty(), "{:?}", segment_files(&dir));
    drop(journal);
    assert_eq!(open(&dir, 1 << 20).stats(), JournalStats::default());
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn a_path_that_is_a_file_is_a_problem_until_it_is_a_directory() {
    let dir = scratch("file-path");
    fs::write(&dir, b"not a directory").unwrap_or_else(|e| panic!("{e}"));
    let mut journal = open(&dir, 1 << 20);
    let problem = journal.problem().map(str::to_string).unwrap_or_default();
    assert_eq!(
        problem,
        format!(
            "{}: is not a directory (the journal needs one)",
            dir.display()
        )
    );
    assert_eq!(Journal::unusable(&dir), Some(problem));
    for n in 0..3 {
        journal.append(&record(n), NOW);
    }
    assert_eq!(journal.stats().write_failures, 3);
    assert_eq!(journal.stats().waiting, 3);
    fs::remove_file(&dir).unwrap_or_else(|e| panic!("{e}"));
    journal.on_tick(Instant::now() + RETRY_INTERVAL);
    assert_eq!(journal.problem(), None);
    assert_eq!(segment_files(&dir).len(), 1, "what waited is on disk");
    journal.append(&record(3), NOW);
    assert_eq!(
        take_all(&mut journal, NOW),
        (0..4).map(record).collect::<Vec<_>>()
    );
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn a_path_that_loops_or_is_read_only_is_a_problem_with_its_cause() {
    let dir = made("loop");
    std::os::unix::fs::symlink(dir.join("b"), dir.join("a")).unwrap_or_else(|e| panic!("{e}"));
    std::os::unix::fs::symlink(dir.join("a"), dir.join("b")).unwrap_or_else(|e| panic!("{e}"));
    let mut journal = open(&dir.join("a"), 1 << 20);
    assert_eq!(
        journal.problem(),
        Some(
            format!(
                "{}: Too many levels of symbolic links (os error 40)",
                dir.join("a").display()
            )
            .as_str()
        )
    );
    journal.append(&record(0), NOW);
    assert_eq!(journal.take(10, NOW), vec![record(0)]);
    let _ = fs::remove_dir_all(&dir);

    let Some(disk) = SmallDisk::mount("read-only", "64k") else {
        eprintln!("a read-only journal is tested on a tmpfs: mounting one needs root");
        return;
    };
    let remounted = Command::new("mount")
        .args(["-o", "remount,ro"])
        .arg(&disk.0)
        .status()
        .is_ok_and(|status| status.success());
    assert!(remounted);
    let journal = open(&disk.0, 1 << 20);
    assert_eq!(
        journal.problem(),
        Some(format!("{}: Read-only file system (os error 30)", disk.0.display()).as_str())
    );
}

#[test]
fn a_directory_gone_under_a_running_journal_keeps_the_records_in_memory() {
    let dir = scratch("unwritable");
    let mut journal = open(&dir, 1 << 20);
    fs::remove_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
    fs::write(&dir, b"now a file").unwrap_or_else(|e| panic!("{e}"));
    for n in 0..3 {
        journal.append(&record(n), NOW);
    }
    assert_eq!(journal.stats().write_failures, 3);
    assert!(journal.problem().is_some());
    // The broker is back before the disk: what waited in memory is replayed from there.
    assert_eq!(
        journal.take(10, NOW),
        (0..3).map(record).collect::<Vec<_>>()
    );
    let _ = fs::remove_file(&dir);
}

#[test]
fn the_memory_queue_keeps_the_newest_within_its_limit() {
    let dir = scratch("queue");
    fs::write(&dir, b"not a directory").unwrap_or_else(|e| panic!("{e}"));
    let mut journal = open(&dir, 1 << 20);
    let each = record(0).encode().map_or(1, |b| b.len() as u64);
    let total = 2 * PENDING_LIMIT / each;
    for n in 0..total {
        journal.append(&record(n), NOW);
    }
    let stats = journal.stats();
    assert_eq!(stats.dropped + stats.waiting, total);
    let replayed = take_all(&mut journal, NOW);
    let first = total - stats.waiting;
    assert_eq!(replayed, (first..total).map(record).collect::<Vec<_>>());
    // As many of the newest as fit, not one more.
    let kept: u64 = replayed.iter().map(encoded_len).sum();
    assert!(kept <= PENDING_LIMIT && kept + encoded_len(&record(first - 1)) > PENDING_LIMIT);
    let _ = fs::remove_file(&dir);
}

/// Replays what `dir` holds in a fresh journal: the records that come out.
fn replay_of(dir: &Path, max_size: u64) -> (Vec<Record>, JournalStats) {
    let mut journal = open(dir, max_size);
    let stats = journal.stats();
    (take_all(&mut journal, NOW), stats)
}

/// How many of `expected` are missing from `replayed`.
fn lost(expected: impl IntoIterator<Item = u64>, replayed: &[Record]) -> usize {
    expected
        .into_iter()
        .filter(|&n| !replayed.contains(&record(n)))
        .count()
}

/// Every kind of damage of the journal's known failure table, reproduced one after the
/// other, with the records it costs printed (`--nocapture`) and asserted.
#[test]
fn the_damage_table_row_by_row() {
    let mut rows: Vec<(&str, String)> = Vec::new();
    let spans = {
        let mut at = MAGIC.len();
        (0..31u64)
            .map(|n| {
                let start = at;
                at += record(n).encode().map_or(0, |b| b.len());
                start
            })
            .collect::<Vec<_>>()
    };
    let damaged_segment = |name: &str, damage: &dyn Fn(&mut Vec<u8>)| {
        let dir = made(name);
        let path = write_segment(&dir, "00000000000000000001.journal", 0..31);
        let mut bytes = fs::read(&path).unwrap_or_default();
        damage(&mut bytes);
        fs::write(&path, bytes).unwrap_or_else(|e| panic!("{e}"));
        let (replayed, _) = replay_of(&dir, 1 << 20);
        let _ = fs::remove_dir_all(&dir);
        lost(0..31, &replayed)
    };
    let first_low = damaged_segment("row-first-low", &|b| b[spans[0]] ^= 0x01);
    let first_high = damaged_segment("row-first-high", &|b| b[spans[0] + 3] ^= 0x80);
    assert_eq!((first_low, first_high), (1, 1));
    rows.push((
        "one bit flipped in the first record's length field (low, high byte)",
        format!("{first_low}, {first_high} of 31"),
    ));
    let middle = damaged_segment("row-middle", &|b| b[spans[15] + 1] ^= 0x04);
    let huge = damaged_segment("row-huge", &|b| {
        b[spans[15]..spans[15] + 4].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    });
    assert_eq!((middle, huge), (1, 1));
    rows.push((
        "one bit flipped in the middle record's length field; a length of 0xFFFFFFF0",
        format!("{middle}; {huge} of 31"),
    ));
    let magic = damaged_segment("row-magic", &|b| b[4] ^= 0x20);
    assert_eq!(magic, 0);
    rows.push((
        "one bit flipped in the MAGIC header",
        format!("{magic} of 31"),
    ));

    // The largest number, as a stray file and as a real segment.
    for (name, content) in [
        ("row-largest-stray", b"stray".to_vec()),
        ("row-largest-segment", Vec::new()),
    ] {
        let dir = made(name);
        if content.is_empty() {
            write_segment(&dir, "18446744073709551615.journal", 100..102);
        } else {
            fs::write(dir.join("18446744073709551615.journal"), content).unwrap_or_default();
        }
        let mut journal = open(&dir, 1 << 20);
        for n in 0..5 {
            journal.append(&record(n), NOW);
        }
        let failures = journal.stats().write_failures;
        drop(journal);
        let (replayed, _) = replay_of(&dir, 1 << 20);
        let lost = lost(0..5, &replayed);
        assert_eq!((lost, failures), (0, 0));
        rows.push((
            if name.ends_with("stray") {
                "a stray 18446744073709551615.journal"
            } else {
                "a real segment named 18446744073709551615.journal"
            },
            format!("{lost} of 5 in the next outage, {failures} write failures"),
        ));
        let _ = fs::remove_dir_all(&dir);
    }

    // A FIFO named like a segment: the start does not wait for it.
    let dir = made("row-fifo");
    write_segment(&dir, "00000000000000000001.journal", 0..5);
    fifo(&dir.join("00000000000000000000.journal"));
    let (done_tx, done_rx) = std::sync::mpsc::channel();
    let fifo_dir = dir.clone();
    std::thread::spawn(move || {
        let _ = done_tx.send(replay_of(&fifo_dir, 1 << 20));
    });
    let (replayed, _) = done_rx
        .recv_timeout(Duration::from_secs(10))
        .unwrap_or_else(|_| panic!("the journal's start waited for a FIFO"));
    let fifo_lost = lost(0..5, &replayed);
    assert_eq!(fifo_lost, 0);
    rows.push((
        "a FIFO named like a segment",
        format!("starts at once, {fifo_lost} of 5 lost"),
    ));
    let _ = fs::remove_dir_all(&dir);

    // An empty segment: no damage, removed.
    let dir = made("row-empty");
    fs::write(dir.join("00000000000000000001.journal"), b"").unwrap_or_default();
    let first = open(&dir, 1 << 20).stats().damaged;
    let second = open(&dir, 1 << 20).stats().damaged;
    assert_eq!((first, second), (0, 0));
    rows.push((
        "an empty segment",
        format!("damaged {first} at the first start, {second} at the next"),
    ));
    let _ = fs::remove_dir_all(&dir);

    // max_size reached by older records, then an outage of about 6 KB of new records.
    let dir = scratch("row-bound");
    let max_size = 64 * 1024;
    let mut journal = open(&dir, max_size);
    let mut older = 0;
    while journal.stats().bytes + 200 < max_size {
        journal.append(&record(older), NOW);
        older += 1;
    }
    drop(journal);
    let mut journal = open(&dir, max_size);
    let newer = 1_000_000..1_000_000 + 6 * 1024 / 50;
    for n in newer.clone() {
        journal.append(&record(n), NOW);
    }
    let dropped = journal.stats().dropped;
    let replayed = take_all(&mut journal, NOW);
    let older_dropped = lost(0..older, &replayed);
    let newer_lost = lost(newer.clone(), &replayed);
    assert_eq!((older_dropped as u64, newer_lost), (dropped, 0));
    rows.push((
        "max_size = 64KiB reached by older records, then about 6 KB of new records",
        format!(
            "{dropped} dropped: {older_dropped} of {older} older, {newer_lost} of {} new",
            newer.end - newer.start
        ),
    ));
    let _ = fs::remove_dir_all(&dir);

    // A path that is a regular file: the records wait in memory, nothing is lost.
    let dir = scratch("row-file");
    fs::write(&dir, b"a file").unwrap_or_else(|e| panic!("{e}"));
    let mut journal = open(&dir, 1 << 20);
    for n in 0..5 {
        journal.append(&record(n), NOW);
    }
    let unusable = journal.problem().is_some();
    let file_lost = lost(0..5, &take_all(&mut journal, NOW));
    assert!(unusable);
    assert_eq!(file_lost, 0);
    rows.push((
        "path names a regular file",
        format!("unhealthy, {file_lost} of 5 lost"),
    ));
    let _ = fs::remove_file(&dir);

    // The disk full, then room again.
    if let Some(disk) = SmallDisk::mount("row-full", "128k") {
        let dir = disk.0.join("history");
        let mut journal = open(&dir, 1 << 20);
        let filler = disk.fill();
        for n in 0..5 {
            journal.append(&record(n), NOW);
        }
        fs::remove_file(filler).unwrap_or_else(|e| panic!("{e}"));
        journal.on_tick(Instant::now() + RETRY_INTERVAL);
        let resumed = journal.problem().is_none();
        for n in 5..10 {
            journal.append(&record(n), NOW);
        }
        drop(journal);
        let (replayed, _) = replay_of(&dir, 1 << 20);
        let full_lost = lost(0..5, &replayed);
        let next_lost = lost(5..10, &replayed);
        assert!(resumed);
        assert_eq!((full_lost, next_lost), (0, 0));
        rows.push((
            "the disk full, then room again",
            format!(
                "resumed; {full_lost} of 5 lost while full, {next_lost} of 5 in the next outage"
            ),
        ));
    }
    for (damage, lost) in rows {
        println!("| {damage} | {lost} |");
    }
}

/// A tmpfs of `size` mounted on a fresh directory, unmounted when dropped (needs root).
struct SmallDisk(PathBuf);

impl SmallDisk {
    fn mount(name: &str, size: &str) -> Option<SmallDisk> {
        let dir = scratch(name);
        fs::create_dir_all(&dir).ok()?;
        let mounted = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(&dir)
            .status()
            .is_ok_and(|status| status.success());
        if !mounted {
            let _ = fs::remove_dir(&dir);
            return None;
        }
        Some(SmallDisk(dir))
    }

    /// Takes all the room left (a file of that name).
    fn fill(&self) -> PathBuf {
        let path = self.0.join("filler");
        let mut file = File::create(&path).unwrap_or_else(|e| panic!("{e}"));
        while file.write_all(&[0xAA; 4096]).is_ok() {}
        while file.write_all(&[0xAA; 1]).is_ok() {}
        path
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
        let _ = fs::remove_dir(&self.0);
    }
}

#[test]
fn a_full_disk_is_a_pause_and_writing_resumes_by_itself() {
    let Some(disk) = SmallDisk::mount("full", "256k") else {
        eprintln!("a full disk is tested on a tmpfs: mounting one needs root");
        return;
    };
    let dir = disk.0.join("history");
    let mut journal = open(&dir, 1 << 20);
    for n in 0..10 {
        journal.append(&record(n), NOW);
    }
    disk.fill();
    for n in 10..500 {
        journal.append(&record(n), NOW);
    }
    let problem = journal.problem().map(str::to_string).unwrap_or_default();
    assert!(problem.contains("No space left on device"), "{problem}");
    assert_eq!(journal.stats().waiting, 500);
    // Still full: tried again, still a pause.
    journal.on_tick(Instant::now() + RETRY_INTERVAL);
    assert!(journal.problem().is_some());
    // The broker comes back first: what waited in memory is replayed from there, and the
    // disk, still full, is still said to be.
    let early = journal.take(100, NOW);
    assert_eq!(early, (0..100).map(record).collect::<Vec<_>>());
    let memory: Vec<Record> = std::iter::from_fn(|| {
        let batch = journal.take(100, NOW);
        (!batch.is_empty()).then_some(batch)
    })
    .flatten()
    .collect();
    assert_eq!(memory, (100..500).map(record).collect::<Vec<_>>());
    // (The replayed segment's deletion made room: taken again.)
    let filler = disk.fill();
    journal.on_tick(Instant::now() + 2 * RETRY_INTERVAL);
    assert!(journal.problem().is_some(), "the disk is still full");
    for n in 0..500 {
        journal.append(&record(n), NOW);
    }
    fs::remove_file(filler).unwrap_or_else(|e| panic!("{e}"));
    journal.on_tick(Instant::now() + 3 * RETRY_INTERVAL);
    assert_eq!(journal.problem(), None);
    for n in 500..510 {
        journal.append(&record(n), NOW);
    }
    assert_eq!(journal.stats().waiting, 510);
    drop(journal);
    // Nothing half written: read again, every record is there and nothing is damaged.
    let mut journal = open(&dir, 1 << 20);
    assert_eq!(journal.stats().damaged, 0);
    assert_eq!(
        take_all(&mut journal, NOW),
        (0..510).map(record).collect::<Vec<_>>()
    );
    drop(journal);
    drop(disk);
}

/// What the journal logs, captured for a test on its thread.
#[derive(Clone, Default)]
struct CapturedLog(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

impl Write for CapturedLog {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for CapturedLog {
    type Writer = CapturedLog;

    fn make_writer(&'a self) -> Self::Writer {
        self.clone()
    }
}

/// Runs `work` with what is logged on this thread captured; returns its result and the log.
fn logged<T>(work: impl FnOnce() -> T) -> (T, String) {
    let log = CapturedLog::default();
    let subscriber = tracing_subscriber::fmt()
        .with_writer(log.clone())
        .with_ansi(false)
        .with_max_level(tracing::Level::INFO)
        .finish();
    let out = tracing::subscriber::with_default(subscriber, work);
    let text = String::from_utf8_lossy(
        &log.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner),
    )
    .into_owned();
    (out, text)
}

/// What lies in the journal's directory beside its segments.
#[derive(Debug, Clone, Copy)]
enum Stray {
    /// A regular file of bytes that are no segment.
    Junk,
    /// An empty file (as `touch` makes it).
    Empty,
    /// The first bytes of a segment's header, no more.
    HeaderPart,
    Fifo,
    Directory,
    Symlink,
}

impl Stray {
    fn make(self, path: &Path) {
        let made = match self {
            Stray::Junk => fs::write(path, b"left here by someone else\n"),
            Stray::Empty => fs::write(path, b""),
            Stray::HeaderPart => fs::write(path, &MAGIC[..5]),
            Stray::Fifo => {
                fifo(path);
                Ok(())
            }
            Stray::Directory => fs::create_dir(path),
            Stray::Symlink => std::os::unix::fs::symlink("/dev/zero", path),
        };
        made.unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    }

    /// Whether the journal removes it (it holds nothing) rather than leaving it alone.
    fn removed(self) -> bool {
        matches!(self, Stray::Empty | Stray::HeaderPart)
    }
}

#[test]
fn every_stray_file_is_said_and_breaks_nothing_whatever_its_number() {
    // Every kind at an ordinary number, at the largest one and in the upper half of the
    // range (where a segment would make the journal number its segments anew).
    let kinds = [
        Stray::Junk,
        Stray::Empty,
        Stray::HeaderPart,
        Stray::Fifo,
        Stray::Directory,
        Stray::Symlink,
    ];
    for (at, kind) in kinds.into_iter().enumerate() {
        for name in [
            format!("{:020}.journal", 5 + at),
            "18446744073709551615.journal".to_string(),
            "09223372036854775809.journal".to_string(),
            // Named like a segment, numbered past the largest sequence number.
            "18446744073709551616.journal".to_string(),
            "99999999999999999999999.journal".to_string(),
        ] {
            let dir = made("strays");
            write_segment(&dir, "00000000000000000001.journal", 0..3);
            let path = dir.join(&name);
            kind.make(&path);
            let (replayed, log) = logged(|| {
                let mut journal = open(&dir, 1 << 20);
                for n in 3..6 {
                    journal.append(&record(n), NOW);
                }
                assert_eq!(journal.problem(), None, "{kind:?} {name}");
                let replayed = take_all(&mut journal, NOW);
                (replayed, journal.stats())
            });
            let (replayed, stats) = replayed;
            assert_eq!(
                replayed,
                (0..6).map(record).collect::<Vec<_>>(),
                "{kind:?} {name}"
            );
            assert_eq!(
                (stats.write_failures, stats.damaged),
                (0, 0),
                "{kind:?} {name}"
            );
            let warned = log
                .lines()
                .filter(|line| line.contains("WARN") && line.contains(&*path.to_string_lossy()))
                .count();
            assert_eq!(warned, 1, "{kind:?} {name} is said once:\n{log}");
            assert!(!log.contains("renumbered"), "{kind:?} {name}:\n{log}");
            assert_eq!(
                fs::symlink_metadata(&path).is_ok(),
                !kind.removed(),
                "{kind:?} {name}"
            );
            let _ = fs::remove_dir_all(&dir);
        }
    }
}
