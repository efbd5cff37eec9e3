//! The contract's rules on the bridge core alone: no broker, no line, the clock and the
//! random generator passed in.

use std::sync::Arc;
use std::time::{Duration, Instant};

use rand::rngs::StdRng;
use rand::SeedableRng;
use rumqttc::QoS;
use serde_json::Value as Json;

use super::{Action, BridgeDevice, Core, CoreSettings, ExternalCommand, HistoryEntry, Incoming};
use crate::bus::{Command, CommandFailure, CommandOutcome, LineEvent, Origin};
use crate::config::GatewayOptions;
use crate::topics::Topics;
use rtu2mqtt_profile::registry;

/// The seed of every test core: equal inputs give equal actions.
const SEED: u64 = 7;

fn seeded() -> StdRng {
    StdRng::seed_from_u64(SEED)
}

const TTL: Duration = Duration::from_secs(60);
/// Longer than any re-announcement delay after Home Assistant's birth message.
const LATER: Duration = Duration::from_secs(6);

fn options() -> GatewayOptions {
    GatewayOptions {
        command_ttl: TTL,
        json_view: false,
        stats_interval: Duration::from_secs(3600),
        metrics_listen: None,
        frame_log: None,
        allow_raw_writes: false,
        max_payload: 256,
    }
}

fn core(now: Instant) -> Core {
    let profile = Arc::new(registry::built_in("wuzhou-valve").unwrap());
    Core::new(
        CoreSettings {
            topics: Topics::new("edge1", "plant"),
            discovery: true,
            options: options(),
            history: false,
            line_names: vec!["a".to_string()],
            devices: vec![BridgeDevice {
                name: "valve".to_string(),
                profile,
                line: 0,
            }],
        },
        now,
        seeded(),
    )
}

/// A connected core whose valve is online.
fn online_core(now: Instant) -> Core {
    let mut core = core(now);
    core.on_connected();
    core.on_line_event(availability(true), now);
    core
}

fn availability(online: bool) -> LineEvent {
    LineEvent::Availability {
        device: "valve".to_string(),
        online,
    }
}

fn message<'m>(topic: &'m str, payload: &'m [u8], pkid: u16, dup: bool) -> Incoming<'m> {
    Incoming {
        topic,
        payload,
        qos: QoS::AtLeastOnce,
        pkid,
        dup,
        retain: false,
    }
}

fn command(core: &mut Core, field: &str, payload: &str, pkid: u16, now: Instant) -> Vec<Action> {
    let topic = format!("plant/valve/{field}/set");
    core.on_message(message(&topic, payload.as_bytes(), pkid, false), now)
}

fn publishes(actions: &[Action]) -> Vec<(String, String, bool)> {
    actions
        .iter()
        .filter_map(|action| match action {
            Action::Publish(p) => Some((p.topic.clone(), p.payload.clone(), p.retain)),
            _ => None,
        })
        .collect()
}

/// The ids of the commands handed to line 0.
fn sent(actions: &[Action]) -> Vec<u64> {
    actions
        .iter()
        .filter_map(|action| match action {
            Action::Send { line: 0, command } => Some(command.id),
            _ => None,
        })
        .collect()
}

fn take_sent(actions: Vec<Action>) -> Vec<Command> {
    actions
        .into_iter()
        .filter_map(|action| match action {
            Action::Send { command, .. } => Some(command),
            _ => None,
        })
        .collect()
}

/// `(value, outcome, detail)` of every result published.
fn results(actions: &[Action]) -> Vec<(String, String, String)> {
    publishes(actions)
        .into_iter()
        .filter(|(topic, ..)| topic.ends_with("/result"))
        .map(|(_, payload, _)| {
            let json: Json = serde_json::from_str(&payload).unwrap();
            let text = |key: &str| json[key].as_str().unwrap_or_default().to_string();
            (text("value"), text("outcome"), text("detail"))
        })
        .collect()
}

fn clears(actions: &[Action], field: &str) -> usize {
    let set = format!("plant/valve/{field}/set");
    publishes(actions)
        .iter()
        .filter(|(topic, payload, retain)| *topic == set && payload.is_empty() && *retain)
        .count()
}

fn finished(id: u64, outcome: CommandOutcome) -> LineEvent {
    LineEvent::CommandFinished {
        id,
        device: "valve".to_string(),
        outcome,
    }
}

#[test]
fn each_bus_outcome_is_published_then_the_retained_command_cleared() {
    let cases = [
        (
            CommandOutcome::Applied {
                detail: "ok".into(),
            },
            "applied",
        ),
        (
            CommandOutcome::NotApplied {
                detail: "reads 40".into(),
            },
            "not_applied",
        ),
        (
            CommandOutcome::Rejected {
                detail: "forbidden".into(),
            },
            "rejected",
        ),
        (
            CommandOutcome::Failed {
                cause: CommandFailure::NoAnswer(rtu2mqtt_modbus::Error::Timeout(
                    Duration::from_millis(300),
                )),
            },
            "failed",
        ),
    ];
    for (outcome, word) in cases {
        let now = Instant::now();
        let mut core = online_core(now);
        let ids = sent(&command(&mut core, "opening", "50", 1, now));
        assert_eq!(ids.len(), 1, "{word}");
        assert_eq!(core.commands_on_bus(), 1);
        let detail = match &outcome {
            CommandOutcome::Applied { detail }
            | CommandOutcome::NotApplied { detail }
            | CommandOutcome::Rejected { detail } => detail.clone(),
            CommandOutcome::Failed { cause } => cause.to_string(),
        };
        let actions = core.on_line_event(finished(ids[0], outcome), now);
        assert_eq!(
            results(&actions),
            vec![("50".to_string(), word.to_string(), detail)]
        );
        let topics: Vec<String> = publishes(&actions).into_iter().map(|p| p.0).collect();
        assert_eq!(
            topics,
            vec!["plant/valve/opening/result", "plant/valve/opening/set"],
            "result first, then the clear"
        );
        assert_eq!(clears(&actions, "opening"), 1);
        assert_eq!(core.commands_on_bus(), 0);
    }
}

#[test]
fn the_profile_rejects_unknown_and_read_only_fields_once_with_a_clear() {
    let now = Instant::now();
    let mut core = online_core(now);
    for (field, reason) in [
        ("no_such_field", "unknown field"),
        ("serial_number", "read-only"),
        ("opening", ""),
    ] {
        let payload = if field == "opening" { "banana" } else { "1" };
        let actions = command(&mut core, field, payload, 1, now);
        assert!(sent(&actions).is_empty(), "{field}");
        let results = results(&actions);
        assert_eq!(results.len(), 1, "{field}");
        assert_eq!(results[0].1, "rejected");
        assert!(results[0].2.contains(reason), "{field}: {:?}", results[0]);
        assert_eq!(clears(&actions, field), 1, "{field}");
    }
    assert_eq!(core.counters(now).commands_rejected, 3);
}

