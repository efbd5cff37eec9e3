//! The end of a soak run: its checks, its figures (memory and descriptors at three points of
//! the run, the trend over its second half) and its counts, printed as text.

use std::collections::BTreeMap;
use std::fmt;
use std::sync::atomic::Ordering;

use std::time::Duration;

use super::chaos::{Counts, OutageCheck};
use super::rig::{ClientCounts, WireAudit};
use super::sampler::{self, Sample, Trend};

/// What the run gathered.
pub struct Inputs<'a> {
    /// How long the run was, and the seed of its schedule.
    pub duration: Duration,
    pub seed: u64,
    pub pid: u32,
    pub running: bool,
    pub panics: usize,
    pub outages: OutageCheck,
    pub counts: Counts,
    pub outcomes: BTreeMap<String, u64>,
    pub wire: WireAudit,
    pub refused: Vec<String>,
    pub clients: &'a ClientCounts,
    pub samples: Vec<Sample>,
    pub journal_on_tmpfs: bool,
}

/// One check: its name, whether it passed, what was found.
#[derive(Debug, Clone)]
pub struct Check {
    pub name: &'static str,
    pub passed: bool,
    pub found: String,
}

/// The report of a run.
#[derive(Debug, Clone)]
pub struct Report {
    pub checks: Vec<Check>,
    /// Figures at three points: (label, sample).
    pub points: Vec<(String, Sample)>,
    /// Anonymous memory, PSS and descriptors over the second half.
    pub trends: Vec<(&'static str, Option<Trend>)>,
    pub counts: Vec<(&'static str, String)>,
    pub seed: u64,
    pub duration_s: u64,
}

/// A figure may rise over the second half by its noise band or by this share of its mean,
/// whichever is larger (memory); descriptors by their noise band or one.
const MEMORY_FLOOR: f64 = 0.02;

/// Memory is judged flat only over the second half of a run this long or longer: the
/// gateway's heap grows over its first half hour under chaos (the allocator's arenas, the
/// journal's replay and the outbox's peaks reaching their high-water marks, docs/reliability.md)
/// and then stays put, so a shorter run's trend shows that settling, not a leak.
const MEMORY_JUDGED_FROM_S: u64 = 60 * 60;

impl Report {
    pub fn new(inputs: Inputs<'_>) -> Report {
        let duration_s = inputs.duration.as_secs();
        let half = duration_s as f64 / 2.0;
        let samples = &inputs.samples;
        let trends: Vec<(&'static str, Option<Trend>)> = vec![
            (
                "anonymous KiB",
                Trend::fit(samples, half, |s| s.anon_kib as f64),
            ),
            ("PSS KiB", Trend::fit(samples, half, |s| s.pss_kib as f64)),
            ("open fds", Trend::fit(samples, half, |s| s.fds as f64)),
        ];
        let flat = |index: usize, floor: &dyn Fn(&Trend) -> f64| match &trends[index].1 {
            Some(trend) => (
                trend.is_flat(floor(trend)),
                format!(
                    "rises {:+.1} over the last {:.0} s ({:+.1}/h), noise band {:.1}, mean {:.0}",
                    trend.rise, trend.window_s, trend.slope_per_hour, trend.noise, trend.mean
                ),
            ),
            None => (false, "too few samples".to_string()),
        };
        let memory_floor = |trend: &Trend| trend.mean * MEMORY_FLOOR;
        let judged = |(flat, found): (bool, String)| {
            if duration_s >= MEMORY_JUDGED_FROM_S {
                (flat, found)
            } else {
                (
                    true,
                    format!(
                        "not judged in a run under {} min (the heap settles over the first half \
                         hour): {found}",
                        MEMORY_JUDGED_FROM_S / 60
                    ),
                )
            }
        };
        let (anon_flat, anon_found) = judged(flat(0, &memory_floor));
        let (pss_flat, pss_found) = judged(flat(1, &memory_floor));
        let (fds_flat, fds_found) = flat(2, &|_| 1.0);
        let outages = &inputs.outages;
        let checks = vec![
            Check {
                name: "no panic",
                passed: inputs.panics == 0,
                found: format!("{} 'panicked' in the gateway's log", inputs.panics),
            },
            Check {
                name: "no restart",
                passed: inputs.running,
                found: format!(
                    "pid {} {}",
                    inputs.pid,
                    if inputs.running {
                        "ran from start to end"
                    } else {
                        "exited"
                    }
                ),
            },
            Check {
                name: "every value measured during an outage arrived",
                passed: outages.total > 0 && outages.missing.is_empty(),
                found: format!(
                    "{} of {} outages' alarm states on the history topic, in order{}",
                    outages.passed,
                    outages.total,
                    if outages.missing.is_empty() {
                        String::new()
                    } else {
                        format!("; missing: {:?}", outages.missing)
                    }
                ),
            },
            Check {
                name: "no refused write on any wire",
                passed: inputs.wire.writes > 0 && inputs.wire.refused_writes == 0,
                found: format!(
                    "{} writes of {} frames heard, {} refused{}",
                    inputs.wire.writes,
                    inputs.wire.frames,
                    inputs.wire.refused_writes,
                    if inputs.refused.is_empty() {
                        String::new()
                    } else {
                        format!(": {:?}", &inputs.refused[..inputs.refused.len().min(10)])
                    }
                ),
            },
            Check {
                name: "anonymous memory flat",
                passed: anon_flat,
                found: anon_found,
            },
            Check {
                name: "PSS flat",
                passed: pss_flat,
                found: pss_found,
            },
            Check {
                name: "open descriptors flat",
                passed: fds_flat,
                found: fds_found,
            },
        ];
        let points = [("1/12", 12.0), ("1/2", 2.0), ("end", 1.0)]
            .into_iter()
            .filter_map(|(label, part)| {
                let at_s = duration_s as f64 / part;
                let sample = sampler::at(samples, at_s)?;
                Some((format!("{label} ({:.0} s)", sample.at_s), sample))
            })
            .collect();
        let c = &inputs.counts;
        let clients = inputs.clients;
        let counts = vec![
            ("MQTT commands sent", c.commands.to_string()),
            ("command outcomes", format!("{:?}", inputs.outcomes)),
            ("broker outages", c.broker_outages.to_string()),
            (
                "journal outages (disk full during a broker outage)",
                if inputs.journal_on_tmpfs {
                    c.journal_outages.to_string()
                } else {
                    "none: no tmpfs could be mounted".to_string()
                },
            ),
            (
                "device drop-outs (a TCP line of 10 silent)",
                c.dropouts.to_string(),
            ),
            ("SIGHUP reloads", c.reloads.to_string()),
            (
                "line server client reads: answered / exception / failed",
                format!(
                    "{} / {} / {}",
                    clients.answers.load(Ordering::Relaxed),
                    clients.exceptions.load(Ordering::Relaxed),
                    clients.failures.load(Ordering::Relaxed)
                ),
            ),
        ];
        Report {
            checks,
            points,
            trends,
            counts,
            seed: inputs.seed,
            duration_s,
        }
    }

    pub fn passed(&self) -> bool {
        self.checks.iter().all(|check| check.passed)
    }
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "soak: {} s, seed {}", self.duration_s, self.seed)?;
        writeln!(
            f,
            "\n| point | anonymous KiB | PSS KiB | open fds | threads |"
        )?;
        writeln!(f, "| --- | ---: | ---: | ---: | ---: |")?;
        for (label, s) in &self.points {
            writeln!(
                f,
                "| {label} | {} | {} | {} | {} |",
                s.anon_kib, s.pss_kib, s.fds, s.threads
            )?;
        }
        writeln!(f, "\ntrend over the second half (least squares):")?;
        for (name, trend) in &self.trends {
            match trend {
                Some(t) => writeln!(
                    f,
                    "  {name}: {:+.2}/h, rise {:+.1} over {:.0} s, noise band ±{:.1}, mean {:.0}",
                    t.slope_per_hour, t.rise, t.window_s, t.noise, t.mean
                )?,
                None => writeln!(f, "  {name}: too few samples")?,
            }
        }
        writeln!(f, "\ncounts:")?;
        for (name, value) in &self.counts {
            writeln!(f, "  {name}: {value}")?;
        }
        writeln!(f, "\nchecks:")?;
        for check in &self.checks {
            let mark = if check.passed { "pass" } else { "FAIL" };
            writeln!(f, "  [{mark}] {}: {}", check.name, check.found)?;
        }
        write!(
            f,
            "\n{}",
            if self.passed() {
                "soak passed"
            } else {
                "soak FAILED"
            }
        )
    }
}
