//! Commands on the line between their arrival and their end: [`CommandSlots`] owns the queue
//! they arrive on and the list of commands whose device is still settling. It runs a command's
//! slot when the scheduler gives it its turn, and re-reads a device that is still settling
//! (outside the slot: the writes are done by then, so nothing can interleave with them any
//! more, and a 60 s settle window must not take the line from the other devices). A command
//! whose field's write interval is still running when its turn comes (a client of the served
//! line wrote the field meanwhile) is held here until the interval ends. What a run
//! leaves for the line to do (note the contact, publish the reads, report the end, close a
//! failed port) comes back as a [`SlotReport`]; the line owns the events channel, the
//! scheduler and the port. The frames of a slot are [`super::run`]'s.

use std::time::{Duration, Instant};

use tokio::sync::mpsc;
use tracing::Instrument;

use super::outcome::{Command, CommandFailure, CommandOutcome};
use super::queue::CommandReceiver;
use super::run::{self, SeenReads, SlotEnd, SlotLink, Stop};
use crate::bus::transaction::Failure;
use rtu2mqtt_modbus::PortFault;
use rtu2mqtt_profile::{CommandPlan, Verification};

/// Pause between two read-backs of a command whose device is still moving.
pub(crate) const SETTLE_REREAD: Duration = Duration::from_millis(500);

/// A command waiting for its slot.
#[derive(Debug)]
pub(crate) struct Pending {
    pub(crate) command: Command,
    pub(crate) arrived: Instant,
}

impl Pending {
    /// This command's end without a slot: it failed for `cause`.
    pub(crate) fn failed(&self, cause: CommandFailure) -> Finished {
        Finished {
            id: self.command.id,
            arrived: self.arrived,
            outcome: CommandOutcome::Failed { cause },
        }
    }
}

/// A command whose writes are done and whose device is still moving toward the value.
#[derive(Debug)]
pub(crate) struct Settle {
    device: usize,
    plan: CommandPlan,
    id: u64,
    arrived: Instant,
    deadline: Instant,
    next_read: Instant,
}

/// A command's end, for the line to count and report.
#[derive(Debug)]
pub(crate) struct Finished {
    pub(crate) id: u64,
    pub(crate) arrived: Instant,
    pub(crate) outcome: CommandOutcome,
}

/// What a slot or a settle re-read of `device` leaves for the line to do, in this order:
/// note that the device answered, publish the reads (and have the blocks the command can have
/// changed read again unless the reads covered them), report the end, close the failed port.
#[derive(Debug)]
pub(crate) struct SlotReport {
    pub(crate) device: usize,
    pub(crate) contact: bool,
    pub(crate) reads: Option<SeenReads>,
    /// The device's read blocks the command can have changed.
    pub(crate) changed: Vec<usize>,
    pub(crate) finished: Option<Finished>,
    pub(crate) port_gone: Option<PortFault>,
    /// A write may have reached the device (every end but a refusal before the writes).
    pub(crate) wrote: bool,
}

/// The line's command queue and its settling commands.
#[derive(Debug)]
pub(crate) struct CommandSlots {
    queue: CommandReceiver,
    /// The sending side (the bridge) is still there.
    open: bool,
    settling: Vec<Settle>,
    /// Commands held until their field's write interval ends: (device, command, end).
    held: Vec<(usize, Pending, Instant)>,
}

impl CommandSlots {
    pub(crate) fn new(queue: CommandReceiver) -> Self {
        CommandSlots {
            queue,
            open: true,
            settling: Vec::new(),
            held: Vec::new(),
        }
    }

    /// Whether commands may still arrive (the queue's sender is there).
    pub(crate) fn is_open(&self) -> bool {
        self.open
    }

    /// The next command already in the queue, without waiting.
    pub(crate) fn try_take(&mut self) -> Option<Command> {
        if !self.open {
            return None;
        }
        match self.queue.try_recv() {
            Ok(command) => Some(command),
            Err(mpsc::error::TryRecvError::Empty) => None,
            Err(mpsc::error::TryRecvError::Disconnected) => {
                self.open = false;
                None
            }
        }
    }