#[test]
fn a_command_waits_while_its_device_is_offline_then_runs() {
    let now = Instant::now();
    let mut core = core(now);
    core.on_connected();
    let actions = command(&mut core, "opening", "50", 1, now);
    assert!(sent(&actions).is_empty() && results(&actions).is_empty());
    assert_eq!(core.counters(now).waiting_commands, 1);
    assert!(sent(&core.on_tick(now + Duration::from_secs(1), Vec::new)).is_empty());
    let actions = core.on_line_event(availability(true), now + Duration::from_secs(2));
    assert_eq!(
        sent(&actions).len(),
        1,
        "the device came back: the command goes out"
    );
    assert_eq!(core.counters(now).waiting_commands, 0);
}

#[test]
fn a_command_expires_when_its_device_stays_offline_past_its_time_to_live() {
    let now = Instant::now();
    let mut core = core(now);
    core.on_connected();
    command(&mut core, "opening", "50", 1, now);
    let before = core.on_tick(now + TTL - Duration::from_secs(1), Vec::new);
    assert!(results(&before).is_empty());
    let actions = core.on_tick(now + TTL, Vec::new);
    let results = results(&actions);
    assert_eq!(results.len(), 1);
    assert_eq!(results[0].1, "expired");
    assert!(results[0].2.contains("stayed offline"), "{:?}", results[0]);
    assert_eq!(clears(&actions, "opening"), 1);
    // Back online later: nothing left to send.
    let later = core.on_line_event(availability(true), now + TTL + LATER);
    assert!(sent(&later).is_empty());
}

#[test]
fn a_newer_command_supersedes_a_waiting_one_without_clearing_it() {
    let now = Instant::now();
    let mut core = core(now);
    core.on_connected();
    command(&mut core, "opening", "20", 1, now);
    let actions = command(&mut core, "opening", "30", 2, now);
    assert_eq!(
        results(&actions),
        vec![(
            "20".to_string(),
            "superseded".to_string(),
            "superseded by a newer command for the same field before it was sent".to_string()
        )]
    );
    assert_eq!(
        clears(&actions, "opening"),
        0,
        "the newer command is retained"
    );
    let actions = core.on_line_event(availability(true), now);
    let commands = take_sent(actions);
    assert_eq!(commands.len(), 1, "only the newest runs");
    assert_eq!(commands[0].device, "valve");
    assert_eq!(commands[0].plan.field(), "opening");
}

#[test]
fn a_qos1_redelivery_is_ignored_but_a_new_message_is_not() {
    let now = Instant::now();
    let mut core = online_core(now);
    let topic = "plant/valve/opening/set";
    let first = core.on_message(message(topic, b"50", 7, false), now);
    assert_eq!(sent(&first).len(), 1);
    let again = core.on_message(message(topic, b"50", 7, true), now);
    assert!(again.is_empty(), "a DUP of a message seen is not run again");
    assert_eq!(core.counters(now).redeliveries_ignored, 1);
    assert_eq!(core.counters(now).commands_received, 1);
    // Not a DUP: a new command (it waits for the one on the bus).
    let new = core.on_message(message(topic, b"50", 7, false), now);
    assert!(sent(&new).is_empty());
    assert_eq!(core.counters(now).commands_received, 2);
    assert_eq!(core.counters(now).waiting_commands, 1);
}

#[test]
fn connecting_subscribes_announces_and_sends_discovery() {
    let now = Instant::now();
    let mut core = core(now);
    let actions = core.on_connected();
    let filters: Vec<&str> = actions
        .iter()
        .filter_map(|action| match action {
            Action::Subscribe { filter, .. } => Some(filter.as_str()),
            _ => None,
        })
        .collect();
    assert_eq!(
        filters,
        vec![
            "plant/+/+/set",
            "plant/gateway/edge1/status",
            "plant/+/availability",
            "plant/+/refresh",
            "homeassistant/status",
            "homeassistant/device/+/config",
            "homeassistant/device/edge1_gateway/+/config"
        ]
    );
    // Not every device's state: what a persistent session still holds of it is dropped.
    let dropped: Vec<&str> = actions
        .iter()
        .filter_map(|action| match action {
            Action::UnsubscribeInTurn { filter } => Some(filter.as_str()),
            _ => None,
        })
        .collect();
    assert_eq!(dropped, vec!["plant/+/+"]);
    let published = publishes(&actions);
    let topics: Vec<&str> = published.iter().map(|p| p.0.as_str()).collect();
    assert_eq!(
        topics,
        vec![
            "plant/gateway/edge1/status",
            "homeassistant/device/edge1_gateway/config",
            "homeassistant/device/edge1_valve/config",
            "plant/valve/availability",
            "homeassistant/device/edge1_gateway/a/config",
        ]
    );
    assert!(published.iter().all(|p| p.2), "all retained");
    assert_eq!(published[0].1, "online");
    assert_eq!(published[3].1, "offline", "the valve has not answered yet");
}

#[test]
fn discovery_documents_name_the_topics_the_core_uses() {
    let now = Instant::now();
    let mut core = online_core(now);
    let actions = core.on_connected();
    let (_, document, _) = publishes(&actions)
        .into_iter()
        .find(|p| p.0 == "homeassistant/device/edge1_valve/config")
        .unwrap();
    let document: Json = serde_json::from_str(&document).unwrap();
    let opening = &document["cmps"]["opening"];
    let topics = core.topics().clone();
    assert_eq!(
        opening["state_topic"],
        topics.state_topic("valve", "opening")
    );
    assert_eq!(
        opening["command_topic"],
        topics.command_topic("valve", "opening")
    );
    let availability: Vec<&str> = document["availability"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["topic"].as_str().unwrap())
        .collect();
    assert_eq!(
        availability,
        vec![
            topics.gateway_status_topic(),
            topics.availability_topic("valve")
        ]
    );
    // A command on the discovered topic is parsed by the core as that field's.
    let actions = command(&mut core, "opening", "50", 1, now);
    assert_eq!(sent(&actions).len(), 1);
}

