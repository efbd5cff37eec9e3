//! Commands on the line: taking them from the queue, running each one's slot when the
//! scheduler gives it its turn, re-reading a device that is still settling (outside the slot:
//! the writes are done by then, so nothing can interleave with them any more, and a 60 s settle
//! window must not take the line from the other devices), publishing what the slot read, and
//! each command's end as a `LineEvent::CommandFinished` after those values, with its latency.
//! The frames of a slot are [`super::slot`]'s.

use std::time::{Duration, Instant};

use tokio::sync::mpsc;
use tracing::Instrument;

use super::device::{DeviceRuntime, Values};
use super::line::Line;
use super::scheduler::PollOutcome;
use super::slot::{self, SeenReads, SlotEnd, Stop};
use super::transaction::{Exchange, Failure};
use super::{Command, CommandFailure, CommandOutcome, LineEvent};
use crate::profile::{CommandPlan, Verification};
use rtu2mqtt_modbus::master::PortFault;

/// Pause between two read-backs of a command whose device is still moving.
pub(super) const SETTLE_REREAD: Duration = Duration::from_millis(500);

/// A command waiting for its slot.
#[derive(Debug)]
pub(super) struct Pending {
    command: Command,
    arrived: Instant,
}

/// A command whose writes are done and whose device is still moving toward the value.
pub(super) struct Settle {
    device: usize,
    plan: CommandPlan,
    id: u64,
    arrived: Instant,
    deadline: Instant,
    pub(super) next_read: Instant,
}

impl Line {
    pub(super) async fn accept_commands(&mut self, now: Instant) {
        while self.commands_open {
            match self.command_rx.try_recv() {
                Ok(command) => self.accept(command, now).await,
                Err(mpsc::error::TryRecvError::Empty) => break,
                Err(mpsc::error::TryRecvError::Disconnected) => self.commands_open = false,
            }
        }
    }

    pub(super) async fn accept(&mut self, command: Command, now: Instant) {
        match self.device_index(&command.device) {
            Some(device) => self.scheduler.push_command(
                device,
                Pending {
                    command,
                    arrived: now,
                },
            ),
            None => {
                let cause = CommandFailure::UnknownDevice {
                    device: command.device.clone(),
                    line: self.spec.name.clone(),
                };
                let (id, device) = (command.id, command.device);
                self.emit(LineEvent::CommandFinished {
                    id,
                    device,
                    outcome: CommandOutcome::Failed { cause },
                })
                .await;
            }
        }
    }

    fn device_index(&self, name: &str) -> Option<usize> {
        self.devices.iter().position(|d| d.spec.name == name)
    }

    pub(super) async fn run_command(&mut self, device: usize, pending: Pending) {
        let Pending { command, arrived } = pending;
        let attempts = self.attempts();
        let (Some(DeviceRuntime { spec, stats, .. }), Some(master)) =
            (self.devices.get_mut(device), self.master.as_mut())
        else {
            let outcome = CommandOutcome::Failed {
                cause: CommandFailure::PortNotOpen,
            };
            self.reply(device, command.id, arrived, outcome).await;
            return;
        };
        let exchange = Exchange::for_device(&self.spec.name, spec, self.timeout, &self.turnaround);
        let span =
            tracing::info_span!("command", device = %spec.name, field = command.plan.field());
        let mut seen = SeenReads::new();
        let end = slot::run_slot(&exchange, master, stats, &command.plan, attempts, &mut seen)
            .instrument(span)
            .await;
        let now = Instant::now();
        match end {
            SlotEnd::Done(outcome) => {
                let answered = matches!(
                    outcome,
                    CommandOutcome::Applied { .. } | CommandOutcome::NotApplied { .. }
                );
                tracing::debug!(device = %spec.name, field = command.plan.field(), %outcome, "command done on the line");
                if answered {
                    self.contact(device, now).await;
                }
                self.publish_reads(device, seen, now).await;
                self.reply(device, command.id, arrived, outcome).await;
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
                self.contact(device, now).await;
                self.publish_reads(device, seen, now).await;
            }
            SlotEnd::PortGone(error) => {
                let outcome = CommandOutcome::Failed {
                    cause: CommandFailure::PortFailed(error.clone()),
                };
                self.reply(device, command.id, arrived, outcome).await;
                self.port_failed(error).await;
            }
        }
    }

