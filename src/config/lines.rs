//! The checks of `[[lines]]`: each line's name, its link (exactly one of a serial `port` and a
//! `tcp://` or `modbus-tcp://` `url`, one line per port or server), its serial and timing keys,
//! its `[lines.serve]` table, and its poll plan's load. Each line's devices are checked by
//! [`super::devices`]; what comes out is the bus's [`LineSpec`]s.

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use super::devices::validate_device;
use super::names::{invalid_name, is_valid_name};
use super::poll_plan::LinePlan;
use super::problem::Problem;
use super::schema::{RawLine, RawServe};
use crate::bus::serve::{Access, ServeFraming, ServeSpec};
use crate::bus::{LineSpec, Transport};
use rtu2mqtt_modbus::link::TcpEndpoint;
use rtu2mqtt_modbus::serial::transport::{Rs485Settings, SerialSettings};
use rtu2mqtt_modbus::tcp::masters::TcpOptions;
use rtu2mqtt_modbus::timing::CharFormat;
use rtu2mqtt_profile::Profile;

/// Baud rates a Modbus RTU line may be configured with.
pub(crate) const ALLOWED_BAUDS: &[u32] = &[
    300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200,
];
/// The serial-line specification's longest sensible wait; rumqttc-style zero means "never".
const MAX_TIMEOUT: Duration = Duration::from_secs(120);

