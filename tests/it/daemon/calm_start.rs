//! A normal start of `rtu2mqtt run` over the simulated seed plant (ptys, a real mosquitto),
//! read the way an operator reads the journal: no warning or error while everything works,
//! the expected start-up facts (a pty that does not apply parity, a device that needs split
//! reads) said once at INFO, one INFO line for a command's arrival and one for its outcome in
//! words, and statistics that show no failure from a normal start.

use crate::support;

use std::io::{BufRead, BufReader};
use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rtu2mqtt_sim::{self as sim, SeedPlant};
use support::child::{self, KillOnDrop};
use support::{Mosquitto, PlantConfig, TestClient};

/// Generous bounds for a busy machine: they only fail when something is broken.
const ANSWER: Duration = Duration::from_secs(15);
/// The start-up window that must stay free of warnings.
const START: Duration = Duration::from_secs(5);

/// One line of the daemon's stderr and when it arrived (since the daemon was spawned).
#[derive(Debug, Clone)]
struct LogLine {
    at: Duration,
    text: String,
}

impl LogLine {
    /// The level word of a plain log line (`<timestamp>  INFO target: message`).
    fn level(&self) -> &str {
        self.text.split_whitespace().nth(1).unwrap_or_default()
    }
}

/// `valve: reads block "live"` out of a split-read line: which device and block it is about.
fn split_fact(text: &str) -> &str {
    let Some(at) = text.find(" reads block \"") else {
        return "";
    };
    let start = text[..at].rfind(' ').map_or(0, |space| space + 1);
    let end = text[at..].find(" in ").map_or(text.len(), |end| at + end);
    &text[start..end]
}

/// `rtu2mqtt run` with its stderr collected line by line; killed on drop.
struct Daemon {
    _child: KillOnDrop,
    started: Instant,
    lines: Arc<Mutex<Vec<LogLine>>>,
    _dir: tempfile::TempDir,
}

impl Daemon {
    fn spawn(config: &str) -> Daemon {
        let dir = tempfile::tempdir().expect("temp dir");
        let config_path = dir.path().join("config.toml");
        std::fs::write(&config_path, config).expect("write config");
        let mut command = child::gateway_run(&config_path);
        command
            .env("RTU2MQTT__HEALTH__STATUS_FILE", dir.path().join("health"))
            .env_remove("JOURNAL_STREAM")
            .env_remove("RTU2MQTT_LOG_FORMAT")
            .env("RUST_LOG", "info")
            .stderr(Stdio::piped());
        let mut daemon = KillOnDrop::spawn(command).expect("rtu2mqtt run starts");
        let started = Instant::now();
        let lines = Arc::new(Mutex::new(Vec::new()));
        let stderr = daemon.0.stderr.take().expect("piped stderr");
        let sink = Arc::clone(&lines);
        std::thread::spawn(move || {
            for text in BufReader::new(stderr).lines().map_while(Result::ok) {
                let line = LogLine {
                    at: started.elapsed(),
                    text,
                };
                sink.lock().expect("log lines").push(line);
            }
        });
        Daemon {
            _child: daemon,
            started,
            lines,
            _dir: dir,
        }
    }

    fn lines(&self) -> Vec<LogLine> {
        self.lines.lock().expect("log lines").clone()
    }

