//! `rtu2mqtt demo`: the seed plant with no hardware. The three simulated seed devices are
//! served on two virtual serial lines (pseudo-terminals: line A 9600 8N1 with the dust collector
//! at 1 and the air shower at 0x81, line B with the valve's 8E1 settings at 1), the embedded
//! MQTT broker listens on 127.0.0.1 (unless `--broker` names one), and the very gateway of
//! `rtu2mqtt run` drives them with the example configuration. The demo then watches the broker
//! like any user would and shows what the gateway publishes: a table redrawn in place on a
//! terminal ([`view`]), or one log line per change with `--log` or when stdout is not a
//! terminal. Ctrl-C (or SIGTERM) stops everything cleanly with exit status 0.

mod capture;
mod view;

use std::collections::VecDeque;
use std::io::{IsTerminal, Write};
use std::path::Path;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _};
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio::sync::mpsc;

use self::capture::StderrCapture;
use self::view::{log_line, PlantView};
use super::{run_gateway, Hooks};
use crate::broker::{self, BrokerError};
use crate::config::{self, validate, Config};
use crate::rtu::timing::{CharFormat, Parity};
use crate::shutdown::{self, Shutdown};
use crate::sim::{lock, SeedPlant};

/// The seed plant's configuration, compiled in so that the demo runs from anywhere.
const EXAMPLE_CONFIG: &str = include_str!("../../config/rtu2mqtt.toml");
/// The demo gateway's MQTT client id (and gateway id in topics).
pub const DEMO_CLIENT_ID: &str = "rtu2mqtt-demo";
/// The prefix the demo falls back to on a broker where a gateway already serves the example's.
pub const SHARED_BROKER_PREFIX: &str = "demo";
/// How long the look for running gateways waits for the broker's answer.
const PROBE_CONNECT: Duration = Duration::from_secs(5);
/// After the subscription is acknowledged, how long retained statuses may keep arriving.
const PROBE_SETTLE: Duration = Duration::from_millis(500);
/// How long the gateway gets to stop (finish its transaction, publish offline).
const STOP_GRACE: Duration = Duration::from_secs(10);
/// The table is redrawn at most this often.
const REDRAW: Duration = Duration::from_millis(200);
/// Log lines kept under the table.
const LOG_LINES_SHOWN: usize = 6;

/// [`BrokerEndpoint::origin`] of the broker the demo started itself: nobody else is on it.
const EMBEDDED_ORIGIN: &str = "embedded broker";

/// The example configuration's MQTT prefix.
fn example_prefix() -> anyhow::Result<String> {
    config::from_str(EXAMPLE_CONFIG, Path::new("."))
        .map(|config| config.mqtt.prefix)
        .map_err(|problems| anyhow::anyhow!("the example configuration: {problems}"))
}

/// Where the demo's MQTT traffic goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BrokerEndpoint {
    pub host: String,
    pub port: u16,
    /// Shown in the header: "embedded broker", "existing broker", "--broker".
    pub origin: &'static str,
}

impl BrokerEndpoint {
    pub fn url(&self) -> String {
        if self.host.contains(':') {
            format!("mqtt://[{}]:{}", self.host, self.port)
        } else {
            format!("mqtt://{}:{}", self.host, self.port)
        }
    }

    /// `mosquitto_pub`/`mosquitto_sub` options reaching it (none for the default 127.0.0.1:1883
    /// and localhost, to keep the hints short).
    fn client_options(&self) -> String {
        let host = match self.host.as_str() {
            "127.0.0.1" | "localhost" => String::new(),
            host => format!("-h {host} "),
        };
        let port = if self.port == 1883 {
            String::new()
        } else {
            format!("-p {} ", self.port)
        };
        format!("{host}{port}")
    }
}