pub(super) fn validate_lines(
    raw_lines: &[RawLine],
    base: &Path,
    problems: &mut Vec<Problem>,
    warnings: &mut Vec<Problem>,
) -> Vec<LineSpec> {
    if raw_lines.is_empty() {
        // A fresh installation: the service runs idle (its MQTT status, the console) until the
        // administrator adds lines and reloads it; nothing polls a port nobody configured.
        warnings.push(Problem::new(
            "lines",
            "no [[lines]] configured: the gateway runs idle, polling nothing, until lines are \
             added and it is reloaded (`systemctl reload rtu2mqtt`)",
        ));
    }
    let mut line_names: HashMap<&str, usize> = HashMap::new();
    let mut links: HashMap<String, usize> = HashMap::new();
    let mut listens: HashMap<String, usize> = HashMap::new();
    let mut device_names: HashMap<String, String> = HashMap::new();
    let mut profiles: HashMap<String, Arc<Profile>> = HashMap::new();
    let mut lines = Vec::new();

    for (index, raw) in raw_lines.iter().enumerate() {
        let place = format!("lines[{index}]");
        let before = problems.len();
        if !is_valid_name(&raw.name) {
            problems.push(invalid_name(&place, &raw.name));
        } else if let Some(first) = line_names.insert(&raw.name, index) {
            problems.push(Problem::new(
                format!("{place}.name"),
                format!("{:?} is already the name of lines[{first}]", raw.name),
            ));
        }
        let transport = validate_transport(raw, &place, index, &mut links, problems, warnings);
        if raw.data_bits != 8 {
            problems.push(Problem::new(
                format!("{place}.data_bits"),
                format!("{} is not 8: Modbus RTU uses 8 data bits", raw.data_bits),
            ));
        }
        if raw.stop_bits != 1 && raw.stop_bits != 2 {
            problems.push(Problem::new(
                format!("{place}.stop_bits"),
                format!("{} must be 1 or 2", raw.stop_bits),
            ));
        }
        if let Some(baud) = raw.baud {
            if !ALLOWED_BAUDS.contains(&baud) {
                problems.push(Problem::new(
                    format!("{place}.baud"),
                    format!("{baud} is not one of {ALLOWED_BAUDS:?}"),
                ));
            }
        }
        if let Some(timeout) = raw.response_timeout {
            check_timeout(&format!("{place}.response_timeout"), timeout, problems);
        }
        if raw.retries > 10 {
            problems.push(Problem::new(
                format!("{place}.retries"),
                format!("{} is more than 10", raw.retries),
            ));
        }
        if raw.offline_after == 0 || raw.offline_after > 100 {
            problems.push(Problem::new(
                format!("{place}.offline_after"),
                format!("{} must be 1–100 failed polls", raw.offline_after),
            ));
        }
        if let Some(byte_timeout) = raw.byte_timeout {
            if byte_timeout.is_zero() || byte_timeout > Duration::from_secs(1) {
                problems.push(Problem::new(
                    format!("{place}.byte_timeout"),
                    format!(
                        "{} must be more than 0 and at most 1s",
                        humantime::format_duration(byte_timeout)
                    ),
                ));
            }
        }
        if raw.broadcast_turnaround > Duration::from_secs(10) {
            problems.push(Problem::new(
                format!("{place}.broadcast_turnaround"),
                "must be at most 10s".to_string(),
            ));
        }
        if raw.devices.is_empty() {
            problems.push(Problem::new(
                format!("{place}.devices"),
                "a line needs at least one [[lines.devices]]",
            ));
        }

        let mut addresses: HashMap<i64, usize> = HashMap::new();
        let mut devices = Vec::new();
        for (device_index, device) in raw.devices.iter().enumerate() {
            let device_place = format!("{place}.devices[{device_index}]");
            if let Some(first) = addresses.insert(device.address, device_index) {
                problems.push(Problem::new(
                    format!("{device_place}.address"),
                    format!(
                        "{} is already used on this line by {place}.devices[{first}] ({})",
                        device.address, raw.devices[first].name
                    ),
                ));
            }
            if let Some(spec) = validate_device(
                device,
                &device_place,
                base,
                &mut profiles,
                &mut device_names,
                problems,
                warnings,
            ) {
                devices.push(spec);
            }
        }
        let serve = raw
            .serve
            .as_ref()
            .and_then(|serve| validate_serve(serve, &place, problems, warnings));
        if let Some(serve) = &serve {
            if let Some(first) = listens.insert(serve.listen.clone(), index) {
                problems.push(Problem::new(
                    format!("{place}.serve.listen"),
                    format!("{} is already where lines[{first}] is served", serve.listen),
                ));
            }
        }
        let Some((path, transport)) = transport else {
            continue;
        };
        if problems.len() != before || devices.is_empty() {
            continue;
        }
        // A Modbus TCP gateway runs its serial side itself, at the setting it is given there:
        // the line's baud and parity only say what that is (for the default response timeout
        // and the bus load), and a device's usual setting is not ours to warn about.
        let our_timing = !is_modbus_tcp(&transport);

        // Character format: the line's own, else the first device's profile defaults.
        let first_limits = devices[0].profile.limits().clone();
        let baud = raw.baud.unwrap_or(first_limits.default_baud);
        let parity = raw.parity.unwrap_or(first_limits.default_parity);
        for device in devices.iter().filter(|_| our_timing) {
            let limits = device.profile.limits();
            if limits.default_parity != parity || limits.default_baud != baud {
                warnings.push(Problem::new(
                    place.clone(),
                    format!(
                        "device {} ({}) usually runs at {} baud, parity {:?}; the line is set \
                         to {baud} baud, parity {parity:?}",
                        device.name,
                        device.profile.name(),
                        limits.default_baud,
                        limits.default_parity
                    ),
                ));
            }
        }
        let spec = LineSpec {
            name: raw.name.clone(),
            serial: SerialSettings {
                path,
                baud,
                format: CharFormat {
                    data_bits: raw.data_bits,
                    parity,
                    stop_bits: raw.stop_bits,
                },
                rs485: raw.rs485.as_ref().map(|rs485| Rs485Settings {
                    rts_on_send: rs485.rts_on_send,
                    delay_before_send: rs485.delay_before_send,
                    delay_after_send: rs485.delay_after_send,
                }),
            },
            transport,
            response_timeout: raw.response_timeout,
            retries: raw.retries,
            offline_after: raw.offline_after,
            echo: raw.echo,
            broadcast_turnaround: raw.broadcast_turnaround,
            byte_timeout: raw.byte_timeout,
            // Opened by the daemon, not by validation.
            recorders: Default::default(),
            console: false,
            devices,
            serve,
        };
        let plan = LinePlan::of(&spec);
        // Continuous polls take what is left: only the periodic ones can overload a line.
        if our_timing && plan.periodic_load > 1.0 {
            problems.push(Problem::new(
                place.clone(),
                format!(
                    "the poll plan needs {:.0} % of the line's time at {baud} baud: lengthen \
                     poll_interval or split the devices over more lines",
                    plan.periodic_load * 100.0
                ),
            ));
        }
        lines.push(spec);
    }
    lines
}