    pub(super) async fn run_settle(&mut self, mut settle: Settle) {
        let attempts = self.attempts();
        let (Some(DeviceRuntime { spec, stats, .. }), Some(master)) =
            (self.devices.get_mut(settle.device), self.master.as_mut())
        else {
            let outcome = CommandOutcome::Failed {
                cause: CommandFailure::PortNotOpen,
            };
            self.reply(settle.device, settle.id, settle.arrived, outcome)
                .await;
            return;
        };
        let exchange = Exchange::for_device(&self.spec.name, spec, self.timeout, &self.turnaround);
        let mut seen = SeenReads::new();
        let result =
            slot::reread(&exchange, master, stats, &settle.plan, attempts, &mut seen).await;
        let now = Instant::now();
        let outcome = match result {
            Ok(Verification::Applied) => CommandOutcome::Applied {
                detail: "read-back confirms the value after settling".into(),
            },
            Ok(Verification::NotApplied(detail)) => CommandOutcome::NotApplied { detail },
            Ok(Verification::Settling) if now < settle.deadline => {
                settle.next_read = now + SETTLE_REREAD;
                self.settling.push(settle);
                return;
            }
            Ok(Verification::Settling) => CommandOutcome::NotApplied {
                detail: "the device was still moving when the settle window ended".into(),
            },
            Err(Stop::Failed(Failure::PortGone(error))) => {
                let outcome = CommandOutcome::Failed {
                    cause: CommandFailure::PortFailed(error.clone()),
                };
                self.reply(settle.device, settle.id, settle.arrived, outcome)
                    .await;
                self.port_failed(error).await;
                return;
            }
            Err(stop) => CommandOutcome::Failed {
                cause: stop.cause(),
            },
        };
        let device = settle.device;
        self.publish_reads(device, seen, now).await;
        self.reply(device, settle.id, settle.arrived, outcome).await;
    }

    /// The device answered a command: it is there.
    async fn contact(&mut self, device: usize, now: Instant) {
        if let Some(change) = self.scheduler.record_contact(device, now) {
            self.availability_changed(device, change).await;
        }
    }

    /// Sends the values of the reads a command slot made that are poll blocks of the device
    /// (they count as that block's poll); every other block is polled at once, so that what
    /// the command changed is reported without waiting for a poll interval.
    async fn publish_reads(&mut self, device: usize, seen: SeenReads, now: Instant) {
        let Some(runtime) = self.devices.get_mut(device) else {
            return;
        };
        let profile = runtime.spec.profile.clone();
        let mut values = Values::new();
        let mut covered = vec![false; profile.read_blocks().len()];
        for (request, answer) in &seen {
            let Some(block) = profile
                .read_blocks()
                .iter()
                .position(|b| &b.request == request)
            else {
                continue;
            };
            runtime.decode_into(block, answer, &mut values);
            if let Some(flag) = covered.get_mut(block) {
                *flag = true;
            }
            self.scheduler
                .record_poll(device, block, PollOutcome::Answered, now);
        }
        self.scheduler.refresh_except(device, &covered, now);
        self.emit_values(device, values).await;
    }

    /// Counts a command's end and reports it on the events channel (after any `Values` of
    /// its slot, so that a command's state is out before its result).
    async fn reply(&mut self, device: usize, id: u64, arrived: Instant, outcome: CommandOutcome) {
        let latency = arrived.elapsed();
        self.stats.commands += 1;
        self.stats.last_command_latency = Some(latency);
        self.stats.worst_command_latency = Some(
            self.stats
                .worst_command_latency
                .map_or(latency, |w| w.max(latency)),
        );
        let device = self
            .devices
            .get(device)
            .map(|runtime| runtime.spec.name.clone())
            .unwrap_or_default();
        self.emit(LineEvent::CommandFinished {
            id,
            device,
            outcome,
        })
        .await;
    }

    pub(super) async fn fail_queued(&mut self, why: &CommandFailure) {
        if self.scheduler.queued_commands() == 0 {
            return;
        }
        for (device, pending) in self.scheduler.drain_commands() {
            let outcome = CommandOutcome::Failed { cause: why.clone() };
            self.reply(device, pending.command.id, pending.arrived, outcome)
                .await;
        }
    }

    /// The port failed: every command waiting for its device to settle has failed.
    pub(super) async fn fail_settling(&mut self, error: &PortFault) {
        for settle in std::mem::take(&mut self.settling) {
            let outcome = CommandOutcome::Failed {
                cause: CommandFailure::PortFailedWhileSettling(error.clone()),
            };
            self.reply(settle.device, settle.id, settle.arrived, outcome)
                .await;
        }
    }

    /// Shutdown: commands waiting for their device to settle end without a verdict.
    pub(super) async fn abandon_settling(&mut self) {
        for settle in std::mem::take(&mut self.settling) {
            let detail = "the gateway shut down before the read-back settled".to_string();
            let outcome = CommandOutcome::NotApplied { detail };
            self.reply(settle.device, settle.id, settle.arrived, outcome)
                .await;
        }
    }
}
