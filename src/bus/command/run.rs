//! A command's bus slot: reads_before → writes computed from their fresh answers → the writes
//! → read-back → verification, with no other transaction in between (read-modify-write and
//! write verification depend on that). Broadcast commands (address 0) send their writes
//! without waiting for answers. The slot only runs frames; what to write is the profile's
//! [`CommandPlan`].
//!
//! Retrying a write is not as harmless as retrying a read: a write whose answer was lost may
//! have been applied, and writing a toggle (the air shower's e-stop) twice undoes it. So a
//! failed write is retried by running the whole slot again: the fresh reads show what the
//! device now holds and the plan recomputes the writes (none, when the state is already the
//! commanded one).

use std::time::Instant;

use rtu2mqtt_modbus::link::Link;
use rtu2mqtt_modbus::{Error as MasterError, PortFault};
use rtu2mqtt_modbus::{ExceptionCode, Request, Response};
use rtu2mqtt_profile::{CommandPlan, Verification};

use super::outcome::{CommandFailure, CommandOutcome};
use crate::bus::scheduler::{BUSY_LIMIT, BUSY_RETRY_DELAY};
use crate::bus::stats::DeviceStats;
use crate::bus::transaction::{ExchangeContext, Failure};

/// How a slot ended.
#[derive(Debug)]
pub(crate) enum SlotEnd {
    Done(CommandOutcome),
    /// Written; the read-back shows the device still moving toward the value. The line
    /// re-reads until `deadline` (see [`reread`]).
    Settling {
        deadline: Instant,
    },
    /// The port failed inside the slot; the command failed and the port must be reopened.
    PortGone(PortFault),
}

/// Why a slot stopped before its verification: the device refused (an exception answer, the
/// device's word) or was not heard.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Stop {
    Refused(ExceptionCode),
    Failed(Failure),
}

impl From<Failure> for Stop {
    fn from(failure: Failure) -> Self {
        Stop::Failed(failure)
    }
}

impl Stop {
    /// What the slot ends with: a port that is gone must also be reopened.
    pub(crate) fn end(self) -> SlotEnd {
        match self {
            Stop::Failed(Failure::PortGone(fault)) => SlotEnd::PortGone(fault),
            stop => failed_with(stop.cause()),
        }
    }

    /// The command's failure cause.
    pub(crate) fn cause(self) -> CommandFailure {
        match self {
            Stop::Refused(code) => CommandFailure::Exception(code),
            Stop::Failed(failure) => failure.into(),
        }
    }
}

fn failed_with(cause: CommandFailure) -> SlotEnd {
    SlotEnd::Done(CommandOutcome::Failed { cause })
}

/// Reads made in a slot with their answers: the line publishes the values of those that are
/// one of the device's poll blocks, instead of polling them again right away.
pub(crate) type SeenReads = Vec<(Request, Response)>;

/// What a slot needs of its line: the exchange context of the device, the link, the device's
/// counters and how many attempts a read may take.
pub(crate) struct SlotLink<'a> {
    pub(crate) exchange: ExchangeContext<'a>,
    pub(crate) master: &'a mut Link,
    pub(crate) stats: &'a mut DeviceStats,
    pub(crate) attempts: u32,
}

/// Runs `plan` on the device of `link`. Its attempts bound the reads and the slot repeats.
/// Every read answered in the slot is added to `seen`.
pub(crate) async fn run_slot(
    link: &mut SlotLink<'_>,
    plan: &CommandPlan,
    seen: &mut SeenReads,
) -> SlotEnd {
    let SlotLink {
        exchange,
        master,
        stats,
        attempts,
    } = link;
    if exchange.slave == 0 {
        return broadcast(master, plan).await;
    }
    let attempts = (*attempts).max(1);
    for attempt in 1..=attempts {
        let before =
            match read_all(exchange, master, stats, plan.reads_before(), attempts, seen).await {
                Ok(answers) => answers,
                Err(stop) => return stop.end(),
            };
        let writes = match plan.writes(&before) {
            Ok(writes) => writes,
            Err(rejection) => {
                return SlotEnd::Done(CommandOutcome::Rejected {
                    detail: rejection.0,
                })
            }
        };
        match write_all(exchange, master, stats, &writes).await {
            Ok(()) => break,
            Err(Stop::Failed(Failure::NoAnswer(problem))) => {
                if attempt == attempts {
                    return failed_with(CommandFailure::WriteUnanswered(problem));
                }
            }
            Err(stop) => return stop.end(),
        }
    }
    match read_back(exchange, master, stats, plan, attempts, seen).await {
        Ok(Verification::Applied) => SlotEnd::Done(CommandOutcome::Applied {
            detail: "read-back confirms the value".into(),
        }),
        Ok(Verification::Reported(detail)) => SlotEnd::Done(CommandOutcome::Applied { detail }),
        Ok(Verification::NotApplied(detail)) => {
            SlotEnd::Done(CommandOutcome::NotApplied { detail })
        }
        Ok(Verification::Settling) => match plan.settle_window() {
            Some(window) => SlotEnd::Settling {
                deadline: Instant::now() + window,
            },
            None => SlotEnd::Done(CommandOutcome::NotApplied {
                detail: "the read-back still shows the device moving".into(),
            }),
        },
        Err(stop) => stop.end(),
    }
}

