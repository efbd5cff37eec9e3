//! A soak run from start to end: the broker, the rig and the gateway started, the chaos and
//! the commands run for the given time beside the sampler, a quiet end, and the report.

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rand::rngs::StdRng;
use rand::SeedableRng;
use tokio_util::sync::CancellationToken;

use super::observer::Observer;
use super::report::{self, Report};
use super::rig::{ClientCounts, ClientRead, Rig, WireAudit};
use super::sampler::Sample;
use super::{chaos, rig, sampler};
use crate::child::KillOnDrop;
use crate::Mosquitto;

/// What to run.
#[derive(Debug, Clone)]
pub struct Options {
    pub duration: Duration,
    /// The gateway binary.
    pub daemon: PathBuf,
    /// Where the configuration, the gateway's log and the samples go.
    pub out_dir: PathBuf,
    /// The seed of the random schedule (printed, so that a run can be repeated).
    pub seed: u64,
}

/// The quiet end of a run: the last outage's replay arrives before the checks.
const QUIET_END: Duration = Duration::from_secs(30);

/// Runs the soak; the report says whether every check passed.
pub async fn run(options: &Options) -> anyhow::Result<Report> {
    std::fs::create_dir_all(&options.out_dir)?;
    let started = Instant::now();
    let mut broker = Mosquitto::start();
    let rig = Rig::start().await?;
    // The journal on a tmpfs of its own, so that a journal outage is a full disk.
    let disk = crate::SmallDisk::mount("16m");
    let journal = match &disk {
        Some(disk) => disk.path().join("history"),
        None => options.out_dir.join("history"),
    };
    let _ = std::fs::remove_dir_all(options.out_dir.join("history"));
    let config_path = options.out_dir.join("soak.toml");
    std::fs::write(&config_path, rig.config(&broker, &journal, 500))?;
    let log_path = options.out_dir.join("gateway.log");
    let mut command = Command::new(&options.daemon);
    command
        .args(["run", "--config"])
        .arg(&config_path)
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log_path)?);
    let mut gateway = KillOnDrop::spawn(command)?;
    let pid = gateway.id();

    let observer = Observer::start(broker.port);
    let ready_by = Instant::now() + Duration::from_secs(60);
    while observer.lock().dust_history.is_empty() {
        anyhow::ensure!(
            Instant::now() < ready_by,
            "the gateway published no history in 60 s"
        );
        anyhow::ensure!(gateway.is_running(), "the gateway exited at start");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }

    let stop = CancellationToken::new();
    let clients = Arc::new(ClientCounts::default());
    for read in [
        // The valve's mode and opening (line-b), the dust collector's status word (line-a).
        ClientRead {
            port: rig.serve_ports[1],
            unit: 1,
            start: 0x19,
            count: 1,
        },
        ClientRead {
            port: rig.serve_ports[1],
            unit: 1,
            start: 0x74,
            count: 1,
        },
        ClientRead {
            port: rig.serve_ports[0],
            unit: 1,
            start: 0x1000,
            count: 1,
        },
    ] {
        rig::spawn_client(read, Arc::clone(&clients), stop.clone());
    }
    let samples: Arc<Mutex<Vec<Sample>>> = Arc::default();
    let sampling = spawn_sampler(
        pid,
        started,
        sample_period(options.duration),
        options.out_dir.join("samples.csv"),
        Arc::clone(&samples),
        stop.clone(),
    );

    let mut rng = StdRng::seed_from_u64(options.seed);
    let mut wire = WireAudit::default();
    let mut refused = Vec::new();
    let mut schedule = chaos::Chaos::new(
        &rig,
        &observer,
        &mut broker,
        (&config_path, &journal),
        pid,
        disk.as_ref(),
        options.duration < Duration::from_secs(600),
    );
    let chaos_until = started + options.duration.saturating_sub(QUIET_END);
    while Instant::now() < chaos_until && gateway.is_running() {
        schedule.next_event(&mut rng, chaos_until).await;
        refused.extend(wire.take(&rig.journals()));
    }
    let end = started + options.duration;
    while Instant::now() < end && gateway.is_running() {
        schedule
            .commands_for(&mut rng, end.min(Instant::now() + Duration::from_secs(5)))
            .await;
        refused.extend(wire.take(&rig.journals()));
    }
    let counts = schedule.counts();
    drop(schedule);
    refused.extend(wire.take(&rig.journals()));
    stop.cancel();
    let _ = sampling.await;

    let running = gateway.is_running();
    let log = std::fs::read_to_string(&log_path).unwrap_or_default();
    let samples = samples.lock().map(|s| s.clone()).unwrap_or_default();
    sampler::write_csv(&options.out_dir.join("samples.csv"), &samples)?;
    let seen = observer.lock();
    let report = Report::new(report::Inputs {
        duration: options.duration,
        seed: options.seed,
        pid,
        running,
        panics: log.matches("panicked").count(),
        outages: counts.checked_outages(&seen.dust_history),
        counts,
        outcomes: seen.outcomes.clone(),
        wire,
        refused,
        clients: &clients,
        samples,
        journal_on_tmpfs: disk.is_some(),
    });
    drop(seen);
    drop(gateway);
    Ok(report)
}

/// Every few seconds; more often in a short run, so that its second half has points enough.
fn sample_period(duration: Duration) -> Duration {
    if duration >= Duration::from_secs(1200) {
        Duration::from_secs(5)
    } else {
        Duration::from_secs(2)
    }
}

/// Samples the gateway every `period` into `samples` and `csv` until `stop`.
fn spawn_sampler(
    pid: u32,
    started: Instant,
    period: Duration,
    csv: PathBuf,
    samples: Arc<Mutex<Vec<Sample>>>,
    stop: CancellationToken,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        use std::io::Write as _;
        let mut file = std::fs::File::create(&csv).ok();
        if let Some(file) = &mut file {
            let _ = writeln!(file, "{}", sampler::CSV_HEADER);
        }
        let mut tick = tokio::time::interval(period);
        loop {
            tokio::select! {
                _ = stop.cancelled() => return,
                _ = tick.tick() => {}
            }
            let Some(sample) = sampler::sample(pid, started.elapsed()) else {
                return;
            };
            if let Some(file) = &mut file {
                let _ = writeln!(file, "{}", sampler::csv_line(&sample));
            }
            if let Ok(mut samples) = samples.lock() {
                samples.push(sample);
            }
        }
    })
}
