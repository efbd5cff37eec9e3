//! The running lines and the configuration reload (SIGHUP, `systemctl reload`).
//!
//! A reload runs what `rtu2mqtt check` runs ([`config::load()`]); an invalid configuration is
//! refused with every problem logged and the running one kept. A valid one is applied per
//! line: a line whose settings and devices are unchanged keeps its task (its polling never
//! pauses); a changed line is stopped (its port released) before its new task starts; removed
//! lines stop, new ones start. Write intervals outlive the lines: every line, old or new, notes
//! its writes on the one [`WriteClock`]. The bridge then learns the new device set
//! ([`Reconfiguration`]): it clears what removed devices left retained and keeps the waiting
//! commands of devices that stay. `[mqtt]`, `[gateway]` and `[health]` are read at start only:
//! a change there is logged as needing a restart and not applied.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{mpsc, watch};

use crate::bridge::core::BridgeDevice;
use crate::bridge::Reconfiguration;
use crate::bus::scheduler::poll_phases;
use crate::bus::{
    spawn_line_in_phase, LineEvent, LineHandle, LineSpec, LineStats, Transport, WriteClock,
};
use crate::config::{self, Config};
use tokio_util::sync::CancellationToken;

/// Where a reload reads its configuration, and the requests for one.
#[derive(Debug)]
pub struct ReloadSource {
    pub path: PathBuf,
    pub requests: mpsc::Receiver<()>,
}

/// One line task and what it was started from.
struct RunningLine {
    spec: LineSpec,
    handle: LineHandle,
    task: tokio::task::JoinHandle<()>,
    stop: CancellationToken,
}

/// The line tasks of the gateway, in configuration order.
pub(super) struct LineSet {
    lines: Vec<RunningLine>,
    events_tx: mpsc::Sender<LineEvent>,
    shutdown: CancellationToken,
    /// Where the lines' frames are recorded, and whether the console reads through them: the
    /// same for a line a reload starts.
    recorders: crate::bus::FrameRecorders,
    console: bool,
    /// Every running line's statistics, for the watchdog.
    stats_tx: watch::Sender<Vec<watch::Receiver<LineStats>>>,
    /// The last writes of the fields with a write interval: a line a reload rebuilds keeps
    /// the intervals that were running.
    writes: WriteClock,
    /// The phases the TCP lines poll in (by how many there are).
    poll_phases: u32,
}

impl LineSet {
    /// Starts one task per line of `specs`.
    pub(super) fn start(
        specs: &[LineSpec],
        events_tx: mpsc::Sender<LineEvent>,
        shutdown: CancellationToken,
        (recorders, console): (crate::bus::FrameRecorders, bool),
    ) -> Self {
        let mut set = LineSet {
            lines: Vec::new(),
            events_tx,
            shutdown,
            recorders,
            console,
            stats_tx: watch::channel(Vec::new()).0,
            writes: WriteClock::new(),
            poll_phases: phases_for(specs),
        };
        for spec in specs {
            let line = set.spawn(spec.clone());
            set.lines.push(line);
        }
        set.publish_stats();
        set
    }

    pub(super) fn handles(&self) -> Vec<LineHandle> {
        self.lines.iter().map(|line| line.handle.clone()).collect()
    }

    /// Every running line's statistics, following reloads.
    pub(super) fn stats(&self) -> watch::Receiver<Vec<watch::Receiver<LineStats>>> {
        self.stats_tx.subscribe()
    }

    fn publish_stats(&self) {
        let stats = self
            .lines
            .iter()
            .map(|line| line.handle.stats_rx.clone())
            .collect();
        self.stats_tx.send_replace(stats);
    }

    fn spawn(&self, mut spec: LineSpec) -> RunningLine {
        spec.recorders = self.recorders.clone();
        spec.console = self.console;
        tracing::info!(line = %spec.name, port = %spec.serial.path, devices = spec.devices.len(), "starting line");
        let token = self.shutdown.child_token();
        let stop = token.clone();
        let events_tx = self.events_tx.clone();
        let (handle, task) = spawn_line_in_phase(
            spec.clone(),
            events_tx,
            token,
            self.writes.clone(),
            self.poll_phases,
        );
        RunningLine {
            spec,
            handle,
            task,
            stop,
        }
    }

    /// Applies `specs` line by line; returns (kept, restarted, started, stopped) counts.
    async fn apply(&mut self, specs: &[LineSpec]) -> [usize; 4] {
        self.poll_phases = phases_for(specs);
        let mut running: Vec<Option<RunningLine>> = self.lines.drain(..).map(Some).collect();
        let mut kept: Vec<Option<RunningLine>> = Vec::new();
        for spec in specs {
            let unchanged = running.iter_mut().find(|slot| {
                slot.as_ref()
                    .is_some_and(|line| same_line(&line.spec, spec))
            });
            kept.push(unchanged.and_then(Option::take));
        }
        // Lines that go or change release their port before any new task opens one.
        let stopping: Vec<RunningLine> = running.into_iter().flatten().collect();
        let restarted = stopping
            .iter()
            .filter(|old| specs.iter().any(|spec| spec.name == old.spec.name))
            .count();
        let stopped = stopping.len() - restarted;
        stop_lines(stopping).await;
        let (mut unchanged, mut spawned) = (0, 0);
        for (spec, line) in specs.iter().zip(kept) {
            let line = match line {
                Some(line) => {
                    unchanged += 1;
                    line
                }
                None => {
                    spawned += 1;
                    self.spawn(spec.clone())
                }
            };
            self.lines.push(line);
        }
        self.publish_stats();
        [
            unchanged,
            restarted,
            spawned - restarted.min(spawned),
            stopped,
        ]
    }

