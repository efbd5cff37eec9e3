//! A served line driven by bytes alone, for the fuzz targets (`fuzz/`): one client's byte
//! stream read and judged by the server exactly as from a socket, and the requests it lets
//! through answered by a stand-in for the line task that plans a client's writes through the
//! line's own policy ([`policy::plan_write`]). Not part of the gateway's interface.

use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::mpsc;

use super::policy;
use super::served_side::echo;
use super::server::{serve_connection, ServeCounters};
use super::{Access, ClientRequest, ServeFraming};
use crate::bus::device_spec::DeviceSpec;
use rtu2mqtt_modbus::{ExceptionCode, Reply, Request, SlaveId};
use rtu2mqtt_profile::{DeviceState, Profile};

/// A request that reached the line, and what the stand-in made of it.
#[derive(Debug)]
pub struct OnLine {
    pub unit: SlaveId,
    pub request: Request,
    /// A write under `profile` access: the command the policy planned, as (field, value
    /// text) per target, or the exception it answered instead.
    pub planned: Option<Result<Vec<(String, String)>, ExceptionCode>>,
}

/// What serving one client's bytes came to.
#[derive(Debug)]
pub struct Served {
    /// Everything the client got back, in its framing.
    pub answers: Vec<u8>,
    pub on_line: Vec<OnLine>,
    /// Why the connection ended.
    pub end: String,
    /// Requests framed and judged.
    pub requests: u64,
}

/// Serves `client`'s bytes (then the end of its stream) on a line with `devices` (address,
/// profile) under `access`, until the connection ends.
pub async fn serve_bytes(
    framing: ServeFraming,
    access: Access,
    devices: &[(SlaveId, Arc<Profile>)],
    client: &[u8],
) -> Served {
    let specs: Vec<DeviceSpec> = devices
        .iter()
        .enumerate()
        .map(|(index, (address, profile))| DeviceSpec {
            name: format!("device{index}"),
            address: *address,
            profile: Arc::clone(profile),
            poll_interval: Duration::from_secs(1),
            publish: Default::default(),
        })
        .collect();
    let (client_end, server_end) = tokio::io::duplex(4096);
    let (server_read, server_write) = tokio::io::split(server_end);
    let (mut client_read, mut client_write) = tokio::io::split(client_end);
    let (line_tx, mut line_rx) = mpsc::channel::<Box<ClientRequest>>(1);
    let counters = Arc::new(ServeCounters::default());
    let send = async {
        // The server may close first (a request it cannot frame): the rest is not read.
        let _ = client_write.write_all(client).await;
        let _ = client_write.shutdown().await;
    };
    let receive = async {
        let mut answers = Vec::new();
        let _ = client_read.read_to_end(&mut answers).await;
        answers
    };
    let line = async {
        let mut on_line = Vec::new();
        while let Some(slot) = line_rx.recv().await {
            let (reply, planned) = stand_in(access, &specs, slot.unit, &slot.request);
            on_line.push(OnLine {
                unit: slot.unit,
                request: slot.request,
                planned,
            });
            let _ = slot.reply.send(reply);
        }
        on_line
    };
    let serve = serve_connection(
        server_read,
        server_write,
        framing,
        access,
        specs.clone(),
        line_tx,
        Arc::clone(&counters),
    );
    let ((), answers, on_line, end) = tokio::join!(send, receive, line, serve);
    Served {
        answers,
        on_line,
        end,
        requests: counters.requests.load(std::sync::atomic::Ordering::Relaxed),
    }
}

type Planned = Option<Result<Vec<(String, String)>, ExceptionCode>>;

/// The line's answer to a request: a read as a device whose items are all zero answers it, a
/// write as the device echoes it once the policy has planned it (under `profile` access).
fn stand_in(
    access: Access,
    devices: &[DeviceSpec],
    unit: SlaveId,
    request: &Request,
) -> (Reply, Planned) {
    if let Some(answer) = request.empty_answer() {
        return (Ok(answer), None);
    }
    let echoed = echo(request).ok_or(ExceptionCode::IllegalFunction);
    let device = devices.iter().find(|device| device.address == unit);
    match device {
        Some(device) if access == Access::Profile => {
            match policy::plan_write(&device.profile, request, &DeviceState::new()) {
                Ok(planned) => {
                    let targets = planned
                        .plan
                        .iter()
                        .flat_map(|plan| plan.targets())
                        .map(|(field, value)| (field.to_string(), value.to_text()))
                        .collect();
                    (echoed, Some(Ok(targets)))
                }
                Err(code) => (Err(code), Some(Err(code))),
            }
        }
        _ => (echoed, None),
    }
}
