//! Complete validation of a [`RawConfig`]: every problem is collected with its place, nothing
//! is opened (profile files and the password file are read, ports and the broker are not).
//! The result is the bus's [`LineSpec`]s and the bridge's settings.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use super::link::{self, shown};
use super::plan::LinePlan;
use super::schema::{
    RawConfig, RawDevice, RawGateway, RawLine, RawMqtt, RawServe, SparkplugSettings,
};
use super::sparkplug::{check_identity, shared_broker, SparkplugConfig};
use super::{Config, GatewayOptions, MqttSettings, Problem, Problems, TlsSettings};
use crate::bus::serve::{Access, ServeFraming, ServeSpec};
use crate::bus::{DeviceSpec, LineSpec, Transport};
use crate::contract::{self, reserved_name_problem, MAX_TOPIC_LEN};
use crate::profile::{Profile, PublishRule};
use rtu2mqtt_modbus::tcp_link::{TcpEndpoint, TcpKind, TcpOptions};
use rtu2mqtt_modbus::timing::CharFormat;
use rtu2mqtt_modbus::transport::{Rs485Settings, SerialSettings};

/// Baud rates a Modbus RTU line may be configured with.
pub const ALLOWED_BAUDS: &[u32] = &[
    300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200,
];
/// The serial-line specification's longest sensible wait; rumqttc-style zero means "never".
const MAX_TIMEOUT: Duration = Duration::from_secs(120);
/// Device, line and client names become topic levels: keep them short.
const MAX_NAME_LEN: usize = contract::MAX_NAME_LEN;
/// Topic prefixes (`plant`, `site1/plant`).
const MAX_PREFIX_LEN: usize = 128;
// The longest topic the gateway builds (`<prefix>/<device>/<field>/result`, and the discovery
// topic `<discovery_prefix>/device/<client_id>_<device>/config`) stays within the length it
// accepts on incoming topics, far below MQTT's 65,535 bytes.
const _: () = assert!(MAX_PREFIX_LEN + 2 * MAX_NAME_LEN + "///result".len() <= MAX_TOPIC_LEN);
const _: () =
    assert!(MAX_PREFIX_LEN + 2 * MAX_NAME_LEN + "/device/_/config".len() <= MAX_TOPIC_LEN);
/// Largest accepted command payload limit (a command is a word or a number).
const MAX_PAYLOAD_LIMIT: usize = 64 * 1024;

/// Validates `raw`; profile paths are relative to `base`.
pub fn validate(raw: &RawConfig, base: &Path) -> Result<Config, Problems> {
    let mut problems = Vec::new();
    let mut warnings = Vec::new();
    let mqtt = validate_mqtt(&raw.mqtt, base, &mut problems);
    let gateway = validate_gateway(&raw.gateway, &mut problems);
    validate_health(raw, &mut problems);
    let lines = validate_lines(&raw.lines, base, &mut problems, &mut warnings);
    if let Some(mqtt) = mqtt.as_ref().filter(|mqtt| mqtt.discovery) {
        check_unique_ids(mqtt, &lines, &mut problems);
    }
    let sparkplug = raw.sparkplug.as_ref().map(|section| {
        validate_sparkplug(
            section,
            &raw.mqtt.client_id,
            mqtt.as_ref(),
            base,
            &mut problems,
        )
    });
    let history = raw
        .history
        .as_ref()
        .and_then(|table| match super::history::check(table) {
            Ok(history) => Some(history),
            Err(found) => {
                problems.extend(found);
                None
            }
        });
    if problems.is_empty() {
        if let (Some(mqtt), Some(gateway)) = (mqtt, gateway) {
            return Ok(Config {
                mqtt,
                gateway,
                sparkplug: sparkplug.flatten(),
                history,
                health: raw.health.clone(),
                lines,
                warnings,
            });
        }
    }
    Err(Problems(problems))
}