/// `[lines.serve]`: where to listen, how clients frame, what they may do.
fn validate_serve(
    raw: &RawServe,
    line_place: &str,
    problems: &mut Vec<Problem>,
    warnings: &mut Vec<Problem>,
) -> Option<ServeSpec> {
    let place = format!("{line_place}.serve");
    let before = problems.len();
    let (framing, address) = if let Some(rest) = raw.listen.strip_prefix("modbus-tcp://") {
        (ServeFraming::ModbusTcp, rest)
    } else if let Some(rest) = raw.listen.strip_prefix("tcp://") {
        (ServeFraming::RawRtu, rest)
    } else {
        problems.push(Problem::new(
            format!("{place}.listen"),
            format!(
                "{:?} must be modbus-tcp://HOST:PORT (Modbus TCP) or tcp://HOST:PORT (RTU \
                 frames over TCP)",
                raw.listen
            ),
        ));
        (ServeFraming::ModbusTcp, "")
    };
    if problems.len() == before && address.parse::<std::net::SocketAddr>().is_err() {
        let port_ok = address
            .rsplit_once(':')
            .is_some_and(|(host, port)| !host.is_empty() && port.parse::<u16>().is_ok());
        if !port_ok {
            problems.push(Problem::new(
                format!("{place}.listen"),
                format!("{:?} needs HOST:PORT after the scheme", raw.listen),
            ));
        }
    }
    let access = Access::from_word(&raw.access);
    if access.is_none() {
        problems.push(Problem::new(
            format!("{place}.access"),
            format!("{:?} is not one of profile, read-only, raw", raw.access),
        ));
    }
    if raw.max_clients == 0 || raw.max_clients > 64 {
        problems.push(Problem::new(
            format!("{place}.max_clients"),
            format!("{} must be 1–64", raw.max_clients),
        ));
    }
    if raw.cache > Duration::from_secs(3600) {
        problems.push(Problem::new(
            format!("{place}.cache"),
            "must be at most 1h".to_string(),
        ));
    }
    let access = access?;
    if access == Access::Raw {
        warnings.push(Problem::new(
            format!("{place}.access"),
            "raw: clients may read and write any register of any unit on the line, past the \
             profiles' rules; use it for commissioning only",
        ));
    }
    (problems.len() == before).then(|| ServeSpec {
        listen: address.to_string(),
        framing,
        access,
        cache: raw.cache,
        max_clients: raw.max_clients,
    })
}

/// Default network allowance of TCP lines (on top of the default response timeout).
pub(crate) const DEFAULT_NETWORK_ALLOWANCE: Duration = Duration::from_millis(200);

/// The server runs the line's serial side itself (a Modbus TCP gateway).
fn is_modbus_tcp(transport: &Transport) -> bool {
    matches!(transport, Transport::Tcp { endpoint, .. } if endpoint.kind.times_its_serial_side())
}

