//! The line task's command side: taking commands and refreshes in, running a command's slot
//! (with the write interval of its fields) and settle re-reads, and carrying out what a slot
//! reports: values, results and the write clock.

use std::time::{Instant, SystemTime};

use tokio::sync::mpsc;

use super::Line;
use crate::bus::command::run::SeenReads;
use crate::bus::command::slots::{Finished, Pending, Settle, SlotReport};
use crate::bus::command::{Command, CommandFailure, CommandOutcome};
use crate::bus::device::{Decode, Values};
use crate::bus::event::{LineEvent, Origin};
use crate::bus::serve::served_side::FIRST_CLIENT_COMMAND_ID;

/// Commands: taking them in, running their slots and carrying out what the slots report.
impl Line {
    pub(super) async fn accept_commands(&mut self, now: Instant) {
        while let Some(command) = self.commands.try_take() {
            self.accept(command, now).await;
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

    /// Takes every refresh request already waiting, without waiting.
    pub(super) fn accept_refreshes(&mut self) {
        while let Some(refreshes) = self.refreshes.as_mut() {
            match refreshes.try_recv() {
                Ok(device) => self.refresh(Some(device)),
                Err(mpsc::error::TryRecvError::Empty) => return,
                Err(mpsc::error::TryRecvError::Disconnected) => self.refresh(None),
            }
        }
    }

    /// A refresh request for `device` (None: their sender is gone, the line stops listening).
    pub(super) fn refresh(&mut self, device: Option<String>) {
        let Some(name) = device else {
            self.refreshes = None;
            return;
        };
        let refreshed = self
            .device_index(&name)
            .is_some_and(|device| self.scheduler.request_refresh(device));
        if refreshed {
            tracing::debug!(device = %name, "refresh: every block is read next");
        } else {
            tracing::info!(device = %name, "refresh not done: the device is offline or not on this line");
        }
    }

    pub(super) fn device_index(&self, name: &str) -> Option<usize> {
        self.devices.iter().position(|d| d.spec.name == name)
    }

    pub(super) async fn run_command(&mut self, device: usize, pending: Pending) {
        // A client wrote one of the command's fields after the bridge sent it: the command
        // waits out the field's interval like any command for it.
        let now = Instant::now();
        if let Some(runtime) = self.devices.get(device) {
            let plan = &pending.command.plan;
            let fields = plan.targets().into_iter().map(|(field, _)| field);
            let busy =
                self.writes
                    .busy_until(&runtime.spec.name, &runtime.spec.profile, fields, now);
            if let Some(until) = busy {
                tracing::debug!(device = %runtime.spec.name, field = plan.field(), wait = ?until - now,
                    "command held: the field's write interval runs");
                self.commands.hold(device, pending, until);
                return;
            }
        }
        let fields: Vec<String> = pending
            .command
            .plan
            .targets()
            .into_iter()
            .map(|(field, _)| field.to_string())
            .collect();
        let (link, commands) = self.slot_link(device);
        let Some(link) = link else {
            let finished = pending.failed(CommandFailure::PortNotOpen);
            self.reply(device, finished).await;
            return;
        };
        let report = commands.run(link, device, pending).await;
        if report.wrote {
            self.note_write(device, &fields).await;
        }
        self.carry_out(report).await;
    }

    /// A slot that wrote `fields` of `device` has ended: their write intervals start now, and
    /// the bridge learns it before the slot's values and end.
    pub(super) async fn note_write(&mut self, device: usize, fields: &[String]) {
        let Some(runtime) = self.devices.get(device) else {
            return;
        };
        let at = Instant::now();
        let name = runtime.spec.name.clone();
        let fields = fields.iter().map(String::as_str);
        let noted = self.writes.wrote(&name, &runtime.spec.profile, fields, at);
        if !noted.is_empty() {
            self.emit(LineEvent::Written {
                device: name,
                fields: noted,
                at,
            })
            .await;
        }
    }

    pub(super) async fn run_settle(&mut self, settle: Settle) {
        let device = settle.device();
        let (link, commands) = self.slot_link(device);
        let Some(link) = link else {
            let finished = settle.finish(CommandOutcome::Failed {
                cause: CommandFailure::PortNotOpen,
            });
            self.reply(device, finished).await;
            return;
        };
        let report = commands.reread(link, settle).await;
        self.carry_out(report).await;
    }

    /// What a slot or a settle re-read reported, in its order: the device's contact, its
    /// reads, the command's end, and last the port's failure.
    pub(super) async fn carry_out(&mut self, report: SlotReport) {
        let SlotReport {
            device,
            contact,
            reads,
            changed,
            finished,
            port_gone,
            wrote: _,
        } = report;
        let now = Instant::now();
        // The command can have changed what a poll read: clients read the device again.
        self.served.cache.forget(device);
        if contact {
            if let Some(change) = self.scheduler.record_contact(device, now) {
                self.availability_changed(device, change).await;
            }
        }
        if let Some(seen) = reads {
            self.publish_reads(device, seen, &changed, now).await;
        }
        if let Some(finished) = finished {
            self.reply(device, finished).await;
        }
        if let Some(error) = port_gone {
            self.port_failed(error).await;
        }
    }

    /// Sends the values of the reads a command slot made that are poll blocks of the device.
    /// A block in `changed` (the command can have changed it) that the slot did not read whole
    /// is polled at once, so that what the command changed is reported without waiting for a
    /// poll interval; no block's cadence moves ([`Scheduler::after_command`]).
    pub(super) async fn publish_reads(
        &mut self,
        device: usize,
        seen: SeenReads,
        changed: &[usize],
        now: Instant,
    ) {
        let Some(runtime) = self.devices.get_mut(device) else {
            return;
        };
        let read_at = SystemTime::now();
        let profile = runtime.spec.profile.clone();
        let mut values = Values::new();
        let blocks = profile.read_blocks().len();
        let mut covered = vec![false; blocks];
        for (request, answer) in &seen {
            let Some(block) = profile
                .read_blocks()
                .iter()
                .position(|b| &b.request == request)
            else {
                continue;
            };
            runtime.decode_into(block, answer, Decode::Every, &mut values);
            if let Some(flag) = covered.get_mut(block) {
                *flag = true;
            }
        }
        let mut changeable = vec![false; blocks];
        for &block in changed {
            if let Some(flag) = changeable.get_mut(block) {
                *flag = true;
            }
        }
        let change = self
            .scheduler
            .after_command(device, &changeable, &covered, now);
        if let Some(change) = change {
            self.availability_changed(device, change).await;
        }
        self.emit_values(device, values, read_at, Origin::Command)
            .await;
    }

    /// Counts a command's end and reports it on the events channel (after any `Values` of
    /// its slot, so that a command's state is out before its result).
    pub(super) async fn reply(&mut self, device: usize, finished: Finished) {
        let Finished {
            id,
            arrived,
            outcome,
        } = finished;
        if id >= FIRST_CLIENT_COMMAND_ID {
            // A client's write whose device settled after its client was answered.
            if let Some(write) = self.served.settled(id) {
                self.client_write_finished(write, outcome).await;
            }
            return;
        }
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
            let finished = pending.failed(why.clone());
            self.reply(device, finished).await;
        }
    }
}