/// The whole section: identity and broker, every problem added to `problems`. `plain` is the
/// checked `[mqtt]` (None when it has problems of its own; the identity is still checked).
pub fn validate_sparkplug(
    raw: &SparkplugSettings,
    plain_client_id: &str,
    plain: Option<&MqttSettings>,
    base: &Path,
    problems: &mut Vec<Problem>,
) -> Option<SparkplugConfig> {
    let identity = check_identity(raw, plain_client_id)
        .map_err(|found| problems.extend(found))
        .ok();
    let mqtt = match &raw.mqtt {
        Some(own) => {
            let checked = validate_mqtt_section("sparkplug.mqtt", own, base, problems)?;
            if let Some(plain) = plain.filter(|plain| same_client(plain, &checked)) {
                problems.push(Problem::new(
                    "sparkplug.mqtt.client_id",
                    format!(
                        "{:?} is also mqtt.client_id on the same broker: the two connections \
                         would take each other over",
                        plain.client_id
                    ),
                ));
                return None;
            }
            MqttSettings {
                clean_session: true,
                ..checked
            }
        }
        None => shared_broker(plain?),
    };
    Some(SparkplugConfig {
        identity: identity?,
        mqtt,
    })
}

fn same_client(a: &MqttSettings, b: &MqttSettings) -> bool {
    a.host == b.host && a.port == b.port && a.client_id == b.client_id
}

/// `[a-z0-9_-]+`, at most 64 characters.
pub fn is_valid_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= MAX_NAME_LEN
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-')
}

/// The problem of a line or device `name` at `place` that [`is_valid_name`] refuses.
fn invalid_name(place: &str, name: &str) -> Problem {
    Problem::new(
        format!("{place}.name"),
        format!(
            "{} must match [a-z0-9_-]+ (at most {MAX_NAME_LEN} characters)",
            shown(name)
        ),
    )
}

/// Why `prefix` cannot be a topic prefix, if it cannot.
pub fn topic_prefix_problem(prefix: &str) -> Option<String> {
    if prefix.is_empty() {
        return Some("must not be empty".into());
    }
    if prefix.len() > MAX_PREFIX_LEN {
        return Some(format!(
            "is {} bytes, longer than {MAX_PREFIX_LEN}",
            prefix.len()
        ));
    }
    if let Some(bad) = prefix.chars().find(|c| matches!(c, '+' | '#' | '\0')) {
        return Some(format!(
            "contains {bad:?}: wildcards and NUL are not allowed in a topic"
        ));
    }
    if prefix.starts_with('$') {
        return Some("starts with '$', which brokers reserve for their own topics".into());
    }
    if prefix.starts_with('/') || prefix.ends_with('/') || prefix.contains("//") {
        return Some("has an empty topic level (leading, trailing or doubled '/')".into());
    }
    None
}

fn validate_mqtt(raw: &RawMqtt, base: &Path, problems: &mut Vec<Problem>) -> Option<MqttSettings> {
    validate_mqtt_section("mqtt", raw, base, problems)
}

