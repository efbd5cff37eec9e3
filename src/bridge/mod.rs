//! The only MQTT user: state, commands, outcomes, availability, discovery and statistics.
//!
//! The decisions are the I/O-free [`core`]; this file is its thin driver. [`Bridge::run`] is
//! one task that owns the core, the MQTT client and the channels, feeds every event to the
//! core (link events from rumqttc's event loop, which runs in its own task ([`mqtt`]); line
//! events, values and command ends alike; a tick) and executes the actions it returns. Every
//! send is a non-blocking `try_*`, so line events are always consumed (polling never stops
//! because MQTT is down).

pub mod commands;
pub mod core;
pub mod discovery;
pub mod json_view;
pub mod metrics;
pub mod mqtt;
pub mod payload;
pub mod prometheus;
pub mod state;

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

use rumqttc::AsyncClient;
use tokio::sync::{mpsc, watch};

use self::core::{Action, BridgeDevice, Core, CoreSettings, Incoming};
use self::metrics::BridgeStats;
use self::mqtt::LinkEvent;
use crate::bus::{LineEvent, LineHandle, LineStats};
use crate::config::Config;
use crate::shutdown::Shutdown;

/// How often waiting commands, expiries and statistics are looked at; the bridge's heartbeat
/// is refreshed at least this often.
pub const TICK: Duration = Duration::from_millis(250);
/// How long shutdown waits for commands on the bus, and then for the Disconnect to complete.
const STOP_GRACE: Duration = Duration::from_secs(3);

/// Liveness of the bridge for the watchdog and the status file.
#[derive(Debug, Clone)]
pub struct BridgeHealth {
    /// Refreshed on every turn of the bridge loop (at least every [`TICK`]).
    pub heartbeat: watch::Receiver<Instant>,
    pub connected: watch::Receiver<bool>,
}

/// A configuration reload, as the bridge learns it: the devices (in configuration order, each
/// with the index of its line) and the running lines' handles in that order.
#[derive(Debug)]
pub struct Reconfiguration {
    pub devices: Vec<BridgeDevice>,
    pub lines: Vec<LineHandle>,
}

/// The bridge task: the core and everything it must not touch itself.
pub struct Bridge {
    core: Core,
    client: AsyncClient,
    link_rx: mpsc::Receiver<LinkEvent>,
    event_loop: tokio::task::JoinHandle<()>,
    lines: Vec<LineHandle>,
    /// Shared with the metrics endpoint, refreshed every tick.
    counters_tx: watch::Sender<BridgeStats>,
    heartbeat_tx: watch::Sender<Instant>,
    connected_tx: watch::Sender<bool>,
    /// Reloads, once [`Bridge::reconfigurations`] has been asked for.
    reconfigure_rx: Option<mpsc::Receiver<Reconfiguration>>,
    /// The running lines' statistics for the metrics endpoint (replaced by a reload).
    line_stats_tx: watch::Sender<Vec<watch::Receiver<LineStats>>>,
}

impl Bridge {
    /// The bridge for `config`'s devices on `lines` (one handle per configured line, in
    /// order), using the client made by [`mqtt::connect`]. Its event loop starts connecting
    /// at once; what it reports waits for [`Bridge::run`].
    pub fn new(
        config: &Config,
        lines: Vec<LineHandle>,
        (client, eventloop): (AsyncClient, rumqttc::EventLoop),
    ) -> (Bridge, BridgeHealth) {
        let (link_tx, link_rx) = mpsc::channel(256);
        let event_loop = mqtt::spawn_event_loop(eventloop, link_tx);
        let now = Instant::now();
        let (heartbeat_tx, heartbeat) = watch::channel(now);
        let (connected_tx, connected) = watch::channel(false);
        let line_stats_tx = watch::channel(stats_receivers(&lines)).0;
        let bridge = Bridge {
            core: Core::new(CoreSettings::from_config(config), now),
            client,
            link_rx,
            event_loop,
            lines,
            counters_tx: watch::channel(BridgeStats::default()).0,
            heartbeat_tx,
            connected_tx,
            reconfigure_rx: None,
            line_stats_tx,
        };
        (
            bridge,
            BridgeHealth {
                heartbeat,
                connected,
            },
        )
    }

