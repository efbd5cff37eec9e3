//! The checks of `[gateway]`: how long a command may wait, how often statistics are published,
//! where metrics are served, the frame log's directory and the largest command payload.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::problem::Problem;
use super::schema::RawGateway;

/// Per-gateway behaviour of the bridge.
#[derive(Debug, Clone, PartialEq)]
pub struct GatewayOptions {
    pub command_ttl: Duration,
    pub json_view: bool,
    pub stats_interval: Duration,
    pub metrics_listen: Option<SocketAddr>,
    pub frame_log: Option<PathBuf>,
    pub allow_raw_writes: bool,
    pub max_payload: usize,
}

/// Largest accepted command payload limit (a command is a word or a number).
const MAX_PAYLOAD_LIMIT: usize = 64 * 1024;

pub(super) fn validate_gateway(
    raw: &RawGateway,
    problems: &mut Vec<Problem>,
) -> Option<GatewayOptions> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_broken_key_is_refused_at_its_place() {
        let raw: RawGateway = toml::from_str(
            "command_ttl = \"0s\"\nstats_interval = \"10ms\"\nmetrics_listen = \"localhost\"\n\
             frame_log = \"/nonexistent/dir/frames.log\"\nmax_payload = 0\n",
        )
        .unwrap_or_else(|error| panic!("{error}"));
        let mut problems = Vec::new();
        assert!(validate_gateway(&raw, &mut problems).is_none());
        let shown: Vec<String> = problems.iter().map(ToString::to_string).collect();
        assert_eq!(
            shown,
            [
                "gateway.command_ttl: 0s must be more than 0 and at most 7 days",
                "gateway.stats_interval: 10ms is under 1s",
                "gateway.metrics_listen: \"localhost\" is not an address:port such as 127.0.0.1:9184",
                "gateway.frame_log: directory /nonexistent/dir does not exist",
                "gateway.max_payload: 0 must be 1–65536 bytes",
            ]
        );
    }
}
