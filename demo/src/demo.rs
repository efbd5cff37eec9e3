//! `rtu2mqtt-demo`: the seed plant with no hardware. The three simulated seed devices are
//! served on two virtual serial lines (pseudo-terminals: line A 9600 8N1 with the dust collector
//! at 1 and the air shower at 0x81, line B with the valve's 8E1 settings at 1), the embedded
//! MQTT broker listens on 127.0.0.1 (unless `--broker` names one), and the very gateway of
//! `rtu2mqtt run` drives them with the example configuration. The demo then watches the broker
//! like any user would and shows what the gateway publishes: a table redrawn in place on a
//! terminal (`view`), or log lines paced so that command results stay readable with `--log` or
//! when stdout is not a terminal. Ctrl-C (or SIGTERM) stops everything cleanly with exit
//! status 0; on a broker the demo did not start, everything it left retained there is cleared.
//!
//! Parts: `endpoint` (which broker and prefix), `plant` (the configuration), `watch` (the
//! subscription), `view` (messages to per-device state), `hints` (the words and example
//! commands), `screen` and `terminal` (the live table), `capture` (the log under it), `pacing`
//! (log mode's rhythm), `cleanup` (leaving a foreign broker clean); this file runs them
//! together.

mod capture;
mod cleanup;
mod endpoint;
mod hints;
mod pacing;
mod plant;
mod screen;
mod terminal;
mod view;
mod watch;

use std::collections::VecDeque;
use std::io::{IsTerminal, Write};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use tokio::sync::mpsc;

use self::capture::StderrCapture;
use self::cleanup::{clear_retained, Leftovers};
use self::endpoint::{choose_broker, choose_placement, EMBEDDED_ORIGIN};
use self::hints::{introduction, table_hints};
use self::pacing::LogPacing;
use self::plant::{console_socket, demo_config, example_prefix};
use self::screen::{compose_screen, keep_log_line, remember_log_line};
use self::terminal::terminal_size;
use self::view::{log_line, DeviceOutline, PlantView};
use self::watch::watch_broker;
use rtu2mqtt::app::{run_gateway, Hooks};
use rtu2mqtt_sim::{lock, SeedPlant};
use tokio_util::sync::CancellationToken;

/// How long the gateway gets to stop (finish its transaction, publish offline).
const STOP_GRACE: Duration = Duration::from_secs(10);

/// The table is redrawn at most this often.
const REDRAW: Duration = Duration::from_millis(200);

/// Beyond a device's start-up delay, how long its first polls may take before an `offline`
/// means offline (a device that needs split reads retries its first blocks).
const FIRST_POLLS: Duration = Duration::from_secs(10);

/// `rtu2mqtt-demo`.
pub fn demo(broker: Option<String>, port: u16, log: bool) -> anyhow::Result<ExitCode> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(run_demo(broker, port, log))
}