    /// Waits for the next command; `None` when the queue has ended (then [`Self::closed`]).
    pub(crate) async fn next(&mut self) -> Option<Command> {
        self.queue.recv().await
    }

    /// The queue has ended: the bridge is gone and the line stops listening to it.
    pub(crate) fn closed(&mut self) {
        self.open = false;
    }

    /// A settling command whose re-read is due at `now`.
    pub(crate) fn take_due_settle(&mut self, now: Instant) -> Option<Settle> {
        let index = self.settling.iter().position(|s| s.next_read <= now)?;
        Some(self.settling.swap_remove(index))
    }

    /// When the next settle re-read or held command is due.
    pub(crate) fn next_due(&self) -> Option<Instant> {
        let settles = self.settling.iter().map(|s| s.next_read);
        settles.chain(self.held.iter().map(|h| h.2)).min()
    }

    /// Holds `pending` for `device` until `until` (its field's write interval ends then).
    pub(crate) fn hold(&mut self, device: usize, pending: Pending, until: Instant) {
        self.held.push((device, pending, until));
    }

    /// A held command whose write interval has ended at `now`, the longest held first.
    pub(crate) fn take_due_held(&mut self, now: Instant) -> Option<(usize, Pending)> {
        let index = self
            .held
            .iter()
            .enumerate()
            .filter(|(_, held)| held.2 <= now)
            .min_by_key(|(_, held)| held.1.arrived)
            .map(|(index, _)| index)?;
        let (device, pending, _) = self.held.remove(index);
        Some((device, pending))
    }

    /// Every held command, removed (the line stops).
    pub(crate) fn drain_held(&mut self) -> Vec<(usize, Pending)> {
        std::mem::take(&mut self.held)
            .into_iter()
            .map(|(device, pending, _)| (device, pending))
            .collect()
    }

    /// Runs `pending`'s slot on `device`.
    pub(crate) async fn run(
        &mut self,
        mut link: SlotLink<'_>,
        device: usize,
        pending: Pending,
    ) -> SlotReport {
        let Pending { command, arrived } = pending;
        let span = tracing::info_span!("command", device = %link.exchange.device, field = command.plan.field());
        let mut seen = SeenReads::new();
        let end = run::run_slot(&mut link, &command.plan, &mut seen)
            .instrument(span)
            .await;
        let now = Instant::now();
        let mut report = SlotReport {
            device,
            contact: false,
            reads: None,
            changed: command.plan.readback_blocks().collect(),
            finished: None,
            port_gone: None,
            wrote: !matches!(end, SlotEnd::Done(CommandOutcome::Rejected { .. })),
        };
        match end {
            SlotEnd::Done(outcome) => {
                tracing::debug!(device = %link.exchange.device, field = command.plan.field(), %outcome, "command done on the line");
                report.contact = matches!(
                    outcome,
                    CommandOutcome::Applied { .. } | CommandOutcome::NotApplied { .. }
                );
                report.reads = Some(seen);
                report.finished = Some(Finished {
                    id: command.id,
                    arrived,
                    outcome,
                });
            }
            SlotEnd::Settling { deadline } => {
                self.settling.push(Settle {
                    device,
                    plan: command.plan,
                    id: command.id,
                    arrived,
                    deadline,
                    next_read: now + SETTLE_REREAD,
                });
                report.contact = true;
                report.reads = Some(seen);
            }
            SlotEnd::PortGone(error) => {
                report.finished = Some(Finished {
                    id: command.id,
                    arrived,
                    outcome: CommandOutcome::Failed {
                        cause: CommandFailure::PortFailed(error.clone()),
                    },
                });
                report.port_gone = Some(error);
            }
        }
        report
    }

