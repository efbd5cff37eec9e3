//! The seed plant's gateway configuration for the demo: the example configuration (compiled in),
//! pointed at the simulated lines and the chosen broker and prefix.

use std::path::Path;

use anyhow::bail;

use super::endpoint::{BrokerEndpoint, Placement};
use rtu2mqtt::config::{self, Config};

/// The seed plant's configuration, compiled in so that the demo runs from anywhere.
pub(super) const EXAMPLE_CONFIG: &str = include_str!("../../../config/rtu2mqtt.toml");

/// Ports tried for the console from the example's on.
const CONSOLE_PORTS: u16 = 10;

/// The demo gateway's MQTT client id (and gateway id in topics).
pub(super) const DEMO_CLIENT_ID: &str = "rtu2mqtt-demo";

/// The example configuration's MQTT prefix.
pub(super) fn example_prefix() -> anyhow::Result<String> {
    config::from_str(EXAMPLE_CONFIG, Path::new("."))
        .map(|config| config.mqtt.prefix)
        .map_err(|problems| anyhow::anyhow!("the example configuration: {problems}"))
}

/// The example configuration on the simulated lines, talking to `endpoint` as
/// [`DEMO_CLIENT_ID`], under the placement's prefix (without discovery when it moved).
pub(super) fn demo_config(
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

/// A socket for the console at the example's address, or the next free port after it (another
/// demo may hold it), held from now on so that nothing takes it before the gateway starts;
/// `config` is set to its address. None (and no console) when none of them is free.
pub(super) fn console_socket(config: &mut Config) -> Option<std::net::TcpListener> {
    let web = config.web.as_mut()?;
    let base = web.listen;
    let bound = (0..CONSOLE_PORTS).find_map(|step| {
        let mut address = base;
        address.set_port(base.port().checked_add(step)?);
        std::net::TcpListener::bind(address).ok()
    });
    match bound.and_then(|socket| Some((socket.local_addr().ok()?, socket))) {
        Some((address, socket)) => {
            web.listen = address;
            Some(socket)
        }
        None => {
            config.web = None;
            None
        }
    }
}
