//! Wiring for the daemon: load and validate the config, start one bus task per line and the
//! MQTT bridge, run until SIGTERM/SIGINT, then stop cleanly. [`run_gateway`] is the library
//! entry point that `run`, the demo and the end-to-end tests share.

pub mod check;
pub mod demo;
pub mod logging;
pub mod read;
pub mod scan;
pub mod simulate;

use std::path::Path;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context as _;
use tokio::sync::{mpsc, oneshot};

use crate::bridge::{self, mqtt, prometheus, Bridge, BridgeHealth};
use crate::bus::{spawn_line, LineHandle};
use crate::config::{self, Config};
use crate::health;
use crate::rtu::frame_log::FrameLog;
use crate::shutdown::{self, Shutdown};

/// Line events waiting for the bridge (the bridge consumes them at once; this absorbs bursts).
const LINE_EVENTS: usize = 1024;
/// How often the bridge loop promises to turn: it beats every tick; four ticks leave room for
/// a busy machine.
const BRIDGE_MAX_QUIET: Duration = bridge::TICK.saturating_mul(4);
/// How long the lines get to finish their transaction after the bridge has stopped.
const LINE_STOP_GRACE: Duration = Duration::from_secs(5);

/// What a caller gets once everything has started.
#[derive(Debug, Clone)]
pub struct Running {
    /// One handle per configured line (statistics with heartbeats, command queues).
    pub lines: Vec<LineHandle>,
    /// The bridge's heartbeat and connection state.
    pub bridge: BridgeHealth,
}

/// Optional observers of [`run_gateway`].
#[derive(Debug, Default)]
pub struct Hooks {
    /// Receives [`Running`] once the lines and the bridge are started (systemd `READY=1`,
    /// the watchdog, tests).
    pub ready_tx: Option<oneshot::Sender<Running>>,
}

/// Runs the gateway described by `config` until `shutdown` fires: the lines finish their
/// transaction on the wire, the bridge publishes `offline` and disconnects.
pub async fn run_gateway(
    mut config: Config,
    shutdown: Shutdown,
    hooks: Hooks,
) -> anyhow::Result<()> {
    for warning in &config.warnings {
        tracing::warn!("configuration: {warning}");
    }
    if let Some(path) = &config.gateway.frame_log {
        let log = FrameLog::create(path)
            .with_context(|| format!("opening the frame log {}", path.display()))?;
        tracing::info!(path = %path.display(), "recording every frame");
        for line in &mut config.lines {
            line.frame_log = Some(log.clone());
        }
    }
    // Everything that can fail comes before the lines start: TLS files, the metrics port.
    let mqtt = mqtt::connect(&config.mqtt).context("MQTT client")?;
    let metrics_listener = match config.gateway.metrics_listen {
        Some(address) => Some(
            prometheus::bind(address)
                .await
                .with_context(|| format!("metrics endpoint on {address}"))?,
        ),
        None => None,
    };

    let (events_tx, events_rx) = mpsc::channel(LINE_EVENTS);
    let mut handles = Vec::new();
    let mut line_tasks = Vec::new();
    for spec in &config.lines {
        tracing::info!(line = %spec.name, port = %spec.serial.path, devices = spec.devices.len(), "starting line");
        let (handle, task) = spawn_line(spec.clone(), events_tx.clone(), shutdown.clone());
        handles.push(handle);
        line_tasks.push(task);
    }
    drop(events_tx);

    let (bridge, bridge_health) = Bridge::new(&config, handles.clone(), mqtt);
    if let Some(listener) = metrics_listener {
        let render = bridge.metrics_renderer();
        tokio::spawn(prometheus::serve(listener, render, shutdown.clone()));
    }
    if let Some(ready_tx) = hooks.ready_tx {
        let _ = ready_tx.send(Running {
            lines: handles,
            bridge: bridge_health,
        });
    }
    bridge.run(events_rx, shutdown).await;

    for task in line_tasks {
        match tokio::time::timeout(LINE_STOP_GRACE, task).await {
            Ok(Ok(())) => {}
            Ok(Err(error)) => tracing::error!(%error, "a line task ended abnormally"),
            Err(_) => tracing::warn!("a line did not stop in time"),
        }
    }
    Ok(())
}

/// `rtu2mqtt run`.
pub fn run(path: &Path) -> anyhow::Result<ExitCode> {
    let config = match config::load(path) {
        Ok(config) => config,
        Err(problems) => {
            eprintln!("rtu2mqtt: {}: {problems}", path.display());
            return Ok(ExitCode::FAILURE);
        }
    };
    // A few timers and sockets: one thread does it with less CPU and memory than a pool.
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let health_settings = config.health.clone();
    runtime.block_on(async move {
        let (trigger, shutdown) = shutdown::channel();
        let signals = tokio::spawn(stop_on_signals(trigger.clone()));
        // READY=1 and the watchdog once the lines and the bridge run; STOPPING=1 on shutdown.
        let (ready_tx, ready_rx) = oneshot::channel::<Running>();
        let watchdog_trigger = trigger.clone();
        let supervision = tokio::spawn(async move {
            let running = ready_rx.await.ok()?;
            let bridge = &running.bridge;
            health::first_connect_attempt(&bridge.connected, health::FIRST_CONNECT_WAIT).await;
            let probe = health::MqttProbe {
                heartbeat: bridge.heartbeat.clone(),
                connected: bridge.connected.clone(),
                max_quiet: BRIDGE_MAX_QUIET,
            };
            health::supervise(health_settings, &running.lines, probe, watchdog_trigger)
        });
        let mut stopping = shutdown.clone();
        let announce_stop = tokio::spawn(async move {
            stopping.fired().await;
            health::notify_stopping();
        });
        let hooks = Hooks {
            ready_tx: Some(ready_tx),
        };
        let result = run_gateway(config, shutdown, hooks).await;
        announce_stop.abort();
        signals.abort();
        if let Ok(Some(watchdog)) = supervision.await {
            watchdog.stop();
        }
        result
    })?;
    tracing::info!("stopped");
    Ok(ExitCode::SUCCESS)
}

/// SIGTERM or SIGINT fires the shutdown; a second one ends the process at once.
pub(crate) async fn stop_on_signals(trigger: shutdown::ShutdownTrigger) {
    use tokio::signal::unix::{signal, SignalKind};
    let (Ok(mut terminate), Ok(mut interrupt)) = (
        signal(SignalKind::terminate()),
        signal(SignalKind::interrupt()),
    ) else {
        tracing::error!("cannot install signal handlers: stop with SIGKILL");
        return;
    };
    tokio::select! {
        _ = terminate.recv() => tracing::info!("SIGTERM: stopping"),
        _ = interrupt.recv() => tracing::info!("SIGINT: stopping"),
    }
    trigger.fire();
    tokio::select! {
        _ = terminate.recv() => {},
        _ = interrupt.recv() => {},
    }
    tracing::warn!("second signal: exiting without a clean stop");
    std::process::exit(130);
}
