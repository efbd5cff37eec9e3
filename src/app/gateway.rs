//! The gateway's wiring: the lines, the bridge, the Sparkplug node, health and the console\nstarted from a checked configuration, reloaded on SIGHUP and stopped in order.

use super::{reload, signals};
use crate::bridge::driver::connection;
use crate::bridge::observers::plant_view::PlantView;
use crate::bridge::{self, Bridge, BridgeHealth};
use crate::bus::{FrameRecorders, LineEvent, LineHandle, LineStats};
use crate::config::{self, Config};
use crate::health;
use crate::sparkplug::{self, NodeLinks};
use crate::web;
use anyhow::Context as _;
use rtu2mqtt_modbus::frame_log::FrameLog;
use rtu2mqtt_modbus::live_frames::LiveFrames;
use std::path::Path;
use std::process::ExitCode;
use std::time::Duration;
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio_util::sync::CancellationToken;

/// Line events waiting for the bridge (the bridge consumes them at once; this absorbs bursts).
const LINE_EVENTS: usize = 1024;
/// How often the bridge loop promises to turn: it beats every tick; four ticks leave room for
/// a busy machine.
const BRIDGE_MAX_QUIET: Duration = bridge::TICK.saturating_mul(4);
/// Line events the Sparkplug node may fall behind by before it misses some (and rebirths).
const SPARKPLUG_EVENTS: usize = 1024;
/// Commands from Sparkplug hosts, and their reports, in flight between the node and the bridge.
const SPARKPLUG_COMMANDS: usize = 64;
/// Replayed history records on their way to the Sparkplug node (the replay waits when full).
const SPARKPLUG_REPLAYED: usize = 1024;
/// How long the Sparkplug node gets to publish its NDEATH after the bridge has stopped.
const SPARKPLUG_STOP_GRACE: Duration = Duration::from_secs(5);

/// The console's commands and refreshes on their way into the bridge; more are refused with
/// "busy" until it has taken some.
const CONSOLE_MESSAGES: usize = 64;

/// What a caller gets once everything has started.
#[derive(Debug, Clone)]
pub struct Running {
    /// One handle per configured line (statistics with heartbeats, command queues), as started.
    pub lines: Vec<LineHandle>,
    /// Every running line's statistics, following configuration reloads (the watchdog).
    pub line_stats: tokio::sync::watch::Receiver<Vec<tokio::sync::watch::Receiver<LineStats>>>,
    /// The bridge's heartbeat and connection state.
    pub bridge: BridgeHealth,
}

/// Optional observers of [`run_gateway`].
#[derive(Debug, Default)]
pub struct Hooks {
    /// Receives [`Running`] once the lines and the bridge are started (systemd `READY=1`,
    /// the watchdog, tests).
    pub ready_tx: Option<oneshot::Sender<Running>>,
    /// Where reloads come from (SIGHUP for `run`); none: the configuration is never reloaded.
    pub reload: Option<reload::ReloadSource>,
    /// A socket already bound for the console at `web.listen` (the demo holds a free port
    /// until the gateway takes it); none: the gateway binds `web.listen` itself.
    pub console_socket: Option<std::net::TcpListener>,
}