/// A broker table in the form of `[mqtt]` at `section` (`mqtt`, `sparkplug.mqtt`).
fn validate_mqtt_section(
    section: &str,
    raw: &RawMqtt,
    base: &Path,
    problems: &mut Vec<Problem>,
) -> Option<MqttSettings> {
    let before = problems.len();
    let mut fail = |key: &str, reason: String| {
        problems.push(Problem::new(format!("{section}.{key}"), reason));
    };
    let endpoint = parse_broker_url(&raw.url);
    if let Err(reason) = &endpoint {
        fail("url", reason.clone());
    }
    // The client id is also a topic level (`plant/gateway/<client_id>/status`).
    if raw.client_id.is_empty()
        || raw.client_id.len() > MAX_NAME_LEN
        || !raw
            .client_id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-' || b == b'.')
    {
        fail(
            "client_id",
            format!(
                "{} must be 1–{MAX_NAME_LEN} characters of A–Z a–z 0–9 _ - .",
                shown(&raw.client_id)
            ),
        );
    }
    if let Some(reason) = topic_prefix_problem(&raw.prefix) {
        fail("prefix", format!("{} {reason}", shown(&raw.prefix)));
    }
    if let Some(reason) = topic_prefix_problem(&raw.discovery_prefix) {
        fail(
            "discovery_prefix",
            format!("{} {reason}", shown(&raw.discovery_prefix)),
        );
    } else if raw.discovery {
        if let Some(reason) = link::prefix_overlap(&raw.prefix, &raw.discovery_prefix) {
            fail("prefix", reason);
        }
    }
    // rumqttc panics on a keep-alive under one second (other than zero, which we refuse too).
    if raw.keep_alive < Duration::from_secs(1) || raw.keep_alive > Duration::from_secs(65535) {
        fail(
            "keep_alive",
            format!(
                "{} must be between 1s and 65535s",
                humantime::format_duration(raw.keep_alive)
            ),
        );
    }
    if raw.inflight == 0 {
        fail(
            "inflight",
            "must be at least 1 (0 would stop every QoS 1 publish)".into(),
        );
    }

    let password = match (&raw.password, &raw.password_file) {
        (Some(_), Some(_)) => {
            fail(
                "password_file",
                "give either password or password_file, not both".into(),
            );
            None
        }
        (Some(password), None) => Some(password.clone()),
        (None, Some(file)) => read_password_file(&resolve(base, file))
            .map_err(|reason| fail("password_file", reason))
            .ok(),
        (None, None) => None,
    };
    if password.is_some() && raw.username.is_none() {
        fail(
            "username",
            "a password is configured but no username".into(),
        );
    }

    // TLS files: each must exist; a client certificate needs its key; mqtts needs a CA.
    let mut existing_file = |key: &str, file: &Option<PathBuf>| -> Option<PathBuf> {
        let path = resolve(base, file.as_ref()?);
        match std::fs::metadata(&path) {
            Ok(meta) if meta.is_file() => Some(path),
            Ok(_) => {
                fail(key, format!("{} is not a file", path.display()));
                None
            }
            Err(error) => {
                fail(key, format!("{}: {error}", path.display()));
                None
            }
        }
    };
    let ca = existing_file("ca_file", &raw.ca_file);
    let cert = existing_file("cert_file", &raw.cert_file);
    let key = existing_file("key_file", &raw.key_file);
    if let Some(reason) = ca.as_deref().and_then(link::ca_file_problem) {
        fail("ca_file", reason);
    }
    if raw.cert_file.is_some() != raw.key_file.is_some() {
        fail(
            "cert_file",
            "a client certificate needs both cert_file and key_file".into(),
        );
    }
    let any_tls_file = raw.ca_file.is_some() || raw.cert_file.is_some() || raw.key_file.is_some();
    match &endpoint {
        Ok(endpoint) if !endpoint.tls && any_tls_file => fail(
            "url",
            "TLS files are configured but the url is mqtt:// (use mqtts://)".into(),
        ),
        _ => {}
    }

    if problems.len() != before {
        return None;
    }
    let endpoint = endpoint.ok()?;
    let tls = if endpoint.tls {
        Some(TlsSettings {
            ca_file: ca,
            client_auth: cert.zip(key),
        })
    } else {
        None
    };
    Some(MqttSettings {
        host: endpoint.host,
        port: endpoint.port,
        tls,
        client_id: raw.client_id.clone(),
        prefix: raw.prefix.clone(),
        username: raw.username.clone(),
        password,
        keep_alive: raw.keep_alive,
        clean_session: raw.clean_session,
        inflight: raw.inflight,
        discovery: raw.discovery,
        discovery_prefix: raw.discovery_prefix.clone(),
    })
}

/// A broker address from `mqtt://host[:port]` or `mqtts://host[:port]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BrokerEndpoint {
    pub host: String,
    pub port: u16,
    pub tls: bool,
}

