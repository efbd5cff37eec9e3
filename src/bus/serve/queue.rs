//! The line task's side of its server: the queue client requests arrive on, and the cache of
//! polled blocks that reads are answered from. A request is taken only when the line is free
//! and no MQTT command waits; after a client's slot a due poll goes first, so clients together
//! cannot starve the polls.

use std::time::{Duration, Instant};

use tokio::sync::mpsc;

use rtu2mqtt_modbus::{Request, Response};

use super::ClientRequest;

/// Client requests that may wait for the line: each connection has at most one in flight.
pub(crate) const CLIENT_QUEUE: usize = 64;

/// Requests from the line's server, if it has one.
#[derive(Debug)]
pub(crate) struct ClientQueue {
    queue: Option<mpsc::Receiver<Box<ClientRequest>>>,
    /// One request taken while the line waited, served at the next free turn.
    held: Option<Box<ClientRequest>>,
}

impl ClientQueue {
    pub(crate) fn new(queue: Option<mpsc::Receiver<Box<ClientRequest>>>) -> Self {
        ClientQueue { queue, held: None }
    }

    /// The next request, without waiting.
    pub(crate) fn try_take(&mut self) -> Option<Box<ClientRequest>> {
        if let Some(held) = self.held.take() {
            return Some(held);
        }
        let queue = self.queue.as_mut()?;
        match queue.try_recv() {
            Ok(request) => Some(request),
            Err(mpsc::error::TryRecvError::Empty) => None,
            Err(mpsc::error::TryRecvError::Disconnected) => {
                self.queue = None;
                None
            }
        }
    }

    /// True when a request is waiting to be served.
    pub(crate) fn is_waiting(&self) -> bool {
        self.held.is_some() || self.queue.as_ref().is_some_and(|queue| !queue.is_empty())
    }

    /// Waits for a request and holds it for the next turn; never ready without a server.
    pub(crate) async fn arrival(&mut self) {
        if self.held.is_some() {
            return std::future::pending().await;
        }
        let Some(queue) = self.queue.as_mut() else {
            return std::future::pending().await;
        };
        match queue.recv().await {
            Some(request) => self.held = Some(request),
            None => self.queue = None,
        }
    }
}

/// The last answer of each polled block and when it came, per device.
#[derive(Debug)]
pub(crate) struct BlockCache {
    max_age: Duration,
    /// Per device, per read block.
    answers: Vec<Vec<Option<CachedPoll>>>,
    /// Per device, per read block: the device answers a part of the block as the whole block
    /// holds it, so a part may be cut from a whole answer.
    linear: Vec<Vec<bool>>,
}

/// One whole answer a device gave a poll.
#[derive(Debug, Clone)]
struct CachedPoll {
    at: Instant,
    request: Request,
    answer: Response,
}

impl BlockCache {
    /// A cache keeping answers for `max_age` (zero: keeps nothing) of devices with the given
    /// read blocks, each block flagged when the device reads it linearly.
    pub(crate) fn new(max_age: Duration, devices: impl Iterator<Item = Vec<bool>>) -> Self {
        let linear: Vec<Vec<bool>> = devices.collect();
        BlockCache {
            max_age,
            answers: linear
                .iter()
                .map(|blocks| vec![None; blocks.len()])
                .collect(),
            linear,
        }
    }

    /// Remembers the device's whole answer to `request` (its block number `block`).
    pub(crate) fn store(
        &mut self,
        device: usize,
        block: usize,
        request: &Request,
        answer: &Response,
        at: Instant,
    ) {
        if self.max_age.is_zero() {
            return;
        }
        if let Some(slot) = self.answers.get_mut(device).and_then(|d| d.get_mut(block)) {
            *slot = Some(CachedPoll {
                at,
                request: request.clone(),
                answer: answer.clone(),
            });
        }
    }

    /// Forgets a device's answers (a write went to it, or it went offline).
    pub(crate) fn forget(&mut self, device: usize) {
        if let Some(blocks) = self.answers.get_mut(device) {
            blocks.fill(None);
        }
    }

    /// The answer to `request` from a poll younger than the cache's age: one that read exactly
    /// what it asks, or, from a block the device reads linearly, the part of a poll's answer
    /// that `request` asks for.
    pub(crate) fn lookup(
        &self,
        device: usize,
        request: &Request,
        now: Instant,
    ) -> Option<Response> {
        let answers = self.answers.get(device)?;
        let linear = self.linear.get(device);
        let young = |poll: &&CachedPoll| now.saturating_duration_since(poll.at) < self.max_age;
        let exact = answers
            .iter()
            .flatten()
            .filter(young)
            .find(|poll| poll.request == *request);
        if let Some(poll) = exact {
            return Some(poll.answer.clone());
        }
        answers
            .iter()
            .enumerate()
            .filter(|(block, _)| linear.and_then(|l| l.get(*block)).copied() == Some(true))
            .filter_map(|(_, poll)| poll.as_ref())
            .filter(young)
            .find_map(|poll| {
                let offset = poll.request.offset_of(request)?;
                let (_, quantity) = request.read_span()?;
                poll.answer.part(offset, quantity)
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_an_exact_young_poll_answers_a_read() {
        let start = Instant::now();
        let block = Request::ReadHoldingRegisters {
            start: 0x1000,
            quantity: 4,
        };
        let answer = Response::HoldingRegisters(vec![1, 2, 3, 4]);
        let mut cache = BlockCache::new(Duration::from_secs(1), [vec![false]].into_iter());
        cache.store(0, 0, &block, &answer, start);
        assert_eq!(cache.lookup(0, &block, start), Some(answer));
        let part = Request::ReadHoldingRegisters {
            start: 0x1001,
            quantity: 2,
        };
        assert_eq!(cache.lookup(0, &part, start), None);
        assert_eq!(
            cache.lookup(0, &block, start + Duration::from_secs(1)),
            None
        );
        cache.forget(0);
        assert_eq!(cache.lookup(0, &block, start), None);

        let mut off = BlockCache::new(Duration::ZERO, [vec![true]].into_iter());
        off.store(0, 0, &block, &Response::HoldingRegisters(vec![0; 4]), start);
        assert_eq!(off.lookup(0, &block, start), None);
    }

    #[test]
    fn a_part_of_a_linearly_read_block_is_cut_from_a_young_poll() {
        let start = Instant::now();
        let block = Request::ReadHoldingRegisters {
            start: 0x00,
            quantity: 11,
        };
        let answer = Response::HoldingRegisters((100..111).collect());
        // Device 0 reads its block linearly, device 1 by offset.
        let mut cache = BlockCache::new(
            Duration::from_secs(1),
            [vec![true], vec![false]].into_iter(),
        );
        cache.store(0, 0, &block, &answer, start);
        cache.store(1, 0, &block, &answer, start);
        let part = Request::ReadHoldingRegisters {
            start: 0x01,
            quantity: 7,
        };
        assert_eq!(
            cache.lookup(0, &part, start),
            Some(Response::HoldingRegisters((101..108).collect()))
        );
        assert_eq!(cache.lookup(1, &part, start), None);
        assert_eq!(cache.lookup(0, &block, start), Some(answer));
        let past_the_end = Request::ReadHoldingRegisters {
            start: 0x08,
            quantity: 4,
        };
        let other_table = Request::ReadInputRegisters {
            start: 0x01,
            quantity: 2,
        };
        for request in [&past_the_end, &other_table] {
            assert_eq!(cache.lookup(0, request, start), None, "{request:?}");
        }
        assert_eq!(cache.lookup(0, &part, start + Duration::from_secs(1)), None);
    }
}
