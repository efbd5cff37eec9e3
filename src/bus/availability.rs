//! Availability of one device on a line: online, offline after `offline_after` consecutive
//! failed polls, and while offline a probe schedule with capped exponential back-off (1 s, 2 s,
//! 4 s … at most 30 s by default) so that a dead device costs its line only one small read per
//! back-off step. Pure: the clock is passed in, nothing here sleeps or touches a port.

use std::time::{Duration, Instant};

/// When a device is declared offline and how it is probed afterwards.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HealthPolicy {
    /// Consecutive failed polls after which the device is offline (at least 1).
    pub offline_after: u32,
    /// Wait before the first probe of an offline device.
    pub probe_initial: Duration,
    /// Cap of the doubling probe interval.
    pub probe_max: Duration,
}

impl HealthPolicy {
    /// The default probing (1 s doubling up to 30 s) with the line's `offline_after`.
    pub fn with_offline_after(offline_after: u32) -> Self {
        HealthPolicy {
            offline_after: offline_after.max(1),
            probe_initial: Duration::from_secs(1),
            probe_max: Duration::from_secs(30),
        }
    }
}

/// What the gateway knows about a device's presence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Availability {
    /// Nothing has been heard yet (start-up, or the device has not been polled yet).
    Unknown,
    Online,
    Offline,
}

/// A change worth an `Availability` event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HealthChange {
    CameOnline,
    WentOffline,
}

/// Health bookkeeping of one device.
#[derive(Debug, Clone)]
pub struct DeviceHealth {
    policy: HealthPolicy,
    availability: Availability,
    consecutive_failures: u32,
    /// Current back-off step while offline; doubled after every failed probe.
    probe_interval: Duration,
    /// When the next probe is due (only while offline).
    next_probe: Option<Instant>,
}

impl DeviceHealth {
    pub fn new(policy: HealthPolicy) -> Self {
        DeviceHealth {
            policy,
            availability: Availability::Unknown,
            consecutive_failures: 0,
            probe_interval: policy.probe_initial,
            next_probe: None,
        }
    }

    pub fn availability(&self) -> Availability {
        self.availability
    }

    pub fn is_offline(&self) -> bool {
        self.availability == Availability::Offline
    }

    pub fn consecutive_failures(&self) -> u32 {
        self.consecutive_failures
    }

    /// When the next probe is due; `None` unless the device is offline.
    pub fn next_probe(&self) -> Option<Instant> {
        self.next_probe
    }

    /// The device answered (a normal answer or an exception: either proves it is there).
    pub fn record_success(&mut self) -> Option<HealthChange> {
        self.consecutive_failures = 0;
        self.probe_interval = self.policy.probe_initial;
        self.next_probe = None;
        match self.availability {
            Availability::Online => None,
            Availability::Unknown | Availability::Offline => {
                self.availability = Availability::Online;
                Some(HealthChange::CameOnline)
            }
        }
    }

    /// A poll or probe failed after its retries (no answer, or only garbage).
    pub fn record_failure(&mut self, now: Instant) -> Option<HealthChange> {
        self.consecutive_failures = self.consecutive_failures.saturating_add(1);
        if self.availability == Availability::Offline {
            // A failed probe: wait longer before the next one, up to the cap.
            self.probe_interval = (self.probe_interval * 2).min(self.policy.probe_max);
            self.next_probe = Some(now + self.probe_interval);
            return None;
        }
        if self.consecutive_failures >= self.policy.offline_after {
            return self.go_offline(now);
        }
        None
    }

    /// The port is gone: the device cannot be reached, whatever its own state.
    pub fn force_offline(&mut self, now: Instant) -> Option<HealthChange> {
        if self.availability == Availability::Offline {
            return None;
        }
        self.go_offline(now)
    }

    /// Probe at `now` with the back-off restarted (the port was just reopened: the device may
    /// well be back, there is no reason to wait out a long back-off step).
    pub fn probe_soon(&mut self, now: Instant) {
        if self.availability == Availability::Offline {
            self.probe_interval = self.policy.probe_initial;
            self.next_probe = Some(now);
        }
    }

    fn go_offline(&mut self, now: Instant) -> Option<HealthChange> {
        let was_known_online = self.availability != Availability::Offline;
        self.availability = Availability::Offline;
        self.probe_interval = self.policy.probe_initial;
        self.next_probe = Some(now + self.probe_interval);
        was_known_online.then_some(HealthChange::WentOffline)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy() -> HealthPolicy {
        HealthPolicy::with_offline_after(3)
    }

    #[test]
    fn first_success_brings_the_device_online_once() {
        let mut health = DeviceHealth::new(policy());
        assert_eq!(health.availability(), Availability::Unknown);
        assert_eq!(health.record_success(), Some(HealthChange::CameOnline));
        assert_eq!(health.record_success(), None);
        assert_eq!(health.availability(), Availability::Online);
    }

    #[test]
    fn offline_after_the_configured_number_of_failures() {
        let now = Instant::now();
        let mut health = DeviceHealth::new(policy());
        health.record_success();
        assert_eq!(health.record_failure(now), None);
        assert_eq!(health.record_failure(now), None);
        assert_eq!(health.record_failure(now), Some(HealthChange::WentOffline));
        assert!(health.is_offline());
        assert_eq!(health.next_probe(), Some(now + Duration::from_secs(1)));
    }

    #[test]
    fn a_success_in_between_resets_the_count() {
        let now = Instant::now();
        let mut health = DeviceHealth::new(policy());
        health.record_failure(now);
        health.record_failure(now);
        health.record_success();
        assert_eq!(health.consecutive_failures(), 0);
        health.record_failure(now);
        health.record_failure(now);
        assert!(!health.is_offline());
    }

    #[test]
    fn a_device_never_heard_goes_offline_too() {
        let now = Instant::now();
        let mut health = DeviceHealth::new(policy());
        for _ in 0..2 {
            health.record_failure(now);
        }
        assert_eq!(health.record_failure(now), Some(HealthChange::WentOffline));
    }

    #[test]
    fn probe_back_off_doubles_up_to_the_cap() {
        let mut now = Instant::now();
        let mut health = DeviceHealth::new(policy());
        for _ in 0..3 {
            health.record_failure(now);
        }
        let mut steps = Vec::new();
        for _ in 0..8 {
            let due = health.next_probe().unwrap();
            steps.push((due - now).as_secs());
            now = due;
            assert_eq!(health.record_failure(now), None);
        }
        assert_eq!(steps, vec![1, 2, 4, 8, 16, 30, 30, 30]);
        assert_eq!(health.record_success(), Some(HealthChange::CameOnline));
        assert_eq!(health.next_probe(), None);
    }

    #[test]
    fn forced_offline_reports_once_and_probe_soon_restarts_the_back_off() {
        let now = Instant::now();
        let mut health = DeviceHealth::new(policy());
        health.record_success();
        assert_eq!(health.force_offline(now), Some(HealthChange::WentOffline));
        assert_eq!(health.force_offline(now), None);
        for step in 1..5 {
            health.record_failure(now + Duration::from_secs(step));
        }
        let later = now + Duration::from_secs(100);
        health.probe_soon(later);
        assert_eq!(health.next_probe(), Some(later));
        health.record_failure(later);
        assert_eq!(health.next_probe(), Some(later + Duration::from_secs(2)));
    }
}
