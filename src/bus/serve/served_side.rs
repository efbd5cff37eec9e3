//! What a served line's task keeps of its clients, in one place: their requests waiting and
//! whose turn it is (after commands, before polls, a due poll between two client slots), the
//! cache of polled blocks their reads are answered from, the server's counters, and their
//! writes still settling on a device. Also the rules of their answers, without I/O: what a
//! write's outcome answers, and which polled blocks a raw write changed.

use std::collections::HashMap;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;

use tokio::sync::mpsc;

use super::queue::{BlockCache, ClientQueue};
use super::server::ServeCounters;
use super::ClientRequest;
use crate::bus::command::{CommandFailure, CommandOutcome};
use crate::bus::stats::LineStats;
use rtu2mqtt_modbus::Reply;
use rtu2mqtt_modbus::{ExceptionCode, Request, Response};

/// Command ids of clients' writes start here, far above the bridge's: a finished command
/// tells by its id whose it was.
pub(crate) const FIRST_CLIENT_COMMAND_ID: u64 = 1 << 63;

/// A client's write as its outcome is published.
#[derive(Debug)]
pub(crate) struct ClientWrite {
    pub(crate) device: String,
    pub(crate) field: String,
    pub(crate) value: String,
    pub(crate) client: String,
}

/// What the server counts that a line's task adds to.
#[derive(Debug, Clone, Copy)]
pub(crate) enum ClientCount {
    /// A read answered from the cache.
    CacheHit,
    /// A write the profile refused.
    Refusal,
    /// A write refused while a write interval runs (06).
    Busy,
}

/// The served side of one line task (see the module's documentation); a line that is not
/// served has one with no requests and no counters.
#[derive(Debug)]
pub(crate) struct ServedSide {
    requests: ClientQueue,
    /// The last slot was a client's: a due poll goes before the next one.
    went_last: bool,
    /// Polled blocks that clients' reads are answered from.
    pub(crate) cache: BlockCache,
    counters: Option<Arc<ServeCounters>>,
    next_command: u64,
    /// Clients' writes still settling on their device, by command id: their end is published
    /// when the read-back settles.
    settling: HashMap<u64, ClientWrite>,
}

impl ServedSide {
    pub(crate) fn new(cache: BlockCache) -> Self {
        ServedSide {
            requests: ClientQueue::new(None),
            went_last: false,
            cache,
            counters: None,
            next_command: FIRST_CLIENT_COMMAND_ID,
            settling: HashMap::new(),
        }
    }

    /// Takes the server's requests and counters (a served line).
    pub(crate) fn serve(
        &mut self,
        requests: Option<mpsc::Receiver<Box<ClientRequest>>>,
        counters: Option<Arc<ServeCounters>>,
    ) {
        self.requests = ClientQueue::new(requests);
        self.counters = counters;
    }

    /// The next client's request when it is the clients' turn: no command queued, and the
    /// last slot not a client's (so a due poll goes between two client slots).
    pub(crate) fn take_turn(&mut self, commands_queued: bool) -> Option<Box<ClientRequest>> {
        if !commands_queued && !self.went_last {
            if let Some(request) = self.requests.try_take() {
                self.went_last = true;
                return Some(request);
            }
        }
        self.went_last = false;
        None
    }

    /// A client's request waits.
    pub(crate) fn is_waiting(&self) -> bool {
        self.requests.is_waiting()
    }

    /// Resolves when a client's request arrives (never on a line that is not served).
    pub(crate) async fn arrival(&mut self) {
        self.requests.arrival().await;
    }

    /// The port is closed: waiting clients are told the device cannot be reached rather than
    /// left to time out.
    pub(crate) fn fail_waiting(&mut self) {
        while let Some(request) = self.requests.try_take() {
            let _ = request
                .reply
                .send(Err(ExceptionCode::GatewayTargetFailedToRespond));
        }
    }

    pub(crate) fn count(&self, what: ClientCount) {
        if let Some(counters) = &self.counters {
            let counter = match what {
                ClientCount::CacheHit => &counters.cache_hits,
                ClientCount::Refusal => &counters.refusals,
                ClientCount::Busy => &counters.busy,
            };
            counter.fetch_add(1, Relaxed);
        }
    }

    /// The id of a client's next write command.
    pub(crate) fn next_command_id(&mut self) -> u64 {
        let id = self.next_command;
        self.next_command += 1;
        id
    }

    /// Keeps a client's write whose device is still settling until its end.
    pub(crate) fn settling(&mut self, id: u64, write: ClientWrite) {
        self.settling.insert(id, write);
    }

    /// The client's write of command `id`, now settled.
    pub(crate) fn settled(&mut self, id: u64) -> Option<ClientWrite> {
        self.settling.remove(&id)
    }

    /// Copies the server's counters into the line's statistics.
    pub(crate) fn fill_stats(&self, stats: &mut LineStats) {
        if let Some(counters) = &self.counters {
            stats.client_requests = counters.requests.load(Relaxed);
            stats.cache_hits = counters.cache_hits.load(Relaxed);
            stats.client_refusals = counters.refusals.load(Relaxed);
            stats.client_busy = counters.busy.load(Relaxed);
            stats.client_evicted = counters.evicted.load(Relaxed);
        }
    }
}

/// What the client of a write is answered for its command's outcome.
pub(crate) fn client_answer(outcome: &CommandOutcome, write: &Request) -> Reply {
    match outcome {
        CommandOutcome::Applied { .. } | CommandOutcome::NotApplied { .. } => {
            echo(write).ok_or(ExceptionCode::IllegalFunction)
        }
        CommandOutcome::Rejected { .. } => Err(ExceptionCode::IllegalDataValue),
        CommandOutcome::Failed {
            cause: CommandFailure::Exception(code),
        } => Err(*code),
        CommandOutcome::Failed { .. } => Err(ExceptionCode::GatewayTargetFailedToRespond),
    }
}

