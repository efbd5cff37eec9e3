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
    queue: Option<mpsc::Receiver<ClientRequest>>,
    /// One request taken while the line waited, served at the next free turn.
    held: Option<ClientRequest>,
}

impl ClientQueue {
    pub(crate) fn new(queue: Option<mpsc::Receiver<ClientRequest>>) -> Self {
        ClientQueue { queue, held: None }
    }

    /// The next request, without waiting.
    pub(crate) fn try_take(&mut self) -> Option<ClientRequest> {
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
    answers: Vec<Vec<Option<(Instant, Request, Response)>>>,
}

impl BlockCache {
    /// A cache keeping answers for `max_age` (zero: keeps nothing) of devices with `blocks`
    /// read blocks each.
    pub(crate) fn new(max_age: Duration, blocks: impl Iterator<Item = usize>) -> Self {
        BlockCache {
            max_age,
            answers: blocks.map(|count| vec![None; count]).collect(),
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
            *slot = Some((at, request.clone(), answer.clone()));
        }
    }

    /// Forgets a device's answers (a write went to it, or it went offline).
    pub(crate) fn forget(&mut self, device: usize) {
        if let Some(blocks) = self.answers.get_mut(device) {
            blocks.fill(None);
        }
    }

    /// The answer to `request` from a poll younger than the cache's age that read exactly
    /// what it asks.
    pub(crate) fn lookup(
        &self,
        device: usize,
        request: &Request,
        now: Instant,
    ) -> Option<Response> {
        self.answers
            .get(device)?
            .iter()
            .flatten()
            .find(|(at, polled, _)| {
                polled == request && now.saturating_duration_since(*at) < self.max_age
            })
            .map(|(_, _, answer)| answer.clone())
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
        let mut cache = BlockCache::new(Duration::from_secs(1), [1].into_iter());
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

        let mut off = BlockCache::new(Duration::ZERO, [1].into_iter());
        off.store(0, 0, &block, &Response::HoldingRegisters(vec![0; 4]), start);
        assert_eq!(off.lookup(0, &block, start), None);
    }
}
