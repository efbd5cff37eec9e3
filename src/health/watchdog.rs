//! The internal watchdog thread: assesses the loops every interval, writes the status file,
//! pings systemd while healthy, and ends a process stuck past the stall limit.

use std::sync::mpsc;
use std::time::{Duration, Instant};

use tokio::sync::watch;

use super::assess::{assess, status_line, LoopSnapshot};
use super::status_file::{wall_clock_ms, write_status_file};
use super::systemd::systemd_watchdog_period;
use crate::bus::LineStats;
use crate::config::HealthSettings;
use tokio_util::sync::CancellationToken;

/// The watchdog's last step when a loop is stuck (the process's exit, in production).
pub type ExitFn = Box<dyn FnOnce(i32) + Send>;

/// Exit status of a process ended by its own watchdog (EX_SOFTWARE): `Restart=on-failure` and
/// Docker's `restart: unless-stopped` both restart it.
pub const EXIT_STUCK: i32 = 70;

/// How long a stuck process gets for a clean stop before the watchdog ends it.
pub const STUCK_GRACE: Duration = Duration::from_secs(5);

/// The internal watchdog, before it runs: the loops it watches.
#[derive(Debug)]
pub struct Watchdog {
    settings: HealthSettings,
    lines: Vec<watch::Receiver<LineStats>>,
    /// The running lines after a configuration reload replaces the watched ones.
    line_set: Option<watch::Receiver<Vec<watch::Receiver<LineStats>>>>,
    mqtt: MqttProbe,
    /// Why the history journal cannot be written, with `[history]`.
    history: Option<watch::Receiver<Option<String>>>,
}

/// Where the watchdog reads the MQTT loop's life.
#[derive(Debug, Clone)]
pub struct MqttProbe {
    /// Refreshed on every turn of the loop.
    pub heartbeat: watch::Receiver<Instant>,
    pub connected: watch::Receiver<bool>,
    /// The loop's promise: it turns at least this often.
    pub max_quiet: Duration,
}

/// A running [`Watchdog`]; [`WatchdogHandle::stop`] ends it and removes the status file.
#[derive(Debug)]
pub struct WatchdogHandle {
    stop_tx: mpsc::Sender<()>,
    thread: std::thread::JoinHandle<()>,
}

impl Watchdog {
    pub fn new(settings: HealthSettings, mqtt: MqttProbe) -> Self {
        Watchdog {
            settings,
            lines: Vec::new(),
            line_set: None,
            mqtt,
            history: None,
        }
    }

    /// Judges the history journal too: while `problem` holds a cause the gateway is
    /// unhealthy (the bridge's [`crate::bridge::BridgeHealth::history_problem`]).
    pub fn watch_history(&mut self, problem: watch::Receiver<Option<String>>) {
        self.history = Some(problem);
    }

    /// Watches one more line (its [`crate::bus::LineHandle::stats_rx`]).
    pub fn watch_line(&mut self, stats_rx: watch::Receiver<LineStats>) {
        self.lines.push(stats_rx);
    }

    /// Watches the lines `line_set` holds from now on, following its changes (a reload stops
    /// and starts lines: a stopped line's statistics must not look like a stuck loop).
    pub fn follow_lines(&mut self, line_set: watch::Receiver<Vec<watch::Receiver<LineStats>>>) {
        self.lines = line_set.borrow().clone();
        self.line_set = Some(line_set);
    }

    /// Starts the watchdog thread. When a loop is stuck past the stall limit it fires
    /// `shutdown`, gives the tasks [`STUCK_GRACE`] to stop, then exits the process with
    /// [`EXIT_STUCK`].
    pub fn spawn(self, shutdown: CancellationToken) -> std::io::Result<WatchdogHandle> {
        self.spawn_with_exit(shutdown, Box::new(|code| std::process::exit(code)))
    }

