//! Report by exception, pure: which of a line's freshly read values are reported, decided once
//! for every consumer (plain topics, JSON view, history, Sparkplug), from each field's
//! `publish` settings (its profile's keys, the device's configured default for the others).
//!
//! A value goes out when it moved beyond its deadband from the last one that went out (any
//! change for anything but a number); not sooner than `min_interval` after that one (the
//! newest value goes out when the interval ends); and, unchanged, every `max_interval` (a
//! heartbeat). A command's reads always go out and become the last published values. A
//! device going offline or coming back forgets what went out: its next values go out as read.
//! Fields without settings pass as they come. The clock is passed in; the line's reporter task
//! ([`super::reporter`]) sleeps until [`Report::next_wake`] and calls [`Report::due`].

use std::collections::HashMap;
use std::time::{Instant, SystemTime};

use super::device::Values;
use super::device_spec::DeviceSpec;
use super::event::{LineEvent, Origin};
use rtu2mqtt_profile::{PublishRule, Value};

/// The publishing state of one line's devices.
#[derive(Debug, Default)]
pub(crate) struct Report {
    /// By device name; only devices with at least one field that has settings.
    devices: HashMap<String, HashMap<String, FieldReport>>,
}

/// One field with `publish` settings.
#[derive(Debug)]
struct FieldReport {
    rule: PublishRule,
    /// The value that went out last, and when.
    last: Option<(Value, Instant)>,
    /// The newest value read since, with its read time, when it did not go out.
    newest: Option<(Value, SystemTime)>,
    /// When the newest value goes out (its `min_interval` held it back).
    flush_at: Option<Instant>,
}

impl FieldReport {
    fn published(&mut self, value: Value, now: Instant) {
        self.last = Some((value, now));
        self.newest = None;
        self.flush_at = None;
    }

    fn forget(&mut self) {
        self.last = None;
        self.newest = None;
        self.flush_at = None;
    }

    fn heartbeat_at(&self) -> Option<Instant> {
        let (_, at) = self.last.as_ref()?;
        Some(*at + self.rule.max_interval?)
    }

    /// Whether `value`, read at `read_at`, goes out now; otherwise it is kept as the newest.
    fn offer(&mut self, value: &Value, read_at: SystemTime, now: Instant) -> bool {
        let Some((last, at)) = &self.last else {
            self.published(value.clone(), now);
            return true;
        };
        if !self.rule.moved(last, value) {
            self.newest = Some((value.clone(), read_at));
            return false;
        }
        let allowed = self.rule.min_interval.map_or(now, |min| *at + min);
        if now >= allowed {
            self.published(value.clone(), now);
            return true;
        }
        self.newest = Some((value.clone(), read_at));
        self.flush_at = Some(allowed);
        false
    }
}

impl Report {
    /// The settings of `devices`' fields: their own keys, the device's for the others.
    pub(crate) fn new(devices: &[DeviceSpec]) -> Self {
        let mut report = Report::default();
        for device in devices {
            let fields: HashMap<String, FieldReport> = device
                .profile
                .fields()
                .iter()
                .map(|field| (field.name.clone(), field.publish.or(device.publish)))
                .filter(|(_, rule)| !rule.is_empty())
                .map(|(name, rule)| {
                    let field = FieldReport {
                        rule,
                        last: None,
                        newest: None,
                        flush_at: None,
                    };
                    (name, field)
                })
                .collect();
            if !fields.is_empty() {
                report.devices.insert(device.name.clone(), fields);
            }
        }
        report
    }

    /// No field of the line has settings: every value passes as it comes.
    pub(crate) fn is_empty(&self) -> bool {
        self.devices.is_empty()
    }

    /// What of `event` is reported now (None: nothing). Values are filtered by their fields'
    /// rules; a command's pass and are the last published; availability forgets the device.
    pub(crate) fn on_event(&mut self, event: LineEvent, now: Instant) -> Option<LineEvent> {
        match event {
            LineEvent::Values {
                device,
                values,
                read_at,
                origin,
            } => {
                let Some(fields) = self.devices.get_mut(&device) else {
                    return Some(LineEvent::Values {
                        device,
                        values,
                        read_at,
                        origin,
                    });
                };
                let passed: Values = values
                    .into_iter()
                    .filter(|(field, value)| match fields.get_mut(field) {
                        None => true,
                        Some(report) if origin == Origin::Command => {
                            report.published(value.clone(), now);
                            true
                        }
                        Some(report) => report.offer(value, read_at, now),
                    })
                    .collect();
                (!passed.is_empty()).then_some(LineEvent::Values {
                    device,
                    values: passed,
                    read_at,
                    origin,
                })
            }
            LineEvent::Availability { device, online } => {
                if let Some(fields) = self.devices.get_mut(&device) {
                    fields.values_mut().for_each(FieldReport::forget);
                }
                Some(LineEvent::Availability { device, online })
            }
            other => Some(other),
        }
    }