#[test]
fn home_assistant_online_brings_discovery_and_state_again() {
    let now = Instant::now();
    let mut core = online_core(now);
    let values = LineEvent::Values {
        device: "valve".to_string(),
        values: vec![("opening".to_string(), rtu2mqtt_profile::Value::Int(40))],
        read_at: std::time::SystemTime::UNIX_EPOCH,
        origin: Origin::Poll,
    };
    core.on_line_event(values, now);
    let start = core.on_tick(now, Vec::new);
    assert_eq!(
        publishes(&start)[0].0,
        "plant/gateway/edge1/stats",
        "statistics at start"
    );
    let quiet = core.on_tick(now + LATER, Vec::new);
    assert!(publishes(&quiet).is_empty());
    let birth = core.on_message(message("homeassistant/status", b"online", 1, false), now);
    assert!(birth.is_empty(), "not at once: after a random delay");
    let actions = core.on_tick(now + LATER, Vec::new);
    let topics: Vec<String> = publishes(&actions).into_iter().map(|p| p.0).collect();
    assert!(topics.contains(&"homeassistant/device/edge1_valve/config".to_string()));
    assert!(
        topics.contains(&"plant/valve/opening".to_string()),
        "{topics:?}"
    );
    let offline = core.on_message(message("homeassistant/status", b"offline", 2, false), now);
    assert!(offline.is_empty());
    assert!(publishes(&core.on_tick(now + LATER * 2, Vec::new)).is_empty());
}

#[test]
fn statistics_go_out_one_document_per_line_and_a_removed_line_is_cleared() {
    let now = Instant::now();
    let mut core = online_core(now);
    let line = || vec![crate::bus::LineStats::new("a", &["valve".to_string()], now)];
    let start = publishes(&core.on_tick(now, line));
    let topics: Vec<&str> = start.iter().map(|p| p.0.as_str()).collect();
    assert_eq!(
        topics,
        ["plant/gateway/edge1/stats", "plant/gateway/edge1/stats/a"]
    );
    let document: Json = serde_json::from_str(&start[1].1).unwrap();
    assert_eq!(document["line"], "a");
    assert!(document["devices"]["valve"].is_object(), "{document}");
    // A reload that drops line `a` clears its statistics and its discovery document.
    let reload = core.on_reconfigure(vec!["b".to_string()], Vec::new(), now);
    let cleared: Vec<(String, String, bool)> = publishes(&reload)
        .into_iter()
        .filter(|p| p.1.is_empty())
        .collect();
    for topic in [
        "plant/gateway/edge1/stats/a",
        "homeassistant/device/edge1_gateway/a/config",
    ] {
        assert!(
            cleared.contains(&(topic.to_string(), String::new(), true)),
            "{topic} not cleared: {cleared:?}"
        );
    }
    // A line document of a line no longer configured, found on the broker, is removed; the
    // configured line's is kept.
    let stale = core.on_message(
        message(
            "homeassistant/device/edge1_gateway/a/config",
            b"{}",
            0,
            false,
        ),
        now,
    );
    assert_eq!(
        publishes(&stale),
        [(
            "homeassistant/device/edge1_gateway/a/config".to_string(),
            String::new(),
            true
        )]
    );
    let kept = core.on_message(
        message(
            "homeassistant/device/edge1_gateway/b/config",
            b"{}",
            0,
            false,
        ),
        now,
    );
    assert!(publishes(&kept).is_empty());
}

#[test]
fn a_stale_discovery_document_of_this_gateway_is_removed() {
    let now = Instant::now();
    let mut core = online_core(now);
    let ours = br#"{"dev":{"identifiers":["edge1_pump"],"via_device":"edge1"}}"#;
    let theirs = br#"{"dev":{"identifiers":["edge1_pump"],"via_device":"other"}}"#;
    let topic = "homeassistant/device/edge1_pump/config";
    let actions = core.on_message(message(topic, ours, 1, false), now);
    assert_eq!(
        publishes(&actions),
        vec![(topic.to_string(), String::new(), true)]
    );
    assert!(core
        .on_message(message(topic, theirs, 2, false), now)
        .is_empty());
    let configured = "homeassistant/device/edge1_valve/config";
    let valve = br#"{"dev":{"via_device":"edge1"}}"#;
    assert!(core
        .on_message(message(configured, valve, 3, false), now)
        .is_empty());
}

#[test]
fn results_wait_for_the_next_connection_while_mqtt_is_down() {
    let now = Instant::now();
    let mut core = online_core(now);
    let id = sent(&command(&mut core, "opening", "50", 1, now))[0];
    core.on_disconnected();
    let applied = CommandOutcome::Applied {
        detail: "ok".into(),
    };
    let actions = core.on_line_event(finished(id, applied), now);
    assert!(publishes(&actions).is_empty(), "nothing to send it on");
    let actions = core.on_connected();
    assert_eq!(results(&actions)[0].1, "applied");
    assert_eq!(clears(&actions, "opening"), 1);
    // A result the client could not queue is kept too.
    let id = sent(&command(&mut core, "opening", "60", 2, now + LATER))[0];
    let failed = CommandOutcome::Failed {
        cause: CommandFailure::PortNotOpen,
    };
    for action in core.on_line_event(finished(id, failed), now + LATER) {
        if let Action::Publish(publish) = action {
            core.on_published(publish, false);
        }
    }
    core.on_disconnected();
    let actions = core.on_connected();
    assert_eq!(results(&actions)[0].1, "failed");
    assert_eq!(core.counters(now).publish_failures, 2);
}

#[test]
fn a_full_line_queue_retries_and_a_stopped_line_fails_the_command() {
    let now = Instant::now();
    let mut core = online_core(now);
    let command_sent = take_sent(command(&mut core, "opening", "50", 1, now));
    let retry = core.on_send_failed(command_sent.into_iter().next().unwrap(), true);
    assert!(retry.is_empty());
    let again = take_sent(core.on_tick(now, Vec::new));
    assert_eq!(again.len(), 1, "tried again on the next tick");
    let actions = core.on_send_failed(again.into_iter().next().unwrap(), false);
    let results = results(&actions);
    assert_eq!(results[0].1, "failed");
    assert_eq!(results[0].2, "the line has stopped");
    assert_eq!(core.commands_on_bus(), 0);
}

#[test]
fn state_of_a_slot_is_published_before_its_result() {
    let now = Instant::now();
    let mut core = online_core(now);
    let id = sent(&command(&mut core, "opening", "50", 1, now))[0];
    let mut actions = core.on_line_event(
        LineEvent::Values {
            device: "valve".to_string(),
            values: vec![("opening".to_string(), rtu2mqtt_profile::Value::Int(50))],
            read_at: std::time::SystemTime::UNIX_EPOCH,
            origin: Origin::Poll,
        },
        now,
    );
    let applied = CommandOutcome::Applied {
        detail: "ok".into(),
    };
    actions.extend(core.on_line_event(finished(id, applied), now));
    let topics: Vec<String> = publishes(&actions).into_iter().map(|p| p.0).collect();
    assert_eq!(
        topics,
        vec![
            "plant/valve/opening",
            "plant/valve/opening/result",
            "plant/valve/opening/set"
        ]
    );
}