/// Reads the plan's read-back on the device of `link` and judges it.
pub(crate) async fn reread(
    link: &mut SlotLink<'_>,
    plan: &CommandPlan,
    seen: &mut SeenReads,
) -> Result<Verification, Stop> {
    read_back(
        &link.exchange,
        link.master,
        link.stats,
        plan,
        link.attempts,
        seen,
    )
    .await
}

/// Reads the plan's read-back and judges it.
async fn read_back(
    exchange: &ExchangeContext<'_>,
    master: &mut Link,
    stats: &mut DeviceStats,
    plan: &CommandPlan,
    attempts: u32,
    seen: &mut SeenReads,
) -> Result<Verification, Stop> {
    let answers = read_all(exchange, master, stats, plan.readback(), attempts, seen).await?;
    Ok(plan.verify(&answers))
}

async fn broadcast(master: &mut Link, plan: &CommandPlan) -> SlotEnd {
    let writes = match plan.writes(&[]) {
        Ok(writes) => writes,
        Err(rejection) => {
            return SlotEnd::Done(CommandOutcome::Rejected {
                detail: rejection.0,
            })
        }
    };
    for write in &writes {
        match master.broadcast(write).await {
            Ok(()) => {}
            Err(MasterError::PortGone(fault)) => return SlotEnd::PortGone(fault),
            Err(error) => return failed_with(CommandFailure::BroadcastFailed(error)),
        }
    }
    SlotEnd::Done(CommandOutcome::Applied {
        detail: "broadcast sent (devices do not answer a broadcast: no read-back)".into(),
    })
}

async fn read_all(
    exchange: &ExchangeContext<'_>,
    master: &mut Link,
    stats: &mut DeviceStats,
    requests: &[Request],
    attempts: u32,
    seen: &mut SeenReads,
) -> Result<Vec<Response>, Stop> {
    let mut answers = Vec::with_capacity(requests.len());
    for request in requests {
        let answer = patiently(exchange, master, stats, request, attempts).await?;
        seen.retain(|(earlier, _)| earlier != request);
        seen.push((request.clone(), answer.clone()));
        answers.push(answer);
    }
    Ok(answers)
}

async fn write_all(
    exchange: &ExchangeContext<'_>,
    master: &mut Link,
    stats: &mut DeviceStats,
    writes: &[Request],
) -> Result<(), Stop> {
    for write in writes {
        // One attempt each: a repeat is decided by the caller after fresh reads.
        patiently(exchange, master, stats, write, 1).await?;
    }
    Ok(())
}

/// An exchange that waits out exception 06 (busy) a bounded number of times; any other
/// exception stops the slot.
async fn patiently(
    exchange: &ExchangeContext<'_>,
    master: &mut Link,
    stats: &mut DeviceStats,
    request: &Request,
    attempts: u32,
) -> Result<Response, Stop> {
    let mut busy = 0;
    loop {
        match exchange.run(master, stats, request, attempts).await? {
            Ok(response) => return Ok(response),
            Err(ExceptionCode::ServerDeviceBusy) if busy < BUSY_LIMIT => {
                busy += 1;
                exchange.turnaround.idle();
                tokio::time::sleep(BUSY_RETRY_DELAY).await;
            }
            Err(code) => return Err(Stop::Refused(code)),
        }
    }
}