    /// Waits for every line to finish its transaction and stop (shutdown has fired).
    pub(super) async fn join(self) {
        stop_lines(self.lines).await;
    }
}

/// How long the lines get to finish their transaction after the bridge has stopped.
const LINE_STOP_GRACE: Duration = Duration::from_secs(5);

/// The phases the TCP lines of `specs` poll in: a few lines poll at once, a plant of them in
/// groups spread over the interval.
fn phases_for(specs: &[LineSpec]) -> u32 {
    let tcp_lines = specs
        .iter()
        .filter(|spec| matches!(spec.transport, Transport::Tcp { .. }))
        .count();
    poll_phases(tcp_lines)
}

/// Stops `lines` and waits for each (bounded by [`LINE_STOP_GRACE`]).
async fn stop_lines(lines: Vec<RunningLine>) {
    for line in &lines {
        line.stop.cancel();
    }
    for line in lines {
        match tokio::time::timeout(LINE_STOP_GRACE, line.task).await {
            Ok(Ok(())) => {}
            Ok(Err(error)) => {
                tracing::error!(%error, line = %line.spec.name, "a line task ended abnormally")
            }
            Err(_) => tracing::warn!(line = %line.spec.name, "a line did not stop in time"),
        }
    }
}

/// Whether `new` can keep running as `old`'s task: same settings, same devices in the same
/// order with the same profiles.
fn same_line(old: &LineSpec, new: &LineSpec) -> bool {
    old.name == new.name
        && old.serial == new.serial
        && old.response_timeout == new.response_timeout
        && old.retries == new.retries
        && old.offline_after == new.offline_after
        && old.echo == new.echo
        && old.broadcast_turnaround == new.broadcast_turnaround
        && old.devices.len() == new.devices.len()
        && old.devices.iter().zip(&new.devices).all(|(a, b)| {
            a.name == b.name
                && a.address == b.address
                && a.poll_interval == b.poll_interval
                && a.publish == b.publish
                && a.profile.name() == b.profile.name()
                && format!("{:?}", a.profile.read_blocks())
                    == format!("{:?}", b.profile.read_blocks())
                && format!("{:?}", a.profile.fields()) == format!("{:?}", b.profile.fields())
        })
}

/// The bridge's view of `config`'s devices.
fn bridge_devices(config: &Config) -> Vec<BridgeDevice> {
    crate::bridge::core::CoreSettings::from_config(config).devices
}

/// Serves reload requests until `shutdown` fires, then hands the lines back for the stop; the
/// console (when on) is told the plant of each configuration applied.
pub(super) async fn serve(
    mut lines: LineSet,
    mut running: Config,
    mut source: Option<ReloadSource>,
    bridge: mpsc::Sender<Reconfiguration>,
    console: Option<watch::Sender<Arc<crate::web::Layout>>>,
    shutdown: CancellationToken,
) -> LineSet {
    loop {
        let request = async {
            match source.as_mut() {
                Some(source) => source.requests.recv().await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            () = shutdown.cancelled() => return lines,
            request = request => {
                let Some(()) = request else {
                    source = None;
                    continue;
                };
                let Some(path) = source.as_ref().map(|source| source.path.clone()) else {
                    continue;
                };
                if let Some(config) = reload(&path, &running, &mut lines, &bridge).await {
                    if let Some(console) = &console {
                        console.send_replace(crate::web::Layout::of(&config, lines.handles()));
                    }
                    running = config;
                }
            }
        }
    }
}

/// One reload; the configuration now running, or None when it was refused.
async fn reload(
    path: &std::path::Path,
    running: &Config,
    lines: &mut LineSet,
    bridge: &mpsc::Sender<Reconfiguration>,
) -> Option<Config> {
    let mut config = match config::load(path) {
        Ok(config) => config,
        Err(problems) => {
            let lines = problems.lines();
            for problem in &lines {
                tracing::error!(%problem, "reload: configuration problem");
            }
            tracing::error!(
                path = %path.display(),
                "reload refused ({} problem(s)): the running configuration is kept",
                lines.len()
            );
            return None;
        }
    };
    for warning in &config.warnings {
        tracing::warn!("configuration: {warning}");
    }
    // Read at start only: say so rather than half-apply them.
    let mut restart_needed = Vec::new();
    if config.mqtt != running.mqtt {
        restart_needed.push("[mqtt]");
    }
    if config.gateway != running.gateway {
        restart_needed.push("[gateway]");
    }
    if config.health != running.health {
        restart_needed.push("[health]");
    }
    if !restart_needed.is_empty() {
        tracing::warn!(
            sections = %restart_needed.join(" "),
            "reload: these settings changed but apply only at start: restart the service to apply them (kept as they were)"
        );
        config.mqtt = running.mqtt.clone();
        config.gateway = running.gateway.clone();
        config.health = running.health.clone();
    }
    let [kept, restarted, started, stopped] = lines.apply(&config.lines).await;
    let news = Reconfiguration {
        devices: bridge_devices(&config),
        lines: lines.handles(),
    };
    if bridge.send(news).await.is_err() {
        tracing::warn!("reload: the bridge has stopped");
    }
    tracing::info!(kept, restarted, started, stopped, "configuration reloaded");
    Some(config)
}