#[test]
fn stopping_announces_offline_and_leaves_waiting_commands_retained() {
    let now = Instant::now();
    let mut core = core(now);
    core.on_connected();
    command(&mut core, "opening", "50", 1, now);
    let actions = core.on_stop();
    assert_eq!(
        publishes(&actions),
        vec![
            (
                "plant/valve/availability".to_string(),
                "offline".to_string(),
                true
            ),
            (
                "plant/gateway/edge1/status".to_string(),
                "offline".to_string(),
                true
            ),
        ]
    );
    assert_eq!(core.counters(now).waiting_commands, 0);
}

#[test]
fn a_command_for_an_unknown_device_is_rejected_naming_the_configured_ones() {
    let now = Instant::now();
    let mut core = online_core(now);
    let topic = "plant/valv/opening/set";
    let actions = core.on_message(message(topic, b"50", 1, false), now);
    let published = publishes(&actions);
    assert_eq!(published.len(), 1, "a result, no clear: {published:?}");
    assert_eq!(published[0].0, "plant/valv/opening/result");
    let (value, outcome, detail) = results(&actions).remove(0);
    assert_eq!((value.as_str(), outcome.as_str()), ("50", "rejected"));
    assert!(
        detail.contains("\"valv\"") && detail.contains("valve"),
        "{detail}"
    );
    // A device another gateway announces under the same prefix is that gateway's business.
    core.on_message(message("plant/pump/availability", b"online", 0, false), now);
    let other = core.on_message(message("plant/pump/speed/set", b"3", 2, false), now);
    assert!(other.is_empty(), "{other:?}");
}

#[test]
fn statistics_go_out_at_start_on_every_reconnect_and_on_home_assistant_online() {
    let now = Instant::now();
    let stats = |actions: &[Action]| {
        publishes(actions)
            .iter()
            .filter(|p| p.0 == "plant/gateway/edge1/stats")
            .count()
    };
    let mut core = core(now);
    assert_eq!(
        stats(&core.on_tick(now, Vec::new)),
        0,
        "not before connecting"
    );
    core.on_connected();
    assert_eq!(stats(&core.on_tick(now, Vec::new)), 1, "at start");
    assert_eq!(stats(&core.on_tick(now + LATER, Vec::new)), 0);
    core.on_disconnected();
    core.on_connected();
    assert_eq!(stats(&core.on_tick(now + LATER, Vec::new)), 1, "reconnect");
    core.on_message(message("homeassistant/status", b"online", 1, false), now);
    assert_eq!(stats(&core.on_tick(now + LATER, Vec::new)), 1, "HA online");
}

#[test]
fn five_identical_commands_at_once_get_five_outcomes() {
    let now = Instant::now();
    let mut core = online_core(now);
    let mut actions = Vec::new();
    for pkid in 1..=5 {
        actions.extend(command(&mut core, "opening", "50", pkid, now));
    }
    let first = sent(&actions);
    assert_eq!(first.len(), 1, "one on the bus");
    let applied = || CommandOutcome::Applied {
        detail: "ok".into(),
    };
    actions.extend(core.on_line_event(finished(first[0], applied()), now));
    let second = sent(&actions);
    assert_eq!(second.len(), 2, "the newest runs next");
    actions.extend(core.on_line_event(finished(second[1], applied()), now));
    let outcomes: Vec<String> = results(&actions).into_iter().map(|r| r.1).collect();
    assert_eq!(
        outcomes,
        [
            "superseded",
            "superseded",
            "superseded",
            "applied",
            "applied"
        ]
    );
}

#[test]
fn a_retained_copy_of_the_waiting_command_is_the_same_command() {
    let now = Instant::now();
    let mut core = core(now);
    core.on_connected();
    command(&mut core, "opening", "50", 1, now);
    let mut again = message("plant/valve/opening/set", b"50", 0, false);
    again.retain = true;
    again.qos = QoS::AtMostOnce;
    assert!(publishes(&core.on_message(again, now)).is_empty());
}

#[test]
fn an_overwritten_own_topic_is_set_right_and_own_echoes_are_not() {
    let now = Instant::now();
    let mut core = online_core(now);
    let values = |opening: i128| LineEvent::Values {
        device: "valve".to_string(),
        values: vec![("opening".to_string(), rtu2mqtt_profile::Value::Int(opening))],
        read_at: std::time::SystemTime::UNIX_EPOCH,
        origin: Origin::Poll,
    };
    core.on_line_event(values(30), now);
    // Before its audit a device's state topics are not watched: nothing comes back of them,
    // and a late message of an earlier subscription is not judged.
    let unwatched = core.on_message(message("plant/valve/opening", b"99", 0, false), now);
    assert!(publishes(&unwatched).is_empty());
    // The valve's turn: its topics are subscribed to behind what is queued.
    let audit = core.on_tick(now, Vec::new);
    assert!(audit.iter().any(|action| matches!(
        action,
        Action::SubscribeInTurn { filter, .. } if filter == "plant/valve/+"
    )));
    // The broker hands over what it holds: ours, the truth.
    let held = core.on_message(message("plant/valve/opening", b"30", 0, false), now);
    assert!(held.is_empty());
    core.on_line_event(values(40), now);
    let echo = core.on_message(message("plant/valve/opening", b"40", 0, false), now);
    assert!(echo.is_empty());
    let fake = core.on_message(message("plant/valve/opening", b"99", 0, false), now);
    assert_eq!(
        publishes(&fake),
        [("plant/valve/opening".to_string(), "40".to_string(), true)]
    );
    // Our `online` comes back first; an `offline` ahead of it would be older than ours.
    let echo = core.on_message(
        message("plant/gateway/edge1/status", b"online", 0, false),
        now,
    );
    assert!(echo.is_empty());
    let will = core.on_message(
        message("plant/gateway/edge1/status", b"offline", 0, false),
        now,
    );
    assert_eq!(
        publishes(&will),
        [(
            "plant/gateway/edge1/status".to_string(),
            "online".to_string(),
            true
        )]
    );
    // Our own two announcements come back first (in order), then the stranger's.
    for word in [&b"offline"[..], b"online"] {
        let echo = core.on_message(message("plant/valve/availability", word, 0, false), now);
        assert!(echo.is_empty());
    }
    let gone = core.on_message(
        message("plant/valve/availability", b"offline", 0, false),
        now,
    );
    assert_eq!(publishes(&gone)[0].1, "online");
    // Another gateway's status is not ours to defend.
    let other = core.on_message(
        message("plant/gateway/edge2/status", b"offline", 0, false),
        now,
    );
    assert!(other.is_empty());
    // The audit's window over: the valve's topics are left, and no longer judged.
    let later = now + super::topic_guard::AUDIT_WINDOW;
    let ended = core.on_tick(later, Vec::new);
    assert!(ended.iter().any(|action| matches!(
        action,
        Action::UnsubscribeInTurn { filter } if filter == "plant/valve/+"
    )));
    let late = core.on_message(message("plant/valve/opening", b"98", 0, false), later);
    assert!(publishes(&late).is_empty());
}

