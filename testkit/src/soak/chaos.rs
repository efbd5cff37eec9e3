//! The random events of a soak run, in rounds that each hold every kind once in a random
//! order (so that even a short run has each): a broker outage with the seed dust collector's
//! alarms walked through new states meanwhile, a TCP line whose devices stop answering, a
//! SIGHUP reload with a changed line, and a journal outage (its tmpfs full during a broker
//! outage, room again before the broker is back). MQTT commands go out all along while the
//! broker is there.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::Rng;
use rtu2mqtt_sim::{self as sim, Occurrence};

use super::observer::{alarm_states, Observer};
use super::rig::{tcp_dust_collectors, Rig};
use crate::{Mosquitto, SmallDisk};

/// Each alarm state is held for two polls of the dust collector's block (1 s apart), and a
/// little more for a machine under load.
const HOLD: Duration = Duration::from_millis(2500);
/// One command every so often while the broker is there.
const COMMAND_GAP: Duration = Duration::from_secs(2);

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Event {
    BrokerOutage,
    DeviceDropout,
    Reload,
    JournalOutage,
}

/// How many of each were made, and the alarm states each broker outage walked through.
#[derive(Debug, Default, Clone)]
pub struct Counts {
    pub broker_outages: u64,
    pub journal_outages: u64,
    pub dropouts: u64,
    pub reloads: u64,
    pub commands: u64,
    pub outage_states: Vec<Vec<u16>>,
}

/// Outages whose states all came on the history topic, in order, of all; and those that did
/// not, with what was expected.
#[derive(Debug, Default, Clone)]
pub struct OutageCheck {
    pub passed: usize,
    pub total: usize,
    pub missing: Vec<Vec<u16>>,
}

impl Counts {
    pub fn checked_outages(&self, history: &[serde_json::Value]) -> OutageCheck {
        let states = alarm_states(history);
        let mut check = OutageCheck {
            total: self.outage_states.len(),
            ..OutageCheck::default()
        };
        for expected in &self.outage_states {
            if states
                .windows(expected.len())
                .any(|window| window == expected.as_slice())
            {
                check.passed += 1;
            } else {
                check.missing.push(expected.clone());
            }
        }
        check
    }
}

/// The schedule and what it acts on.
pub struct Chaos<'a> {
    rig: &'a Rig,
    observer: &'a Observer,
    broker: &'a mut Mosquitto,
    config_path: &'a Path,
    journal: &'a Path,
    pid: u32,
    disk: Option<&'a SmallDisk>,
    round: Vec<Event>,
    counts: Counts,
    alarms: u16,
    /// The response timeout of the first TCP line, which each reload changes.
    timeout_ms: u64,
    /// A run of minutes: shorter events, closer together, so that each kind comes.
    short: bool,
}

impl<'a> Chaos<'a> {
    pub fn new(
        rig: &'a Rig,
        observer: &'a Observer,
        broker: &'a mut Mosquitto,
        (config_path, journal): (&'a Path, &'a Path),
        pid: u32,
        disk: Option<&'a SmallDisk>,
        short: bool,
    ) -> Self {
        Chaos {
            rig,
            observer,
            broker,
            config_path,
            journal,
            pid,
            disk,
            round: Vec::new(),
            counts: Counts::default(),
            alarms: 0,
            timeout_ms: 500,
            short,
        }
    }

    pub fn counts(&self) -> Counts {
        self.counts.clone()
    }

    /// A quiet spell with commands, then the next event of the round (a new round when it is
    /// done); nothing starts that could not end before `until`.
    pub async fn next_event(&mut self, rng: &mut StdRng, until: Instant) {
        if self.round.is_empty() {
            self.round = vec![
                Event::BrokerOutage,
                Event::DeviceDropout,
                Event::Reload,
                Event::JournalOutage,
            ];
            self.round.shuffle(rng);
        }
        let quiet = Duration::from_secs(if self.short {
            rng.gen_range(3..=8)
        } else {
            rng.gen_range(10..=40)
        });
        self.commands_for(rng, (Instant::now() + quiet).min(until))
            .await;
        // The longest event: a journal outage of 8 + 4 s, and the replay after it.
        if Instant::now() + Duration::from_secs(20) > until {
            self.commands_for(rng, until).await;
            return;
        }
        match self.round.pop() {
            Some(Event::BrokerOutage) => {
                let seconds = if self.short {
                    rng.gen_range(8..=12)
                } else {
                    rng.gen_range(8..=20)
                };
                self.broker_outage(rng, Duration::from_secs(seconds), None)
                    .await;
            }
            Some(Event::JournalOutage) => {
                if let Some(disk) = self.disk {
                    let filler = disk.fill();
                    self.counts.journal_outages += 1;
                    self.broker_outage(rng, Duration::from_secs(12), Some(filler))
                        .await;
                }
            }
            Some(Event::DeviceDropout) => {
                let line = rng.gen_range(0..self.rig.tcp.len());
                let faults = self.rig.tcp[line].tcp_faults();
                faults.update(|f| f.never_answer = Occurrence::probability(1.0));
                self.counts.dropouts += 1;
                let seconds = if self.short {
                    rng.gen_range(8..=12)
                } else {
                    rng.gen_range(10..=30)
                };
                self.commands_for(rng, Instant::now() + Duration::from_secs(seconds))
                    .await;
                faults.clear();
            }
            Some(Event::Reload) => self.reload(),
            None => {}
        }
    }

    /// The broker killed for `length` while the dust collector's alarms take new states; with
    /// `filler`, the journal's disk is full until the last 4 s of it.
    async fn broker_outage(&mut self, rng: &mut StdRng, length: Duration, filler: Option<PathBuf>) {
        self.broker.kill();
        self.counts.broker_outages += 1;
        let began = Instant::now();
        let mut states = Vec::new();
        let mut filler = filler;
        while began.elapsed() + HOLD <= length {
            let mut next = self.alarms;
            while next == self.alarms {
                next = rng.gen_range(0..8);
            }
            self.alarms = next;
            sim::lock(&self.rig.seed.dust_collector).set_alarms(next);
            states.push(next);
            tokio::time::sleep(HOLD).await;
            if began.elapsed() + Duration::from_secs(4) >= length {
                if let Some(path) = filler.take() {
                    let _ = std::fs::remove_file(path);
                }
            }
        }
        if let Some(path) = filler.take() {
            let _ = std::fs::remove_file(path);
        }
        self.counts.outage_states.push(states);
        self.broker.restart();
    }

    /// The first TCP line's response timeout changed in the configuration, and SIGHUP.
    fn reload(&mut self) {
        self.timeout_ms = if self.timeout_ms == 500 { 600 } else { 500 };
        let text = self.rig.config(self.broker, self.journal, self.timeout_ms);
        if std::fs::write(self.config_path, text).is_ok()
            && kill(Pid::from_raw(self.pid as i32), Signal::SIGHUP).is_ok()
        {
            self.counts.reloads += 1;
        }
    }

    /// Sends a `gear` command to a random dust collector on a TCP line every
    /// [`COMMAND_GAP`] until `until`.
    pub async fn commands_for(&mut self, rng: &mut StdRng, until: Instant) {
        let devices = tcp_dust_collectors();
        while Instant::now() < until {
            if let Some(device) = devices.choose(rng) {
                let gear = rng.gen_range(1..=10);
                if self
                    .observer
                    .command(&format!("plant/{device}/gear/set"), &gear.to_string())
                {
                    self.counts.commands += 1;
                }
            }
            let left = until.saturating_duration_since(Instant::now());
            tokio::time::sleep(COMMAND_GAP.min(left)).await;
        }
    }
}
