//! One device's runtime on its line, in one place instead of parallel per-device vectors: its
//! configuration, its statistics, the blocks it refused merged (read by parts from then on),
//! and the one path from a read answer to the values the line publishes (field data that does
//! not decode is counted and logged, never published). No frames are run here.

use crate::profile::Value;
use crate::rtu::Response;

use super::stats::DeviceStats;
use super::DeviceSpec;

/// Decoded values of a device, by field name, ready for a `LineEvent::Values`.
pub type Values = Vec<(String, Value)>;

/// A configured device as its line runs it.
#[derive(Debug, Clone)]
pub struct DeviceRuntime {
    pub spec: DeviceSpec,
    pub stats: DeviceStats,
    /// Per block: the device refused the merged block, read its used runs instead.
    pub read_by_parts: Vec<bool>,
}

impl DeviceRuntime {
    pub fn new(spec: DeviceSpec) -> Self {
        DeviceRuntime {
            stats: DeviceStats::new(&spec.name),
            read_by_parts: vec![false; spec.profile.read_blocks().len()],
            spec,
        }
    }

    /// Decodes `answer` to the device's read block `block` and adds its valid values to
    /// `values`.
    pub fn decode_into(&mut self, block: usize, answer: &Response, values: &mut Values) {
        for reading in self.spec.profile.decode_block(block, answer) {
            match reading.value {
                Ok(value) => values.push((reading.field, value)),
                Err(error) => {
                    self.stats.field_errors += 1;
                    tracing::warn!(
                        device = %self.spec.name,
                        field = %reading.field,
                        "invalid field data, not published: {error}"
                    );
                }
            }
        }
    }
}