/// `mqtt://host[:port]` (or a bare `host[:port]`) as host and port, read as the configuration's
/// `mqtt.url` is; the demo talks plain MQTT only.
pub fn parse_broker_url(url: &str) -> anyhow::Result<(String, u16)> {
    let url = if url.contains("://") {
        url.to_string()
    } else {
        format!("mqtt://{url}")
    };
    let endpoint = validate::parse_broker_url(&url).map_err(|problem| anyhow::anyhow!(problem))?;
    if endpoint.tls {
        bail!("`{url}`: the demo talks plain MQTT only (mqtt://host:port)");
    }
    Ok((endpoint.host, endpoint.port))
}

/// The given broker, the embedded one on `port`, or (when `port` is taken by something that
/// answers MQTT, as the `mosquitto` service Debian starts after installing it) that one.
fn choose_broker(broker: Option<String>, port: u16) -> anyhow::Result<BrokerEndpoint> {
    if let Some(url) = broker {
        let (host, port) = parse_broker_url(&url)?;
        return Ok(BrokerEndpoint {
            host,
            port,
            origin: "--broker",
        });
    }
    if port == 0 {
        bail!("--port 0: give the embedded broker a port (1883 by default)");
    }
    match broker::start(port) {
        Ok(embedded) => Ok(BrokerEndpoint {
            host: embedded.addr().ip().to_string(),
            port: embedded.addr().port(),
            origin: EMBEDDED_ORIGIN,
        }),
        Err(error @ BrokerError::PortInUse { .. }) => {
            let address = std::net::SocketAddr::from(([127, 0, 0, 1], port));
            if broker::mqtt_handshake(address).is_ok() {
                tracing::warn!(
                    "127.0.0.1:{port} is already served by an MQTT broker: the demo uses it \
                     (--port N starts the embedded broker on another port)"
                );
                Ok(BrokerEndpoint {
                    host: "127.0.0.1".to_string(),
                    port,
                    origin: "existing broker",
                })
            } else {
                Err(error.into())
            }
        }
        Err(error) => Err(error.into()),
    }
}

/// Where on the broker the demo publishes: the example's prefix, or another one when a gateway
/// already serves the example's prefix there.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Placement {
    pub prefix: Option<String>,
    /// Said loudly in the introduction and under the table when the prefix had to change.
    pub notice: Option<String>,
}

/// Gateway ids whose retained `<prefix>/gateway/<id>/status` is `online` on `endpoint`.
pub async fn gateways_online(
    endpoint: &BrokerEndpoint,
    prefix: &str,
) -> anyhow::Result<Vec<String>> {
    let client_id = format!("rtu2mqtt-demo-probe-{}", std::process::id());
    let mut options = MqttOptions::new(client_id, endpoint.host.clone(), endpoint.port);
    options.set_keep_alive(Duration::from_secs(30));
    options.set_clean_session(true);
    let (client, mut event_loop) = AsyncClient::new(options, 16);
    let filter = format!("{prefix}/gateway/+/status");
    let mut online = Vec::new();
    let mut settled_at: Option<tokio::time::Instant> = None;
    let connect_deadline = tokio::time::Instant::now() + PROBE_CONNECT;
    loop {
        let deadline = settled_at.unwrap_or(connect_deadline);
        let event = match tokio::time::timeout_at(deadline, event_loop.poll()).await {
            Ok(event) => event,
            Err(_) if settled_at.is_some() => break,
            Err(_) => bail!(
                "{}: no answer from the broker within {PROBE_CONNECT:?}",
                endpoint.url()
            ),
        };
        match event.with_context(|| format!("cannot reach the broker at {}", endpoint.url()))? {
            Event::Incoming(Packet::ConnAck(_)) => {
                client
                    .subscribe(filter.clone(), QoS::AtMostOnce)
                    .await
                    .context("asking the broker for gateway statuses")?;
            }
            Event::Incoming(Packet::SubAck(_)) => {
                settled_at = Some(tokio::time::Instant::now() + PROBE_SETTLE);
            }
            Event::Incoming(Packet::Publish(publish)) => {
                let id = publish
                    .topic
                    .strip_prefix(&format!("{prefix}/gateway/"))
                    .and_then(|rest| rest.strip_suffix("/status"));
                if let Some(id) = id {
                    if publish.retain && publish.payload.as_ref() == b"online" {
                        online.push(id.to_string());
                    }
                }
            }
            _ => {}
        }
    }
    let _ = client.try_disconnect();
    online.sort();
    online.dedup();
    Ok(online)
}

