//! One poll of one block: the merged block, or its used runs one by one once the device has
//! refused the merged block with exception 02 (remembered per device, said once at INFO and
//! counted as a split-read fallback, not as an exception), and what the reply means for the
//! device's health. Decoding and reporting are the line's.

use rtu2mqtt_modbus::link::Link;
use rtu2mqtt_modbus::Reply;
use rtu2mqtt_modbus::{ExceptionCode, Response};
use rtu2mqtt_profile::ReadBlock;

use super::device::DeviceRuntime;
use super::scheduler::PollOutcome;
use super::stats::DeviceStats;
use super::transaction::{ExchangeContext, Failure, Turnaround};

/// What one poll of a device needs from its line.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PollContext<'a> {
    pub line: &'a str,
    pub timeout: std::time::Duration,
    pub turnaround: &'a Turnaround,
    pub attempts: u32,
}

/// Reads `block`, `device`'s read block number `index`, falling back to its used runs (for
/// good) when the device refuses the merged block with exception 02.
pub(crate) async fn read_block(
    context: PollContext<'_>,
    master: &mut Link,
    device: &mut DeviceRuntime,
    index: usize,
    block: &ReadBlock,
) -> Result<Reply, Failure> {
    let DeviceRuntime {
        spec,
        stats,
        read_by_parts,
        ..
    } = device;
    let exchange =
        ExchangeContext::for_device(context.line, spec, context.timeout, context.turnaround);
    let attempts = context.attempts;
    let by_parts = read_by_parts.get(index).copied().unwrap_or(false);
    if by_parts {
        return read_runs(&exchange, master, stats, block, attempts).await;
    }
    let reply = exchange
        .run(master, stats, &block.request, attempts)
        .await?;
    if block.used_runs.len() > 1 && reply == Err(ExceptionCode::IllegalDataAddress) {
        // The device's way of saying "not across the gaps": an expected answer, not a failure.
        // The exchange counted it as an exception; it moves to its own counter.
        stats.exceptions = stats.exceptions.saturating_sub(1);
        stats.split_read_fallbacks += 1;
        tracing::info!(
            "{}: reads block {:?} in {} parts (the device refuses the merged read)",
            spec.name,
            block.name,
            block.used_runs.len()
        );
        if let Some(flag) = read_by_parts.get_mut(index) {
            *flag = true;
        }
        return read_runs(&exchange, master, stats, block, attempts).await;
    }
    Ok(reply)
}

/// What a poll's reply says about the device.
pub(crate) fn outcome(reply: &Reply, device: &str, block: &str) -> PollOutcome {
    match reply {
        Ok(_) => PollOutcome::Answered,
        Err(ExceptionCode::ServerDeviceBusy) => PollOutcome::Busy,
        Err(
            code @ (ExceptionCode::ServerDeviceFailure
            | ExceptionCode::GatewayTargetFailedToRespond),
        ) => {
            tracing::warn!(device, block, "poll failed: {code}");
            PollOutcome::Failed
        }
        Err(code) => {
            // The device is there and refuses this read: a profile problem, not an outage.
            tracing::warn!(device, block, "poll refused: {code}");
            PollOutcome::Answered
        }
    }
}

/// Reads a block's used runs one by one and assembles the block's answer with zeros in the
/// places no field uses. An exception to any run is the block's reply.
async fn read_runs(
    exchange: &ExchangeContext<'_>,
    master: &mut Link,
    stats: &mut DeviceStats,
    block: &ReadBlock,
    attempts: u32,
) -> Result<Reply, Failure> {
    let mut answer = block
        .request
        .empty_answer()
        .unwrap_or(Response::HoldingRegisters(Vec::new()));
    for &(offset, length) in &block.used_runs {
        let Some(request) = block.request.sub_read(offset, length) else {
            continue;
        };
        match exchange.run(master, stats, &request, attempts).await? {
            Ok(part) => answer.place(offset, &part),
            Err(code) => return Ok(Err(code)),
        }
    }
    Ok(Ok(answer))
}
