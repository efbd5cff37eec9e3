//! The poll plan of one device, derived from its [`DeviceSpec`] and profile: which blocks, how
//! often (the device's poll interval, never below the profile's minimum; slow blocks on the
//! profile's slow interval), how long to stay quiet after start-up, and which block is the
//! cheapest probe of an offline device. Pure data; the [`super::scheduler`] runs it.

use std::time::Duration;

use crate::profile::{PollClass, ReadBlock};
use crate::rtu::Request;

use super::DeviceSpec;

/// One block of a device's poll plan.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BlockPlan {
    pub class: PollClass,
    /// Bytes of the expected answer frame: the probe is the block with the smallest.
    pub answer_bytes: usize,
}

/// How one device is polled.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DevicePlan {
    pub blocks: Vec<BlockPlan>,
    /// Period of the fast blocks (already raised to the profile's minimum).
    pub poll_interval: Duration,
    /// Period of the slow blocks (never shorter than `poll_interval`).
    pub slow_interval: Duration,
    /// Quiet time after the gateway starts before the first transaction with the device.
    pub startup_delay: Duration,
}

impl DevicePlan {
    /// The plan of a configured device.
    pub fn for_device(spec: &DeviceSpec) -> Self {
        let limits = spec.profile.limits();
        let poll_interval = spec.poll_interval.max(limits.min_poll_interval);
        // Nothing answers a read sent to the broadcast address: such a device is write-only.
        let blocks = if spec.address == 0 {
            Vec::new()
        } else {
            spec.profile
                .read_blocks()
                .iter()
                .map(|block| BlockPlan {
                    class: block.class,
                    answer_bytes: read_answer_bytes(block),
                })
                .collect()
        };
        DevicePlan {
            blocks,
            poll_interval,
            slow_interval: limits.slow_interval.max(poll_interval),
            startup_delay: limits.startup_delay,
        }
    }

    /// The block that costs the line least: what an offline device is probed with.
    pub fn probe_block(&self) -> Option<usize> {
        self.blocks
            .iter()
            .enumerate()
            .min_by_key(|(_, block)| block.answer_bytes)
            .map(|(index, _)| index)
    }

    /// Interval of `block`.
    pub fn interval_of(&self, block: usize) -> Duration {
        match self.blocks.get(block).map(|b| b.class) {
            Some(PollClass::Slow) => self.slow_interval,
            _ => self.poll_interval,
        }
    }
}

/// Length of the answer frame to a read request (address, function, byte count, data, CRC).
pub fn read_answer_bytes(block: &ReadBlock) -> usize {
    request_answer_bytes(&block.request)
}

/// Length of the normal answer frame to `request`, address and CRC included.
pub fn request_answer_bytes(request: &Request) -> usize {
    match request {
        Request::ReadCoils { quantity, .. } | Request::ReadDiscreteInputs { quantity, .. } => {
            5 + usize::from(*quantity).div_ceil(8)
        }
        Request::ReadHoldingRegisters { quantity, .. }
        | Request::ReadInputRegisters { quantity, .. } => 5 + 2 * usize::from(*quantity),
        // Echo of address and value, or of start and quantity.
        Request::WriteSingleCoil { .. }
        | Request::WriteSingleRegister { .. }
        | Request::WriteMultipleCoils { .. }
        | Request::WriteMultipleRegisters { .. } => 8,
    }
}

/// Length of the request frame itself, address and CRC included.
pub fn request_bytes(request: &Request) -> usize {
    match request {
        Request::WriteMultipleCoils { values, .. } => 9 + values.len().div_ceil(8),
        Request::WriteMultipleRegisters { values, .. } => 9 + 2 * values.len(),
        _ => 8,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_lengths_match_the_golden_frames() {
        // 81 01 00 00 00 16 A2 04 → 81 01 03 b0 b1 b2 CRC (8 bytes).
        let coils = Request::ReadCoils {
            start: 0,
            quantity: 22,
        };
        assert_eq!(request_bytes(&coils), 8);
        assert_eq!(request_answer_bytes(&coils), 8);
        // 01 03 10 00 00 06 → 01 03 0C + 12 bytes + CRC (17 bytes).
        let words = Request::ReadHoldingRegisters {
            start: 0x1000,
            quantity: 6,
        };
        assert_eq!(request_answer_bytes(&words), 17);
        // The golden FC10 write of four words is 17 bytes long.
        let write = Request::WriteMultipleRegisters {
            start: 0x1000,
            values: vec![0x0300, 5, 2, 10],
        };
        assert_eq!(request_bytes(&write), 17);
        // 81 0F 00 00 00 0C 02 b0 b1 CRC: 11 bytes.
        let coils_write = Request::WriteMultipleCoils {
            start: 0,
            values: vec![false; 12],
        };
        assert_eq!(request_bytes(&coils_write), 11);
        assert_eq!(request_answer_bytes(&coils_write), 8);
    }

    #[test]
    fn probe_is_the_smallest_block() {
        let plan = DevicePlan {
            blocks: vec![
                BlockPlan {
                    class: PollClass::Fast,
                    answer_bytes: 17,
                },
                BlockPlan {
                    class: PollClass::Slow,
                    answer_bytes: 7,
                },
                BlockPlan {
                    class: PollClass::Fast,
                    answer_bytes: 9,
                },
            ],
            poll_interval: Duration::from_secs(1),
            slow_interval: Duration::from_secs(60),
            startup_delay: Duration::ZERO,
        };
        assert_eq!(plan.probe_block(), Some(1));
        assert_eq!(plan.interval_of(1), Duration::from_secs(60));
        assert_eq!(plan.interval_of(2), Duration::from_secs(1));
    }
}