/// The example's prefix unless a gateway is online under it on this broker (a real one, or
/// another demo): then [`SHARED_BROKER_PREFIX`], so that the demo neither answers that gateway's
/// commands nor leaves its devices `offline` when it stops. Refuses when both are taken.
async fn choose_placement(
    endpoint: &BrokerEndpoint,
    example_prefix: &str,
) -> anyhow::Result<Placement> {
    if endpoint.origin == EMBEDDED_ORIGIN {
        return Ok(Placement {
            prefix: None,
            notice: None,
        });
    }
    let taken = gateways_online(endpoint, example_prefix).await?;
    if taken.is_empty() {
        return Ok(Placement {
            prefix: None,
            notice: None,
        });
    }
    let also_taken = gateways_online(endpoint, SHARED_BROKER_PREFIX).await?;
    if !also_taken.is_empty() {
        bail!(
            "{}: gateways are online under both `{example_prefix}/` ({}) and \
             `{SHARED_BROKER_PREFIX}/` ({}); the demo would take over their topics. Run it on \
             its embedded broker (without --broker, --port N if 1883 is taken)",
            endpoint.url(),
            taken.join(", "),
            also_taken.join(", ")
        );
    }
    let notice = format!(
        "NOTE: gateway {} is online under {example_prefix}/ on this broker: the demo uses \
         {SHARED_BROKER_PREFIX}/ instead (no Home Assistant discovery)",
        taken.join(", ")
    );
    tracing::warn!("{notice}");
    Ok(Placement {
        prefix: Some(SHARED_BROKER_PREFIX.to_string()),
        notice: Some(notice),
    })
}

/// The example configuration on the simulated lines, talking to `endpoint` as
/// [`DEMO_CLIENT_ID`], under the placement's prefix (without discovery when it moved).
pub fn demo_config(
    endpoint: &BrokerEndpoint,
    placement: &Placement,
    line_a: &Path,
    line_b: &Path,
) -> anyhow::Result<Config> {
    let mut config = config::from_str(EXAMPLE_CONFIG, Path::new("."))
        .map_err(|problems| anyhow::anyhow!("the example configuration: {problems}"))?;
    let devices = |index: usize| -> Vec<&str> {
        config.lines.get(index).map_or(Vec::new(), |line| {
            line.devices.iter().map(|d| d.name.as_str()).collect()
        })
    };
    if config.lines.len() != 2
        || devices(0) != ["dust_collector", "air_shower"]
        || devices(1) != ["valve"]
    {
        bail!("the example configuration no longer describes the seed plant the demo simulates");
    }
    config.lines[0].serial.path = line_a.to_string_lossy().into_owned();
    config.lines[1].serial.path = line_b.to_string_lossy().into_owned();
    config.mqtt.host = endpoint.host.clone();
    config.mqtt.port = endpoint.port;
    config.mqtt.tls = None;
    config.mqtt.username = None;
    config.mqtt.password = None;
    config.mqtt.client_id = DEMO_CLIENT_ID.to_string();
    if let Some(prefix) = &placement.prefix {
        // The demo's devices must not appear in a Home Assistant that watches this broker for
        // the real plant.
        config.mqtt.prefix = prefix.clone();
        config.mqtt.discovery = false;
    }
    // The pty is not a /dev/ttyUSB path any more: drop the advice about the example's paths.
    config
        .warnings
        .retain(|warning| !warning.place.ends_with(".port"));
    Ok(config)
}