/// The line's link from exactly one of `port` and `url`, with its keys checked: the path (or
/// url, which stands for it in logs) and the transport. Two lines on one port or one server
/// are a problem.
fn validate_transport(
    raw: &RawLine,
    place: &str,
    index: usize,
    links: &mut HashMap<String, usize>,
    problems: &mut Vec<Problem>,
    warnings: &mut Vec<Problem>,
) -> Option<(String, Transport)> {
    let tcp_keys = [
        ("network_allowance", raw.network_allowance),
        ("connect_timeout", raw.connect_timeout),
        ("keepalive", raw.keepalive),
    ];
    let (path, transport, key, taken) = match (&raw.port, &raw.url) {
        (Some(_), Some(_)) => {
            problems.push(Problem::new(
                place,
                "set either `port` (a serial port) or `url` (tcp://… or modbus-tcp://…), not both",
            ));
            return None;
        }
        (None, None) => {
            problems.push(Problem::new(
                place,
                "needs `port` (a serial port such as /dev/serial/by-id/…) or `url` \
                 (tcp://host:port for a serial device server, modbus-tcp://host:port for a \
                 Modbus TCP gateway)",
            ));
            return None;
        }
        (Some(port), None) => {
            let port_place = format!("{place}.port");
            if port.is_empty() {
                problems.push(Problem::new(port_place, "must not be empty"));
                return None;
            }
            if is_unstable_port_path(port) {
                warnings.push(Problem::new(
                    &port_place,
                    format!(
                        "{port} may name another adapter after a replug or reboot; prefer \
                         /dev/serial/by-id/… or /dev/serial/by-path/…"
                    ),
                ));
            }
            for (key, value) in tcp_keys {
                if value.is_some() {
                    problems.push(Problem::new(
                        format!("{place}.{key}"),
                        "applies only to lines with a `url`",
                    ));
                }
            }
            // Keyed by the port the name reaches: a by-id link and its target, or
            // `/dev/./ttyA` and `/dev/ttyA`, are one port (the second line would fail for ever
            // at run time).
            let identity = port_identity(port).to_string_lossy().into_owned();
            (port.clone(), Transport::Serial, "port", identity)
        }
        (None, Some(url)) => {
            let url_place = format!("{place}.url");
            let endpoint = match TcpEndpoint::parse(url) {
                Ok(endpoint) => endpoint,
                Err(error) => {
                    problems.push(Problem::new(url_place, error.to_string()));
                    return None;
                }
            };
            if raw.echo {
                problems.push(Problem::new(
                    format!("{place}.echo"),
                    "applies only to serial ports (a TCP server does not echo)",
                ));
            }
            if raw.rs485.is_some() {
                problems.push(Problem::new(
                    format!("{place}.rs485"),
                    "applies only to serial ports (the server drives its own RS485 transceiver)",
                ));
            }
            for (key, value) in &tcp_keys {
                if let Some(value) = value {
                    check_timeout(&format!("{place}.{key}"), *value, problems);
                }
            }
            let defaults = TcpOptions::default();
            let transport = Transport::Tcp {
                options: TcpOptions {
                    connect_timeout: raw.connect_timeout.unwrap_or(defaults.connect_timeout),
                    keepalive: raw.keepalive.unwrap_or(defaults.keepalive),
                    broadcast_turnaround: raw.broadcast_turnaround,
                },
                network_allowance: raw.network_allowance.unwrap_or(DEFAULT_NETWORK_ALLOWANCE),
                endpoint: endpoint.clone(),
            };
            // One server, one line, whichever kind names it.
            (endpoint.url(), transport, "url", endpoint.address)
        }
    };
    if let Some(first) = links.insert(taken, index) {
        problems.push(Problem::new(
            format!("{place}.{key}"),
            format!("{path} is already the {key} of lines[{first}]"),
        ));
    }
    Some((path, transport))
}

fn check_timeout(place: &str, timeout: Duration, problems: &mut Vec<Problem>) {
    if timeout.is_zero() || timeout > MAX_TIMEOUT {
        problems.push(Problem::new(
            place,
            format!(
                "{} must be more than 0 and at most 120s",
                humantime::format_duration(timeout)
            ),
        ));
    }
}

/// `/dev/ttyUSB0`-style names follow plug order; by-id and by-path names do not.
fn is_unstable_port_path(port: &str) -> bool {
    ["/dev/ttyUSB", "/dev/ttyACM"]
        .iter()
        .any(|prefix| port.starts_with(prefix))
}

/// The path a port name reaches: links and `.`/`..` resolved when it exists (a by-id link and
/// its target are one port), else normalised lexically (`/dev/./ttyA` is `/dev/ttyA`).
pub(crate) fn port_identity(port: &str) -> PathBuf {
    let path = Path::new(port);
    std::fs::canonicalize(path).unwrap_or_else(|_| normalize(path))
}