    /// [`Watchdog::spawn`] with the final step given: `exit` receives [`EXIT_STUCK`] (tests
    /// observe it instead of ending the test process).
    pub fn spawn_with_exit(
        self,
        shutdown: CancellationToken,
        exit: ExitFn,
    ) -> std::io::Result<WatchdogHandle> {
        let (stop_tx, stop_rx) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("watchdog".to_string())
            .spawn(move || self.run(stop_rx, shutdown, exit))?;
        Ok(WatchdogHandle { stop_tx, thread })
    }

    fn run(mut self, stop_rx: mpsc::Receiver<()>, shutdown: CancellationToken, exit: ExitFn) {
        let systemd_period = systemd_watchdog_period();
        let interval = match systemd_period {
            Some(period) => self.settings.interval.min(period / 3),
            None => self.settings.interval,
        }
        .max(Duration::from_millis(100));
        let pid = std::process::id();
        let mut file_warned = false;
        let mut was_healthy = true;
        // The connection state's last change, as seen by this thread (to the interval).
        let mut connected = *self.mqtt.connected.borrow();
        let mut connection_changed = Instant::now();
        loop {
            if let Some(line_set) = &mut self.line_set {
                if line_set.has_changed().unwrap_or(false) {
                    self.lines = line_set.borrow_and_update().clone();
                }
            }
            let now = Instant::now();
            let connected_now = *self.mqtt.connected.borrow();
            if connected_now != connected {
                connected = connected_now;
                connection_changed = now;
            }
            let mqtt = LoopSnapshot {
                last_beat: *self.mqtt.heartbeat.borrow(),
                connected,
                connection_changed,
                max_quiet: self.mqtt.max_quiet,
            };
            let lines: Vec<LineStats> = self.lines.iter().map(|rx| rx.borrow().clone()).collect();
            let mut assessment = assess(now, wall_clock_ms(), pid, &lines, &mqtt, &self.settings);
            if let Some(history) = &self.history {
                assessment = assessment.with_history(history.borrow().as_deref());
            }
            let report = &assessment.report;
            if let Some(path) = &self.settings.status_file {
                match write_status_file(path, report) {
                    Ok(()) => file_warned = false,
                    Err(error) if !file_warned => {
                        file_warned = true;
                        // Met first when running by hand: the service's RuntimeDirectory=
                        // is what provides /run/rtu2mqtt.
                        tracing::warn!(
                            path = %path.display(),
                            %error,
                            "cannot write the status file (`rtu2mqtt health` reads it; under \
                             systemd its directory exists; by hand set \
                             RTU2MQTT__HEALTH__STATUS_FILE to another path, or to nothing to \
                             write none)"
                        );
                    }
                    Err(_) => {}
                }
            }
            if assessment.loops_alive {
                if systemd_period.is_some() {
                    let status = status_line(report);
                    let _ = sd_notify::notify(
                        false,
                        &[
                            sd_notify::NotifyState::Watchdog,
                            sd_notify::NotifyState::Status(&status),
                        ],
                    );
                }
                if !was_healthy {
                    tracing::info!("all loops alive again");
                }
            } else if was_healthy {
                tracing::error!(problems = %report.problems.join("; "), "a loop is not alive: systemd watchdog pings withheld");
            }
            was_healthy = assessment.loops_alive;

            if !assessment.stuck.is_empty() {
                tracing::error!(
                    stuck = %assessment.stuck.join(", "),
                    limit = %humantime::format_duration(self.settings.stall_limit),
                    "stuck longer than the stall limit: stopping the process"
                );
                shutdown.cancel();
                // The runtime may be the thing that is stuck: give a clean stop a moment, then
                // end regardless so that a supervisor restarts us.
                let _ = stop_rx.recv_timeout(STUCK_GRACE);
                exit(EXIT_STUCK);
                return;
            }

            match stop_rx.recv_timeout(interval) {
                Err(mpsc::RecvTimeoutError::Timeout) => continue,
                Ok(()) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
            }
        }
        if let Some(path) = &self.settings.status_file {
            let _ = std::fs::remove_file(path);
        }
    }
}

impl WatchdogHandle {
    /// Ends the watchdog thread and removes the status file: a stopped daemon is not healthy.
    pub fn stop(self) {
        let _ = self.stop_tx.send(());
        let _ = self.thread.join();
    }
}