/// `rtu2mqtt demo`.
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
    let config = demo_config(
        &endpoint,
        &placement,
        &plant.line_a.path(),
        &plant.line_b.path(),
    )?;

    let table = !log && std::io::stdout().is_terminal();
    let mut view = PlantView::new(
        &config.mqtt.prefix,
        &config
            .lines
            .iter()
            .flat_map(|line| &line.devices)
            .map(|device| {
                let fields = device
                    .profile
                    .fields()
                    .iter()
                    .map(|field| (field.name.clone(), field.ha.entity_category.is_some()));
                (device.name.clone(), fields.collect())
            })
            .collect::<Vec<_>>(),
    );
    let mut intro = introduction(&endpoint, &config);
    let mut hints = table_hints(&endpoint, &config);
    if let Some(notice) = &placement.notice {
        intro = format!("{notice}\n{intro}");
        hints = format!("{notice}\n{hints}");
    }

    let (trigger, shutdown) = shutdown::channel();
    let signals = tokio::spawn(super::stop_on_signals(trigger.clone()));
    let (messages_tx, mut messages_rx) = mpsc::channel(1024);
    let watcher = tokio::spawn(watch_broker(
        endpoint.clone(),
        format!("{}/#", config.mqtt.prefix),
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
    // A closed stdout (`rtu2mqtt demo --log | head`) ends the demo cleanly instead of a panic
    // in println!.
    if !table && writeln!(stdout, "{intro}").is_err() {
        trigger.fire();
    }

    let mut gateway = tokio::spawn(run_gateway(config, shutdown.clone(), Hooks::default()));
    let started = Instant::now();
    let mut recent_log: VecDeque<String> = VecDeque::new();
    let mut dirty = true;
    let mut redraw = tokio::time::interval(REDRAW);
    redraw.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    if table {
        let _ = write!(stdout, "\x1b[2J");
    }
    let mut stopping = shutdown.clone();
    let gateway_result = loop {
        tokio::select! {
            _ = stopping.fired() => break None,
            result = &mut gateway => break Some(result),
            Some((topic, payload)) = messages_rx.recv() => {
                if let Some(change) = view.apply(&topic, &payload) {
                    if table {
                        dirty = true;
                    } else if writeln!(stdout, "{}", log_line(started.elapsed(), &change)).is_err() {
                        trigger.fire();
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
                if table && dirty {
                    dirty = false;
                    let header = format!(
                        "rtu2mqtt demo: {} fields published, {}s",
                        view.published_fields(),
                        started.elapsed().as_secs()
                    );
                    let screen = compose_screen(&view, &header, &hints, &recent_log, terminal_size());
                    let _ = stdout.write_all(screen.as_bytes());
                    let _ = stdout.flush();
                }
            }
        }
    };
    drop(capture);

    let outcome = match gateway_result {
        // The gateway ended by itself: that is an error unless a shutdown asked for it.
        Some(result) => result.context("the gateway task failed")?.and_then(|()| {
            if shutdown.is_fired() {
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
    trigger.fire();
    let _ = watcher.await;
    signals.abort();
    drop(plant);
    outcome?;
    let _ = writeln!(
        stdout,
        "rtu2mqtt demo stopped after {}s ({} fields published).",
        started.elapsed().as_secs(),
        view.published_fields()
    );
    Ok(ExitCode::SUCCESS)
}

/// What is running and how to poke it.
fn introduction(endpoint: &BrokerEndpoint, config: &Config) -> String {
    let options = endpoint.client_options();
    let prefix = &config.mqtt.prefix;
    let mut text = format!(
        "rtu2mqtt demo: the seed plant, simulated, on {} ({}).\n",
        endpoint.url(),
        endpoint.origin
    );
    for line in &config.lines {
        let devices: Vec<String> = line
            .devices
            .iter()
            .map(|d| format!("{} at address {}", d.name, address_text(d.address)))
            .collect();
        text.push_str(&format!(
            "  {} on {} ({} {}): {}\n",
            line.name,
            line.serial.path,
            line.serial.baud,
            format_text(&line.serial.format),
            devices.join(", ")
        ));
    }
    text.push_str(&format!(
        "Try, in another terminal:\n  \
         mosquitto_sub {options}-v -t '{prefix}/#'\n  \
         mosquitto_pub {options}-t {prefix}/dust_collector/gear/set -m 8\n  \
         mosquitto_pub {options}-t {prefix}/valve/opening/set -m 40\n  \
         mosquitto_pub {options}-t {prefix}/air_shower/emergency_stop/set -m ON\n\
         Ctrl-C stops.\n"
    ));
    text
}

/// The table's lines under the plant: where things run and how to poke them.
fn table_hints(endpoint: &BrokerEndpoint, config: &Config) -> String {
    let options = endpoint.client_options();
    let prefix = &config.mqtt.prefix;
    let lines: Vec<String> = config
        .lines
        .iter()
        .map(|line| {
            format!(
                "{} {} {}",
                line.name,
                line.serial.path,
                format_text(&line.serial.format)
            )
        })
        .collect();
    format!(
        "{} ({}) · {}\n\
         try: mosquitto_pub {options}-t {prefix}/dust_collector/gear/set -m 8\n     \
         mosquitto_pub {options}-t {prefix}/valve/opening/set -m 40\n     \
         mosquitto_pub {options}-t {prefix}/air_shower/emergency_stop/set -m ON    Ctrl-C stops\n",
        endpoint.url(),
        endpoint.origin,
        lines.join(" · ")
    )
}

/// One frame of the live table: cursor home, the plant (compact when the full table would not
/// fit the terminal), the hints, the latest log lines as room allows, each line cleared to its
/// end, and the rest of the screen cleared.
fn compose_screen(
    view: &PlantView,
    header: &str,
    hints: &str,
    log: &VecDeque<String>,
    (width, height): (usize, usize),
) -> String {
    let hint_lines = hints.lines().count();
    let mut table = view.render_table(header, width, false);
    if table.lines().count() + hint_lines + 1 > height {
        table = view.render_table(header, width, true);
    }
    let mut lines: Vec<String> = table.lines().map(str::to_string).collect();
    lines.extend(hints.lines().map(str::to_string));
    let room = height.saturating_sub(lines.len() + 1);
    if room > 1 && !log.is_empty() {
        lines.push("log:".to_string());
        let shown = log.len().min(room - 1);
        for line in log.iter().skip(log.len() - shown) {
            lines.push(format!("  {}", without_timestamp(line)));
        }
    }
    let mut frame = String::from("\x1b[H");
    for line in lines.iter().take(height.saturating_sub(1).max(1)) {
        let clipped: String = line.chars().take(width).collect();
        frame.push_str(&clipped);
        frame.push_str("\x1b[K\n");
    }
    frame.push_str("\x1b[J");
    frame
}

/// A log line without its leading RFC 3339 timestamp (the table is live; the time is now).
fn without_timestamp(line: &str) -> &str {
    match line.split_once(' ') {
        Some((first, rest)) if first.len() >= 20 && first.ends_with('Z') && first.contains('T') => {
            rest.trim_start()
        }
        _ => line,
    }
}

/// `8N1`, `8E1`: the way serial settings are written on device labels.
fn format_text(format: &CharFormat) -> String {
    let parity = match format.parity {
        Parity::None => 'N',
        Parity::Even => 'E',
        Parity::Odd => 'O',
    };
    format!("{}{parity}{}", format.data_bits, format.stop_bits)
}

/// `1`, `129 (0x81)`: decimal, with hex where the device's documents use it.
fn address_text(address: u8) -> String {
    if address > 9 {
        format!("{address} (0x{address:02X})")
    } else {
        address.to_string()
    }
}

/// Keeps the latest [`LOG_LINES_SHOWN`] lines, dropping ordinary lines before warnings and
/// errors (the pty's parity warning should not scroll away behind routine news).
fn remember_log_line(recent: &mut VecDeque<String>, line: String) {
    recent.push_back(line);
    if recent.len() > LOG_LINES_SHOWN {
        let is_alarm = |line: &String| line.contains(" WARN ") || line.contains("ERROR ");
        match recent.iter().position(|line| !is_alarm(line)) {
            Some(ordinary) => {
                recent.remove(ordinary);
            }
            None => {
                recent.pop_front();
            }
        }
    }
}

fn keep_log_line(line: &str) -> bool {
    !line.trim().is_empty()
}

/// Columns and rows of the terminal on stdout (100 × 40 when unknown).
fn terminal_size() -> (usize, usize) {
    nix::ioctl_read_bad!(window_size, libc::TIOCGWINSZ, libc::winsize);
    let mut size = libc::winsize {
        ws_row: 0,
        ws_col: 0,
        ws_xpixel: 0,
        ws_ypixel: 0,
    };
    // SAFETY: TIOCGWINSZ writes one `winsize` into the struct we own; a failure leaves it zero.
    let result = unsafe { window_size(libc::STDOUT_FILENO, &mut size) };
    match result {
        Ok(_) if size.ws_col >= 40 && size.ws_row >= 10 => {
            (usize::from(size.ws_col), usize::from(size.ws_row))
        }
        _ => (100, 40),
    }
}

/// Subscribes to `filter` like any MQTT user and forwards every message until shutdown;
/// reconnects with a pause (the broker may start after the view, or restart).
async fn watch_broker(
    endpoint: BrokerEndpoint,
    filter: String,
    messages_tx: mpsc::Sender<(String, Vec<u8>)>,
    mut shutdown: Shutdown,
) {
    let client_id = format!("rtu2mqtt-demo-view-{}", std::process::id());
    let mut options = MqttOptions::new(client_id, endpoint.host.clone(), endpoint.port);
    options.set_keep_alive(Duration::from_secs(30));
    options.set_max_packet_size(broker::MAX_PAYLOAD_SIZE, broker::MAX_PAYLOAD_SIZE);
    let (client, mut event_loop) = AsyncClient::new(options, 64);
    loop {
        let event = tokio::select! {
            _ = shutdown.fired() => break,
            event = event_loop.poll() => event,
        };
        match event {
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                if let Err(error) = client.try_subscribe(filter.clone(), QoS::AtMostOnce) {
                    tracing::warn!(%error, "demo view: cannot subscribe");
                }
            }
            Ok(Event::Incoming(Packet::Publish(publish))) => {
                if messages_tx
                    .send((publish.topic.clone(), publish.payload.to_vec()))
                    .await
                    .is_err()
                {
                    break;
                }
            }
            Ok(_) => {}
            Err(error) => {
                tracing::debug!(%error, "demo view: broker connection lost; retrying");
                tokio::select! {
                    _ = shutdown.fired() => break,
                    _ = tokio::time::sleep(Duration::from_millis(500)) => {}
                }
            }
        }
    }
    let _ = client.try_disconnect();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broker_urls() {
        assert_eq!(
            parse_broker_url("mqtt://10.0.0.5:1884").unwrap(),
            ("10.0.0.5".to_string(), 1884)
        );
        assert_eq!(
            parse_broker_url("mqtt://broker.local").unwrap(),
            ("broker.local".to_string(), 1883)
        );
        assert_eq!(
            parse_broker_url("localhost:1883").unwrap(),
            ("localhost".to_string(), 1883)
        );
        assert!(parse_broker_url("mqtts://host:8883").is_err());
        assert!(parse_broker_url("mqtt://host:99999").is_err());
        assert!(parse_broker_url("mqtt://user@host").is_err());
        assert!(parse_broker_url("mqtt://").is_err());
        assert!(parse_broker_url("mqtt://host:0").is_err());
        assert_eq!(
            parse_broker_url("mqtt://[::1]:1884").unwrap(),
            ("::1".to_string(), 1884)
        );
    }

    #[test]
    fn the_example_configuration_is_the_seed_plant() {
        let endpoint = BrokerEndpoint {
            host: "127.0.0.1".to_string(),
            port: 18830,
            origin: "test",
        };
        let placement = Placement {
            prefix: None,
            notice: None,
        };
        let config = demo_config(
            &endpoint,
            &placement,
            Path::new("/dev/pts/98"),
            Path::new("/dev/pts/99"),
        )
        .unwrap();
        assert_eq!(config.lines[0].serial.path, "/dev/pts/98");
        assert_eq!(config.lines[1].serial.path, "/dev/pts/99");
        assert_eq!(config.mqtt.port, 18830);
        assert_eq!(config.mqtt.client_id, DEMO_CLIENT_ID);
        let hints = introduction(&endpoint, &config);
        assert!(hints.contains("mosquitto_pub -p 18830 -t plant/dust_collector/gear/set -m 8"));
        assert!(hints.contains("(9600 8E1): valve at address 1"), "{hints}");
        assert!(
            hints.contains("air_shower at address 129 (0x81)"),
            "{hints}"
        );
    }

    #[test]
    fn a_moved_demo_publishes_under_its_own_prefix_without_discovery() {
        let endpoint = BrokerEndpoint {
            host: "127.0.0.1".to_string(),
            port: 1883,
            origin: "--broker",
        };
        let placement = Placement {
            prefix: Some(SHARED_BROKER_PREFIX.to_string()),
            notice: Some("moved".to_string()),
        };
        let config = demo_config(
            &endpoint,
            &placement,
            Path::new("/dev/pts/98"),
            Path::new("/dev/pts/99"),
        )
        .unwrap();
        assert_eq!(config.mqtt.prefix, "demo");
        assert!(!config.mqtt.discovery);
        let hints = introduction(&endpoint, &config);
        assert!(
            hints.contains("mosquitto_pub -t demo/dust_collector/gear/set -m 8"),
            "{hints}"
        );
        assert!(!hints.contains("plant/"), "{hints}");
    }

    #[test]
    fn warnings_outlive_ordinary_log_lines() {
        let mut recent = VecDeque::new();
        remember_log_line(&mut recent, "t  WARN parity ignored".to_string());
        for i in 0..20 {
            remember_log_line(&mut recent, format!("t  INFO news {i}"));
        }
        assert_eq!(recent.len(), LOG_LINES_SHOWN);
        assert_eq!(recent[0], "t  WARN parity ignored");
        assert_eq!(recent[LOG_LINES_SHOWN - 1], "t  INFO news 19");
    }

    #[test]
    fn log_lines_lose_their_timestamp_under_the_table() {
        assert_eq!(
            without_timestamp("2026-11-22T02:56:06.029508Z  INFO rtu2mqtt::bridge: up"),
            "INFO rtu2mqtt::bridge: up"
        );
        assert_eq!(without_timestamp("plain words"), "plain words");
    }

    #[test]
    fn the_screen_fits_the_terminal() {
        let fields: Vec<(String, bool)> =
            (0..40).map(|i| (format!("setting_{i}"), i >= 4)).collect();
        let view = PlantView::new("plant", &[("valve".to_string(), fields)]);
        let log: VecDeque<String> = (0..10).map(|i| format!("log line {i}")).collect();
        let hints = "a\nb\nc\n";
        let tall = compose_screen(&view, "header", hints, &log, (80, 60));
        assert!(tall.contains("setting_39"));
        assert!(tall.contains("log line 9"));
        let short = compose_screen(&view, "header", hints, &log, (80, 12));
        assert!(!short.contains("setting_39"), "{short}");
        assert!(short.contains("+ 36 settings and diagnostics not shown"));
        assert!(short.matches('\n').count() <= 11, "{short}");
        assert!(short.starts_with("\x1b[H") && short.ends_with("\x1b[J"));
    }

    #[test]
    fn hints_stay_short_for_the_default_broker() {
        let endpoint = BrokerEndpoint {
            host: "127.0.0.1".to_string(),
            port: 1883,
            origin: "test",
        };
        assert_eq!(endpoint.client_options(), "");
    }
}
