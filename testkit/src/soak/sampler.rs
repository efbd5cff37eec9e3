//! What `/proc` says about the gateway process over a soak run: anonymous memory and PSS from
//! `smaps_rollup`, open descriptors from `fd/`, sampled at a fixed period into a CSV, and the
//! least-squares trend of a figure over the last part of the run with the noise around it.

use std::io::Write as _;
use std::path::Path;
use std::time::Duration;

/// One sample of the gateway process.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Seconds since the run started.
    pub at_s: f64,
    /// `Anonymous:` of smaps_rollup: resident anonymous pages (heap, stacks).
    pub anon_kib: u64,
    /// `Pss:` of smaps_rollup: resident pages, shared ones divided among their users.
    pub pss_kib: u64,
    /// Entries of `/proc/<pid>/fd`.
    pub fds: u64,
    pub threads: u64,
}

/// `name:` in a /proc file of `key: value` lines, its first number.
fn field(text: &str, name: &str) -> Option<u64> {
    text.lines()
        .find(|line| line.starts_with(name))
        .and_then(|line| line.split_whitespace().nth(1))
        .and_then(|value| value.parse().ok())
}

/// Samples process `pid` now; None once it is gone.
pub fn sample(pid: u32, at: Duration) -> Option<Sample> {
    let rollup = std::fs::read_to_string(format!("/proc/{pid}/smaps_rollup")).ok()?;
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd")).ok()?.count() as u64;
    Some(Sample {
        at_s: at.as_secs_f64(),
        anon_kib: field(&rollup, "Anonymous:")?,
        pss_kib: field(&rollup, "Pss:")?,
        fds,
        threads: field(&status, "Threads:").unwrap_or(0),
    })
}

pub const CSV_HEADER: &str = "seconds,anonymous_kib,pss_kib,fds,threads";

pub fn csv_line(sample: &Sample) -> String {
    format!(
        "{:.1},{},{},{},{}",
        sample.at_s, sample.anon_kib, sample.pss_kib, sample.fds, sample.threads
    )
}

/// Writes every sample to `path` as CSV.
pub fn write_csv(path: &Path, samples: &[Sample]) -> std::io::Result<()> {
    let mut file = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(file, "{CSV_HEADER}")?;
    for sample in samples {
        writeln!(file, "{}", csv_line(sample))?;
    }
    file.flush()
}

/// The sample nearest to `at_s`.
pub fn at(samples: &[Sample], at_s: f64) -> Option<Sample> {
    samples
        .iter()
        .min_by(|a, b| (a.at_s - at_s).abs().total_cmp(&(b.at_s - at_s).abs()))
        .copied()
}

/// The least-squares line through a figure over a window, and how far the points stray from it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trend {
    /// Units per hour.
    pub slope_per_hour: f64,
    /// What the line rises over the whole window.
    pub rise: f64,
    /// Twice the standard deviation of the points around the line: the noise band.
    pub noise: f64,
    pub mean: f64,
    pub window_s: f64,
}

impl Trend {
    /// Fits `figure` over the samples from `from_s` on; None with fewer than three.
    pub fn fit(samples: &[Sample], from_s: f64, figure: impl Fn(&Sample) -> f64) -> Option<Trend> {
        let points: Vec<(f64, f64)> = samples
            .iter()
            .filter(|s| s.at_s >= from_s)
            .map(|s| (s.at_s, figure(s)))
            .collect();
        if points.len() < 3 {
            return None;
        }
        let n = points.len() as f64;
        let mean_t = points.iter().map(|p| p.0).sum::<f64>() / n;
        let mean = points.iter().map(|p| p.1).sum::<f64>() / n;
        let stt: f64 = points.iter().map(|p| (p.0 - mean_t).powi(2)).sum();
        let sty: f64 = points.iter().map(|p| (p.0 - mean_t) * (p.1 - mean)).sum();
        let slope = if stt > 0.0 { sty / stt } else { 0.0 };
        let residual: f64 = points
            .iter()
            .map(|p| (p.1 - (mean + slope * (p.0 - mean_t))).powi(2))
            .sum::<f64>()
            / (n - 2.0);
        let window_s = points[points.len() - 1].0 - points[0].0;
        Some(Trend {
            slope_per_hour: slope * 3600.0,
            rise: slope * window_s,
            noise: 2.0 * residual.sqrt(),
            mean,
            window_s,
        })
    }

    /// Flat: the line rises over the window no more than the noise band or `floor`, whichever
    /// is larger.
    pub fn is_flat(&self, floor: f64) -> bool {
        self.rise <= self.noise.max(floor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(figure: impl Fn(f64) -> u64) -> Vec<Sample> {
        (0..100)
            .map(|i| {
                let at_s = f64::from(i) * 10.0;
                Sample {
                    at_s,
                    anon_kib: figure(at_s),
                    pss_kib: 0,
                    fds: 0,
                    threads: 0,
                }
            })
            .collect()
    }

    #[test]
    fn a_steady_figure_with_noise_is_flat_and_a_leak_is_not() {
        let steady = samples(|t| 10_000 + if (t as u64 / 10) % 2 == 0 { 40 } else { 0 });
        let trend = Trend::fit(&steady, 0.0, |s| s.anon_kib as f64).expect("fit");
        assert!(trend.rise.abs() < 5.0, "{trend:?}");
        assert!(trend.is_flat(1.0), "{trend:?}");
        // 1 KiB a minute: 16 KiB over the window, far above its noise.
        let leak = samples(|t| 10_000 + (t / 60.0) as u64);
        let trend = Trend::fit(&leak, 0.0, |s| s.anon_kib as f64).expect("fit");
        assert!((trend.slope_per_hour - 60.0).abs() < 2.0, "{trend:?}");
        assert!(!trend.is_flat(1.0), "{trend:?}");
    }

    #[test]
    fn the_figures_of_this_process_are_read() {
        let sample = sample(std::process::id(), Duration::ZERO).expect("/proc of this process");
        assert!(
            sample.anon_kib > 0 && sample.pss_kib > 0 && sample.fds >= 3,
            "{sample:?}"
        );
    }
}