#[test]
fn overloaded_commands_are_refused_with_their_outcome() {
    let now = Instant::now();
    let mut core = online_core(now);
    core.set_overloaded(true);
    let actions = command(&mut core, "opening", "50", 1, now);
    assert!(sent(&actions).is_empty());
    let (_, outcome, detail) = results(&actions).remove(0);
    assert_eq!(outcome, "rejected");
    assert!(detail.contains("overloaded"), "{detail}");
    core.set_overloaded(false);
    assert_eq!(sent(&command(&mut core, "opening", "50", 2, now)).len(), 1);
}

/// A connected core with one air shower, `shower`, on line 0.
fn shower_core(now: Instant) -> Core {
    let profile = Arc::new(registry::built_in("lixian-air-shower").unwrap());
    let mut core = Core::new(
        CoreSettings {
            topics: Topics::new("edge1", "plant"),
            discovery: false,
            options: options(),
            history: false,
            line_names: vec!["a".to_string()],
            devices: vec![BridgeDevice {
                name: "shower".to_string(),
                profile,
                line: 0,
            }],
        },
        now,
        seeded(),
    );
    core.on_connected();
    core
}

fn shower(online: bool) -> LineEvent {
    LineEvent::Availability {
        device: "shower".to_string(),
        online,
    }
}

#[test]
fn an_action_goes_to_the_line_only_after_its_command_is_cleared() {
    let now = Instant::now();
    let mut core = shower_core(now);
    core.on_line_event(shower(true), now);
    let set = "plant/shower/voice_start/set";
    let actions = core.on_message(message(set, b"PRESS", 1, false), now);
    assert!(sent(&actions).is_empty(), "not before the clearing is back");
    assert_eq!(
        publishes(&actions),
        [(set.to_string(), String::new(), true)]
    );
    let back = core.on_message(message(set, b"", 0, false), now);
    assert_eq!(sent(&back).len(), 1);
    // A state write is idempotent: it goes at once.
    let gear = core.on_message(message("plant/shower/breeze/set", b"ON", 2, false), now);
    assert_eq!(sent(&gear).len(), 1);
}

/// Found by fuzzing (`fuzz/`, mqtt_command): a device that went offline while its action's
/// clearing went round the broker got the action at once; it waits for the device instead,
/// and is cleared again before it runs.
#[test]
fn an_action_whose_device_went_offline_during_its_clearing_waits_for_it() {
    let now = Instant::now();
    let mut core = shower_core(now);
    core.on_line_event(shower(true), now);
    let set = "plant/shower/voice_start/set";
    assert!(sent(&core.on_message(message(set, b"PRESS", 1, false), now)).is_empty());
    core.on_line_event(shower(false), now);
    let back = core.on_message(message(set, b"", 0, false), now);
    assert!(
        sent(&back).is_empty(),
        "handed to the line of an offline device"
    );
    let online = core.on_line_event(shower(true), now);
    assert!(sent(&online).is_empty(), "not before it is cleared again");
    assert_eq!(retained_clears(&online), [set.to_string()]);
    let again = core.on_message(message(set, b"", 0, false), now);
    assert_eq!(sent(&again).len(), 1);
}

// ----- external commands (Sparkplug DCMDs) -----

fn external(field: &str, text: &str) -> ExternalCommand {
    ExternalCommand {
        device: "valve".to_string(),
        field: field.to_string(),
        text: text.to_string(),
    }
}

/// The line's report that command `id` was applied.
fn applied(id: u64) -> LineEvent {
    finished(
        id,
        CommandOutcome::Applied {
            detail: "ok".into(),
        },
    )
}

fn reports(actions: &[Action]) -> Vec<(String, bool)> {
    actions
        .iter()
        .filter_map(|action| match action {
            Action::Report(report) => Some((report.field.clone(), report.applied)),
            _ => None,
        })
        .collect()
}

#[test]
fn an_external_command_is_validated_and_reported_like_a_plain_one() {
    let now = Instant::now();
    let mut core = online_core(now);
    for (field, text, reason) in [
        ("no_such_field", "1", "unknown field"),
        ("serial_number", "1", "read-only"),
        ("opening", "banana", ""),
        ("opening", "", "empty"),
    ] {
        let actions = core.on_external_command(external(field, text), now);
        assert!(
            sent(&actions).is_empty(),
            "{field} {text:?}: nothing for the bus"
        );
        let results = results(&actions);
        assert_eq!(results.len(), 1, "{field} {text:?}");
        assert_eq!(results[0].1, "rejected");
        assert!(results[0].2.contains(reason), "{field}: {:?}", results[0]);
        assert_eq!(clears(&actions, field), 0, "no retained command to clear");
        assert_eq!(reports(&actions), vec![(field.to_string(), false)]);
    }
    let counters = core.counters(now);
    assert_eq!(counters.commands_received, 4);
    assert_eq!(counters.commands_rejected, 4);

    let actions = core.on_external_command(external("opening", "50"), now);
    let ids = sent(&actions);
    assert_eq!(ids.len(), 1);
    assert!(reports(&actions).is_empty(), "no end yet");
    let actions = core.on_line_event(applied(ids[0]), now);
    assert_eq!(
        results(&actions),
        vec![("50".to_string(), "applied".to_string(), "ok".to_string())]
    );
    assert_eq!(reports(&actions), vec![("opening".to_string(), true)]);
    assert_eq!(core.counters(now).commands_applied, 1);
}

#[test]
fn an_external_command_that_does_not_apply_is_reported_as_not_applied() {
    let now = Instant::now();
    let mut core = online_core(now);
    let ids = sent(&core.on_external_command(external("opening", "50"), now));
    let actions = core.on_line_event(
        finished(
            ids[0],
            CommandOutcome::NotApplied {
                detail: "reads 40".into(),
            },
        ),
        now,
    );
    assert_eq!(results(&actions)[0].1, "not_applied");
    assert_eq!(reports(&actions), vec![("opening".to_string(), false)]);
}

