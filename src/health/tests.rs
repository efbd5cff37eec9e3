//! The health machinery's tests: the pure judgement, the status file, systemd's rule and the
//! watchdog thread.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use tokio::sync::watch;

use super::*;
use crate::bus::LineStats;
use tokio_util::sync::CancellationToken;

fn settings() -> HealthSettings {
    HealthSettings {
        status_file: None,
        interval: Duration::from_secs(5),
        stale_after: Duration::from_secs(15),
        stall_limit: Duration::from_secs(60),
    }
}

fn line(name: &str, heartbeat: Instant) -> LineStats {
    let mut stats = LineStats::new(name, &["a".to_string(), "b".to_string()], heartbeat);
    stats.port_open = true;
    stats.devices[0].online = true;
    stats
}

fn mqtt(last_beat: Instant, connected: bool) -> LoopSnapshot {
    LoopSnapshot {
        last_beat,
        connected,
        connection_changed: last_beat,
        max_quiet: Duration::from_secs(30),
    }
}

#[test]
fn fresh_loops_are_healthy() {
    let start = Instant::now();
    let now = start + Duration::from_secs(100);
    let lines = [
        line("a", now - Duration::from_secs(1)),
        line("b", now - Duration::from_secs(14)),
    ];
    let result = assess(
        now,
        1,
        2,
        &lines,
        &mqtt(now - Duration::from_secs(40), true),
        &settings(),
    );
    assert!(result.report.healthy, "{:?}", result.report.problems);
    assert!(result.stuck.is_empty());
    assert_eq!(result.report.lines[0].devices_online, 1);
    assert_eq!(result.report.lines[0].devices, 2);
    assert_eq!(result.report.lines[1].beat_age_ms, 14_000);
}

#[test]
fn a_stale_line_is_unhealthy_then_stuck() {
    let start = Instant::now();
    let now = start + Duration::from_secs(200);
    let quiet = assess(
        now,
        1,
        2,
        &[line("a", now - Duration::from_secs(16))],
        &mqtt(now, true),
        &settings(),
    );
    assert!(!quiet.report.healthy);
    assert!(!quiet.report.lines[0].alive);
    assert!(quiet.stuck.is_empty());
    assert!(quiet.report.problems[0].contains("line a"));

    let stuck = assess(
        now,
        1,
        2,
        &[line("a", now - Duration::from_secs(61))],
        &mqtt(now, true),
        &settings(),
    );
    assert_eq!(stuck.stuck, vec!["line a".to_string()]);
}

#[test]
fn the_mqtt_loop_gets_its_keep_alive_as_grace() {
    let start = Instant::now();
    let now = start + Duration::from_secs(500);
    let lines = [line("a", now)];
    let idle = assess(
        now,
        1,
        2,
        &lines,
        &mqtt(now - Duration::from_secs(44), true),
        &settings(),
    );
    assert!(idle.report.healthy);
    let silent = assess(
        now,
        1,
        2,
        &lines,
        &mqtt(now - Duration::from_secs(46), true),
        &settings(),
    );
    assert!(!silent.report.healthy);
    assert!(silent.stuck.is_empty());
    let stuck = assess(
        now,
        1,
        2,
        &lines,
        &mqtt(now - Duration::from_secs(91), true),
        &settings(),
    );
    assert_eq!(stuck.stuck, vec!["MQTT loop".to_string()]);
}

#[test]
fn a_zero_stall_limit_never_ends_the_process() {
    let start = Instant::now();
    let now = start + Duration::from_secs(10_000);
    let mut no_exit = settings();
    no_exit.stall_limit = Duration::ZERO;
    let result = assess(now, 1, 2, &[line("a", start)], &mqtt(start, true), &no_exit);
    assert!(!result.report.healthy);
    assert!(result.stuck.is_empty());
}

#[test]
fn a_closed_port_or_lost_broker_is_reported_but_alive() {
    let now = Instant::now() + Duration::from_secs(100);
    let mut unplugged = line("a", now);
    unplugged.port_open = false;
    let result = assess(now, 1, 2, &[unplugged], &mqtt(now, false), &settings());
    assert!(result.report.healthy);
    assert!(!result.report.mqtt.connected);
    assert_eq!(
        result.report.problems.len(),
        2,
        "{:?}",
        result.report.problems
    );
}

