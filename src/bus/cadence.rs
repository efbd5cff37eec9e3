//! The poll plan of one device, derived from its [`DeviceSpec`] and profile: which blocks, how
//! often (fast blocks on the device's poll interval, never below the profile's minimum; slow
//! blocks on the profile's slow interval; a block with its own period on that period; `once`
//! blocks on no period at all), how long to stay quiet after start-up, and which block is the
//! cheapest probe of an offline device. Pure data; the [`super::scheduler`] runs it.

use std::time::Duration;

use rtu2mqtt_profile::PollClass;

use super::device_spec::DeviceSpec;

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
                    answer_bytes: block.request.answer_len(),
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

    /// Interval of `block`: its period, or for a `once` block how soon a read that failed is
    /// tried again (the poll interval).
    pub fn interval_of(&self, block: usize) -> Duration {
        self.period_of(block).unwrap_or(self.poll_interval)
    }

    /// The period `block` is polled on; None for a `once` block, which has none.
    pub fn period_of(&self, block: usize) -> Option<Duration> {
        match self.blocks.get(block).map(|b| b.class) {
            Some(PollClass::Slow) => Some(self.slow_interval),
            Some(PollClass::Every(period)) => Some(period),
            Some(PollClass::Once) => None,
            Some(PollClass::Fast) | None => Some(self.poll_interval),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
