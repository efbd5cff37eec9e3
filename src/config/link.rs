//! Checks that keep a configuration from breaking the MQTT link or leaking a secret: names the
//! contract reserves, bounded lengths shown without echoing a huge value, one port spelled two
//! ways, a topic prefix inside the discovery prefix's topic space (or the reverse), a CA file
//! that holds no certificate, and broker URLs shown with their password masked. Pure checks:
//! they read files (the CA) but open nothing.

use std::path::{Component, Path, PathBuf};

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::CertificateDer;
use rustls::RootCertStore;

/// Longest part of a user's value quoted in a message; longer ones are cut and their length
/// given (a 70,000-character name must not become a 70,000-character log line).
const SHOWN_MAX: usize = 48;

/// `value` quoted for a message, cut to [`SHOWN_MAX`] characters.
pub fn shown(value: &str) -> String {
    if value.chars().count() <= SHOWN_MAX {
        return format!("{value:?}");
    }
    let head: String = value.chars().take(SHOWN_MAX).collect();
    format!("{head:?}… ({} bytes)", value.len())
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

/// The path a port name reaches: links and `.`/`..` resolved when it exists (a by-id link and
/// its target are one port), else normalised lexically (`/dev/./ttyA` is `/dev/ttyA`).
pub fn port_identity(port: &str) -> PathBuf {
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
    fn long_values_are_cut() {
        let long = "x".repeat(70_000);
        let text = shown(&long);
        assert!(text.len() < 100, "{text}");
        assert!(text.ends_with("(70000 bytes)"), "{text}");
        assert_eq!(shown("valve"), "\"valve\"");
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
}
