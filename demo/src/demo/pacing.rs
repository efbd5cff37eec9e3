//! Log mode's pace: which changes are printed at once and which are gathered, so that values
//! that move on every poll (counters, measurements, a valve on its way) do not scroll the
//! command results away. Pure: the caller passes the time since the demo started.
//!
//! The rule, the same for every field: a value that changes after having been still for
//! [`QUIET`] is printed at once (`dust_collector/gear = 8`). A field's first value, and any
//! change of a field that already changed within [`QUIET`], waits for the next summary: one
//! line per device with the latest of those values, at most once every [`QUIET`], once the
//! oldest waiting value is [`GATHER`] old (so a first poll lands in one line). Availability,
//! commands, outcomes and clearings are always printed at once.

use std::collections::{HashMap, HashSet};
use std::time::Duration;

use super::view::{log_line, Change};

/// How long a field must have been still for its change to be printed at once, and the least
/// time between two summaries.
pub(super) const QUIET: Duration = Duration::from_secs(10);

/// How long a summary waits for more values after the first one it will carry.
pub(super) const GATHER: Duration = Duration::from_secs(2);

/// What log mode has printed and what waits for the next summary.
#[derive(Debug, Default)]
pub(super) struct LogPacing {
    seen: HashSet<(String, String)>,
    last_change: HashMap<(String, String), Duration>,
    /// Per device (first-seen order), the waiting fields with their latest values.
    waiting: Vec<(String, Vec<(String, String)>)>,
    waiting_since: Option<Duration>,
    last_summary: Option<Duration>,
}

impl LogPacing {
    /// The line to print now for `change`, if any (otherwise it waits for a summary).
    pub(super) fn on_change(&mut self, now: Duration, change: &Change) -> Option<String> {
        let Change::Value {
            device,
            field,
            value,
        } = change
        else {
            if let Change::Cleared { device, field } = change {
                self.forget_waiting(device, field);
            }
            return Some(log_line(now, change));
        };
        let key = (device.clone(), field.clone());
        let first = self.seen.insert(key.clone());
        let lively = self
            .last_change
            .get(&key)
            .is_some_and(|at| now.saturating_sub(*at) < QUIET);
        if !first {
            self.last_change.insert(key, now);
        }
        if first || lively {
            self.wait(now, device, field, value);
            None
        } else {
            self.forget_waiting(device, field);
            Some(log_line(now, change))
        }
    }

    /// The summary lines due at `now` (none most of the time).
    pub(super) fn due(&mut self, now: Duration) -> Vec<String> {
        let gathered = self
            .waiting_since
            .is_some_and(|since| now.saturating_sub(since) >= GATHER);
        let rested = self
            .last_summary
            .map_or(true, |last| now.saturating_sub(last) >= QUIET);
        if gathered && rested {
            self.summary(now)
        } else {
            Vec::new()
        }
    }

    /// Whatever waits, now (the demo is stopping).
    pub(super) fn summary(&mut self, now: Duration) -> Vec<String> {
        self.waiting_since = None;
        if self.waiting.is_empty() {
            return Vec::new();
        }
        self.last_summary = Some(now);
        std::mem::take(&mut self.waiting)
            .into_iter()
            .map(|(device, fields)| {
                let values: Vec<String> = fields
                    .iter()
                    .map(|(field, value)| format!("{field} {value}"))
                    .collect();
                format!(
                    "{:>8.2}s  {device}: {}",
                    now.as_secs_f64(),
                    values.join(" · ")
                )
            })
            .collect()
    }

    fn wait(&mut self, now: Duration, device: &str, field: &str, value: &str) {
        self.waiting_since.get_or_insert(now);
        let index = match self.waiting.iter().position(|(d, _)| d == device) {
            Some(index) => index,
            None => {
                self.waiting.push((device.to_string(), Vec::new()));
                self.waiting.len() - 1
            }
        };
        let fields = &mut self.waiting[index].1;
        match fields.iter_mut().find(|(f, _)| f == field) {
            Some((_, latest)) => *latest = value.to_string(),
            None => fields.push((field.to_string(), value.to_string())),
        }
    }

    fn forget_waiting(&mut self, device: &str, field: &str) {
        for (waiting_device, fields) in &mut self.waiting {
            if waiting_device == device {
                fields.retain(|(f, _)| f != field);
            }
        }
        self.waiting.retain(|(_, fields)| !fields.is_empty());
        if self.waiting.is_empty() {
            self.waiting_since = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn value(field: &str, value: &str) -> Change {
        Change::Value {
            device: "valve".into(),
            field: field.into(),
            value: value.into(),
        }
    }

    fn at(seconds: f64) -> Duration {
        Duration::from_secs_f64(seconds)
    }

    #[test]
    fn first_values_arrive_as_one_summary() {
        let mut pacing = LogPacing::default();
        assert_eq!(pacing.on_change(at(1.0), &value("opening", "30")), None);
        assert_eq!(pacing.on_change(at(1.5), &value("mode", "manual")), None);
        assert!(pacing.due(at(2.0)).is_empty());
        assert_eq!(
            pacing.due(at(3.0)),
            vec!["    3.00s  valve: opening 30 · mode manual"]
        );
        assert!(pacing.due(at(4.0)).is_empty());
    }

    #[test]
    fn a_still_value_that_changes_is_printed_at_once() {
        let mut pacing = LogPacing::default();
        pacing.on_change(at(1.0), &value("setpoint", "120.00"));
        assert_eq!(
            pacing
                .on_change(at(5.0), &value("setpoint", "40.00"))
                .as_deref(),
            Some("    5.00s  valve/setpoint = 40.00")
        );
        // It was printed: nothing of it waits any more.
        assert!(pacing.due(at(8.0)).is_empty());
    }

    #[test]
    fn lively_values_make_at_most_one_summary_per_quiet_period() {
        let mut pacing = LogPacing::default();
        let mut printed = Vec::new();
        for second in 1..=60 {
            let now = at(f64::from(second));
            let text = second.to_string();
            printed.extend(pacing.on_change(now, &value("measured_1", &text)));
            printed.extend(pacing.due(now));
        }
        // The first change is news; then one summary every 10 s at most.
        assert!(printed.len() <= 8, "{printed:#?}");
        assert_eq!(printed[0], "    2.00s  valve/measured_1 = 2");
        assert!(printed
            .last()
            .is_some_and(|l| l.contains("valve: measured_1 ")));
        // Outcomes are never held back.
        let result = Change::CommandResult {
            device: "valve".into(),
            field: "opening".into(),
            outcome: "applied".into(),
            value: "40".into(),
            detail: String::new(),
        };
        assert!(pacing.on_change(at(61.0), &result).is_some());
        assert_eq!(pacing.summary(at(62.0)).len(), 1);
    }
}
