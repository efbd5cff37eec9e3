//! The line task's served side: a client's request as a line slot. Reads come from the poll
//! cache or the wire, writes are planned through the profile (or passed raw), kept to the
//! fields' write intervals, and answered as the device answered; a broadcast (unit 0) goes out
//! once and is answered as soon as it is on the line.

use std::time::Instant;

use super::Line;
use crate::bus::command::slots::Pending;
use crate::bus::command::{Command, CommandOutcome};
use crate::bus::event::LineEvent;
use crate::bus::serve::policy;
use crate::bus::serve::served_side::{
    block_overlaps, client_answer, echo, written_span, ClientCount, ClientWrite,
};
use crate::bus::serve::{Access, ClientRequest};
use crate::bus::transaction::{ExchangeContext, Failure};
use rtu2mqtt_modbus::{Error as MasterError, Reply};
use rtu2mqtt_modbus::{ExceptionCode, Request};

/// The address every device on a line hears and none answers.
const BROADCAST: u8 = 0;

/// Client requests: the cache, the profile's write planning, and the exchange on the line.
impl Line {
    pub(super) async fn run_client(&mut self, slot: ClientRequest) {
        let ClientRequest {
            client,
            unit,
            request,
            probe,
            reply,
        } = slot;
        let device = self.devices.iter().position(|d| d.spec.address == unit);
        let access = self.spec.serve.as_ref().map_or(Access::Raw, |s| s.access);
        if let Some(device) = device {
            if let Some(answer) = self.served.cache.lookup(device, &request, Instant::now()) {
                self.served.count(ClientCount::CacheHit);
                let _ = reply.send(Ok(answer));
                return;
            }
            if request.is_write() {
                self.served.cache.forget(device);
                if access == Access::Profile {
                    let answer = self.run_client_write(device, &client, &request).await;
                    let _ = reply.send(answer);
                    return;
                }
            }
        }
        // A raw write passes as it came, but not inside a write interval of a field it covers.
        let raw_write = match device.and_then(|d| self.devices.get(d).map(|r| (d, r))) {
            Some((device, runtime)) if request.is_write() => {
                // By address through each field's own write, and as the profile's shared frames
                // read it (the dust collector's gear at 0x1001 of its settings frame).
                let profile = &runtime.spec.profile;
                let mut fields = profile.fields_touched(&request);
                for reading in profile.decode_write(&request).unwrap_or_default() {
                    if !fields.contains(&reading.field) {
                        fields.push(reading.field);
                    }
                }
                if let Err(code) = self.client_write_allowed(device, &client, &fields) {
                    let _ = reply.send(Err(code));
                    return;
                }
                Some((device, fields))
            }
            _ => None,
        };
        let attempts = if probe { 1 } else { self.attempts() };
        let Some(master) = self.master.as_mut() else {
            let _ = reply.send(Err(ExceptionCode::GatewayTargetFailedToRespond));
            return;
        };
        if unit == BROADCAST {
            // Every device hears address 0 and none answers it: there is no answer to wait
            // for and none whose absence could call for another attempt. A write goes out
            // once and its client is told at once what an answered write is told (the echo),
            // while the line keeps its broadcast turnaround; a read could only time out, so
            // it is answered 0B at once and never sent.
            let Some(echoed) = echo(&request) else {
                let _ = reply.send(Err(ExceptionCode::GatewayTargetFailedToRespond));
                return;
            };
            let mut waiting = Some(reply);
            let sent = master
                .broadcast_then(&request, || {
                    if let Some(reply) = waiting.take() {
                        let _ = reply.send(Ok(echoed));
                    }
                })
                .await;
            tracing::debug!(%client, ?request, ?sent, "client broadcast on the line");
            if let Some((device, fields)) = raw_write {
                self.note_write(device, &fields).await;
            }
            if let Err(error) = sent {
                if let Some(reply) = waiting {
                    let _ = reply.send(Err(ExceptionCode::GatewayTargetFailedToRespond));
                }
                if let MasterError::PortGone(fault) = error {
                    self.port_failed(fault).await;
                }
            }
            return;
        }
        let mut passer_by = crate::bus::stats::DeviceStats::new(&format!("unit {unit}"));
        let unknown = format!("unit {unit}");
        let (name, stats) = match device.and_then(|d| self.devices.get_mut(d)) {
            Some(runtime) => (runtime.spec.name.as_str(), &mut runtime.stats),
            None => (unknown.as_str(), &mut passer_by),
        };
        let exchange = ExchangeContext {
            line: &self.spec.name,
            device: name,
            slave: unit,
            timeout: self.timeout,
            turnaround: &self.turnaround,
        };
        let result = exchange.run(master, stats, &request, attempts).await;
        tracing::debug!(%client, unit, ?request, ?result, "client request on the line");
        if let Some((device, fields)) = raw_write {
            self.note_write(device, &fields).await;
        }
        match result {
            Ok(answer) => {
                if let (Some(device), Ok(_)) = (device, &answer) {
                    self.after_raw_write(device, &request);
                }
                let _ = reply.send(answer);
            }
            Err(Failure::NoAnswer(_)) => {
                let _ = reply.send(Err(ExceptionCode::GatewayTargetFailedToRespond));
            }
            Err(Failure::PortGone(error)) => {
                let _ = reply.send(Err(ExceptionCode::GatewayTargetFailedToRespond));
                self.port_failed(error).await;
            }
        }
    }