/// Runs the gateway described by `config` until `shutdown` fires: the lines finish their
/// transaction on the wire, the bridge publishes `offline` and disconnects.
pub async fn run_gateway(
    mut config: Config,
    shutdown: CancellationToken,
    hooks: Hooks,
) -> anyhow::Result<()> {
    for warning in &config.warnings {
        tracing::warn!("configuration: {warning}");
    }
    let mut recorders = FrameRecorders::default();
    if let Some(path) = &config.gateway.frame_log {
        let log = FrameLog::create(path)
            .with_context(|| format!("opening the frame log {}", path.display()))?;
        tracing::info!(path = %path.display(), "recording every frame");
        recorders.log = Some(log);
    }
    let console = config.web.is_some();
    if console {
        recorders.live = Some(LiveFrames::default());
    }
    for line in &mut config.lines {
        line.recorders = recorders.clone();
        line.console = console;
    }
    // Everything that can fail comes before the lines start: TLS files, the HTTP ports.
    let mqtt = connection::connect(&config.mqtt).context("MQTT client")?;
    let node = sparkplug::session_for(&config);
    if let Some((_, node_mqtt)) = &node {
        connection::options(node_mqtt, &node_mqtt.topics()).context("Sparkplug MQTT client")?;
    }
    let metrics_listener = match config.gateway.metrics_listen {
        Some(address) => Some(
            web::listener::Listener::bind(address, None)
                .await
                .context("the metrics endpoint (gateway.metrics_listen)")?,
        ),
        None => None,
    };
    let console_listener = match &config.web {
        Some(settings) => {
            let listener = match hooks.console_socket {
                Some(socket) => web::listener::Listener::from_std(socket, settings.tls.as_ref()),
                None => web::listener::Listener::bind(settings.listen, settings.tls.as_ref()).await,
            }
            .context("the console (web.listen)")?;
            let scheme = if settings.tls.is_some() {
                "https"
            } else {
                "http"
            };
            tracing::info!(
                address = %format!("{scheme}://{}", settings.listen),
                login = settings.token.is_some(),
                "console listening"
            );
            Some((listener, settings.clone()))
        }
        None => None,
    };

    let (events_tx, events_rx) = mpsc::channel(LINE_EVENTS);
    let lines = reload::LineSet::start(
        &config.lines,
        events_tx,
        shutdown.clone(),
        (recorders.clone(), console),
    );
    let handles = lines.handles();
    let line_stats = lines.stats();

    let (mut bridge, bridge_health) = Bridge::new(&config, handles.clone(), mqtt);
    let (events_rx, node_task) = match node {
        Some((session, node_mqtt)) => {
            let node = NodeWiring {
                session,
                mqtt: node_mqtt,
                stats_interval: config.gateway.stats_interval,
                bd_seq_store: sparkplug::core::bd_seq::BdSeqStore::for_config(&config),
                history: config.history.is_some(),
            };
            let (events_rx, task) = node.start(&mut bridge, &handles, events_rx, &shutdown);
            (events_rx, Some(task))
        }
        None => (events_rx, None),
    };
    if let Some(listener) = metrics_listener {
        tokio::spawn(web::serve_metrics(
            listener,
            bridge.figures(),
            shutdown.clone(),
        ));
    }
    let mut console_layout = None;
    if let (Some((listener, settings)), Some(frames)) = (console_listener, recorders.live) {
        let view = PlantView::new(&config.mqtt.prefix);
        bridge.publish_into(view.clone());
        let (messages, local_rx) = mpsc::channel(CONSOLE_MESSAGES);
        bridge.accept_local_messages(local_rx);
        let parts = web::ConsoleParts {
            view,
            figures: bridge.figures(),
            health: bridge_health.clone(),
            layout: {
                let (layout_tx, layout) =
                    tokio::sync::watch::channel(web::Layout::of(&config, handles.clone()));
                console_layout = Some(layout_tx);
                layout
            },
            messages,
            frames,
        };
        let console = web::Console::new(&config, settings, parts);
        tokio::spawn(web::serve(listener, console, shutdown.clone()));
    }
    let reconfigurations = bridge.reconfigurations();
    if let Some(ready_tx) = hooks.ready_tx {
        let _ = ready_tx.send(Running {
            lines: handles,
            line_stats,
            bridge: bridge_health,
        });
    }
    // The lines' owner from here on: it applies reloads until the shutdown, then hands them
    // back to be waited for.
    let reloads = tokio::spawn(reload::serve(
        lines,
        config,
        hooks.reload,
        reconfigurations,
        console_layout,
        shutdown.clone(),
    ));
    bridge.run(events_rx, shutdown).await;
    if let Some(task) = node_task {
        if tokio::time::timeout(SPARKPLUG_STOP_GRACE, task)
            .await
            .is_err()
        {
            tracing::warn!("the Sparkplug node did not stop in time");
        }
    }

    match reloads.await {
        Ok(lines) => lines.join().await,
        Err(error) => tracing::error!(%error, "the line supervisor ended abnormally"),
    }
    Ok(())
}