/// Parses `mqtt://host[:port]` / `mqtts://host[:port]` (IPv6 hosts in brackets).
pub fn parse_broker_url(url: &str) -> Result<BrokerEndpoint, String> {
    // Every message shows the URL with any password masked: it goes to the journal.
    let shown_url = link::masked_url(url);
    let (tls, rest) = if let Some(rest) = url.strip_prefix("mqtt://") {
        (false, rest)
    } else if let Some(rest) = url.strip_prefix("mqtts://") {
        (true, rest)
    } else {
        return Err(format!("{shown_url:?} must start with mqtt:// or mqtts://"));
    };
    let rest = rest.strip_suffix('/').unwrap_or(rest);
    if rest.contains('/') || rest.contains('@') || rest.contains('?') {
        return Err(format!(
            "{shown_url:?}: give only host and port (credentials go in username/password)"
        ));
    }
    let default_port = if tls { 8883 } else { 1883 };
    let (host, port) = if let Some(bracketed) = rest.strip_prefix('[') {
        let Some((host, after)) = bracketed.split_once(']') else {
            return Err(format!("{shown_url:?}: unclosed '[' in an IPv6 address"));
        };
        match after.strip_prefix(':') {
            Some(port) => (host, Some(port)),
            None if after.is_empty() => (host, None),
            None => {
                return Err(format!(
                    "{shown_url:?}: unexpected text after the IPv6 address"
                ))
            }
        }
    } else {
        match rest.rsplit_once(':') {
            Some((host, port)) => (host, Some(port)),
            None => (rest, None),
        }
    };
    if host.is_empty() {
        return Err(format!("{shown_url:?} has no host"));
    }
    let port = match port {
        None => default_port,
        Some(text) => match text.parse::<u16>() {
            Ok(port) if port > 0 => port,
            _ => return Err(format!("{shown_url:?}: port {text:?} is not 1–65535")),
        },
    };
    Ok(BrokerEndpoint {
        host: host.to_string(),
        port,
        tls,
    })
}

/// Reads a password file that only its owner and group may read (mode 0640 or stricter).
fn read_password_file(path: &Path) -> Result<String, String> {
    use std::os::unix::fs::PermissionsExt;
    let meta = std::fs::metadata(path).map_err(|error| format!("{}: {error}", path.display()))?;
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o137 != 0 {
        return Err(format!(
            "{} has mode {mode:04o}: a password file must be 0640 or stricter \
             (no access for others, no write for the group)",
            path.display()
        ));
    }
    let text =
        std::fs::read_to_string(path).map_err(|error| format!("{}: {error}", path.display()))?;
    let password = text.trim_end_matches(['\r', '\n']).to_string();
    if password.is_empty() {
        return Err(format!("{} is empty", path.display()));
    }
    Ok(password)
}

fn validate_health(raw: &RawConfig, problems: &mut Vec<Problem>) {
    let health = &raw.health;
    if health.interval < Duration::from_millis(100) {
        problems.push(Problem::new(
            "health.interval",
            "must be at least 100ms".to_string(),
        ));
    }
    if health.stale_after <= health.interval {
        problems.push(Problem::new(
            "health.stale_after",
            "must be longer than health.interval".to_string(),
        ));
    }
}

/// Home Assistant would drop one of two entities sharing a `unique_id`
/// (device `a` + field `b_c` and device `a_b` + field `c`).
fn check_unique_ids(mqtt: &MqttSettings, lines: &[LineSpec], problems: &mut Vec<Problem>) {
    let fields = lines
        .iter()
        .flat_map(|line| line.devices.iter())
        .flat_map(|device| {
            (device.profile.fields().iter())
                .map(|field| (device.name.as_str(), field.name.as_str()))
        });
    for id in mqtt.topics().unique_id_collisions(fields) {
        problems.push(Problem::new(
            "lines",
            format!("two fields would share the Home Assistant unique_id {id:?}: rename a device"),
        ));
    }
}

