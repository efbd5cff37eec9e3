//! The gateway page's figures: the MQTT connection, the history journal, the bridge's and the
//! lines' statistics documents (as `…/stats` publishes them), the version and uptime, and the
//! configuration in effect with every secret masked (no password or token ever reaches a
//! browser: they are left out, only whether one is set is shown).

use std::sync::Arc;

use axum::extract::State;
use axum::Json;
use serde_json::{json, Value as Json_};

use super::Console;
use crate::bridge::observers::statistics::{line_stats_json, stats_json};
use crate::config::Config;

/// What stands in for a secret that is set.
const MASK: &str = "********";

fn secret(set: bool) -> Json_ {
    if set {
        Json_::from(MASK)
    } else {
        Json_::Null
    }
}

fn millis(duration: std::time::Duration) -> u64 {
    duration.as_millis() as u64
}

/// The configuration in effect, as the page shows it: every key a person may check, secrets
/// masked.
pub fn effective_config(config: &Config) -> Json_ {
    let mqtt = &config.mqtt;
    let scheme = if mqtt.tls.is_some() { "mqtts" } else { "mqtt" };
    let lines: Vec<Json_> = config
        .lines
        .iter()
        .map(|line| {
            json!({
                "name": line.name,
                "link": line.transport.describe(&line.serial),
                "baud": line.serial.baud,
                "format": line.serial.format.to_string(),
                "response_timeout_ms": line.response_timeout.map(millis),
                "retries": line.retries,
                "offline_after": line.offline_after,
                "serve": line.serve.as_ref().map(|serve| json!({
                    "listen": serve.url(),
                    "access": serve.access.word(),
                    "max_clients": serve.max_clients,
                })),
                "devices": line.devices.iter().map(|device| json!({
                    "name": device.name,
                    "address": device.address,
                    "profile": device.profile.name(),
                    "poll_interval_ms": millis(device.poll_interval),
                })).collect::<Vec<_>>(),
            })
        })
        .collect();
    json!({
        "mqtt": {
            "url": format!("{scheme}://{}:{}", mqtt.host, mqtt.port),
            "client_id": mqtt.client_id,
            "prefix": mqtt.prefix,
            "username": mqtt.username,
            "password": secret(mqtt.password.is_some()),
            "discovery": mqtt.discovery,
            "discovery_prefix": mqtt.discovery_prefix,
            "keep_alive_s": mqtt.keep_alive.as_secs(),
            "clean_session": mqtt.clean_session,
        },
        "gateway": {
            "command_ttl_s": config.gateway.command_ttl.as_secs(),
            "json_view": config.gateway.json_view,
            "stats_interval_s": config.gateway.stats_interval.as_secs(),
            "metrics_listen": config.gateway.metrics_listen.map(|a| a.to_string()),
            "frame_log": config.gateway.frame_log.as_ref().map(|p| p.display().to_string()),
            "max_payload": config.gateway.max_payload,
        },
        "lines": lines,
        "sparkplug": config.sparkplug.as_ref().map(|s| json!({
            "group_id": s.identity.group_id,
            "edge_node_id": s.identity.edge_node_id,
            "primary_host_id": s.identity.primary_host_id,
        })),
        "history": config.history.as_ref().map(|h| json!({
            "path": h.path.display().to_string(),
            "max_size": h.max_size,
            "max_age_s": h.max_age.as_secs(),
        })),
        "web": config.web.as_ref().map(|w| json!({
            "listen": w.listen.to_string(),
            "token": secret(w.token.is_some()),
            "tls": w.tls.is_some(),
        })),
    })
}

/// `GET /api/stats`: the statistics documents of the bridge (`gateway`) and of every line
/// (`lines`, each with the idle gap before a request besides what `…/stats/<line>` carries).
pub async fn stats(State(console): State<Arc<Console>>) -> Json<Json_> {
    let lines = console.figures.line_stats();
    let documents: Vec<Json_> = lines
        .iter()
        .map(|line| {
            let mut document = line_stats_json(line);
            if let Some(object) = document.as_object_mut() {
                let ms = |gap: Option<std::time::Duration>| {
                    gap.map(|gap| (gap.as_secs_f64() * 1e6).round() / 1e3)
                };
                object.insert("idle_gap_ms".into(), json!(ms(line.turnaround_mean)));
                object.insert("worst_idle_gap_ms".into(), json!(ms(line.turnaround_worst)));
            }
            document
        })
        .collect();
    Json(json!({
        "gateway": stats_json(&lines, &console.figures.counters()),
        "lines": documents,
    }))
}

/// `GET /api/gateway`: connection, journal, version, uptime, configuration.
pub async fn gateway(State(console): State<Arc<Console>>) -> Json<Json_> {
    let connected = *console.health.connected.borrow();
    let history_problem = console.health.history_problem.borrow().clone();
    let heartbeat_age = console.health.heartbeat.borrow().elapsed();
    Json(json!({
        "version": env!("CARGO_PKG_VERSION"),
        "uptime_s": console.started.elapsed().as_secs(),
        "mqtt_connected": connected,
        "bridge_heartbeat_ms": millis(heartbeat_age),
        "history_problem": history_problem,
        "status_topic": console.topics.gateway_status_topic(),
        "status": console.view.get(&console.topics.gateway_status_topic()).map(|p| p.payload),
        "config": serde_json::from_str::<Json_>(&console.layout().effective_config)
            .unwrap_or(Json_::Null),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_secret_is_shown() {
        let text = "[mqtt]\nurl = \"mqtt://127.0.0.1:1883\"\nclient_id = \"edge1\"\n\
                    username = \"plant\"\npassword = \"hunter2-secret\"\n\
                    [web]\nlisten = \"127.0.0.1:8080\"\ntoken = \"0123456789abcdef-secret\"\n\
                    [[lines]]\nname = \"a\"\nport = \"/dev/null\"\n\
                    [[lines.devices]]\nname = \"valve\"\nprofile = \"wuzhou-valve\"\naddress = 1\n";
        let config = crate::config::from_str(text, std::path::Path::new(".")).unwrap();
        let shown = effective_config(&config).to_string();
        assert!(!shown.contains("secret"), "{shown}");
        assert!(shown.contains("\"password\":\"********\""), "{shown}");
        assert!(shown.contains("\"username\":\"plant\""), "{shown}");
    }
}
