//! The checks of a broker table in the form of `[mqtt]` (`[mqtt]` itself and
//! `[sparkplug.mqtt]`): the broker URL, the client id and topic prefixes (they become topic
//! levels), keep-alive and inflight, the password (or its file, which only its owner and group
//! may read) and the TLS files (each must exist; a CA file must hold a certificate). Messages
//! show a broker URL with its password masked. Files are read, nothing is opened.

use std::path::{Path, PathBuf};
use std::time::Duration;

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::CertificateDer;
use rustls::RootCertStore;

use super::files::{read_password_file, resolve};
use super::names::{shown, MAX_NAME_LEN};
use super::problem::Problem;
use super::schema::RawMqtt;
use crate::topics::{Topics, MAX_TOPIC_LEN};

/// How to reach the broker, checked.
#[derive(Debug, Clone, PartialEq)]
pub struct MqttSettings {
    pub host: String,
    pub port: u16,
    /// Present for `mqtts://`.
    pub tls: Option<TlsSettings>,
    pub client_id: String,
    /// Topic prefix (`plant`).
    pub prefix: String,
    pub username: Option<String>,
    /// From the file, the environment or `password_file`.
    pub password: Option<String>,
    pub keep_alive: Duration,
    pub clean_session: bool,
    pub inflight: u16,
    pub discovery: bool,
    pub discovery_prefix: String,
}

impl MqttSettings {
    /// The topics and Home Assistant names of this gateway.
    pub fn topics(&self) -> Topics {
        Topics::new(&self.client_id, &self.prefix).with_discovery_prefix(&self.discovery_prefix)
    }
}

/// TLS files (checked to exist; read when connecting).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsSettings {
    /// The CA bundle the broker's certificate is verified against; None: the system's trust
    /// store.
    pub ca_file: Option<PathBuf>,
    /// Client certificate and key.
    pub client_auth: Option<(PathBuf, PathBuf)>,
}

/// Topic prefixes (`plant`, `site1/plant`).
const MAX_PREFIX_LEN: usize = 128;
// The longest topic the gateway builds (`<prefix>/<device>/<field>/result`, and the discovery
// topic `<discovery_prefix>/device/<client_id>_<device>/config`) stays within the length it
// accepts on incoming topics, far below MQTT's 65,535 bytes.
const _: () = assert!(MAX_PREFIX_LEN + 2 * MAX_NAME_LEN + "///result".len() <= MAX_TOPIC_LEN);
const _: () =
    assert!(MAX_PREFIX_LEN + 2 * MAX_NAME_LEN + "/device/_/config".len() <= MAX_TOPIC_LEN);

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

pub(super) fn validate_mqtt(
    raw: &RawMqtt,
    base: &Path,
    problems: &mut Vec<Problem>,
) -> Option<MqttSettings> {
    validate_mqtt_section("mqtt", raw, base, problems)
}