    fn all(&self) -> String {
        self.lines()
            .iter()
            .map(|line| line.text.as_str())
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// The lines that contain every one of `parts`.
    fn matching(&self, parts: &[&str]) -> Vec<LogLine> {
        self.lines()
            .into_iter()
            .filter(|line| parts.iter().all(|part| line.text.contains(part)))
            .collect()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_normal_start_is_calm_and_a_command_is_two_lines_in_words() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).expect("seed plant on ptys");
    // Running, as in the demo: a gear command then takes effect.
    sim::lock(&plant.dust_collector).set_power(true);
    let client_id = "calm-start-gw";
    let mut client = TestClient::connect(broker.port, "calm-start-observer").await;
    client.subscribe("plant/#").await;
    let config = PlantConfig {
        gateway: "stats_interval = \"1s\"",
        ..PlantConfig::default()
    }
    .text(&broker, &plant, client_id);
    let daemon = Daemon::spawn(&config);

    for device in ["dust_collector", "air_shower", "valve"] {
        client
            .wait_for(&format!("plant/{device}/availability"), ANSWER, |m| {
                m.text() == "online"
            })
            .await;
    }
    // Past the start-up window (by the daemon's clock) before anything is judged.
    let rest = START.saturating_sub(daemon.started.elapsed());
    tokio::time::sleep(rest + Duration::from_millis(200)).await;

    // (1) Nothing in the first seconds of a normal start looks like trouble.
    let troubled: Vec<String> = daemon
        .lines()
        .into_iter()
        .filter(|line| line.at <= START && matches!(line.level(), "WARN" | "ERROR"))
        .map(|line| line.text)
        .collect();
    assert!(
        troubled.is_empty(),
        "warnings or errors in a normal start: {troubled:#?}\nwhole log:\n{}",
        daemon.all()
    );

    // (2) The pty that does not take parity: said once, at INFO, as a fact.
    let parity = daemon.matching(&["parity even is not applied by a pseudo-terminal"]);
    assert_eq!(parity.len(), 1, "the parity fact once: {}", daemon.all());
    assert_eq!(parity[0].level(), "INFO", "{parity:?}");
    assert!(parity[0].text.contains("line-b"), "{parity:?}");
    assert!(
        parity[0].text.contains("timing still follows 8E1"),
        "{parity:?}"
    );
    assert!(
        daemon.matching(&["does not take this setting"]).is_empty(),
        "{}",
        daemon.all()
    );

    // (3) The valve's split reads: once per block, at INFO, and no exception talk.
    let split = daemon.matching(&["reads block"]);
    assert!(
        split
            .iter()
            .any(|line| line.text.contains("valve: reads block \"live\" in ")),
        "the valve reads its live block in parts: {}",
        daemon.all()
    );
    for line in &split {
        assert_eq!(line.level(), "INFO", "{line:?}");
        let fact = split_fact(&line.text);
        let same = split.iter().filter(|l| split_fact(&l.text) == fact).count();
        assert_eq!(same, 1, "{fact:?} said once: {}", daemon.all());
    }
    assert!(
        daemon.matching(&["exception 02"]).is_empty(),
        "{}",
        daemon.all()
    );

    // (4) A gear command: one INFO line when it arrives, one INFO line for its outcome.
    client
        .publish("plant/dust_collector/gear/set", "8", false)
        .await;
    let result = client
        .wait_for("plant/dust_collector/gear/result", ANSWER, |m| {
            m.json()["outcome"] == "applied"
        })
        .await;
    assert_eq!(result.json()["value"], "8");
    // The outcome line is written before the result is published: give the pipe a moment.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let about_gear = daemon.matching(&["device=dust_collector", "field=gear"]);
    let info: Vec<&LogLine> = about_gear
        .iter()
        .filter(|line| line.level() == "INFO")
        .collect();
    assert_eq!(info.len(), 2, "two INFO lines for the command: {info:#?}");
    assert!(
        info[0].text.contains("command received") && info[0].text.contains("value=\"8\""),
        "{info:#?}"
    );
    assert!(
        info[1].text.contains("outcome=applied")
            && info[1]
                .text
                .contains("detail=\"read-back confirms the value\""),
        "the outcome in words: {info:#?}"
    );
    assert!(
        daemon.matching(&["Applied {"]).is_empty() && daemon.matching(&["outcome=\""]).is_empty(),
        "outcomes in words, not debug formatting: {}",
        daemon.all()
    );

    // (5) The valve's statistics from a normal start: no failure, no exception; the split
    // reads counted on their own.
    let topic = format!("plant/gateway/{client_id}/stats/line-b");
    let stats = client
        .wait_for_new(&topic, ANSWER, |m| {
            m.json()["devices"]["valve"]["transactions"]
                .as_u64()
                .is_some_and(|count| count > 0)
        })
        .await
        .json();
    let valve = &stats["devices"]["valve"];
    assert_eq!(valve["failures"], 0, "{valve}");
    assert_eq!(valve["exceptions"], 0, "{valve}");
    assert_eq!(
        valve["split_read_fallbacks"].as_u64(),
        Some(split.iter().filter(|l| l.text.contains("valve:")).count() as u64),
        "{valve}"
    );
    drop(daemon);
}