    /// A client's write went to `device` as it was sent (`raw` access): the device's blocks
    /// of the table it wrote, at the addresses it wrote, are read again at once (a `once`
    /// block included), like after a command.
    pub(super) fn after_raw_write(&mut self, device: usize, write: &Request) {
        let Some(runtime) = self.devices.get(device) else {
            return;
        };
        let written = written_span(write);
        let changed: Vec<bool> = runtime
            .spec
            .profile
            .read_blocks()
            .iter()
            .map(|block| written.is_some_and(|span| block_overlaps(&block.request, span)))
            .collect();
        if changed.iter().any(|&changed| changed) {
            let none = vec![false; changed.len()];
            self.scheduler
                .after_command(device, &changed, &none, Instant::now());
        }
    }

    /// A client's write under `profile` access: planned by the device's profile on its known
    /// state (a refusal sends nothing), then run as a command slot whose reads are published.
    pub(super) async fn run_client_write(
        &mut self,
        device: usize,
        client: &str,
        write: &Request,
    ) -> Reply {
        let Some(runtime) = self.devices.get(device) else {
            return Err(ExceptionCode::GatewayPathUnavailable);
        };
        let name = runtime.spec.name.clone();
        let planned = policy::plan_write(&runtime.spec.profile, write, &runtime.known_state());
        let planned = match planned {
            Ok(planned) => planned,
            Err(code) => {
                tracing::info!(%client, device = %name, ?write, "client write refused: {code}");
                self.served.count(ClientCount::Refusal);
                return Err(code);
            }
        };
        self.client_write_allowed(device, client, &planned.covered)?;
        let Some(plan) = planned.plan else {
            // Only zeros on buttons and toggles: the device itself would do nothing.
            tracing::debug!(%client, device = %name, ?write, "client write leaves the device as it is");
            return echo(write).ok_or(ExceptionCode::IllegalFunction);
        };
        let field = plan.field().to_string();
        let write_record = ClientWrite {
            device: name.clone(),
            field: field.clone(),
            value: plan
                .targets()
                .iter()
                .map(|(_, value)| value.to_text())
                .collect::<Vec<_>>()
                .join(","),
            client: client.to_string(),
        };
        let id = self.served.next_command_id();
        let pending = Pending {
            command: Command {
                id,
                device: name.clone(),
                plan,
            },
            arrived: Instant::now(),
        };
        let (link, commands) = self.slot_link(device);
        let Some(link) = link else {
            return Err(ExceptionCode::GatewayTargetFailedToRespond);
        };
        let mut report = commands.run(link, device, pending).await;
        if report.wrote {
            self.note_write(device, &planned.covered).await;
        }
        let finished = report.finished.take();
        let answer = match &finished {
            Some(finished) => {
                tracing::info!(%client, device = %name, %field, outcome = %finished.outcome, "client write");
                client_answer(&finished.outcome, write)
            }
            // Written; the device is still moving toward the value.
            None if report.port_gone.is_none() => {
                tracing::info!(%client, device = %name, %field, "client write applied, settling");
                echo(write).ok_or(ExceptionCode::IllegalFunction)
            }
            None => Err(ExceptionCode::GatewayTargetFailedToRespond),
        };
        self.carry_out(report).await;
        match finished {
            Some(finished) => {
                self.client_write_finished(write_record, finished.outcome)
                    .await;
            }
            None => {
                self.served.settling(id, write_record);
            }
        }
        answer
    }

    /// The write-interval rule for a client's write covering `fields` of `device`: refused at
    /// once with 06 (server device busy) while the interval of any of them runs, whoever
    /// wrote last; the client may send it again later.
    pub(super) fn client_write_allowed(
        &self,
        device: usize,
        client: &str,
        fields: &[String],
    ) -> Result<(), ExceptionCode> {
        let Some(runtime) = self.devices.get(device) else {
            return Ok(());
        };
        let now = Instant::now();
        let covered = fields.iter().map(String::as_str);
        let name = &runtime.spec.name;
        let Some(until) = self
            .writes
            .busy_until(name, &runtime.spec.profile, covered, now)
        else {
            return Ok(());
        };
        tracing::info!(%client, device = %name, ?fields, wait = ?until - now,
            "client write refused: the write interval runs (06, busy)");
        self.served.count(ClientCount::Busy);
        Err(ExceptionCode::ServerDeviceBusy)
    }

    /// Reports a client's write's end to the bridge (after the values of its reads).
    pub(super) async fn client_write_finished(
        &mut self,
        write: ClientWrite,
        outcome: CommandOutcome,
    ) {
        let ClientWrite {
            device,
            field,
            value,
            client,
        } = write;
        self.emit(LineEvent::ClientWriteFinished {
            device,
            field,
            value,
            client,
            outcome,
        })
        .await;
    }
}