#[test]
fn an_external_command_waits_expires_and_is_superseded_like_a_plain_one() {
    let now = Instant::now();
    let mut core = core(now);
    core.on_connected();
    let waiting = core.on_external_command(external("opening", "20"), now);
    assert!(sent(&waiting).is_empty() && reports(&waiting).is_empty());
    // A plain command for the same field replaces it: the sender learns it did not apply.
    let actions = command(&mut core, "opening", "30", 1, now);
    assert_eq!(results(&actions)[0].1, "superseded");
    assert_eq!(reports(&actions), vec![("opening".to_string(), false)]);
    // An external one replacing a plain one: nothing to report for the plain one, whose
    // (possibly retained) message is cleared.
    let actions = core.on_external_command(external("opening", "40"), now);
    assert_eq!(results(&actions)[0].0, "30");
    assert!(reports(&actions).is_empty());
    assert_eq!(clears(&actions, "opening"), 1);
    // The device stays offline past the time to live.
    let actions = core.on_tick(now + TTL, Vec::new);
    assert_eq!(results(&actions)[0].1, "expired");
    assert_eq!(reports(&actions), vec![("opening".to_string(), false)]);
}

#[test]
fn plain_commands_are_never_reported() {
    let now = Instant::now();
    let mut core = online_core(now);
    let actions = command(&mut core, "opening", "banana", 1, now);
    assert!(reports(&actions).is_empty());
    let ids = sent(&command(&mut core, "opening", "50", 2, now));
    let actions = core.on_line_event(applied(ids[0]), now);
    assert!(reports(&actions).is_empty());
}

// ----- reload -----

fn device(name: &str, profile: &str, line: usize) -> BridgeDevice {
    BridgeDevice {
        name: name.to_string(),
        profile: Arc::new(registry::built_in(profile).unwrap()),
        line,
    }
}

fn retained_clears(actions: &[Action]) -> Vec<String> {
    actions
        .iter()
        .filter_map(|action| match action {
            Action::Publish(p) if p.retain && p.payload.is_empty() => Some(p.topic.clone()),
            _ => None,
        })
        .collect()
}

#[test]
fn a_removed_device_is_cleared_and_a_kept_ones_waiting_command_stays() {
    let now = Instant::now();
    let options = GatewayOptions {
        command_ttl: Duration::from_secs(60),
        json_view: true,
        stats_interval: Duration::from_secs(3600),
        metrics_listen: None,
        frame_log: None,
        allow_raw_writes: false,
        max_payload: 256,
    };
    let valve = device("valve", "wuzhou-valve", 1);
    let dust = device("dust_collector", "ruiwan-dust-collector", 0);
    let mut core = Core::new(
        CoreSettings {
            topics: Topics::new("edge1", "plant"),
            discovery: true,
            options,
            history: false,
            line_names: vec!["a".into(), "b".into()],
            devices: vec![dust.clone(), valve.clone()],
        },
        now,
        seeded(),
    );
    core.on_connected();
    core.on_line_event(
        LineEvent::Availability {
            device: "dust_collector".into(),
            online: false,
        },
        now,
    );
    // Commands for two offline devices wait.
    for topic in ["plant/valve/opening/set", "plant/dust_collector/gear/set"] {
        core.on_message(
            Incoming {
                topic,
                payload: b"3",
                qos: QoS::AtLeastOnce,
                pkid: 1,
                dup: false,
                retain: false,
            },
            now,
        );
    }
    assert_eq!(core.counters(now).waiting_commands, 2);

    // The dust collector's line is gone; the valve's line is now the first.
    let moved = BridgeDevice { line: 0, ..valve };
    let actions = core.on_reconfigure(vec!["b".into()], vec![moved], now);
    let cleared = retained_clears(&actions);
    for topic in [
        "plant/dust_collector/gear",
        "plant/dust_collector/availability",
        "plant/dust_collector",
        "homeassistant/device/edge1_dust_collector/config",
        "plant/dust_collector/gear/set",
    ] {
        assert!(
            cleared.iter().any(|t| t == topic),
            "{topic} not cleared: {cleared:?}"
        );
    }
    assert!(cleared.iter().all(|t| !t.contains("valve")), "{cleared:?}");
    let failed = actions.iter().any(|action| {
        matches!(action, Action::Publish(p) if p.topic == "plant/dust_collector/gear/result"
            && p.payload.contains("no longer configured"))
    });
    assert!(failed, "no result for the removed device's command");
    assert_eq!(
        core.counters(now).waiting_commands,
        1,
        "the valve's command was lost"
    );

    // Once the valve is online, its command goes to its new line index.
    let actions = core.on_line_event(
        LineEvent::Availability {
            device: "valve".into(),
            online: true,
        },
        now,
    );
    assert!(actions
        .iter()
        .any(|action| matches!(action, Action::Send { line: 0, .. })));
}

// ----- determinism -----

/// Every action of `core` over a script of events: a command, its end, Home Assistant's birth
/// and ticks every 10 ms until after the longest re-announcement delay, as the driver would
/// see them (with the instant of each tick's actions).
fn script(mut core: Core, now: Instant) -> Vec<String> {
    let mut seen = Vec::new();
    let mut record = |at: Duration, actions: Vec<Action>| {
        for action in actions {
            seen.push(format!("{at:?} {action:?}"));
        }
    };
    record(Duration::ZERO, core.on_connected());
    record(Duration::ZERO, core.on_line_event(availability(true), now));
    let actions = command(&mut core, "opening", "50", 1, now);
    let id = sent(&actions)[0];
    record(Duration::ZERO, actions);
    record(Duration::ZERO, core.on_line_event(applied(id), now));
    let birth = message("homeassistant/status", b"online", 2, false);
    record(Duration::ZERO, core.on_message(birth, now));
    let mut at = Duration::ZERO;
    while at <= LATER {
        record(at, core.on_tick(now + at, Vec::new));
        at += Duration::from_millis(10);
    }
    seen
}

#[test]
fn two_cores_with_the_same_seed_decide_the_same() {
    let now = Instant::now();
    let first = script(core(now), now);
    let second = script(core(now), now);
    assert!(
        first.iter().any(|line| line.contains("edge1_valve/config")),
        "the script reaches the re-announcement: {first:#?}"
    );
    assert_eq!(first, second);
}

fn history_core(now: Instant) -> Core {
    let profile = Arc::new(registry::built_in("wuzhou-valve").unwrap());
    Core::new(
        CoreSettings {
            topics: Topics::new("edge1", "plant"),
            discovery: false,
            options: options(),
            history: true,
            line_names: vec!["a".to_string()],
            devices: vec![BridgeDevice {
                name: "valve".to_string(),
                profile,
                line: 0,
            }],
        },
        now,
        seeded(),
    )
}

fn history_entries(actions: &[Action]) -> Vec<HistoryEntry> {
    actions
        .iter()
        .filter_map(|action| match action {
            Action::History(entry) => Some(entry.clone()),
            _ => None,
        })
        .collect()
}

fn opening_at(opening: i64, at_ms: u64) -> LineEvent {
    LineEvent::Values {
        device: "valve".to_string(),
        values: vec![(
            "opening".to_string(),
            rtu2mqtt_profile::Value::Int(i128::from(opening)),
        )],
        read_at: std::time::UNIX_EPOCH + Duration::from_millis(at_ms),
        origin: Origin::Poll,
    }
}

