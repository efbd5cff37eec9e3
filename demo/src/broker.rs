//! The embedded MQTT broker of `rtu2mqtt-demo`: rumqttd serving MQTT 3.1.1 on
//! `127.0.0.1:<port>`, so the demo needs nothing installed and standard clients
//! (`mosquitto_sub`, `mosquitto_pub`, Home Assistant, MQTT Explorer) can watch and poke the plant.
//!
//! It owns only the broker's settings and its start-up check. It is not meant for production:
//! no authentication, no persistence, loopback only. rumqttd runs on its own threads and cannot
//! be stopped from outside; it lives until the process exits, which is what the demo wants.

use std::io::{Read, Write};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, TcpListener, TcpStream};
use std::time::{Duration, Instant};

use std::collections::HashMap;

use rumqttd::{Broker, Config, ConnectionSettings, RouterConfig, ServerSettings};

/// Largest payload a client may publish: room for a Home Assistant device-discovery document
/// of the largest profile (tens of fields, each a component with its own keys).
pub const MAX_PAYLOAD_SIZE: usize = 256 * 1024;

/// How long [`start`] waits for the broker to answer its first CONNECT.
const READY_TIMEOUT: Duration = Duration::from_secs(10);

/// Why the embedded broker could not start.
#[derive(Debug, thiserror::Error)]
pub enum BrokerError {
    #[error(
        "127.0.0.1:{port} is already in use ({source}); is another MQTT broker running? \
         Use `--port N` for another port, or `--broker mqtt://127.0.0.1:{port}` to use that broker"
    )]
    PortInUse { port: u16, source: std::io::Error },
    #[error("the embedded broker did not start: {0}")]
    Thread(std::io::Error),
    #[error(
        "the embedded broker on 127.0.0.1:{port} did not answer an MQTT CONNECT within {timeout:?}"
    )]
    NotReady { port: u16, timeout: Duration },
}

/// A running embedded broker.
#[derive(Debug, Clone, Copy)]
pub struct EmbeddedBroker {
    addr: SocketAddr,
}

impl EmbeddedBroker {
    /// Where clients connect.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// `mqtt://127.0.0.1:<port>`, the form the gateway's `mqtt.url` takes.
    pub fn url(&self) -> String {
        format!("mqtt://{}", self.addr)
    }
}

/// rumqttd's configuration, built in code: one MQTT 3.1.1 listener on loopback. (rumqttd 0.20
/// offers no `TCP_NODELAY` setting for the connections it accepts; the gateway's own sockets
/// set it, in `rtu2mqtt::bridge::driver::connection::client`.)
pub fn broker_config(port: u16) -> Config {
    let connections = ConnectionSettings {
        // Time a client has to send CONNECT after the TCP connection opens.
        connection_timeout_ms: 10_000,
        max_payload_size: MAX_PAYLOAD_SIZE,
        max_inflight_count: 100,
        auth: None,
        external_auth: None,
        dynamic_filters: true,
    };
    let server = ServerSettings {
        name: "demo-v4".to_string(),
        listen: SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, port)),
        tls: None,
        next_connection_delay_ms: 1,
        connections,
    };
    let router = RouterConfig {
        max_connections: 64,
        max_outgoing_packet_count: 200,
        // A segment must hold at least one maximal publish; four of them bound the memory the
        // commit log of a busy demo may take (retained messages are kept apart and survive).
        max_segment_size: 4 * MAX_PAYLOAD_SIZE,
        max_segment_count: 4,
        custom_segment: None,
        initialized_filters: None,
        shared_subscriptions_strategy: Default::default(),
    };
    Config {
        id: 0,
        router,
        v4: Some(HashMap::from([("1".to_string(), server)])),
        ..Config::default()
    }
}

/// Starts the broker on `127.0.0.1:<port>` and returns once it answers an MQTT CONNECT.
///
/// The port is probed first so that a port already taken gives a clear error instead of a
/// broker thread that logs and dies (rumqttd reports bind errors only in its log).
pub fn start(port: u16) -> Result<EmbeddedBroker, BrokerError> {
    let addr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, port));
    match TcpListener::bind(addr) {
        Ok(probe) => drop(probe),
        Err(source) => return Err(BrokerError::PortInUse { port, source }),
    }
    let config = broker_config(port);
    std::thread::Builder::new()
        .name("mqtt-broker".to_string())
        .spawn(move || {
            let mut broker = Broker::new(config);
            if let Err(error) = broker.start() {
                tracing::error!(%error, "embedded MQTT broker stopped");
            }
        })
        .map_err(BrokerError::Thread)?;

    let deadline = Instant::now() + READY_TIMEOUT;
    while Instant::now() < deadline {
        if mqtt_handshake(addr).is_ok() {
            tracing::info!(%addr, "embedded MQTT broker ready");
            return Ok(EmbeddedBroker { addr });
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Err(BrokerError::NotReady {
        port,
        timeout: READY_TIMEOUT,
    })
}

/// One MQTT 3.1.1 CONNECT → CONNACK (accepted) → DISCONNECT exchange: proof that the broker
/// serves MQTT, not merely that something listens.
pub fn mqtt_handshake(addr: SocketAddr) -> std::io::Result<()> {
    const CLIENT_ID: &[u8] = b"rtu2mqtt-probe";
    let mut connect = vec![0x10, 0];
    connect.extend_from_slice(&[0x00, 0x04, b'M', b'Q', b'T', b'T']);
    connect.push(0x04); // protocol level 4: MQTT 3.1.1
    connect.push(0x02); // clean session, no will, no credentials
    connect.extend_from_slice(&[0x00, 0x0A]); // keep-alive 10 s
    connect.extend_from_slice(&(CLIENT_ID.len() as u16).to_be_bytes());
    connect.extend_from_slice(CLIENT_ID);
    connect[1] = (connect.len() - 2) as u8;

    let mut stream = TcpStream::connect_timeout(&addr, Duration::from_secs(1))?;
    stream.set_read_timeout(Some(Duration::from_secs(2)))?;
    stream.set_write_timeout(Some(Duration::from_secs(2)))?;
    stream.write_all(&connect)?;
    let mut connack = [0u8; 4];
    stream.read_exact(&mut connack)?;
    if connack != [0x20, 0x02, 0x00, 0x00] {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("unexpected CONNACK {connack:02X?}"),
        ));
    }
    stream.write_all(&[0xE0, 0x00])?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_listens_on_loopback_only() {
        let config = broker_config(18830);
        let servers = config.v4.as_ref().map(|v4| v4.values().collect::<Vec<_>>());
        let servers = servers.unwrap_or_default();
        assert_eq!(servers.len(), 1);
        assert_eq!(servers[0].listen, "127.0.0.1:18830".parse().unwrap());
        assert!(config.v5.is_none() && config.ws.is_none() && config.console.is_none());
        assert!(config.router.max_segment_size >= MAX_PAYLOAD_SIZE);
    }

    #[test]
    fn a_taken_port_is_a_clear_error() {
        let holder = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = holder.local_addr().unwrap().port();
        let error = start(port).unwrap_err();
        assert!(matches!(error, BrokerError::PortInUse { .. }), "{error}");
        assert!(error.to_string().contains("--broker"));
    }
}
