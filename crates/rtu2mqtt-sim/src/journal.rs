//! What a simulated line saw and did, for tests to inspect: every request frame as received
//! (with its arrival time and the silence before it), the bytes sent back, writes per device,
//! and bytes that were not a frame.

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rtu2mqtt_modbus::frame::SlaveId;

use super::device::lock;

/// One frame received by the simulated line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RequestRecord {
    /// The frame exactly as received (CRC included).
    pub frame: Vec<u8>,
    /// When its first byte arrived.
    pub arrived: Instant,
    /// Silence on the line before the first byte (since the end of the previous frame in
    /// either direction); None for the first frame.
    pub silence_before: Option<Duration>,
    pub crc_ok: bool,
    /// The bytes sent back for it (after faults), None when nothing was sent.
    pub answer: Option<Vec<u8>>,
    /// When the answer's last byte was due and went out, None when nothing was sent.
    pub answer_timing: Option<AnswerTiming>,
}

/// When an answer's last byte went out, from the simulator's side of the pty.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AnswerTiming {
    /// When its last byte was due on the wire (paced: start plus the answer's wire time).
    pub due: Instant,
    /// Just before the write that handed the last byte to the pty: the master cannot have seen
    /// it sooner, and sees it as soon as the write is done. The line's silence runs from here.
    pub handed_over: Instant,
    /// When that write returned (later than `handed_over` by the system call and any
    /// preemption of the simulator's thread in between).
    pub write_returned: Instant,
}

/// Records kept; older ones are dropped so a long demo or soak run stays in bounded memory
/// (counters keep counting).
pub const MAX_RECORDS: usize = 10_000;

#[derive(Debug, Default)]
struct Inner {
    requests: VecDeque<RequestRecord>,
    /// Every frame ever received, including records no longer kept.
    total_requests: usize,
    writes: BTreeMap<SlaveId, u32>,
    discarded_bytes: usize,
}

/// The shared journal of one line.
#[derive(Debug, Clone, Default)]
pub struct Journal {
    inner: Arc<Mutex<Inner>>,
}

impl Journal {
    pub fn new() -> Self {
        Self::default()
    }

    pub(crate) fn record(&self, record: RequestRecord) {
        let mut inner = lock(&self.inner);
        if inner.requests.len() == MAX_RECORDS {
            inner.requests.pop_front();
        }
        inner.requests.push_back(record);
        inner.total_requests += 1;
    }

    pub(crate) fn count_write(&self, address: SlaveId) {
        *lock(&self.inner).writes.entry(address).or_insert(0) += 1;
    }

    pub(crate) fn count_discarded(&self, bytes: usize) {
        lock(&self.inner).discarded_bytes += bytes;
    }

    /// The frames received so far (the last [`MAX_RECORDS`]).
    pub fn requests(&self) -> Vec<RequestRecord> {
        lock(&self.inner).requests.iter().cloned().collect()
    }

    /// The frames received so far, bytes only.
    pub fn frames(&self) -> Vec<Vec<u8>> {
        lock(&self.inner)
            .requests
            .iter()
            .map(|r| r.frame.clone())
            .collect()
    }

    /// Takes the frames received so far out of the journal (counters stay).
    pub fn drain_requests(&self) -> Vec<RequestRecord> {
        lock(&self.inner).requests.drain(..).collect()
    }

    /// Frames received since the start (or the last [`Journal::clear`]), kept or not.
    pub fn request_count(&self) -> usize {
        lock(&self.inner).total_requests
    }

    /// Write requests (CRC-valid, addressed to the device) the device received.
    pub fn writes_to(&self, address: SlaveId) -> u32 {
        lock(&self.inner).writes.get(&address).copied().unwrap_or(0)
    }

    /// Bytes received that did not make a frame (noise, truncated frames).
    pub fn discarded_bytes(&self) -> usize {
        lock(&self.inner).discarded_bytes
    }

    /// The smallest silence seen before a request (None before the second request).
    pub fn min_silence(&self) -> Option<Duration> {
        lock(&self.inner)
            .requests
            .iter()
            .filter_map(|r| r.silence_before)
            .min()
    }

    pub fn clear(&self) {
        *lock(&self.inner) = Inner::default();
    }

    /// Waits until at least `count` frames were received, or `timeout` passed; returns the
    /// number received.
    pub async fn wait_for_requests(&self, count: usize, timeout: Duration) -> usize {
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            let seen = self.request_count();
            if seen >= count || tokio::time::Instant::now() >= deadline {
                return seen;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_newest_records_and_counts_all() {
        let journal = Journal::new();
        let start = Instant::now();
        for i in 0..MAX_RECORDS + 5 {
            journal.record(RequestRecord {
                frame: (i as u32).to_be_bytes().to_vec(),
                arrived: start,
                silence_before: None,
                crc_ok: true,
                answer: None,
                answer_timing: None,
            });
        }
        assert_eq!(journal.request_count(), MAX_RECORDS + 5);
        let kept = journal.requests();
        assert_eq!(kept.len(), MAX_RECORDS);
        assert_eq!(kept[0].frame, 5u32.to_be_bytes().to_vec());
        assert_eq!(journal.drain_requests().len(), MAX_RECORDS);
        assert!(journal.requests().is_empty());
    }
}