#[test]
fn each_change_set_goes_to_the_history_stream_with_its_read_instant_connected_or_not() {
    let now = Instant::now();
    let mut core = history_core(now);
    // Not connected yet: the change set still goes out (to the journal, the driver decides).
    let first = history_entries(&core.on_line_event(opening_at(40, 1_796_223_601_123), now));
    assert_eq!(
        first,
        vec![HistoryEntry {
            device: "valve".to_string(),
            topic: "plant/valve/history".to_string(),
            at_ms: 1_796_223_601_123,
            document: r#"{"ts":"2026-12-02T15:00:01.123Z","values":{"opening":40}}"#.to_string(),
        }]
    );
    // The same value again is no change.
    assert!(
        history_entries(&core.on_line_event(opening_at(40, 1_796_223_602_000), now)).is_empty()
    );
    core.on_connected();
    let changed = history_entries(&core.on_line_event(opening_at(41, 1_796_223_603_000), now));
    assert_eq!(changed.len(), 1);
    assert_eq!(
        changed[0].document,
        r#"{"ts":"2026-12-02T15:00:03.000Z","values":{"opening":41}}"#
    );
}

#[test]
fn without_history_no_change_set_is_made() {
    let now = Instant::now();
    let mut core = online_core(now);
    assert!(history_entries(&core.on_line_event(opening_at(40, 0), now)).is_empty());
}

/// The refresh requests among `actions`, as (line, device).
fn refreshes(actions: &[Action]) -> Vec<(usize, String)> {
    actions
        .iter()
        .filter_map(|action| match action {
            Action::Refresh { line, device } => Some((*line, device.clone())),
            _ => None,
        })
        .collect()
}

#[test]
fn a_live_refresh_goes_to_the_line_and_a_retained_one_is_cleared_instead() {
    let now = Instant::now();
    let mut core = online_core(now);
    let clear = vec![("plant/valve/refresh".to_string(), String::new(), true)];
    // Live: to the line, then cleared (it may have been retained: MQTT 3.1.1 does not say).
    let actions = core.on_message(message("plant/valve/refresh", b"1", 1, false), now);
    assert_eq!(refreshes(&actions), vec![(0, "valve".to_string())]);
    assert_eq!(publishes(&actions), clear);

    // From the broker's retained store: stale, so cleared and not done.
    let retained = Incoming {
        retain: true,
        ..message("plant/valve/refresh", b"1", 2, false)
    };
    let actions = core.on_message(retained, now);
    assert!(refreshes(&actions).is_empty(), "{actions:?}");
    assert_eq!(publishes(&actions), clear);

    // Our own clearing coming back, and refreshes of devices that are not ours: nothing.
    for (topic, payload) in [
        ("plant/valve/refresh", &b""[..]),
        ("plant/pump/refresh", &b"1"[..]),
    ] {
        let actions = core.on_message(message(topic, payload, 3, false), now);
        assert!(refreshes(&actions).is_empty(), "{topic}: {actions:?}");
        assert!(publishes(&actions).is_empty(), "{topic}: {actions:?}");
    }
}

#[test]
fn a_write_the_line_reports_holds_commands_and_dcmds_for_the_fields_interval() {
    let now = Instant::now();
    let mut core = online_core(now);
    // A client of the served line wrote the setpoint (interval 10 s): the line says so.
    let written = LineEvent::Written {
        device: "valve".to_string(),
        fields: vec!["setpoint".to_string()],
        at: now,
    };
    assert!(take_sent(core.on_line_event(written, now)).is_empty());
    let second = Duration::from_secs(1);
    assert!(take_sent(command(&mut core, "setpoint", "50", 1, now + second)).is_empty());
    // A Sparkplug DCMD for the same field a second later waits too, and the newest wins.
    let actions = core.on_external_command(external("setpoint", "60"), now + second * 2);
    assert!(take_sent(actions).is_empty());
    assert!(take_sent(core.on_tick(now + second * 9, Vec::new)).is_empty());
    let sent = take_sent(core.on_tick(now + second * 10, Vec::new));
    assert_eq!(sent.len(), 1);
    assert_eq!(sent[0].plan.field(), "setpoint");
    assert_eq!(sent[0].plan.target().to_text(), "60.00");
    // Another field is not held.
    assert_eq!(
        take_sent(command(&mut core, "opening", "40", 2, now + second)).len(),
        1
    );
}