/// `.` dropped and `..` applied without touching the file system.
fn normalize(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for component in path.components() {
        match component {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtu2mqtt_modbus::link::TcpKind;

    /// Validates one-device lines given by their link keys; problems and warnings as text.
    fn link_findings(lines: &[&str]) -> (Vec<String>, Vec<String>) {
        let mut text = String::from("[mqtt]\nurl = \"mqtt://localhost\"\nclient_id = \"edge1\"\n");
        for (index, keys) in lines.iter().enumerate() {
            text.push_str(&format!(
                "[[lines]]\nname = \"line{index}\"\n{keys}\n[[lines.devices]]\nname = \"dev{index}\"\n\
                 profile = \"wuzhou-valve\"\naddress = 1\n"
            ));
        }
        match crate::config::from_str(&text, Path::new(".")) {
            Ok(config) => (
                Vec::new(),
                config.warnings.iter().map(|w| w.to_string()).collect(),
            ),
            Err(problems) => (
                problems.0.iter().map(|p| p.to_string()).collect(),
                Vec::new(),
            ),
        }
    }

    fn has(findings: &[String], words: &str) -> bool {
        findings.iter().any(|finding| finding.contains(words))
    }

    #[test]
    fn a_served_line_is_checked_with_places_and_raw_access_warns() {
        let serve = |table: &str| format!("port = \"/dev/ttyS1\"\n[lines.serve]\n{table}");
        let (problems, warnings) = link_findings(&[&serve(
            "listen = \"modbus-tcp://0.0.0.0:5020\"\naccess = \"raw\"\ncache = \"1s\"",
        )]);
        assert!(problems.is_empty(), "{problems:?}");
        assert!(
            has(&warnings, "lines[0].serve.access: raw: clients may"),
            "{warnings:?}"
        );
        for (table, place) in [
            ("listen = \"http://h:1\"", "lines[0].serve.listen"),
            ("listen = \"modbus-tcp://5020\"", "lines[0].serve.listen"),
            (
                "listen = \"tcp://h:1\"\naccess = \"write\"",
                "lines[0].serve.access",
            ),
            (
                "listen = \"tcp://h:1\"\nmax_clients = 0",
                "lines[0].serve.max_clients",
            ),
        ] {
            let (problems, _) = link_findings(&[&serve(table)]);
            assert!(has(&problems, place), "{table}: {problems:?}");
        }
        let (problems, _) = link_findings(&[
            &serve("listen = \"modbus-tcp://0.0.0.0:5020\""),
            "port = \"/dev/ttyS2\"\n[lines.serve]\nlisten = \"modbus-tcp://0.0.0.0:5020\"",
        ]);
        assert!(
            has(&problems, "lines[1].serve.listen: 0.0.0.0:5020 is already"),
            "{problems:?}"
        );
    }

    #[test]
    fn a_line_has_exactly_one_of_port_and_url() {
        let (problems, _) = link_findings(&["port = \"/dev/ttyS1\"\nurl = \"tcp://h:4001\""]);
        assert!(
            has(&problems, "lines[0]: set either `port`"),
            "{problems:?}"
        );
        let (problems, _) = link_findings(&[""]);
        assert!(has(&problems, "lines[0]: needs `port`"), "{problems:?}");
    }

    #[test]
    fn urls_are_checked_with_clear_reasons() {
        let (problems, _) = link_findings(&["url = \"udp://h:4001\""]);
        assert!(
            has(&problems, "lines[0].url: unknown scheme \"udp\""),
            "{problems:?}"
        );
        let (problems, _) = link_findings(&["url = \"tcp://10.0.0.5\""]);
        assert!(
            has(
                &problems,
                "lines[0].url: \"tcp://10.0.0.5\" has no port number"
            ),
            "{problems:?}"
        );
        let (problems, _) = link_findings(&["url = \"modbus-tcp://h:502\"\necho = true"]);
        assert!(
            has(&problems, "lines[0].echo: applies only to serial ports"),
            "{problems:?}"
        );
        let (problems, _) = link_findings(&["port = \"/dev/ttyS1\"\nnetwork_allowance = \"50ms\""]);
        assert!(
            has(
                &problems,
                "lines[0].network_allowance: applies only to lines with a `url`"
            ),
            "{problems:?}"
        );
    }

    #[test]
    fn two_lines_on_one_server_are_refused() {
        let (problems, _) =
            link_findings(&["url = \"tcp://h:4001\"", "url = \"modbus-tcp://h:4001\""]);
        assert!(
            has(
                &problems,
                "lines[1].url: modbus-tcp://h:4001 is already the url of lines[0]"
            ),
            "{problems:?}"
        );
        let (problems, _) = link_findings(&["port = \"/dev/ttyS1\"", "port = \"/dev/ttyS1\""]);
        assert!(
            has(
                &problems,
                "lines[1].port: /dev/ttyS1 is already the port of lines[0]"
            ),
            "{problems:?}"
        );
    }

    #[test]
    fn tcp_lines_get_their_transport_and_modbus_tcp_takes_the_gateways_serial_setting() {
        let (problems, warnings) = link_findings(&["url = \"modbus-tcp://gw:502\"\nbaud = 19200"]);
        assert!(problems.is_empty(), "{problems:?}");
        assert!(warnings.is_empty(), "{warnings:?}");
        let text = "[mqtt]\nurl = \"mqtt://localhost\"\nclient_id = \"edge1\"\n[[lines]]\n\
                    name = \"gw\"\nurl = \"modbus-tcp://10.0.0.6:502\"\nbaud = 19200\n\
                    [[lines.devices]]\nname = \"v\"\nprofile = \"wuzhou-valve\"\naddress = 1\n";
        let config = crate::config::from_str(text, Path::new(".")).unwrap();
        // The gateway's serial setting times the line's figures: the valve's 8E1 at 19200.
        assert_eq!(config.lines[0].serial.baud, 19200);
        assert_eq!(
            config.lines[0].serial.format.parity,
            rtu2mqtt_modbus::timing::Parity::Even
        );
        let text =
            "[mqtt]\nurl = \"mqtt://localhost\"\nclient_id = \"edge1\"\n[[lines]]\nname = \"a\"\n\
                    url = \"tcp://10.0.0.5:4001\"\nconnect_timeout = \"2s\"\n[[lines.devices]]\n\
                    name = \"v\"\nprofile = \"wuzhou-valve\"\naddress = 1\n";
        let config = crate::config::from_str(text, Path::new(".")).unwrap();
        let line = &config.lines[0];
        assert_eq!(line.serial.path, "tcp://10.0.0.5:4001");
        match &line.transport {
            Transport::Tcp {
                endpoint,
                options,
                network_allowance,
            } => {
                assert_eq!(endpoint.kind, TcpKind::RawRtu);
                assert_eq!(options.connect_timeout, Duration::from_secs(2));
                assert_eq!(*network_allowance, DEFAULT_NETWORK_ALLOWANCE);
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn ports_are_compared_resolved() {
        assert_eq!(
            port_identity("/nonexistent/./a/../ttyA"),
            PathBuf::from("/nonexistent/ttyA")
        );
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("ttyA");
        std::fs::write(&target, b"").unwrap();
        let link = dir.path().join("by-id");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        assert_eq!(
            port_identity(&link.to_string_lossy()),
            port_identity(&target.to_string_lossy())
        );
    }

    #[test]
    fn serial_keys_are_refused_at_their_place_on_the_line() {
        let (problems, _) = link_findings(&[
            "port = \"/dev/ttyS1\"\ndata_bits = 7\nstop_bits = 3\nbaud = 1234\nretries = 11\n\
             offline_after = 0\nbyte_timeout = \"2s\"\nresponse_timeout = \"0s\"",
        ]);
        for expected in [
            "lines[0].data_bits: 7 is not 8: Modbus RTU uses 8 data bits",
            "lines[0].stop_bits: 3 must be 1 or 2",
            "lines[0].baud: 1234 is not one of [300, 600,",
            "lines[0].retries: 11 is more than 10",
            "lines[0].offline_after: 0 must be 1–100 failed polls",
            "lines[0].byte_timeout: 2s must be more than 0 and at most 1s",
            "lines[0].response_timeout: 0s must be more than 0 and at most 120s",
        ] {
            assert!(has(&problems, expected), "{expected}: {problems:?}");
        }
    }

    #[test]
    fn an_unstable_port_name_warns_and_a_line_name_is_unique() {
        let (problems, warnings) = link_findings(&["port = \"/dev/ttyUSB0\""]);
        assert!(problems.is_empty(), "{problems:?}");
        assert!(
            has(
                &warnings,
                "lines[0].port: /dev/ttyUSB0 may name another adapter"
            ),
            "{warnings:?}"
        );
        let text = "[mqtt]\nurl = \"mqtt://localhost\"\nclient_id = \"edge1\"\n\
                    [[lines]]\nname = \"a\"\nport = \"/dev/ttyS1\"\n[[lines.devices]]\nname = \"v1\"\n\
                    profile = \"wuzhou-valve\"\naddress = 1\n\
                    [[lines]]\nname = \"a\"\nport = \"/dev/ttyS2\"\n[[lines.devices]]\nname = \"v2\"\n\
                    profile = \"wuzhou-valve\"\naddress = 1\n";
        let problems = crate::config::from_str(text, Path::new("."))
            .err()
            .map(|problems| problems.to_string())
            .unwrap_or_default();
        assert!(
            problems.contains("lines[1].name: \"a\" is already the name of lines[0]"),
            "{problems}"
        );
    }
}