    /// When [`Report::due`] has something next: a held value's interval ends or a heartbeat.
    pub(crate) fn next_wake(&self) -> Option<Instant> {
        self.devices
            .values()
            .flat_map(HashMap::values)
            .flat_map(|field| [field.flush_at, field.heartbeat_at()])
            .flatten()
            .min()
    }

    /// The values due at `now` (`wall` is the same instant on the wall clock): held values
    /// whose `min_interval` ended and that still moved (one event per device and read time),
    /// then heartbeats (one event per device, read at `wall`).
    pub(crate) fn due(&mut self, now: Instant, wall: SystemTime) -> Vec<LineEvent> {
        let mut events = Vec::new();
        let mut names: Vec<&String> = self.devices.keys().collect();
        names.sort();
        let names: Vec<String> = names.into_iter().cloned().collect();
        for device in names {
            let Some(fields) = self.devices.get_mut(&device) else {
                continue;
            };
            let mut flushed: Vec<(SystemTime, Values)> = Vec::new();
            let mut beats = Values::new();
            let mut order: Vec<&String> = fields.keys().collect();
            order.sort();
            let order: Vec<String> = order.into_iter().cloned().collect();
            for name in order {
                let Some(field) = fields.get_mut(&name) else {
                    continue;
                };
                if field.flush_at.is_some_and(|at| at <= now) {
                    field.flush_at = None;
                    let moved = match (&field.last, &field.newest) {
                        (Some((last, _)), Some((newest, _))) => field.rule.moved(last, newest),
                        _ => false,
                    };
                    if let (true, Some((value, read_at))) = (moved, field.newest.take()) {
                        field.published(value.clone(), now);
                        match flushed.iter_mut().find(|(at, _)| *at == read_at) {
                            Some((_, values)) => values.push((name.clone(), value)),
                            None => flushed.push((read_at, vec![(name.clone(), value)])),
                        }
                        continue;
                    }
                }
                if field.heartbeat_at().is_some_and(|at| at <= now) {
                    let value = match (field.newest.take(), &field.last) {
                        (Some((newest, _)), _) => newest,
                        (None, Some((last, _))) => last.clone(),
                        (None, None) => continue,
                    };
                    field.published(value.clone(), now);
                    beats.push((name, value));
                }
            }
            for (read_at, values) in flushed {
                events.push(LineEvent::Values {
                    device: device.clone(),
                    values,
                    read_at,
                    origin: Origin::Poll,
                });
            }
            if !beats.is_empty() {
                events.push(LineEvent::Values {
                    device,
                    values: beats,
                    read_at: wall,
                    origin: Origin::Heartbeat,
                });
            }
        }
        events
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::time::Duration;

    use super::*;
    use rtu2mqtt_profile::publish::{Amount, RawPublish};
    use rtu2mqtt_profile::registry::built_in;

    const S: Duration = Duration::from_secs(1);

    /// The dust collector (`gear`, `fan_speed`, `mode`, …) with `publish` as its default.
    fn report(publish: RawPublish) -> Report {
        let device = DeviceSpec {
            name: "dust".into(),
            address: 1,
            profile: Arc::new(built_in("ruiwan-dust-collector").unwrap()),
            poll_interval: S,
            publish: PublishRule::from_raw(&publish).unwrap(),
        };
        Report::new(&[device])
    }

    fn values(origin: Origin, pairs: &[(&str, Value)]) -> LineEvent {
        LineEvent::Values {
            device: "dust".into(),
            values: pairs
                .iter()
                .map(|(f, v)| (f.to_string(), v.clone()))
                .collect(),
            read_at: SystemTime::UNIX_EPOCH,
            origin,
        }
    }

    fn read(pairs: &[(&str, Value)]) -> LineEvent {
        values(Origin::Poll, pairs)
    }

    /// The (field, value) pairs an event reports, with its origin.
    fn reported(event: Option<LineEvent>) -> Vec<(String, Value)> {
        match event {
            Some(LineEvent::Values { values, .. }) => values,
            None => Vec::new(),
            Some(other) => panic!("not values: {other:?}"),
        }
    }

    fn speed(rpm: i64) -> Value {
        Value::Int(rpm.into())
    }

    fn pairs(list: &[(&str, Value)]) -> Vec<(String, Value)> {
        list.iter()
            .map(|(f, v)| (f.to_string(), v.clone()))
            .collect()
    }

    #[test]
    fn without_settings_everything_passes_untouched() {
        let mut report = report(RawPublish::default());
        assert!(report.is_empty());
        let t0 = Instant::now();
        let event = read(&[("fan_speed", speed(1450))]);
        assert_eq!(report.on_event(event.clone(), t0), Some(event.clone()));
        assert_eq!(report.on_event(event.clone(), t0), Some(event));
        assert_eq!(report.next_wake(), None);
    }

    #[test]
    fn a_deadband_holds_small_moves_from_the_last_published_value() {
        let mut report = report(RawPublish {
            deadband: Some(50.0),
            ..RawPublish::default()
        });
        let t0 = Instant::now();
        let first = report.on_event(read(&[("fan_speed", speed(1450))]), t0);
        assert_eq!(reported(first), pairs(&[("fan_speed", speed(1450))]));
        // Creeping up 30 at a time: measured from 1450, not from the last read.
        assert!(reported(report.on_event(read(&[("fan_speed", speed(1480))]), t0 + S)).is_empty());
        assert!(reported(report.on_event(read(&[("fan_speed", speed(1500))]), t0 + S)).is_empty());
        let out = report.on_event(read(&[("fan_speed", speed(1501))]), t0 + 2 * S);
        assert_eq!(reported(out), pairs(&[("fan_speed", speed(1501))]));
        // No heartbeat, no held value: nothing to wake for.
        assert_eq!(report.next_wake(), None);
    }

    #[test]
    fn min_interval_coalesces_and_the_newest_value_goes_out_when_it_ends() {
        let mut report = report(RawPublish {
            min_interval: Some(5 * S),
            ..RawPublish::default()
        });
        let t0 = Instant::now();
        assert_eq!(
            reported(report.on_event(read(&[("gear", speed(1))]), t0)),
            pairs(&[("gear", speed(1))])
        );
        assert!(reported(report.on_event(read(&[("gear", speed(2))]), t0 + S)).is_empty());
        let newest = LineEvent::Values {
            device: "dust".into(),
            values: pairs(&[("gear", speed(3))]),
            read_at: SystemTime::UNIX_EPOCH + 3 * S,
            origin: Origin::Poll,
        };
        assert!(reported(report.on_event(newest, t0 + 3 * S)).is_empty());
        assert_eq!(report.next_wake(), Some(t0 + 5 * S));
        assert!(report
            .due(t0 + 5 * S - Duration::from_millis(1), SystemTime::now())
            .is_empty());
        let flushed = report.due(t0 + 5 * S, SystemTime::now());
        assert_eq!(
            flushed,
            [LineEvent::Values {
                device: "dust".into(),
                values: pairs(&[("gear", speed(3))]),
                read_at: SystemTime::UNIX_EPOCH + 3 * S,
                origin: Origin::Poll,
            }]
        );
        assert_eq!(report.next_wake(), None);
        // The next change waits for the interval from that publication.
        assert!(reported(report.on_event(read(&[("gear", speed(4))]), t0 + 6 * S)).is_empty());
        assert_eq!(report.next_wake(), Some(t0 + 10 * S));
        // A value back at the last published one cancels the pending one.
        assert!(reported(report.on_event(read(&[("gear", speed(3))]), t0 + 7 * S)).is_empty());
        assert!(report.due(t0 + 10 * S, SystemTime::now()).is_empty());
        // After the interval, a change goes out at once.
        let out = report.on_event(read(&[("gear", speed(5))]), t0 + 11 * S);
        assert_eq!(reported(out), pairs(&[("gear", speed(5))]));
    }

    #[test]
    fn a_heartbeat_republishes_the_unchanged_value_every_max_interval() {
        let mut report = report(RawPublish {
            deadband: Some(100.0),
            max_interval: Some(60 * S),
            ..RawPublish::default()
        });
        let t0 = Instant::now();
        let wall = SystemTime::UNIX_EPOCH + 1000 * S;
        report.on_event(read(&[("fan_speed", speed(1450)), ("gear", speed(5))]), t0);
        assert_eq!(report.next_wake(), Some(t0 + 60 * S));
        // A small move is held, and goes out with the heartbeat (the live value).
        assert!(reported(report.on_event(read(&[("fan_speed", speed(1460))]), t0 + S)).is_empty());
        assert!(report.due(t0 + 59 * S, wall).is_empty());
        let beat = report.due(t0 + 60 * S, wall);
        assert_eq!(
            beat,
            [LineEvent::Values {
                device: "dust".into(),
                values: pairs(&[("fan_speed", speed(1460)), ("gear", speed(5))]),
                read_at: wall,
                origin: Origin::Heartbeat,
            }]
        );
        // The next one a full interval later, unchanged.
        assert_eq!(report.next_wake(), Some(t0 + 120 * S));
        let beat = report.due(t0 + 120 * S, wall);
        assert_eq!(
            reported(beat.into_iter().next()),
            pairs(&[("fan_speed", speed(1460)), ("gear", speed(5))])
        );
        // A publication starts the field's interval again.
        let out = report.on_event(read(&[("fan_speed", speed(1700))]), t0 + 130 * S);
        assert_eq!(reported(out), pairs(&[("fan_speed", speed(1700))]));
        assert_eq!(report.next_wake(), Some(t0 + 180 * S));
        let beat = report.due(t0 + 180 * S, wall);
        assert_eq!(
            reported(beat.into_iter().next()),
            pairs(&[("gear", speed(5))])
        );
        assert_eq!(report.next_wake(), Some(t0 + 190 * S));
    }

    #[test]
    fn enumerations_and_on_off_go_out_on_any_change_subject_to_min_interval() {
        let mut report = report(RawPublish {
            deadband: Some(1000.0),
            min_interval: Some(2 * S),
            ..RawPublish::default()
        });
        let t0 = Instant::now();
        let on = Value::Bool(true);
        report.on_event(read(&[("power", on.clone())]), t0);
        report.on_event(read(&[("power", Value::Bool(false))]), t0 + S);
        let flushed = report.due(t0 + 2 * S, SystemTime::UNIX_EPOCH);
        assert_eq!(
            reported(flushed.into_iter().next()),
            pairs(&[("power", Value::Bool(false))])
        );
        let out = report.on_event(read(&[("power", on.clone())]), t0 + 5 * S);
        assert_eq!(reported(out), pairs(&[("power", on.clone())]));
        assert!(reported(report.on_event(read(&[("power", on)]), t0 + 9 * S)).is_empty());
    }

    #[test]
    fn a_commands_reads_always_go_out_and_become_the_last_published() {
        let mut report = report(RawPublish {
            deadband: Some(100.0),
            min_interval: Some(10 * S),
            ..RawPublish::default()
        });
        let t0 = Instant::now();
        report.on_event(read(&[("fan_speed", speed(1000))]), t0);
        // Held back by min_interval.
        assert!(reported(report.on_event(read(&[("fan_speed", speed(1500))]), t0 + S)).is_empty());
        // A command's read-back goes out, inside the band and the interval alike.
        let back = values(Origin::Command, &[("fan_speed", speed(1510))]);
        assert_eq!(
            reported(report.on_event(back, t0 + 2 * S)),
            pairs(&[("fan_speed", speed(1510))])
        );
        // The held value is gone; the band is now measured from the read-back.
        assert_eq!(report.next_wake(), None);
        assert!(report.due(t0 + 10 * S, SystemTime::now()).is_empty());
        assert!(
            reported(report.on_event(read(&[("fan_speed", speed(1600))]), t0 + 20 * S)).is_empty()
        );
        let out = report.on_event(read(&[("fan_speed", speed(1611))]), t0 + 21 * S);
        assert_eq!(reported(out), pairs(&[("fan_speed", speed(1611))]));
    }

    #[test]
    fn a_device_back_from_offline_reports_its_first_values_at_once() {
        let mut report = report(RawPublish {
            deadband: Some(100.0),
            min_interval: Some(30 * S),
            max_interval: Some(60 * S),
            ..RawPublish::default()
        });
        let t0 = Instant::now();
        report.on_event(read(&[("fan_speed", speed(1000))]), t0);
        report.on_event(read(&[("fan_speed", speed(1200))]), t0 + S);
        let offline = LineEvent::Availability {
            device: "dust".into(),
            online: false,
        };
        assert_eq!(report.on_event(offline.clone(), t0 + 2 * S), Some(offline));
        // Nothing held, no heartbeat of a device that is away.
        assert_eq!(report.next_wake(), None);
        let online = LineEvent::Availability {
            device: "dust".into(),
            online: true,
        };
        report.on_event(online, t0 + 3 * S);
        let out = report.on_event(read(&[("fan_speed", speed(1000))]), t0 + 3 * S);
        assert_eq!(reported(out), pairs(&[("fan_speed", speed(1000))]));
    }

    #[test]
    fn a_fields_own_keys_win_over_the_devices() {
        let profile = built_in("ruiwan-dust-collector").unwrap();
        let field = profile.field("fan_speed").unwrap().clone();
        let mut with_own = field.clone();
        with_own.publish.deadband = Amount::parse("5");
        let device = PublishRule {
            deadband: Amount::parse("500"),
            ..PublishRule::default()
        };
        let rule = with_own.publish.or(device);
        assert!(!rule.moved(&speed(1000), &speed(1005)));
        assert!(rule.moved(&speed(1000), &speed(1006)));
        assert_eq!(field.publish.or(device).deadband, Amount::parse("500"));
    }
}
