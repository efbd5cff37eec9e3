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

use crate::profile::{CommandPlan, Verification};
use crate::rtu::master::{Error as MasterError, Master};
use crate::rtu::{ExceptionCode, Request, Response};

use super::scheduler::{BUSY_LIMIT, BUSY_RETRY_DELAY};
use super::stats::DeviceStats;
use super::transaction::{Exchange, Failure};
use super::CommandOutcome;

/// How a slot ended.
#[derive(Debug)]
pub enum SlotEnd {
    Done(CommandOutcome),
    /// Written; the read-back shows the device still moving toward the value. The line
    /// re-reads until `deadline` (see [`reread`]).
    Settling {
        deadline: Instant,
    },
    /// The port failed inside the slot; the command failed and the port must be reopened.
    PortGone(std::io::Error),
}

/// Reads made in a slot with their answers: the line publishes the values of those that are
/// one of the device's poll blocks, instead of polling them again right away.
pub type SeenReads = Vec<(Request, Response)>;

/// Runs `plan` on the device of `exchange`. `attempts` bounds the reads and the slot repeats.
/// Every read answered in the slot is added to `seen`.
pub async fn run_slot(
    exchange: &Exchange<'_>,
    master: &mut Master,
    stats: &mut DeviceStats,
    plan: &CommandPlan,
    attempts: u32,
    seen: &mut SeenReads,
) -> SlotEnd {
    if exchange.slave == 0 {
        return broadcast(master, plan).await;
    }
    let mut last_problem = String::from("not sent");
    let mut written = false;
    for _ in 0..attempts.max(1) {
        let before =
            match read_all(exchange, master, stats, plan.reads_before(), attempts, seen).await {
                Ok(answers) => answers,
                Err(failure) => return failed(failure),
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
            Ok(()) => {
                written = true;
                break;
            }
            Err(Failure::NoAnswer(problem)) => last_problem = problem,
            Err(failure) => return failed(failure),
        }
    }
    if !written {
        return SlotEnd::Done(CommandOutcome::Failed {
            detail: format!("no answer to the write: {last_problem}"),
        });
    }
    match reread(exchange, master, stats, plan, attempts, seen).await {
        Ok(Verification::Applied) => SlotEnd::Done(CommandOutcome::Applied {
            detail: "read-back confirms the value".into(),
        }),
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
        Err(failure) => failed(failure),
    }
}

/// Reads the plan's read-back and judges it.
pub async fn reread(
    exchange: &Exchange<'_>,
    master: &mut Master,
    stats: &mut DeviceStats,
    plan: &CommandPlan,
    attempts: u32,
    seen: &mut SeenReads,
) -> Result<Verification, Failure> {
    let answers = read_all(exchange, master, stats, plan.readback(), attempts, seen).await?;
    Ok(plan.verify(&answers))
}

/// The outcome of a failure inside a slot.
pub fn failed(failure: Failure) -> SlotEnd {
    match failure {
        Failure::PortGone(error) => SlotEnd::PortGone(error),
        Failure::Exception(code) => SlotEnd::Done(CommandOutcome::Failed {
            detail: format!("device answered {code}"),
        }),
        Failure::NoAnswer(problem) => SlotEnd::Done(CommandOutcome::Failed {
            detail: format!("no answer after the retries: {problem}"),
        }),
    }
}

async fn broadcast(master: &mut Master, plan: &CommandPlan) -> SlotEnd {
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
            Err(MasterError::Io(error)) => return SlotEnd::PortGone(error),
            Err(error) => {
                return SlotEnd::Done(CommandOutcome::Failed {
                    detail: format!("broadcast failed: {error}"),
                })
            }
        }
    }
    SlotEnd::Done(CommandOutcome::Applied {
        detail: "broadcast sent (devices do not answer a broadcast: no read-back)".into(),
    })
}

async fn read_all(
    exchange: &Exchange<'_>,
    master: &mut Master,
    stats: &mut DeviceStats,
    requests: &[Request],
    attempts: u32,
    seen: &mut SeenReads,
) -> Result<Vec<Response>, Failure> {
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
    exchange: &Exchange<'_>,
    master: &mut Master,
    stats: &mut DeviceStats,
    writes: &[Request],
) -> Result<(), Failure> {
    for write in writes {
        // One attempt each: a repeat is decided by the caller after fresh reads.
        patiently(exchange, master, stats, write, 1).await?;
    }
    Ok(())
}

/// An exchange that waits out exception 06 (busy) a bounded number of times.
async fn patiently(
    exchange: &Exchange<'_>,
    master: &mut Master,
    stats: &mut DeviceStats,
    request: &Request,
    attempts: u32,
) -> Result<Response, Failure> {
    let mut busy = 0;
    loop {
        match exchange.run(master, stats, request, attempts).await {
            Err(Failure::Exception(ExceptionCode::ServerDeviceBusy)) if busy < BUSY_LIMIT => {
                busy += 1;
                exchange.turnaround.idle();
                tokio::time::sleep(BUSY_RETRY_DELAY).await;
            }
            other => return other,
        }
    }
}