fn validate_gateway(raw: &RawGateway, problems: &mut Vec<Problem>) -> Option<GatewayOptions> {
    let before = problems.len();
    let mut fail = |place: &str, reason: String| {
        problems.push(Problem::new(format!("gateway.{place}"), reason));
    };
    if raw.command_ttl.is_zero() || raw.command_ttl > Duration::from_secs(7 * 24 * 3600) {
        fail(
            "command_ttl",
            format!(
                "{} must be more than 0 and at most 7 days",
                humantime::format_duration(raw.command_ttl)
            ),
        );
    }
    if raw.stats_interval < Duration::from_secs(1) {
        fail(
            "stats_interval",
            format!(
                "{} is under 1s",
                humantime::format_duration(raw.stats_interval)
            ),
        );
    }
    let metrics_listen = match &raw.metrics_listen {
        None => None,
        Some(text) => match text.parse::<SocketAddr>() {
            Ok(address) => Some(address),
            Err(_) => {
                fail(
                    "metrics_listen",
                    format!("{text:?} is not an address:port such as 127.0.0.1:9184"),
                );
                None
            }
        },
    };
    if let Some(file) = &raw.frame_log {
        let parent = file
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        if !parent.is_dir() {
            fail(
                "frame_log",
                format!("directory {} does not exist", parent.display()),
            );
        }
    }
    if raw.max_payload == 0 || raw.max_payload > MAX_PAYLOAD_LIMIT {
        fail(
            "max_payload",
            format!("{} must be 1–{MAX_PAYLOAD_LIMIT} bytes", raw.max_payload),
        );
    }
    if problems.len() != before {
        return None;
    }
    if raw.allow_raw_writes {
        tracing::warn!(
            "gateway.allow_raw_writes: this version has no raw register write topic; only \
             profile fields can be written"
        );
    }
    Some(GatewayOptions {
        command_ttl: raw.command_ttl,
        json_view: raw.json_view,
        stats_interval: raw.stats_interval,
        metrics_listen,
        frame_log: raw.frame_log.clone(),
        allow_raw_writes: raw.allow_raw_writes,
        max_payload: raw.max_payload,
    })
}