    /// Runs until `shutdown` fires, then announces `offline` and disconnects.
    pub async fn run(mut self, mut events_rx: mpsc::Receiver<LineEvent>, mut shutdown: Shutdown) {
        let mut tick = tokio::time::interval(TICK);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            self.heartbeat_tx.send_replace(Instant::now());
            tokio::select! {
                _ = shutdown.fired() => break,
                Some(event) = self.link_rx.recv() => self.on_link(event),
                Some(news) = next_reconfiguration(&mut self.reconfigure_rx) => {
                    self.on_reconfigure(news);
                }
                Some(event) = events_rx.recv() => {
                    let actions = self.core.on_line_event(event, Instant::now());
                    self.execute(actions);
                }
                _ = tick.tick() => {
                    let now = Instant::now();
                    let lines = &self.lines;
                    let actions = self.core.on_tick(now, || line_stats(lines));
                    self.execute(actions);
                    self.counters_tx.send_replace(self.core.counters(now));
                }
            }
        }
        self.stop(events_rx).await;
    }

    /// Where a configuration reload tells this bridge its new devices and lines.
    pub fn reconfigurations(&mut self) -> mpsc::Sender<Reconfiguration> {
        let (tx, rx) = mpsc::channel(1);
        self.reconfigure_rx = Some(rx);
        tx
    }

    fn on_reconfigure(&mut self, news: Reconfiguration) {
        let names = news.lines.iter().map(|line| line.name.clone()).collect();
        self.line_stats_tx
            .send_replace(stats_receivers(&news.lines));
        self.lines = news.lines;
        let actions = self
            .core
            .on_reconfigure(names, news.devices, Instant::now());
        self.execute(actions);
    }

    fn on_link(&mut self, event: LinkEvent) {
        match event {
            LinkEvent::Connected { .. } => {
                let actions = self.core.on_connected();
                self.connected_tx.send_replace(true);
                self.execute(actions);
            }
            LinkEvent::Disconnected { .. } => {
                self.core.on_disconnected();
                self.connected_tx.send_replace(false);
            }
            LinkEvent::Message(publish) => {
                let actions = self.core.on_message(Incoming::of(&publish), Instant::now());
                self.execute(actions);
            }
            LinkEvent::Closed => {}
        }
    }

    /// Carries out the core's actions, reporting back what could not be done.
    fn execute(&mut self, actions: Vec<Action>) {
        let mut queue = VecDeque::from(actions);
        while let Some(action) = queue.pop_front() {
            match action {
                Action::Publish(publish) => {
                    let sent = match self.client.try_publish(
                        publish.topic.as_str(),
                        publish.qos,
                        publish.retain,
                        publish.payload.clone(),
                    ) {
                        Ok(()) => true,
                        Err(error) => {
                            tracing::warn!(%error, topic = %publish.topic, "publish dropped");
                            false
                        }
                    };
                    self.core.on_published(publish, sent);
                }
                Action::Subscribe { filter, qos } => {
                    if let Err(error) = self.client.try_subscribe(&filter, qos) {
                        tracing::error!(%error, topic = %filter, "cannot subscribe");
                    }
                }
                Action::Send { line, command } => {
                    let refused = match self.lines.get(line) {
                        Some(handle) => match handle.command_tx.try_send(command) {
                            Ok(()) => None,
                            Err(mpsc::error::TrySendError::Full(command)) => Some((command, true)),
                            Err(mpsc::error::TrySendError::Closed(command)) => {
                                Some((command, false))
                            }
                        },
                        None => Some((command, false)),
                    };
                    if let Some((command, full)) = refused {
                        queue.extend(self.core.on_send_failed(command, full, Instant::now()));
                    }
                }
            }
        }
    }

    /// Renders the Prometheus text for the metrics endpoint from live line statistics (of the
    /// lines running now, reloads included) and the bridge's counters (refreshed every tick).
    pub fn metrics_renderer(&self) -> prometheus::Render {
        let lines = self.line_stats_tx.subscribe();
        let counters = self.counters_tx.subscribe();
        Arc::new(move || {
            let stats: Vec<LineStats> = lines
                .borrow()
                .iter()
                .map(|rx| rx.borrow().clone())
                .collect();
            let bridge = counters.borrow().clone();
            metrics::prometheus_text(&stats, &bridge)
        })
    }

    async fn stop(mut self, mut events_rx: mpsc::Receiver<LineEvent>) {
        // Commands already on the bus finish there (the lines complete their transaction):
        // report them if they do so quickly.
        let deadline = tokio::time::Instant::now() + STOP_GRACE;
        while self.core.commands_on_bus() > 0 {
            match tokio::time::timeout_at(deadline, events_rx.recv()).await {
                Ok(Some(event)) => {
                    let actions = self.core.on_line_event(event, Instant::now());
                    self.execute(actions);
                }
                _ => break,
            }
        }
        let actions = self.core.on_stop();
        self.execute(actions);
        if self.core.is_connected() {
            if let Err(error) = self.client.try_disconnect() {
                tracing::warn!(%error, "cannot queue the MQTT disconnect");
            }
            // Its own bound: the event loop waits up to its close grace for the broker.
            let closed = tokio::time::timeout(STOP_GRACE, async {
                while let Some(event) = self.link_rx.recv().await {
                    if matches!(event, LinkEvent::Closed) {
                        break;
                    }
                }
            })
            .await;
            if closed.is_err() {
                tracing::warn!("MQTT disconnect did not complete in time");
            }
        }
        self.event_loop.abort();
        tracing::info!("bridge stopped");
    }
}

/// The next reload, or never when nobody can send one.
async fn next_reconfiguration(
    rx: &mut Option<mpsc::Receiver<Reconfiguration>>,
) -> Option<Reconfiguration> {
    if let Some(receiver) = rx {
        if let Some(news) = receiver.recv().await {
            return Some(news);
        }
        *rx = None;
    }
    std::future::pending().await
}

/// Where each line's statistics can be read.
fn stats_receivers(lines: &[LineHandle]) -> Vec<watch::Receiver<LineStats>> {
    lines.iter().map(|line| line.stats_rx.clone()).collect()
}

/// The current statistics of every line.
fn line_stats(lines: &[LineHandle]) -> Vec<LineStats> {
    lines
        .iter()
        .map(|line| line.stats_rx.borrow().clone())
        .collect()
}