/// A broker table in the form of `[mqtt]` at `section` (`mqtt`, `sparkplug.mqtt`).
pub(super) fn validate_mqtt_section(
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
        if let Some(reason) = prefix_overlap(&raw.prefix, &raw.discovery_prefix) {
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
    if let Some(reason) = ca.as_deref().and_then(ca_file_problem) {
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
///
/// By hand, not with the `url` crate: splitting a scheme, a host and a port is all it takes,
/// while `url` brings its IDNA and Unicode tables into the edge build and words its errors
/// without the port the user wrote.
pub fn parse_broker_url(url: &str) -> Result<BrokerEndpoint, String> {
    // Every message shows the URL with any password masked: it goes to the journal.
    let shown_url = masked_url(url);
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

/// `url` with the password of any `user:password@` masked (`mqtt://user:***@host`).
pub fn masked_url(url: &str) -> String {
    let (scheme, rest) = match url.split_once("://") {
        Some((scheme, rest)) => (Some(scheme), rest),
        None => (None, url),
    };
    let Some((credentials, host)) = rest.rsplit_once('@') else {
        return url.to_string();
    };
    let user = match credentials.split_once(':') {
        Some((user, _password)) => format!("{user}:***"),
        None => credentials.to_string(),
    };
    match scheme {
        Some(scheme) => format!("{scheme}://{user}@{host}"),
        None => format!("{user}@{host}"),
    }
}

/// Why `prefix` and the discovery prefix collide, if they do: equal, or one a topic-level
/// prefix of the other (the gateway's topics would land in Home Assistant's space, or the
/// reverse: a device `status` would publish its JSON view on Home Assistant's status topic).
pub fn prefix_overlap(prefix: &str, discovery_prefix: &str) -> Option<String> {
    let within = |outer: &str, inner: &str| {
        inner
            .strip_prefix(outer)
            .is_some_and(|rest| rest.starts_with('/'))
    };
    if prefix == discovery_prefix {
        Some(format!(
            "{} is also the discovery prefix: give the gateway's topics their own prefix",
            shown(prefix)
        ))
    } else if within(discovery_prefix, prefix) || within(prefix, discovery_prefix) {
        Some(format!(
            "{} and the discovery prefix {} nest inside each other: their topics would collide",
            shown(prefix),
            shown(discovery_prefix)
        ))
    } else {
        None
    }
}

/// Why the CA file at `path` cannot serve as one, if it cannot: it must hold at least one PEM
/// certificate that TLS accepts as a trust anchor (what the connection will need), so a wrong
/// file is refused by `check` instead of making `run` retry TLS for ever.
pub fn ca_file_problem(path: &Path) -> Option<String> {
    let bytes = match std::fs::read(path) {
        Ok(bytes) => bytes,
        Err(error) => return Some(format!("{}: {error}", path.display())),
    };
    let mut certificates = Vec::new();
    for item in CertificateDer::pem_slice_iter(&bytes) {
        match item {
            Ok(certificate) => certificates.push(certificate),
            Err(error) => {
                return Some(format!(
                    "{}: not a readable PEM file ({error})",
                    path.display()
                ))
            }
        }
    }
    if certificates.is_empty() {
        return Some(format!(
            "{} holds no PEM certificate (-----BEGIN CERTIFICATE-----)",
            path.display()
        ));
    }
    let mut store = RootCertStore::empty();
    let (added, _ignored) = store.add_parsable_certificates(certificates);
    (added == 0).then(|| {
        format!(
            "{}: none of its certificates can be parsed as a CA certificate",
            path.display()
        )
    })
}

/// A self-signed CA certificate for tests (no key exists for it anywhere).
#[cfg(test)]
pub(crate) const TEST_CA_PEM: &str = "\
-----BEGIN CERTIFICATE-----\n\
MIIBjTCCATOgAwIBAgIUFcVc4p544C3GCa2DXsefqg15KlIwCgYIKoZIzj0EAwIw\n\
GzEZMBcGA1UEAwwQcnR1Mm1xdHQgdGVzdCBDQTAgFw0yNjEyMDExODQwNTJaGA8y\n\
MTI2MTEwNzE4NDA1MlowGzEZMBcGA1UEAwwQcnR1Mm1xdHQgdGVzdCBDQTBZMBMG\n\
ByqGSM49AgEGCCqGSM49AwEHA0IABDooV2QOgy9gN3hZqvHbnicmdinZJ/pfp14K\n\
E+Xr+ZoT+TOC1nJUvH3/aRP9IXCf4z1q3ZbjPSB0l4hKhDww6p+jUzBRMB0GA1Ud\n\
DgQWBBTC48ExldxpKItWcB1McSUgpnLpKjAfBgNVHSMEGDAWgBTC48ExldxpKItW\n\
cB1McSUgpnLpKjAPBgNVHRMBAf8EBTADAQH/MAoGCCqGSM49BAMCA0gAMEUCICz6\n\
Ofc3bjjLjzhDIZWGCmUTG/ykpyliEf4jAsMey8FqAiEAtro+2+juIX/1GiH4oGw8\n\
GAuWp5RCL17ALiPZAE3z2LI=\n\
-----END CERTIFICATE-----\n\
";

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
        std::fs::write(dir.path().join("ca.crt"), TEST_CA_PEM).unwrap();
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

    #[test]
    fn passwords_are_masked() {
        assert_eq!(
            masked_url("mqtt://user:secret@host:1883"),
            "mqtt://user:***@host:1883"
        );
        assert_eq!(masked_url("mqtt://user@host"), "mqtt://user@host");
        assert_eq!(masked_url("mqtt://host"), "mqtt://host");
        assert_eq!(masked_url("u:p@w@host"), "u:***@host");
    }

    #[test]
    fn a_ca_file_must_hold_a_certificate() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ca.crt");
        std::fs::write(&path, TEST_CA_PEM).unwrap();
        assert_eq!(ca_file_problem(&path), None);
        for junk in [
            "x",
            "",
            "-----BEGIN PRIVATE KEY-----\nMAA=\n-----END PRIVATE KEY-----\n",
            "-----BEGIN CERTIFICATE-----\nMAA=\n-----END CERTIFICATE-----\n",
        ] {
            std::fs::write(&path, junk).unwrap();
            assert!(ca_file_problem(&path).is_some(), "{junk:?} accepted");
        }
    }

    #[test]
    fn prefixes_must_not_nest() {
        assert!(prefix_overlap("plant", "homeassistant").is_none());
        assert!(prefix_overlap("plantx", "plant").is_none());
        assert!(prefix_overlap("ha", "ha").is_some());
        assert!(prefix_overlap("ha/plant", "ha").is_some());
        assert!(prefix_overlap("plant", "plant/ha").is_some());
    }

    #[test]
    fn each_broken_key_is_refused_at_its_place_in_its_own_section() {
        let text =
            "[mqtt]\nurl = \"mqtt://broker\"\nclient_id = \"edge 1\"\nprefix = \"homeassistant\"\n\
                    keep_alive = \"500ms\"\ninflight = 0\n";
        let raw = crate::config::load::load_str(text).unwrap();
        let mut problems = Vec::new();
        let settings =
            validate_mqtt_section("sparkplug.mqtt", &raw.mqtt, Path::new("."), &mut problems);
        assert!(settings.is_none());
        let shown: Vec<String> = problems.iter().map(ToString::to_string).collect();
        assert_eq!(
            shown,
            [
                "sparkplug.mqtt.client_id: \"edge 1\" must be 1–64 characters of A–Z a–z 0–9 _ - .",
                "sparkplug.mqtt.prefix: \"homeassistant\" is also the discovery prefix: give the \
                 gateway's topics their own prefix",
                "sparkplug.mqtt.keep_alive: 500ms must be between 1s and 65535s",
                "sparkplug.mqtt.inflight: must be at least 1 (0 would stop every QoS 1 publish)",
            ]
        );
    }

    #[test]
    fn a_url_with_a_password_is_refused_with_the_password_masked() {
        let problem = parse_broker_url("mqtt://gw:s3cret@broker:1883").unwrap_err();
        assert!(!problem.contains("s3cret"), "{problem}");
        assert!(problem.contains("gw:***@broker"), "{problem}");
    }
}
