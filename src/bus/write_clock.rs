//! When each field with a `min_write_interval` was last written on its device, by any source
//! (an MQTT or Sparkplug command, a client of a served line): the one write-interval rule.
//! The line task notes a write once its slot has run (the write reached the device, or may
//! have), and asks here before a write whether every field it covers is past its interval.
//! One clock serves every line of the gateway and outlives them, so a line rebuilt by a
//! configuration reload keeps the intervals that were running.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use rtu2mqtt_profile::Profile;

/// The last write of each (device, field) that has a write interval. Cloning shares it.
#[derive(Debug, Clone, Default)]
pub struct WriteClock {
    last: Arc<Mutex<HashMap<(String, String), Instant>>>,
}

impl WriteClock {
    pub fn new() -> Self {
        Self::default()
    }

    fn last(&self) -> MutexGuard<'_, HashMap<(String, String), Instant>> {
        // A panic elsewhere while holding the lock leaves a map of instants, still usable.
        self.last
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Notes a write of `fields` of `device` at `at`; fields without a write interval in
    /// `profile` are not kept (nothing limits them).
    pub fn wrote<'f>(
        &self,
        device: &str,
        profile: &Profile,
        fields: impl IntoIterator<Item = &'f str>,
        at: Instant,
    ) -> Vec<String> {
        let mut last = self.last();
        let mut noted = Vec::new();
        for field in fields {
            let limited = profile
                .field(field)
                .is_some_and(|info| info.min_write_interval.is_some());
            if !limited {
                continue;
            }
            let entry = last
                .entry((device.to_string(), field.to_string()))
                .or_insert(at);
            *entry = (*entry).max(at);
            noted.push(field.to_string());
        }
        noted
    }

    /// When a write of `fields` of `device` may reach the device: the latest end of their
    /// intervals (as `profile` sets them), or `None` when none of them is running at `now`.
    pub fn busy_until<'f>(
        &self,
        device: &str,
        profile: &Profile,
        fields: impl IntoIterator<Item = &'f str>,
        now: Instant,
    ) -> Option<Instant> {
        let last = self.last();
        fields
            .into_iter()
            .filter_map(|field| {
                let interval = profile.field(field)?.min_write_interval?;
                let written = last.get(&(device.to_string(), field.to_string()))?;
                Some(*written + interval)
            })
            .filter(|free| *free > now)
            .max()
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use rtu2mqtt_profile::registry::built_in;

    #[test]
    fn an_interval_runs_from_the_last_write_of_any_covered_field() {
        let profile = built_in("ruiwan-dust-collector").unwrap();
        let clock = WriteClock::new();
        let start = Instant::now();
        // Power has no interval: it is not kept and never waits.
        assert_eq!(
            clock.wrote("dust", &profile, ["power", "gear"], start),
            ["gear"]
        );
        assert_eq!(clock.busy_until("dust", &profile, ["power"], start), None);
        let second = Duration::from_secs(1);
        assert_eq!(
            clock.busy_until("dust", &profile, ["power", "gear"], start),
            Some(start + second)
        );
        // Another device's gear is its own.
        assert_eq!(clock.busy_until("other", &profile, ["gear"], start), None);
        assert_eq!(
            clock.busy_until("dust", &profile, ["gear"], start + second),
            None
        );
        // A clone is the same clock (a line rebuilt by a reload keeps it).
        let kept = clock.clone();
        kept.wrote("dust", &profile, ["pulse_interval"], start + second);
        assert_eq!(
            clock.busy_until("dust", &profile, ["gear", "pulse_interval"], start + second),
            Some(start + second * 2)
        );
        // An older note never moves the last write back.
        clock.wrote("dust", &profile, ["pulse_interval"], start);
        assert_eq!(
            clock.busy_until("dust", &profile, ["pulse_interval"], start + second),
            Some(start + second * 2)
        );
    }
}
