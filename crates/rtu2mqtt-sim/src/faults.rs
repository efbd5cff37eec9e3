//! Fault injection for a simulated line: a shared, run-time changeable set of [`Faults`]
//! (dropped, corrupted, truncated, late, misaddressed or echoed answers, answers delivered in
//! chunks with pauses between them, garbage, silenced devices, exceptions on demand). The server asks it once per answer; tests change it while
//! the line runs through a [`FaultHandle`].

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rand::Rng;

use rtu2mqtt_modbus::frame::{ExceptionCode, SlaveId};

use super::device::lock;

/// When a fault strikes: the next `next` answers, and after those each answer with
/// `probability` (0 = never, 1 = always).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Occurrence {
    pub next: u32,
    pub probability: f64,
}

impl Occurrence {
    pub const NEVER: Self = Self {
        next: 0,
        probability: 0.0,
    };
    pub const ALWAYS: Self = Self {
        next: 0,
        probability: 1.0,
    };

    /// The next `count` answers.
    pub fn next(count: u32) -> Self {
        Self {
            next: count,
            probability: 0.0,
        }
    }

    /// Each answer with probability `p`.
    pub fn probability(p: f64) -> Self {
        Self {
            next: 0,
            probability: p.clamp(0.0, 1.0),
        }
    }

    /// Whether the fault strikes this time (consumes one of `next`).
    pub fn strike(&mut self, rng: &mut impl Rng) -> bool {
        if self.next > 0 {
            self.next -= 1;
            return true;
        }
        self.probability > 0.0 && rng.gen_bool(self.probability.clamp(0.0, 1.0))
    }
}

/// The faults of a simulated line. `Default` is a healthy line.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Faults {
    /// The faults below apply to answers of this device only (None: every device). `silenced`
    /// and `idle_garbage_every` are separate.
    pub target: Option<SlaveId>,
    /// The answer is not sent.
    pub drop: Occurrence,
    /// One bit of the answer's CRC is flipped.
    pub corrupt_crc: Occurrence,
    /// The answer loses its last `truncate_bytes` bytes (at least 1).
    pub truncate: Occurrence,
    pub truncate_bytes: usize,
    /// `garbage_bytes` random bytes go out right before the answer.
    pub garbage_before: Occurrence,
    pub garbage_bytes: usize,
    /// The answer carries the address `wrong_address` (CRC recomputed, so only the address is
    /// wrong).
    pub wrong_address: Occurrence,
    pub wrong_address_value: SlaveId,
    /// The answer is replaced by this exception.
    pub exception: Occurrence,
    pub exception_code: Option<ExceptionCode>,
    /// Extra delay before the answer (on top of t3.5).
    pub delay: Duration,
    /// A pause in the middle of the answer (a gap inside a frame).
    pub pause_mid_answer: Option<Duration>,
    /// The answer goes out in chunks with a pause after each (a slow device, or a USB adapter
    /// handing bytes over per latency timer). Takes precedence over `pause_mid_answer`.
    pub answer_chunks: Option<AnswerChunks>,
    /// Every request is echoed back at once, like an RS485 adapter that hears itself.
    pub echo: bool,
    /// Devices that answer nothing at all (they still count as not having received anything).
    pub silenced: BTreeSet<SlaveId>,
    /// Random bytes sent while the line is idle, this often.
    pub idle_garbage_every: Option<Duration>,
}

/// What the server does to one answer, decided once per answer.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AnswerFaults {
    pub drop: bool,
    pub corrupt_crc: bool,
    pub truncate_bytes: usize,
    pub garbage_before: Vec<u8>,
    pub wrong_address: Option<SlaveId>,
    pub exception: Option<ExceptionCode>,
    pub delay: Duration,
    pub pause_mid_answer: Option<Duration>,
    pub answer_chunks: Option<AnswerChunks>,
}

/// An answer sent `bytes` at a time (at least 1) with `gap` of silence between two chunks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AnswerChunks {
    pub bytes: usize,
    pub gap: Duration,
}

/// The shared handle on a line's faults.
#[derive(Debug, Clone, Default)]
pub struct FaultHandle {
    inner: Arc<Mutex<Faults>>,
}

impl FaultHandle {
    pub fn new(faults: Faults) -> Self {
        Self {
            inner: Arc::new(Mutex::new(faults)),
        }
    }

    /// A copy of the faults in force.
    pub fn get(&self) -> Faults {
        lock(&self.inner).clone()
    }

    /// Replaces the faults.
    pub fn set(&self, faults: Faults) {
        *lock(&self.inner) = faults;
    }

    /// Changes the faults in place: `faults.update(|f| f.drop = Occurrence::next(2))`.
    pub fn update(&self, change: impl FnOnce(&mut Faults)) {
        change(&mut lock(&self.inner));
    }

    /// Back to a healthy line.
    pub fn clear(&self) {
        self.set(Faults::default());
    }

    /// Silences (or revives) one device.
    pub fn silence(&self, address: SlaveId, silent: bool) {
        self.update(|f| {
            if silent {
                f.silenced.insert(address);
            } else {
                f.silenced.remove(&address);
            }
        });
    }

    pub fn is_silenced(&self, address: SlaveId) -> bool {
        lock(&self.inner).silenced.contains(&address)
    }

    pub fn idle_garbage_every(&self) -> Option<Duration> {
        lock(&self.inner).idle_garbage_every
    }

    pub fn echo(&self) -> bool {
        lock(&self.inner).echo
    }

    /// Decides the faults of one answer from device `address`.
    pub fn for_answer(&self, address: SlaveId) -> AnswerFaults {
        let mut faults = lock(&self.inner);
        if faults.target.is_some_and(|target| target != address) {
            return AnswerFaults::default();
        }
        let mut rng = rand::thread_rng();
        let mut decided = AnswerFaults {
            delay: faults.delay,
            pause_mid_answer: faults.pause_mid_answer,
            answer_chunks: faults.answer_chunks,
            ..AnswerFaults::default()
        };
        decided.drop = faults.drop.strike(&mut rng);
        decided.corrupt_crc = faults.corrupt_crc.strike(&mut rng);
        if faults.truncate.strike(&mut rng) {
            decided.truncate_bytes = faults.truncate_bytes.max(1);
        }
        if faults.garbage_before.strike(&mut rng) {
            decided.garbage_before = random_bytes(&mut rng, faults.garbage_bytes.max(1));
        }
        if faults.wrong_address.strike(&mut rng) {
            decided.wrong_address = Some(faults.wrong_address_value);
        }
        if faults.exception.strike(&mut rng) {
            decided.exception = Some(
                faults
                    .exception_code
                    .unwrap_or(ExceptionCode::ServerDeviceFailure),
            );
        }
        decided
    }
}

/// `count` random bytes.
pub fn random_bytes(rng: &mut impl Rng, count: usize) -> Vec<u8> {
    (0..count).map(|_| rng.gen()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counted_faults_strike_exactly_that_often() {
        let handle = FaultHandle::default();
        handle.update(|f| f.drop = Occurrence::next(2));
        let drops: Vec<bool> = (0..4).map(|_| handle.for_answer(1).drop).collect();
        assert_eq!(drops, vec![true, true, false, false]);
    }

    #[test]
    fn target_limits_faults_to_one_device() {
        let handle = FaultHandle::default();
        handle.update(|f| {
            f.target = Some(0x81);
            f.corrupt_crc = Occurrence::ALWAYS;
        });
        assert!(!handle.for_answer(1).corrupt_crc);
        assert!(handle.for_answer(0x81).corrupt_crc);
    }
}