    /// Re-reads a settling command's device: its end, or back to the list while the device
    /// is still moving and the settle window lasts.
    pub(crate) async fn reread(
        &mut self,
        mut link: SlotLink<'_>,
        mut settle: Settle,
    ) -> SlotReport {
        let mut seen = SeenReads::new();
        let result = run::reread(&mut link, &settle.plan, &mut seen).await;
        let now = Instant::now();
        let mut report = SlotReport {
            device: settle.device,
            contact: false,
            reads: None,
            changed: settle.plan.readback_blocks().collect(),
            finished: None,
            port_gone: None,
            wrote: false,
        };
        let outcome = match result {
            Ok(Verification::Applied) => CommandOutcome::Applied {
                detail: "read-back confirms the value after settling".into(),
            },
            Ok(Verification::Reported(detail)) => CommandOutcome::Applied { detail },
            Ok(Verification::NotApplied(detail)) => CommandOutcome::NotApplied { detail },
            Ok(Verification::Settling) if now < settle.deadline => {
                settle.next_read = now + SETTLE_REREAD;
                self.settling.push(settle);
                return report;
            }
            Ok(Verification::Settling) => CommandOutcome::NotApplied {
                detail: "the device was still moving when the settle window ended".into(),
            },
            Err(Stop::Failed(Failure::PortGone(error))) => {
                report.finished = Some(settle.finish(CommandOutcome::Failed {
                    cause: CommandFailure::PortFailed(error.clone()),
                }));
                report.port_gone = Some(error);
                return report;
            }
            Err(stop) => CommandOutcome::Failed {
                cause: stop.cause(),
            },
        };
        report.reads = Some(seen);
        report.finished = Some(settle.finish(outcome));
        report
    }

    /// The port failed: every command waiting for its device to settle has failed.
    pub(crate) fn fail_settling(&mut self, error: &PortFault) -> Vec<(usize, Finished)> {
        std::mem::take(&mut self.settling)
            .into_iter()
            .map(|settle| {
                let cause = CommandFailure::PortFailedWhileSettling(error.clone());
                (
                    settle.device,
                    settle.finish(CommandOutcome::Failed { cause }),
                )
            })
            .collect()
    }

    /// Shutdown: commands waiting for their device to settle end without a verdict.
    pub(crate) fn abandon_settling(&mut self) -> Vec<(usize, Finished)> {
        std::mem::take(&mut self.settling)
            .into_iter()
            .map(|settle| {
                let detail = "the gateway shut down before the read-back settled".to_string();
                (
                    settle.device,
                    settle.finish(CommandOutcome::NotApplied { detail }),
                )
            })
            .collect()
    }
}

impl Settle {
    /// The device being re-read.
    pub(crate) fn device(&self) -> usize {
        self.device
    }

    /// This command's end.
    pub(crate) fn finish(&self, outcome: CommandOutcome) -> Finished {
        Finished {
            id: self.id,
            arrived: self.arrived,
            outcome,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtu2mqtt_profile::registry::built_in;
    use rtu2mqtt_profile::DeviceState;

    #[test]
    fn a_held_command_is_due_when_its_write_interval_ends() {
        let (_commands, queue) = super::super::queue::command_queue(1);
        let mut slots = CommandSlots::new(queue);
        let profile = built_in("ruiwan-dust-collector").unwrap();
        let plan = profile
            .plan_command("gear", "8", &DeviceState::new())
            .unwrap();
        let now = Instant::now();
        let until = now + Duration::from_secs(1);
        let command = Command {
            id: 7,
            device: "dust".into(),
            plan,
        };
        slots.hold(
            0,
            Pending {
                command,
                arrived: now,
            },
            until,
        );
        assert_eq!(slots.next_due(), Some(until));
        assert!(slots.take_due_held(now).is_none());
        let (device, pending) = slots.take_due_held(until).unwrap();
        assert_eq!((device, pending.command.id), (0, 7));
        assert_eq!(slots.next_due(), None);
        // Held commands fail when the line stops, with their id.
        slots.hold(0, pending, until);
        let held = slots.drain_held();
        let finished = held[0].1.failed(CommandFailure::ShuttingDown);
        assert_eq!(finished.id, 7);
        assert!(slots.drain_held().is_empty());
    }
}