#[test]
fn a_heartbeat_publishes_state_json_view_and_history_even_when_unchanged() {
    let now = Instant::now();
    let mut core = Core::new(
        CoreSettings {
            topics: Topics::new("edge1", "plant"),
            discovery: false,
            options: GatewayOptions {
                json_view: true,
                ..options()
            },
            history: true,
            line_names: vec!["a".to_string()],
            devices: vec![BridgeDevice {
                name: "valve".to_string(),
                profile: Arc::new(registry::built_in("wuzhou-valve").unwrap()),
                line: 0,
            }],
        },
        now,
        seeded(),
    );
    core.on_connected();
    core.on_line_event(availability(true), now);
    let first = core.on_line_event(opening_at(40, 1_796_223_601_000), now);
    let topics = |actions: &[Action]| -> Vec<String> {
        publishes(actions)
            .into_iter()
            .map(|(topic, ..)| topic)
            .collect()
    };
    assert_eq!(topics(&first), ["plant/valve/opening", "plant/valve"]);
    // The same value read again: nothing anywhere.
    let again = core.on_line_event(opening_at(40, 1_796_223_602_000), now);
    assert!(topics(&again).is_empty() && history_entries(&again).is_empty());
    // The same value as a heartbeat: everywhere, with the heartbeat's instant.
    let mut heartbeat = opening_at(40, 1_796_223_661_000);
    if let LineEvent::Values { origin, .. } = &mut heartbeat {
        *origin = Origin::Heartbeat;
    }
    let beat = core.on_line_event(heartbeat, now);
    assert_eq!(
        publishes(&beat),
        [
            ("plant/valve/opening".to_string(), "40".to_string(), true),
            (
                "plant/valve".to_string(),
                r#"{"opening":40}"#.to_string(),
                true
            )
        ]
    );
    assert_eq!(
        history_entries(&beat)
            .into_iter()
            .map(|entry| entry.document)
            .collect::<Vec<_>>(),
        [r#"{"ts":"2026-12-02T15:01:01.000Z","values":{"opening":40}}"#]
    );
}

// ----- announcing many devices -----

/// A gateway of 60 valves and one line announces 50 of them on the connect and the rest on
/// the next tick (the valves first, then the line): discovery, availability, every state and
/// the JSON view of each valve; a value that moves before its device's turn waits for the
/// turn and goes out once, with its newest value. When the driver's outbox has room before the
/// tick, the next ten are announced at once.
#[test]
fn many_devices_are_announced_a_batch_per_tick() {
    let now = Instant::now();
    let profile = Arc::new(registry::built_in("wuzhou-valve").unwrap());
    let names: Vec<String> = (0..60).map(|n| format!("valve{n:02}")).collect();
    let mut core = Core::new(
        CoreSettings {
            topics: Topics::new("edge1", "plant"),
            discovery: true,
            options: GatewayOptions {
                json_view: true,
                ..options()
            },
            history: false,
            line_names: vec!["a".to_string()],
            devices: names
                .iter()
                .map(|name| BridgeDevice {
                    name: name.clone(),
                    profile: Arc::clone(&profile),
                    line: 0,
                })
                .collect(),
        },
        now,
        seeded(),
    );
    let opening = |value: i128| rtu2mqtt_profile::Value::Int(value);
    // Known before the connection: the first connect republishes it in each device's turn.
    for name in &names {
        core.on_line_event(
            LineEvent::Values {
                device: name.clone(),
                values: vec![("opening".to_string(), opening(40))],
                read_at: std::time::SystemTime::UNIX_EPOCH,
                origin: Origin::Poll,
            },
            now,
        );
    }
    let announced = |actions: &[Action], kind: &str| -> Vec<String> {
        publishes(actions)
            .into_iter()
            .map(|p| p.0)
            .filter(|topic| match kind {
                "config" => topic.starts_with("homeassistant/device/edge1_valve"),
                "opening" => topic.ends_with("/opening"),
                _ => topic.starts_with("plant/valve") && topic.matches('/').count() == 1,
            })
            .collect()
    };
    let first = core.on_connected();
    assert_eq!(announced(&first, "config").len(), 50);
    assert_eq!(announced(&first, "opening").len(), 50);
    assert_eq!(announced(&first, "view").len(), 50);
    assert!(publishes(&first)
        .iter()
        .any(|p| p.0 == "homeassistant/device/edge1_gateway/config"));
    // valve59 moves before its turn: kept for the turn, published once then.
    let moved = core.on_line_event(
        LineEvent::Values {
            device: "valve59".to_string(),
            values: vec![("opening".to_string(), opening(41))],
            read_at: std::time::SystemTime::UNIX_EPOCH,
            origin: Origin::Poll,
        },
        now,
    );
    assert!(announced(&moved, "opening").is_empty());
    assert!(announced(&moved, "view").is_empty());
    // The driver's outbox has room before the tick: the next ten, valve50 to valve59, go now.
    assert!(core.is_announcing());
    let on_room = core.on_announce_room();
    assert_eq!(announced(&on_room, "config").len(), 10);
    assert_eq!(
        announced(&on_room, "config")[0],
        "homeassistant/device/edge1_valve50/config"
    );
    assert_eq!(announced(&on_room, "opening").len(), 10);
    let valve59 = publishes(&on_room)
        .into_iter()
        .find(|p| p.0 == "plant/valve59/opening")
        .map(|p| p.1);
    assert_eq!(valve59.as_deref(), Some("41"), "the newest value, once");
    let second = core.on_tick(now, Vec::new);
    assert!(!core.is_announcing());
    assert!(announced(&second, "config").is_empty());
    assert!(announced(&second, "opening").is_empty());
    // In its turn and after, the device publishes on change again.
    let after = core.on_line_event(
        LineEvent::Values {
            device: "valve59".to_string(),
            values: vec![("opening".to_string(), opening(42))],
            read_at: std::time::SystemTime::UNIX_EPOCH,
            origin: Origin::Poll,
        },
        now,
    );
    assert_eq!(announced(&after, "opening"), ["plant/valve59/opening"]);
    assert!(publishes(&second)
        .iter()
        .any(|p| p.0 == "homeassistant/device/edge1_gateway/a/config"));
    let quiet = core.on_tick(now + Duration::from_millis(250), Vec::new);
    assert!(announced(&quiet, "config").is_empty());
    assert!(announced(&quiet, "opening").is_empty());
}

/// Without discovery a connect still republishes each device's availability and state in its
/// turn; a reload that removes a device whose turn has not come yet clears its topics, and
/// nothing is published on them afterwards.
#[test]
fn a_device_removed_before_its_turn_is_not_announced_afterwards() {
    let now = Instant::now();
    let profile = Arc::new(registry::built_in("wuzhou-valve").unwrap());
    let names: Vec<String> = (0..60).map(|n| format!("valve{n:02}")).collect();
    let devices: Vec<BridgeDevice> = names
        .iter()
        .map(|name| BridgeDevice {
            name: name.clone(),
            profile: Arc::clone(&profile),
            line: 0,
        })
        .collect();
    let mut core = Core::new(
        CoreSettings {
            topics: Topics::new("edge1", "plant"),
            discovery: false,
            options: options(),
            history: false,
            line_names: vec!["a".to_string()],
            devices: devices.clone(),
        },
        now,
        seeded(),
    );
    for name in &names {
        core.on_line_event(
            LineEvent::Values {
                device: name.clone(),
                values: vec![("opening".to_string(), rtu2mqtt_profile::Value::Int(40))],
                read_at: std::time::SystemTime::UNIX_EPOCH,
                origin: Origin::Poll,
            },
            now,
        );
    }
    let first = core.on_connected();
    let topics_of = |actions: &[Action], device: &str| -> Vec<String> {
        publishes(actions)
            .into_iter()
            .map(|p| p.0)
            .filter(|topic| topic.starts_with(&format!("plant/{device}")))
            .collect()
    };
    assert!(
        topics_of(&first, "valve59").is_empty(),
        "valve59's turn is later"
    );
    assert!(core.is_announcing());
    // The reload keeps valve00 to valve58; valve59 is gone before its turn.
    let kept: Vec<BridgeDevice> = devices[..59].to_vec();
    let reload = core.on_reconfigure(vec!["a".to_string()], kept, now);
    let cleared: Vec<(String, String, bool)> = publishes(&reload)
        .into_iter()
        .filter(|p| p.0 == "plant/valve59/availability")
        .collect();
    assert_eq!(
        cleared,
        [(
            "plant/valve59/availability".to_string(),
            String::new(),
            true
        )],
        "its retained availability is cleared"
    );
    let mut later = Vec::new();
    for _ in 0..4 {
        later.extend(core.on_tick(now, Vec::new));
    }
    assert!(
        topics_of(&later, "valve59").is_empty(),
        "nothing goes out on a removed device's topics: {:?}",
        topics_of(&later, "valve59")
    );
    assert!(
        !topics_of(&later, "valve58").is_empty(),
        "the kept ones get their turn"
    );
}
