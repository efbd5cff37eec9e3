//! The gateway's figures as node metrics: per line the port state, the bus load and the
//! transaction statistics (`Lines/<line>/Bus Load`), declared for the NBIRTH
//! ([`node_metric_specs`]) and sampled from the lines' statistics ([`figures`], [`feed`]).
//! Reads statistics only; never touches a line.

use std::time::Duration;

use tokio::sync::{mpsc, watch};

use super::protobuf::{DataType, MetricValue};
use super::session::NodeMetricSpec;
use crate::bus::LineStats;
use tokio_util::sync::CancellationToken;

/// The figures of one line: metric name suffix, datatype and how to read it.
type Reading = (&'static str, DataType, fn(&LineStats) -> MetricValue);

const READINGS: &[Reading] = &[
    ("Port Open", DataType::Boolean, |s| {
        MetricValue::Boolean(s.port_open)
    }),
    // Percent of wall time, one decimal: a fraction would be a noisy float.
    ("Bus Load", DataType::Float, |s| {
        MetricValue::Float(((s.bus_load * 1000.0).round() / 10.0) as f32)
    }),
    ("Transactions", DataType::UInt64, |s| {
        MetricValue::Long(s.transactions)
    }),
    ("Timeouts", DataType::UInt64, |s| {
        MetricValue::Long(s.timeouts)
    }),
    ("CRC Errors", DataType::UInt64, |s| {
        MetricValue::Long(s.crc_errors)
    }),
    ("Exceptions", DataType::UInt64, |s| {
        MetricValue::Long(s.exceptions)
    }),
    ("Port Failures", DataType::UInt64, |s| {
        MetricValue::Long(s.port_failures)
    }),
    ("Commands", DataType::UInt64, |s| {
        MetricValue::Long(s.commands)
    }),
];

fn metric_name(line: &str, reading: &str) -> String {
    format!("Lines/{line}/{reading}")
}

/// The node metrics declared for the configured lines, in configuration order.
pub(crate) fn node_metric_specs(lines: &[String]) -> Vec<NodeMetricSpec> {
    lines
        .iter()
        .flat_map(|line| {
            READINGS
                .iter()
                .map(|(reading, datatype, _)| NodeMetricSpec {
                    name: metric_name(line, reading),
                    datatype: *datatype,
                })
        })
        .collect()
}

/// The current values of every line's figures.
pub(crate) fn figures(stats: &[LineStats]) -> Vec<(String, MetricValue)> {
    stats
        .iter()
        .flat_map(|line| {
            READINGS
                .iter()
                .map(|(reading, _, read)| (metric_name(&line.line, reading), read(line)))
        })
        .collect()
}

/// Samples the lines' statistics every `interval` and hands the figures to the node (which
/// publishes only what changed) until shutdown or until the node is gone.
pub(crate) async fn feed(
    lines: Vec<watch::Receiver<LineStats>>,
    values: mpsc::Sender<Vec<(String, MetricValue)>>,
    interval: Duration,
    shutdown: CancellationToken,
) {
    let mut tick = tokio::time::interval(interval);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            () = shutdown.cancelled() => return,
            _ = tick.tick() => {
                let stats: Vec<LineStats> = lines.iter().map(|rx| rx.borrow().clone()).collect();
                // Never waits on a slow node: the next sample carries the same figures.
                match values.try_send(figures(&stats)) {
                    Ok(()) | Err(mpsc::error::TrySendError::Full(_)) => {}
                    Err(mpsc::error::TrySendError::Closed(_)) => return,
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    #[test]
    fn every_declared_figure_has_a_value_of_its_type() {
        let names = ["line-a".to_string(), "line-b".to_string()];
        let specs = node_metric_specs(&names);
        let mut stats: Vec<LineStats> = names
            .iter()
            .map(|line| LineStats::new(line, &[], Instant::now()))
            .collect();
        stats[0].bus_load = 0.12345;
        stats[1].transactions = 7;
        let values = figures(&stats);
        assert_eq!(specs.len(), values.len());
        for (spec, (name, value)) in specs.iter().zip(&values) {
            assert_eq!(&spec.name, name);
            let matches = matches!(
                (spec.datatype, value),
                (DataType::Boolean, MetricValue::Boolean(_))
                    | (DataType::Float, MetricValue::Float(_))
                    | (DataType::UInt64, MetricValue::Long(_))
            );
            assert!(matches, "{name}: {value:?}");
        }
        let value_of = |name: &str| {
            values
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, v)| v.clone())
        };
        assert_eq!(
            value_of("Lines/line-a/Bus Load"),
            Some(MetricValue::Float(12.3))
        );
        assert_eq!(
            value_of("Lines/line-b/Transactions"),
            Some(MetricValue::Long(7))
        );
    }
}