/// The Sparkplug edge node, ready to be wired beside the bridge.
struct NodeWiring {
    session: sparkplug::Session,
    mqtt: config::MqttSettings,
    stats_interval: Duration,
    bd_seq_store: Option<sparkplug::core::bd_seq::BdSeqStore>,
    /// `[history]` is configured: replayed records also go out as historical DDATA.
    history: bool,
}

impl NodeWiring {
    /// Starts the node: line events fanned out to the bridge and the node (the returned
    /// receiver is the bridge's), the node's commands into the bridge's command path with
    /// their reports back, line figures sampled into node metrics. The task ends after
    /// `shutdown` with the node's NDEATH.
    fn start(
        self,
        bridge: &mut Bridge,
        lines: &[LineHandle],
        events: mpsc::Receiver<LineEvent>,
        shutdown: &CancellationToken,
    ) -> (mpsc::Receiver<LineEvent>, tokio::task::JoinHandle<()>) {
        let (bridge_events_tx, bridge_events_rx) = mpsc::channel(LINE_EVENTS);
        let (node_events_tx, node_events_rx) = broadcast::channel(SPARKPLUG_EVENTS);
        tokio::spawn(fan_out(events, bridge_events_tx, node_events_tx));
        let (commands_tx, commands_rx) = mpsc::channel(SPARKPLUG_COMMANDS);
        let (reports_tx, reports_rx) = mpsc::channel(SPARKPLUG_COMMANDS);
        bridge.accept_external_commands(commands_rx, reports_tx);
        // One sample in flight: a slow node gets the next, fresher one.
        let (values_tx, values_rx) = mpsc::channel(1);
        let stats = lines.iter().map(|line| line.stats_rx.clone()).collect();
        tokio::spawn(sparkplug::core::node_metrics::feed(
            stats,
            values_tx,
            self.stats_interval,
            shutdown.clone(),
        ));
        let replayed = self.history.then(|| {
            let (replayed_tx, replayed_rx) = mpsc::channel(SPARKPLUG_REPLAYED);
            bridge.forward_replays(replayed_tx);
            replayed_rx
        });
        let links = NodeLinks {
            line_events: node_events_rx,
            commands: commands_tx,
            reports: reports_rx,
            node_values: values_rx,
            shutdown: shutdown.clone(),
            bd_seq_store: self.bd_seq_store,
            replayed,
            packet_limit: bridge.packet_limit("sparkplug", sparkplug::MAX_OUTGOING_PACKET),
        };
        let task = tokio::spawn(sparkplug::run(self.session, self.mqtt, links));
        (bridge_events_rx, task)
    }
}

/// Hands every line event to the bridge (waiting for room: it must see them all) and to the
/// Sparkplug node (never waiting: a slow node lags, notices and rebirths).
async fn fan_out(
    mut events: mpsc::Receiver<LineEvent>,
    bridge: mpsc::Sender<LineEvent>,
    node: broadcast::Sender<LineEvent>,
) {
    while let Some(event) = events.recv().await {
        // No receiver only while the node has ended: nothing to keep.
        let _ = node.send(event.clone());
        if bridge.send(event).await.is_err() {
            return;
        }
    }
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
    let keeps_history = config.history.is_some();
    runtime.block_on(async move {
        let shutdown = CancellationToken::new();
        let trigger = shutdown.clone();
        let signals = tokio::spawn(signals::stop_on_signals(trigger.clone()));
        // SIGHUP reloads; never the signal's default action (ending the process).
        let reload = match signals::hangups() {
            Ok(requests) => Some(reload::ReloadSource {
                path: path.to_path_buf(),
                requests,
            }),
            Err(error) => {
                tracing::error!(%error, "cannot handle SIGHUP: reload by restarting the service");
                None
            }
        };
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
            let history_problem = keeps_history.then(|| bridge.history_problem.clone());
            health::supervise(
                health_settings,
                running.line_stats,
                probe,
                history_problem,
                watchdog_trigger,
            )
        });
        let stopping = shutdown.clone();
        let announce_stop = tokio::spawn(async move {
            stopping.cancelled().await;
            health::notify_stopping();
        });
        let hooks = Hooks {
            ready_tx: Some(ready_tx),
            reload,
            console_socket: None,
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