fn report_text(timestamp_ms: u64, healthy: bool, connected: bool, state_age_ms: u64) -> String {
    let report = StatusReport {
        timestamp_ms,
        pid: 1,
        healthy,
        mqtt: MqttStatus {
            alive: true,
            connected,
            beat_age_ms: 0,
            state_age_ms,
        },
        lines: vec![],
        history: None,
        problems: if healthy {
            vec![]
        } else {
            vec!["line a has not turned for 20s".to_string()]
        },
    };
    serde_json::to_string(&report).unwrap()
}

#[test]
fn a_journal_that_cannot_be_written_is_unhealthy_until_it_can_and_keeps_systemd_pinged() {
    let now = Instant::now();
    let lines = [line("a", now)];
    let judged = |problem: Option<&str>| {
        assess(now, 1_000, 2, &lines, &mqtt(now, true), &settings()).with_history(problem)
    };
    let cause = "/var/lib/rtu2mqtt/history: Read-only file system (os error 30)";
    let sick = judged(Some(cause));
    assert!(!sick.report.healthy);
    assert!(
        sick.loops_alive,
        "the watchdog is still pinged: a restart would not help"
    );
    assert_eq!(
        sick.report.problems,
        [format!("history journal cannot be written: {cause}")]
    );
    let text = serde_json::to_string(&sick.report).unwrap_or_default();
    assert!(
        text.contains(
            r#""history":{"writable":false,"problem":"/var/lib/rtu2mqtt/history: Read-only"#
        ),
        "{text}"
    );
    let verdict = judge_status(&text, 1_000, Duration::from_secs(30));
    assert_eq!(
        verdict.err(),
        Some(format!("history journal cannot be written: {cause}"))
    );

    let well = judged(None);
    assert!(well.report.healthy);
    let text = serde_json::to_string(&well.report).unwrap_or_default();
    assert!(text.contains(r#""history":{"writable":true}"#), "{text}");
    assert!(judge_status(&text, 1_000, Duration::from_secs(30)).is_ok());
    // Without `[history]` the report says nothing of it.
    let without = assess(now, 1_000, 2, &lines, &mqtt(now, true), &settings());
    assert!(!serde_json::to_string(&without.report)
        .unwrap_or_default()
        .contains("history"));
}

#[test]
fn judge_accepts_only_fresh_healthy_reports() {
    let max_age = Duration::from_secs(30);
    let now = 1_000_000;
    assert!(judge_status(&report_text(now - 29_000, true, true, 0), now, max_age).is_ok());
    let old = judge_status(&report_text(now - 31_000, true, true, 0), now, max_age);
    assert!(old.unwrap_err().contains("old"));
    let sick = judge_status(&report_text(now, false, true, 0), now, max_age);
    assert!(sick.unwrap_err().contains("line a"));
    assert!(judge_status(&report_text(now, true, false, 10_000), now, max_age).is_ok());
    let lost = judge_status(&report_text(now, true, false, 31_000), now, max_age);
    assert!(lost.unwrap_err().contains("not connected"));
    assert!(judge_status("{not json", now, max_age).is_err());
    assert!(judge_status("", now, max_age).is_err());
}

#[test]
fn status_file_round_trips_and_health_command_reads_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("health");
    let now = Instant::now();
    let report = assess(
        now,
        wall_clock_ms(),
        7,
        &[line("a", now)],
        &mqtt(now, true),
        &settings(),
    )
    .report;
    write_status_file(&path, &report).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let read: StatusReport = serde_json::from_str(&text).unwrap();
    assert_eq!(read, report);
    let code = check_status_file(&path, Duration::from_secs(30)).unwrap();
    assert_eq!(code, ExitCode::SUCCESS);
    let missing = check_status_file(&dir.path().join("nope"), Duration::from_secs(30));
    assert_eq!(missing.unwrap(), ExitCode::FAILURE);
}

#[test]
fn watchdog_period_follows_sd_watchdog_enabled() {
    let period = Some(Duration::from_secs(30));
    assert_eq!(watchdog_period_from(Some("30000000"), None, 7), period);
    assert_eq!(watchdog_period_from(Some("30000000"), Some("7"), 7), period);
    assert_eq!(watchdog_period_from(Some("30000000"), Some("8"), 7), None);
    assert_eq!(watchdog_period_from(Some("0"), None, 7), None);
    assert_eq!(watchdog_period_from(Some("soon"), None, 7), None);
    assert_eq!(watchdog_period_from(None, Some("7"), 7), None);
}

#[tokio::test]
async fn readiness_waits_for_the_first_connection_but_not_forever() {
    let (_heartbeat_tx, heartbeat) = watch::channel(Instant::now());
    let (connected_tx, connected) = watch::channel(false);
    let probe = MqttProbe {
        heartbeat,
        connected,
        max_quiet: Duration::from_secs(1),
    };
    assert!(!first_connect_attempt(&probe.connected, Duration::from_millis(50)).await);
    let waiting = tokio::spawn({
        let connected = probe.connected.clone();
        async move { first_connect_attempt(&connected, Duration::from_secs(600)).await }
    });
    tokio::task::yield_now().await;
    connected_tx.send_replace(true);
    assert!(waiting.await.unwrap());
}

#[test]
fn settings_deserialize_with_defaults() {
    let parsed: HealthSettings = toml::from_str("stall_limit = \"2m\"").unwrap();
    assert_eq!(parsed.stall_limit, Duration::from_secs(120));
    assert_eq!(parsed.status_file, Some(PathBuf::from(DEFAULT_STATUS_FILE)));
    let none: HealthSettings = toml::from_str("status_file = \"\"").unwrap();
    assert_eq!(none.status_file, None);
    // An unknown key is refused where the configuration is read, with its place.
    let misspelt = "[mqtt]\nurl = \"mqtt://x\"\nclient_id = \"e\"\n[health]\nstall = \"1s\"";
    let problems = crate::config::load::load_str(misspelt)
        .unwrap_err()
        .to_string();
    assert!(problems.contains("health.stall: unknown key"), "{problems}");
}

#[test]
fn a_stuck_line_fires_the_shutdown_then_ends_the_process() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("health");
    let settings = HealthSettings {
        status_file: Some(path.clone()),
        interval: Duration::from_millis(100),
        stale_after: Duration::from_millis(200),
        stall_limit: Duration::from_millis(300),
    };
    // The MQTT loop promises an hour of quiet, so only the line can be stuck.
    let (_heartbeat_tx, heartbeat) = watch::channel(Instant::now());
    let (_connected_tx, connected) = watch::channel(true);
    let probe = MqttProbe {
        heartbeat,
        connected,
        max_quiet: Duration::from_secs(3600),
    };
    let (_stats_tx, stats_rx) = watch::channel(line("a", Instant::now()));
    let mut watchdog = Watchdog::new(settings, probe);
    watchdog.watch_line(stats_rx);
    let token = CancellationToken::new();
    let trigger = token.clone();
    let (exit_tx, exit_rx) = mpsc::channel();
    let handle = watchdog
        .spawn_with_exit(
            trigger,
            Box::new(move |code| {
                let _ = exit_tx.send(code);
            }),
        )
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while !token.is_cancelled() {
        assert!(Instant::now() < deadline, "the shutdown was never fired");
        std::thread::sleep(Duration::from_millis(20));
    }
    // A clean stop within the grace period: the process still ends, with EXIT_STUCK.
    handle.stop();
    assert_eq!(
        exit_rx.recv_timeout(Duration::from_secs(10)),
        Ok(EXIT_STUCK)
    );
    let report: StatusReport =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert!(!report.healthy, "the last status tells why");
    assert!(
        report.problems[0].contains("line a"),
        "{:?}",
        report.problems
    );
}

#[test]
fn watchdog_writes_then_removes_the_status_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("health");
    let mut health = settings();
    health.status_file = Some(path.clone());
    health.interval = Duration::from_millis(100);
    let (_heartbeat_tx, heartbeat) = watch::channel(Instant::now());
    let (_connected_tx, connected) = watch::channel(true);
    let probe = MqttProbe {
        heartbeat,
        connected,
        max_quiet: Duration::from_secs(1),
    };
    let (_stats_tx, stats_rx) = watch::channel(line("a", Instant::now()));
    let mut watchdog = Watchdog::new(health, probe);
    watchdog.watch_line(stats_rx);
    let _token = CancellationToken::new();
    let trigger = _token.clone();
    let handle = watchdog.spawn(trigger).unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while !path.exists() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    let text = std::fs::read_to_string(&path).unwrap();
    let report = judge_status(&text, wall_clock_ms(), Duration::from_secs(30)).unwrap();
    assert_eq!(report.lines[0].name, "a");
    handle.stop();
    assert!(!path.exists());
}
