//! When each device on a line begins its answers, learned from how its answers came
//! ([`Arrival`]): the serial master plans an answer's first read by it, so that a device that
//! answers as it did before costs one wake-up for all but the last byte of its answer instead
//! of one for its first byte and one for its head.
//!
//! The estimate follows a quicker answer at once and a slower one an eighth of the way, so
//! that it stays near the device's quickest: a read planned too late finds the answer already
//! complete and starts t3.5 late, a read planned too early only waits on for the rest. A
//! device whose answers come in batches (an adapter's latency timer) twice in a row is not
//! planned for until an answer comes paced again: a planned read would only add a wake-up.

use std::collections::HashMap;
use std::time::Duration;

use crate::frame::SlaveId;
use crate::serial::reception::Arrival;

/// Batched answers in a row after which a device's answers are no longer planned for.
const BATCHED_LIMIT: u8 = 2;

/// What is known of one device's answers.
#[derive(Debug, Clone, Copy)]
struct Onset {
    /// How soon after the request's drain its answers' first byte has come, at the quickest.
    first_byte_after: Duration,
    /// Answers in a row whose last byte came with others.
    batched_in_a_row: u8,
}

/// The answer onsets of a line's devices.
#[derive(Debug, Default)]
pub(crate) struct AnswerOnsets {
    devices: HashMap<SlaveId, Onset>,
}

impl AnswerOnsets {
    /// How soon after the request's drain the answer of `slave` is expected to begin, when it
    /// is known well enough to plan by.
    pub(crate) fn expected(&self, slave: SlaveId) -> Option<Duration> {
        self.devices
            .get(&slave)
            .filter(|onset| onset.batched_in_a_row < BATCHED_LIMIT)
            .map(|onset| onset.first_byte_after)
    }

    /// The answer of `slave` came as `arrival` says.
    pub(crate) fn learn(&mut self, slave: SlaveId, arrival: Arrival) {
        let bound = arrival.first_byte_after;
        let onset = self.devices.entry(slave).or_insert(Onset {
            first_byte_after: bound,
            batched_in_a_row: 0,
        });
        if arrival.paced {
            onset.batched_in_a_row = 0;
            onset.first_byte_after = if bound < onset.first_byte_after {
                bound
            } else {
                onset.first_byte_after + (bound - onset.first_byte_after) / 8
            };
        } else {
            // A batch's last byte was seen late by the batching: its bound says the answer
            // began no later, never that it began later.
            onset.batched_in_a_row = onset.batched_in_a_row.saturating_add(1);
            onset.first_byte_after = onset.first_byte_after.min(bound);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn us(n: u64) -> Duration {
        Duration::from_micros(n)
    }

    fn paced(first_byte_after: Duration) -> Arrival {
        Arrival {
            first_byte_after,
            paced: true,
        }
    }

    fn batched(first_byte_after: Duration) -> Arrival {
        Arrival {
            first_byte_after,
            paced: false,
        }
    }

    #[test]
    fn a_device_is_planned_for_once_it_has_answered() {
        let mut onsets = AnswerOnsets::default();
        assert_eq!(onsets.expected(1), None);
        onsets.learn(1, paced(us(3_000)));
        assert_eq!(onsets.expected(1), Some(us(3_000)));
        assert_eq!(onsets.expected(2), None);
    }

    #[test]
    fn a_quicker_answer_is_followed_at_once_and_a_slower_one_an_eighth_of_the_way() {
        let mut onsets = AnswerOnsets::default();
        onsets.learn(1, paced(us(3_000)));
        onsets.learn(1, paced(us(2_800)));
        assert_eq!(onsets.expected(1), Some(us(2_800)));
        onsets.learn(1, paced(us(3_600)));
        assert_eq!(onsets.expected(1), Some(us(2_900)));
        // A batch only ever lowers the estimate.
        onsets.learn(1, batched(us(9_000)));
        assert_eq!(onsets.expected(1), Some(us(2_900)));
        onsets.learn(1, batched(us(2_500)));
        assert_eq!(onsets.expected(1), None);
    }

    #[test]
    fn answers_in_batches_twice_in_a_row_are_not_planned_for_until_one_comes_paced() {
        let mut onsets = AnswerOnsets::default();
        onsets.learn(7, paced(us(3_000)));
        onsets.learn(7, batched(us(3_100)));
        assert_eq!(onsets.expected(7), Some(us(3_000)));
        onsets.learn(7, paced(us(3_000)));
        onsets.learn(7, batched(us(3_100)));
        onsets.learn(7, batched(us(3_100)));
        assert_eq!(onsets.expected(7), None);
        onsets.learn(7, paced(us(3_200)));
        assert_eq!(onsets.expected(7), Some(us(3_025)));
    }
}