async fn run_demo(broker: Option<String>, port: u16, log: bool) -> anyhow::Result<ExitCode> {
    let endpoint = choose_broker(broker, port)?;
    let placement = choose_placement(&endpoint, &example_prefix()?).await?;
    let plant = SeedPlant::spawn(true).context("serving the simulated devices on ptys")?;
    // A running plant: the dust collector is switched on, so its settings can be changed
    // (in standby it acknowledges writes and ignores them, as the real one does).
    lock(&plant.dust_collector).set_power(true);
    let mut config = demo_config(
        &endpoint,
        &placement,
        &plant.line_a.path(),
        &plant.line_b.path(),
    )?;
    let console_socket = console_socket(&mut config);

    let table = !log && std::io::stdout().is_terminal();
    let devices = config.lines.iter().flat_map(|line| &line.devices);
    let outlines: Vec<DeviceOutline> = devices
        .clone()
        .map(|device| DeviceOutline {
            name: device.name.clone(),
            fields: device
                .profile
                .fields()
                .iter()
                .map(|field| (field.name.clone(), field.ha.entity_category.is_some()))
                .collect(),
            starting_allowance: device.profile.limits().startup_delay + FIRST_POLLS,
        })
        .collect();
    let mut view = PlantView::new(config.mqtt.topics(), &outlines);
    let mut pacing = LogPacing::default();
    // On a broker others use, whatever the demo leaves retained is cleared when it stops.
    let mut leftovers = (endpoint.origin != EMBEDDED_ORIGIN).then(|| {
        let names: Vec<String> = devices.map(|device| device.name.clone()).collect();
        Leftovers::new(
            &config.mqtt.prefix,
            &config.mqtt.client_id,
            &names,
            config
                .mqtt
                .discovery
                .then_some(config.mqtt.discovery_prefix.as_str()),
        )
    });
    let mut intro = introduction(&endpoint, &config);
    let mut hints = table_hints(&endpoint, &config);
    if let Some(notice) = &placement.notice {
        intro = format!("{notice}\n{intro}");
        hints = format!("{notice}\n{hints}");
    }

    let shutdown = CancellationToken::new();

    let trigger = shutdown.clone();
    let signals = tokio::spawn(rtu2mqtt::app::signals::stop_on_signals(trigger.clone()));
    let (messages_tx, mut messages_rx) = mpsc::channel(1024);
    let mut filters = vec![format!("{}/#", config.mqtt.prefix)];
    filters.extend(leftovers.as_ref().and_then(Leftovers::discovery_filter));
    let watcher = tokio::spawn(watch_broker(
        endpoint.clone(),
        filters,
        messages_tx,
        shutdown.clone(),
    ));

    let (log_tx, mut log_rx) = mpsc::unbounded_channel();
    let capture = if table {
        match StderrCapture::start(log_tx) {
            Ok(capture) => Some(capture),
            Err(error) => {
                tracing::warn!(%error, "cannot capture the log under the table");
                None
            }
        }
    } else {
        drop(log_tx);
        None
    };
    let mut stdout = std::io::stdout();
    // A closed stdout (`rtu2mqtt-demo --log | head`) ends the demo cleanly instead of a panic
    // in println!.
    if !table && writeln!(stdout, "{intro}").is_err() {
        trigger.cancel();
    }

    let hooks = Hooks {
        console_socket,
        ..Hooks::default()
    };
    let mut gateway = tokio::spawn(run_gateway(config, shutdown.clone(), hooks));
    let started = Instant::now();
    let mut recent_log: VecDeque<String> = VecDeque::new();
    let mut dirty = true;
    let mut marked_on_screen = false;
    let mut redraw = tokio::time::interval(REDRAW);
    redraw.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    if table {
        let _ = write!(stdout, "\x1b[2J");
    }
    let stopping = shutdown.clone();
    let gateway_result = loop {
        tokio::select! {
            _ = stopping.cancelled() => break None,
            result = &mut gateway => break Some(result),
            Some(seen) = messages_rx.recv() => {
                if let Some(leftovers) = &mut leftovers {
                    leftovers.note(&seen.topic);
                }
                let now = started.elapsed();
                if let Some(change) = view.apply_at(&seen.topic, &seen.payload, seen.retained, now) {
                    if table {
                        dirty = true;
                    } else if let Some(line) = pacing.on_change(now, &change) {
                        if writeln!(stdout, "{line}").is_err() {
                            trigger.cancel();
                        }
                    }
                }
            }
            Some(line) = log_rx.recv() => {
                if keep_log_line(&line) {
                    remember_log_line(&mut recent_log, line);
                    dirty = true;
                }
            }
            _ = redraw.tick() => {
                let now = started.elapsed();
                let mut lines: Vec<String> = view
                    .expired_starts(now)
                    .iter()
                    .map(|change| log_line(now, change))
                    .collect();
                dirty |= !lines.is_empty();
                if table {
                    let marked = view.highlights_at(now);
                    if dirty || marked || marked_on_screen {
                        dirty = false;
                        marked_on_screen = marked;
                        let header = format!(
                            "rtu2mqtt-demo: {} fields published, {}s",
                            view.published_fields(),
                            now.as_secs()
                        );
                        let screen =
                            compose_screen(&view, &header, &hints, &recent_log, terminal_size(), now);
                        let _ = stdout.write_all(screen.as_bytes());
                        let _ = stdout.flush();
                    }
                } else {
                    lines.extend(pacing.due(now));
                    if lines.iter().any(|line| writeln!(stdout, "{line}").is_err()) {
                        trigger.cancel();
                    }
                }
            }
        }
    };
    drop(capture);

    let outcome = match gateway_result {
        // The gateway ended by itself: that is an error unless a shutdown asked for it.
        Some(result) => result.context("the gateway task failed")?.and_then(|()| {
            if shutdown.is_cancelled() {
                Ok(())
            } else {
                Err(anyhow::anyhow!("the gateway stopped unexpectedly"))
            }
        }),
        None => match tokio::time::timeout(STOP_GRACE, gateway).await {
            Ok(result) => result.context("the gateway task failed")?,
            Err(_) => Err(anyhow::anyhow!(
                "the gateway did not stop within {STOP_GRACE:?}"
            )),
        },
    };
    trigger.cancel();
    let _ = watcher.await;
    signals.abort();
    drop(plant);
    if table {
        // Off the footer's row.
        let _ = writeln!(stdout);
    } else {
        for line in pacing.summary(started.elapsed()) {
            let _ = writeln!(stdout, "{line}");
        }
    }
    if let Some(leftovers) = &leftovers {
        // The gateway has stopped: nothing republishes what is cleared now.
        match clear_retained(&endpoint, &leftovers.topics()).await {
            Ok(cleared) => {
                let _ = writeln!(
                    stdout,
                    "Cleared the {cleared} retained topics the demo used on {} (values, \
                     availability, discovery).",
                    endpoint.url()
                );
            }
            Err(error) => tracing::warn!("{error:#}: the demo's retained topics may remain"),
        }
    }
    outcome?;
    let _ = writeln!(
        stdout,
        "rtu2mqtt-demo stopped after {}s ({} fields published).",
        started.elapsed().as_secs(),
        view.published_fields()
    );
    Ok(ExitCode::SUCCESS)
}