fn validate_lines(
    raw_lines: &[RawLine],
    base: &Path,
    problems: &mut Vec<Problem>,
    warnings: &mut Vec<Problem>,
) -> Vec<LineSpec> {
    if raw_lines.is_empty() {
        problems.push(Problem::new(
            "lines",
            "no [[lines]] configured: the gateway would have nothing to do",
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
        // A Modbus TCP gateway runs its serial side itself: no baud of ours times it.
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
            frame_log: None,
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

fn validate_device(
    raw: &RawDevice,
    place: &str,
    base: &Path,
    profiles: &mut HashMap<String, Arc<Profile>>,
    names: &mut HashMap<String, String>,
    problems: &mut Vec<Problem>,
) -> Option<DeviceSpec> {
    let before = problems.len();
    if !is_valid_name(&raw.name) {
        problems.push(invalid_name(place, &raw.name));
    } else if let Some(reason) = reserved_name_problem(&raw.name) {
        problems.push(Problem::new(format!("{place}.name"), reason));
    } else {
        if let Some(first) = names.get(&raw.name) {
            problems.push(Problem::new(
                format!("{place}.name"),
                format!("{:?} is already the name of {first}", raw.name),
            ));
        } else {
            names.insert(raw.name.clone(), place.to_string());
        }
    }

    let profile = match profiles.get(&raw.profile) {
        Some(profile) => Some(profile.clone()),
        None => match resolve_profile(&raw.profile, base) {
            Ok(profile) => {
                // Once per profile: its field names become topic levels.
                for reason in field_name_problems(&profile) {
                    problems.push(Problem::new(format!("{place}.profile"), reason));
                }
                let profile = Arc::new(profile);
                profiles.insert(raw.profile.clone(), profile.clone());
                Some(profile)
            }
            Err(reason) => {
                problems.push(Problem::new(format!("{place}.profile"), reason));
                None
            }
        },
    };
    let profile = profile?;
    let limits = profile.limits();
    let range = &limits.address_range;
    let address = match u8::try_from(raw.address) {
        Ok(address) if range.contains(&address) => Some(address),
        _ => {
            problems.push(Problem::new(
                format!("{place}.address"),
                format!(
                    "{} is outside {}–{} allowed by profile {}",
                    raw.address,
                    range.start(),
                    range.end(),
                    profile.name()
                ),
            ));
            None
        }
    };
    let poll_interval = raw.poll_interval.unwrap_or(limits.default_poll_interval);
    // Zero is continuous polling, which keeps the profile's minimum by itself.
    if !poll_interval.is_zero() && poll_interval < limits.min_poll_interval {
        problems.push(Problem::new(
            format!("{place}.poll_interval"),
            format!(
                "{} is under the minimum {} of profile {}",
                humantime::format_duration(poll_interval),
                humantime::format_duration(limits.min_poll_interval),
                profile.name()
            ),
        ));
    }
    if poll_interval > Duration::from_secs(24 * 3600) {
        problems.push(Problem::new(
            format!("{place}.poll_interval"),
            "must be at most 24h".to_string(),
        ));
    }
    for (number, exponent) in profile.exponents_read_too_rarely(poll_interval) {
        problems.push(Problem::new(
            format!("{place}.poll_interval"),
            format!(
                "at {} the exponent `{exponent}` of `{number}` (profile {}) would be read less \
                 often than `{number}` itself; poll the device at most as often as the \
                 exponent's block is read",
                humantime::format_duration(poll_interval),
                profile.name()
            ),
        ));
    }
    let publish = device_publish(raw, place, &profile, problems);
    if problems.len() != before {
        return None;
    }
    Some(DeviceSpec {
        name: raw.name.clone(),
        address: address?,
        profile,
        poll_interval,
        publish,
    })
}

/// The device's `publish` table, checked, and with it each field's own keys: together they
/// must still hold (a field's `min_interval` over the device's `max_interval` is refused).
fn device_publish(
    raw: &RawDevice,
    place: &str,
    profile: &Profile,
    problems: &mut Vec<Problem>,
) -> PublishRule {
    let Some(table) = &raw.publish else {
        return PublishRule::default();
    };
    let rule = match PublishRule::from_raw(table) {
        Ok(rule) => rule,
        Err(found) => {
            for (key, reason) in found {
                problems.push(Problem::new(format!("{place}.publish.{key}"), reason));
            }
            return PublishRule::default();
        }
    };
    for field in profile.fields() {
        if let Some(reason) = field.publish.or(rule).interval_problem() {
            problems.push(Problem::new(
                format!("{place}.publish"),
                format!(
                    "field `{}` of profile {}: {reason}",
                    field.name,
                    profile.name()
                ),
            ));
        }
    }
    rule
}

/// Default network allowance of TCP lines (on top of the default response timeout).
pub const DEFAULT_NETWORK_ALLOWANCE: Duration = Duration::from_millis(200);

fn is_modbus_tcp(transport: &Transport) -> bool {
    matches!(transport, Transport::Tcp { endpoint, .. } if endpoint.kind == TcpKind::ModbusTcp)
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
            let identity = link::port_identity(port).to_string_lossy().into_owned();
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
            if endpoint.kind == TcpKind::ModbusTcp {
                for (key, set) in [
                    ("baud", raw.baud.is_some()),
                    ("parity", raw.parity.is_some()),
                ] {
                    if set {
                        warnings.push(Problem::new(
                            format!("{place}.{key}"),
                            "means nothing on a modbus-tcp:// line (the gateway's own serial \
                             settings apply): ignored",
                        ));
                    }
                }
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

/// Field names of `profile` the contract cannot carry: reserved words, or longer than a topic
/// level may be.
fn field_name_problems(profile: &Profile) -> Vec<String> {
    let mut reasons = Vec::new();
    for field in profile.fields() {
        let name = &field.name;
        if name.len() > MAX_NAME_LEN {
            reasons.push(format!(
                "profile {}: field {} is a topic level and must be at most {MAX_NAME_LEN} \
                 characters",
                shown(profile.name()),
                shown(name)
            ));
        } else if let Some(reason) = reserved_name_problem(name) {
            reasons.push(format!("profile {}: field {reason}", shown(profile.name())));
        }
    }
    reasons
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

fn resolve(base: &Path, path: &Path) -> PathBuf {
    if path.is_absolute() {
        path.to_path_buf()
    } else {
        base.join(path)
    }
}

/// A built-in profile by name, else a profile file (relative to the config file).
fn resolve_profile(spec: &str, base: &Path) -> Result<Profile, String> {
    crate::profile::registry::load(spec, Some(base)).map_err(|error| error.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broker_urls() {
        assert_eq!(
            parse_broker_url("mqtt://127.0.0.1:1883"),
            Ok(BrokerEndpoint {
                host: "127.0.0.1".into(),
                port: 1883,
                tls: false
            })
        );
        assert_eq!(
            parse_broker_url("mqtts://broker.example").map(|e| (e.port, e.tls)),
            Ok((8883, true))
        );
        assert_eq!(
            parse_broker_url("mqtt://[::1]:1884").map(|e| (e.host, e.port)),
            Ok(("::1".to_string(), 1884))
        );
        for bad in [
            "tcp://host:1883",
            "mqtt://",
            "mqtt://host:0",
            "mqtt://host:99999",
            "mqtt://user:pw@host",
            "mqtt://host/path",
            "mqtt://[::1",
        ] {
            assert!(parse_broker_url(bad).is_err(), "{bad} accepted");
        }
    }

    #[test]
    fn topic_prefixes() {
        for good in ["plant", "site1/plant", "a-b_c"] {
            assert_eq!(topic_prefix_problem(good), None, "{good}");
        }
        for bad in [
            "", "pl+ant", "plant/#", "nul\0", "$SYS", "/plant", "plant/", "a//b",
        ] {
            assert!(topic_prefix_problem(bad).is_some(), "{bad:?} accepted");
        }
    }

    #[test]
    fn names() {
        assert!(is_valid_name("dust_collector"));
        assert!(is_valid_name("line-a"));
        for bad in ["", "Dust", "a b", "a/b", "a+", "ä", &"x".repeat(65)] {
            assert!(!is_valid_name(bad), "{bad:?} accepted");
        }
    }

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
    fn tcp_lines_get_their_transport_and_modbus_tcp_warns_about_serial_settings() {
        let (problems, warnings) = link_findings(&["url = \"modbus-tcp://gw:502\"\nbaud = 19200"]);
        assert!(problems.is_empty(), "{problems:?}");
        assert!(
            has(
                &warnings,
                "lines[0].baud: means nothing on a modbus-tcp:// line"
            ),
            "{warnings:?}"
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

    fn mqtt_problems(mqtt_table: &str, base: &Path) -> Vec<String> {
        let text = format!("[mqtt]\nclient_id = \"edge1\"\n{mqtt_table}\n");
        let raw = crate::config::load::load_str(&text).unwrap();
        let mut problems = Vec::new();
        let settings = validate_mqtt(&raw.mqtt, base, &mut problems);
        assert_eq!(settings.is_none(), !problems.is_empty());
        problems.iter().map(|p| p.to_string()).collect()
    }

    #[test]
    fn tls_settings_are_checked() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("ca.crt"), super::link::TEST_CA_PEM).unwrap();
        std::fs::write(dir.path().join("client.crt"), "x").unwrap();
        let base = dir.path();
        assert_eq!(
            mqtt_problems("url = \"mqtts://broker:8883\"\nca_file = \"ca.crt\"", base),
            Vec::<String>::new()
        );
        // Without ca_file, the system's trust store.
        assert_eq!(
            mqtt_problems("url = \"mqtts://broker:8883\"", base),
            Vec::<String>::new()
        );
        // Each broken setting, and how its first problem begins.
        let broken = [
            (
                "url = \"mqtt://broker\"\nca_file = \"ca.crt\"",
                "mqtt.url: TLS files",
            ),
            (
                "url = \"mqtts://broker\"\nca_file = \"ca.crt\"\ncert_file = \"client.crt\"",
                "mqtt.cert_file: a client certificate needs",
            ),
            (
                "url = \"mqtts://broker\"\nca_file = \"nowhere.crt\"",
                "mqtt.ca_file: ",
            ),
            (
                "url = \"mqtt://broker\"\nusername = \"u\"\npassword = \"p\"\npassword_file = \"pw\"",
                "mqtt.password_file: give either",
            ),
            (
                "url = \"mqtt://broker\"\npassword = \"p\"",
                "mqtt.username:",
            ),
        ];
        for (keys, first_problem) in broken {
            let problems = mqtt_problems(keys, base);
            assert!(
                problems[0].starts_with(first_problem),
                "{keys}: {problems:?}"
            );
        }
    }

    #[test]
    fn password_file_must_not_be_world_readable() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("password");
        std::fs::write(&path, "s3cret\n").unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
        let error = read_password_file(&path).unwrap_err();
        assert!(error.contains("0644"), "{error}");
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o640)).unwrap();
        assert_eq!(read_password_file(&path).unwrap(), "s3cret");
    }

    const PLAIN: &str = "[mqtt]\nurl = \"mqtt://127.0.0.1:1883\"\nclient_id = \"edge1\"\n";
    const LINE: &str = "[[lines]]\nname = \"a\"\nport = \"/dev/ttyS0\"\n[[lines.devices]]\nname = \"valve\"\nprofile = \"wuzhou-valve\"\naddress = 3\n";

    fn load_with_sparkplug(extra: &str) -> Result<super::super::Config, String> {
        super::super::from_str(&format!("{PLAIN}{LINE}{extra}"), Path::new("."))
            .map_err(|problems| problems.to_string())
    }

    #[test]
    fn absent_means_no_edge_node_and_present_shares_the_broker_by_default() {
        let config = load_with_sparkplug("").unwrap_or_else(|problems| panic!("{problems}"));
        assert!(config.sparkplug.is_none());
        let Ok(config) = load_with_sparkplug("[sparkplug]\ngroup_id = \"plant\"\n") else {
            panic!("[sparkplug] refused");
        };
        let Some(sparkplug) = config.sparkplug else {
            panic!("[sparkplug] ignored");
        };
        assert_eq!(sparkplug.identity.edge_node_id, "edge1");
        assert_eq!(sparkplug.mqtt.client_id, "edge1-sparkplug");
        assert_eq!(sparkplug.mqtt.port, 1883);
        assert!(sparkplug.mqtt.clean_session);
    }

    #[test]
    fn its_own_broker_is_checked_like_mqtt_with_every_problem_placed() {
        let Ok(config) = load_with_sparkplug(
            "[sparkplug]\ngroup_id = \"plant\"\n[sparkplug.mqtt]\nurl = \"mqtt://scada:1884\"\nclient_id = \"edge1\"\n",
        ) else {
            panic!("own broker refused");
        };
        let mqtt = config.sparkplug.map(|sparkplug| sparkplug.mqtt);
        assert_eq!(
            mqtt.map(|mqtt| (mqtt.host, mqtt.port)),
            Some(("scada".into(), 1884))
        );

        let Err(problems) = load_with_sparkplug(
            "[sparkplug]\ngroup_id = \"a/b\"\n[sparkplug.mqtt]\nurl = \"http://x\"\nclient_id = \"edge1\"\ninflight = 0\n",
        ) else {
            panic!("bad section accepted");
        };
        for expected in [
            "sparkplug.group_id: `a/b` contains `/`",
            "sparkplug.mqtt.url: \"http://x\" must start with mqtt://",
            "sparkplug.mqtt.inflight: must be at least 1",
        ] {
            assert!(problems.contains(expected), "{expected}\n{problems}");
        }

        let Err(problems) = load_with_sparkplug(
            "[sparkplug]\ngroup_id = \"plant\"\n[sparkplug.mqtt]\nurl = \"mqtt://127.0.0.1:1883\"\nclient_id = \"edge1\"\n",
        ) else {
            panic!("a client id taking over the plain connection accepted");
        };
        assert!(
            problems.contains("sparkplug.mqtt.client_id: \"edge1\" is also mqtt.client_id"),
            "{problems}"
        );

        let Err(problems) = load_with_sparkplug("[sparkplug]\nedge_node_id = \"gw\"\ncolour = 1\n")
        else {
            panic!("missing group_id accepted");
        };
        assert!(
            problems.contains("sparkplug.group_id: required"),
            "{problems}"
        );
        assert!(
            problems.contains("sparkplug.colour: unknown key"),
            "{problems}"
        );
    }
}