/// Where a write lands: (holding registers rather than coils, first address, count).
pub(crate) fn written_span(write: &Request) -> Option<(bool, u16, u16)> {
    let count = |len: usize| u16::try_from(len).ok();
    match write {
        Request::WriteSingleCoil { address, .. } => Some((false, *address, 1)),
        Request::WriteSingleRegister { address, .. } => Some((true, *address, 1)),
        Request::WriteMultipleCoils { start, values } => {
            Some((false, *start, count(values.len())?))
        }
        Request::WriteMultipleRegisters { start, values } => {
            Some((true, *start, count(values.len())?))
        }
        _ => None,
    }
}

/// Whether the read `block` reads any item of `(registers, start, count)`.
pub(crate) fn block_overlaps(block: &Request, (registers, start, count): (bool, u16, u16)) -> bool {
    let same_table = match block {
        Request::ReadHoldingRegisters { .. } => registers,
        Request::ReadCoils { .. } => !registers,
        _ => false,
    };
    let Some((first, len)) = block.read_span() else {
        return false;
    };
    let (first, end) = (u32::from(first), u32::from(first) + u32::from(len));
    let (start, stop) = (u32::from(start), u32::from(start) + u32::from(count));
    same_table && start < end && first < stop
}

/// The normal answer to a write: the device echoes what it was asked.
pub(crate) fn echo(write: &Request) -> Option<Response> {
    Some(match write {
        Request::WriteSingleRegister { address, value } => Response::WriteSingleRegister {
            address: *address,
            value: *value,
        },
        Request::WriteSingleCoil { address, value } => Response::WriteSingleCoil {
            address: *address,
            value: *value,
        },
        Request::WriteMultipleRegisters { start, values } => Response::WriteMultipleRegisters {
            start: *start,
            quantity: u16::try_from(values.len()).ok()?,
        },
        Request::WriteMultipleCoils { start, values } => Response::WriteMultipleCoils {
            start: *start,
            quantity: u16::try_from(values.len()).ok()?,
        },
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use tokio::sync::oneshot;

    use super::*;

    fn request(tx: &mpsc::Sender<Box<ClientRequest>>, address: u16) -> oneshot::Receiver<Reply> {
        let (reply, answer) = oneshot::channel();
        let sent = tx.try_send(Box::new(ClientRequest {
            client: "test".to_string(),
            unit: 1,
            request: Request::ReadHoldingRegisters {
                start: address,
                quantity: 1,
            },
            probe: false,
            reply,
        }));
        assert!(sent.is_ok());
        answer
    }

    fn served() -> (ServedSide, mpsc::Sender<Box<ClientRequest>>) {
        let (tx, rx) = mpsc::channel(8);
        let mut side = ServedSide::new(BlockCache::new(Duration::ZERO, std::iter::empty()));
        side.serve(Some(rx), Some(Arc::new(ServeCounters::default())));
        (side, tx)
    }

    #[test]
    fn clients_wait_behind_commands_and_take_turns_with_polls() {
        let (mut side, tx) = served();
        let _first = request(&tx, 1);
        let _second = request(&tx, 2);
        assert!(
            side.take_turn(true).is_none(),
            "a queued command goes first"
        );
        let first = side.take_turn(false).expect("the clients' turn");
        assert_eq!(
            first.request,
            Request::ReadHoldingRegisters {
                start: 1,
                quantity: 1
            }
        );
        assert!(
            side.take_turn(false).is_none(),
            "a poll between two client slots"
        );
        let second = side.take_turn(false).expect("then the next client");
        assert_eq!(
            second.request,
            Request::ReadHoldingRegisters {
                start: 2,
                quantity: 1
            }
        );
        assert!(!side.is_waiting());
    }

    #[test]
    fn waiting_clients_are_told_the_device_cannot_be_reached_when_the_port_closes() {
        let (mut side, tx) = served();
        let mut answer = request(&tx, 1);
        side.fail_waiting();
        assert_eq!(
            answer.try_recv().ok(),
            Some(Err(ExceptionCode::GatewayTargetFailedToRespond))
        );
    }

    #[test]
    fn client_commands_are_told_apart_from_the_bridges_and_settle_by_id() {
        let (mut side, _tx) = served();
        let id = side.next_command_id();
        assert!(id >= FIRST_CLIENT_COMMAND_ID);
        assert_eq!(side.next_command_id(), id + 1);
        let write = ClientWrite {
            device: "valve".to_string(),
            field: "mode".to_string(),
            value: "1".to_string(),
            client: "test".to_string(),
        };
        side.settling(id, write);
        assert_eq!(side.settled(id).map(|w| w.field), Some("mode".to_string()));
        assert!(side.settled(id).is_none());
    }

    #[test]
    fn a_write_is_answered_as_its_outcome_says() {
        let write = Request::WriteSingleRegister {
            address: 7,
            value: 3,
        };
        let echoed: Reply = Ok(Response::WriteSingleRegister {
            address: 7,
            value: 3,
        });
        let failed = CommandOutcome::Failed {
            cause: CommandFailure::Exception(ExceptionCode::IllegalDataAddress),
        };
        assert_eq!(
            client_answer(&failed, &write),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(echo(&write).map(Ok), Some(echoed));
        assert_eq!(written_span(&write), Some((true, 7, 1)));
        let block = Request::ReadHoldingRegisters {
            start: 0,
            quantity: 8,
        };
        assert!(block_overlaps(&block, (true, 7, 1)));
        assert!(!block_overlaps(&block, (true, 8, 1)));
        assert!(!block_overlaps(&block, (false, 7, 1)));
    }
}
