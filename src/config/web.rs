//! The `[web]` table: where the browser console listens, the token that lets a person in, and
//! its optional TLS certificate (the console itself is `crate::web`'s). Without the table, or
//! without `listen`, the gateway serves no HTTP at all (but `gateway.metrics_listen`).

use std::net::SocketAddr;
use std::path::PathBuf;

use serde::Deserialize;

use super::files::{read_password_file, resolve};
use super::problem::Problem;

/// The shortest token accepted: a guessable one would open the plant to its network.
pub const MIN_TOKEN_LEN: usize = 16;

/// The table as written.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct RawWeb {
    /// `host:port` to listen on (`127.0.0.1:8080`); absent: no console.
    pub listen: Option<String>,
    /// The login token itself, meant for the environment (`RTU2MQTT__WEB__TOKEN`).
    pub token: Option<String>,
    /// A file holding the login token (mode 0640 or stricter), like `mqtt.password_file`.
    pub token_file: Option<PathBuf>,
    /// PEM certificate chain: the console speaks HTTPS (with `key_file`).
    pub cert_file: Option<PathBuf>,
    /// PEM private key of `cert_file`.
    pub key_file: Option<PathBuf>,
}

/// The checked `[web]` table.
#[derive(Clone, PartialEq, Eq)]
pub struct WebSettings {
    pub listen: SocketAddr,
    /// None: a read-only console on a loopback address, without a login.
    pub token: Option<String>,
    /// The certificate chain and key files, for HTTPS.
    pub tls: Option<(PathBuf, PathBuf)>,
}

impl std::fmt::Debug for WebSettings {
    /// The token is a secret: never in a log line.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WebSettings")
            .field("listen", &self.listen)
            .field("token", &self.token.as_ref().map(|_| "***"))
            .field("tls", &self.tls)
            .finish()
    }
}

/// Checks the table (paths relative to `base`); None when the console is off or a problem
/// was found (each named with its place, `web.listen`).
pub(super) fn validate_web(
    raw: &RawWeb,
    base: &std::path::Path,
    problems: &mut Vec<Problem>,
) -> Option<WebSettings> {
    let before = problems.len();
    let mut fail = |place: &str, reason: String| {
        problems.push(Problem::new(format!("web.{place}"), reason));
    };
    let token = match (&raw.token, &raw.token_file) {
        (Some(_), Some(_)) => {
            fail(
                "token_file",
                "give either token or token_file, not both".into(),
            );
            None
        }
        (Some(token), None) => Some(token.trim().to_string()),
        (None, Some(file)) => match read_password_file(&resolve(base, file)) {
            Ok(token) => Some(token),
            Err(reason) => {
                fail("token_file", reason);
                None
            }
        },
        (None, None) => None,
    };
    if let Some(token) = &token {
        if token.chars().count() < MIN_TOKEN_LEN {
            fail(
                "token",
                format!("must be at least {MIN_TOKEN_LEN} characters (`openssl rand -hex 16`)"),
            );
        }
    }
    let tls = match (&raw.cert_file, &raw.key_file) {
        (Some(cert), Some(key)) => {
            let (cert, key) = (resolve(base, cert), resolve(base, key));
            for (place, path) in [("cert_file", &cert), ("key_file", &key)] {
                if !path.is_file() {
                    fail(place, format!("{} is not a readable file", path.display()));
                }
            }
            Some((cert, key))
        }
        (None, None) => None,
        (Some(_), None) => {
            fail("key_file", "is required with cert_file".into());
            None
        }
        (None, Some(_)) => {
            fail("cert_file", "is required with key_file".into());
            None
        }
    };
    let listen = match &raw.listen {
        None => {
            if raw.token.is_some() || raw.token_file.is_some() || tls.is_some() {
                fail(
                    "listen",
                    "is required for the console (127.0.0.1:8080); without it nothing is served"
                        .into(),
                );
            }
            return None;
        }
        Some(text) => match text.parse::<SocketAddr>() {
            Ok(address) => Some(address),
            Err(_) => {
                fail(
                    "listen",
                    format!("{text:?} is not an address:port such as 127.0.0.1:8080"),
                );
                None
            }
        },
    };
    if let (Some(listen), None) = (listen, &token) {
        if !listen.ip().is_loopback() {
            fail(
                "listen",
                format!(
                    "{listen} is reachable from other machines: without a token the console \
                     listens only on a loopback address (127.0.0.1:8080); set token_file \
                     (or RTU2MQTT__WEB__TOKEN) to serve it on {listen}"
                ),
            );
        }
    }
    match listen {
        Some(listen) if problems.len() == before => Some(WebSettings { listen, token, tls }),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(raw: RawWeb) -> (Option<WebSettings>, Vec<String>) {
        let mut problems = Vec::new();
        let settings = validate_web(&raw, std::path::Path::new("."), &mut problems);
        (settings, problems.iter().map(|p| p.to_string()).collect())
    }

    #[test]
    fn without_listen_there_is_no_console() {
        assert_eq!(check(RawWeb::default()), (None, vec![]));
    }

    #[test]
    fn without_a_token_only_a_loopback_address_is_taken() {
        let (settings, problems) = check(RawWeb {
            listen: Some("127.0.0.1:8080".into()),
            ..RawWeb::default()
        });
        assert_eq!(problems, Vec::<String>::new());
        assert_eq!(settings.map(|s| s.token), Some(None));
        let (settings, problems) = check(RawWeb {
            listen: Some("0.0.0.0:8080".into()),
            ..RawWeb::default()
        });
        assert!(settings.is_none());
        assert!(
            problems[0].starts_with("web.listen: 0.0.0.0:8080 is reachable from other machines"),
            "{problems:?}"
        );
    }

    #[test]
    fn a_token_opens_every_address_and_must_be_long() {
        let (settings, problems) = check(RawWeb {
            listen: Some("0.0.0.0:8080".into()),
            token: Some("0123456789abcdef".into()),
            ..RawWeb::default()
        });
        assert_eq!(problems, Vec::<String>::new());
        assert!(settings.is_some());
        let (_, problems) = check(RawWeb {
            listen: Some("127.0.0.1:8080".into()),
            token: Some("short".into()),
            ..RawWeb::default()
        });
        assert!(
            problems[0].starts_with("web.token: must be at least 16"),
            "{problems:?}"
        );
    }

    #[test]
    fn the_token_never_shows_in_a_log_line() {
        let (settings, _) = check(RawWeb {
            listen: Some("127.0.0.1:8080".into()),
            token: Some("0123456789abcdef-secret".into()),
            ..RawWeb::default()
        });
        let shown = format!("{settings:?}");
        assert!(!shown.contains("secret"), "{shown}");
    }

    #[test]
    fn half_a_certificate_is_a_problem() {
        let (_, problems) = check(RawWeb {
            listen: Some("127.0.0.1:8443".into()),
            cert_file: Some("cert.pem".into()),
            ..RawWeb::default()
        });
        assert!(problems
            .iter()
            .any(|p| p.starts_with("web.key_file: is required")));
    }
}
