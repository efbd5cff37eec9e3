//! The demo's promises, checked with real MQTT clients (`mosquitto_sub` / `mosquitto_pub`):
//! the embedded broker serves, keeps and clears retained messages and forwards live ones; and
//! the real `rtu2mqtt-demo` binary publishes every field of the three seed devices, applies
//! commands (the simulated devices behave: gear set, e-stop opens the doors, the valve moves),
//! and stops cleanly with exit status 0 on SIGINT, with its own broker, with a broker already
//! on its port, and with `--broker`; on a broker it did not start it leaves nothing retained
//! of its own behind (and everybody else's untouched).

use crate::support;

use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read};
use std::net::SocketAddr;
use std::process::{Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use nix::sys::signal::{kill, Signal};
use support::child::KillOnDrop;
use support::free_port;

fn mosquitto_pub(port: u16, args: &[&str]) -> Output {
    let output = Command::new("mosquitto_pub")
        .args(["-h", "127.0.0.1", "-p", &port.to_string(), "-q", "1"])
        .args(args)
        .output()
        .expect("mosquitto_pub runs (apt install mosquitto-clients)");
    assert!(
        output.status.success(),
        "mosquitto_pub {args:?}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

/// Subscribes for `seconds` and returns every message as `<retain> <topic> <payload>`.
fn collect_for(port: u16, filter: &str, seconds: u32) -> Vec<String> {
    let output = Command::new("mosquitto_sub")
        .args(["-h", "127.0.0.1", "-p", &port.to_string(), "-q", "1"])
        .args(["-t", filter, "-W", &seconds.to_string(), "-F", "%r %t %p"])
        .output()
        .expect("mosquitto_sub runs (apt install mosquitto-clients)");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        !stderr.contains("refused") && !stderr.contains("Error"),
        "mosquitto_sub failed: {stderr}"
    );
    String::from_utf8_lossy(&output.stdout)
        .lines()
        .map(str::to_string)
        .collect()
}

/// A long-running `mosquitto_sub -v` whose lines arrive on a channel.
struct Subscriber {
    _child: KillOnDrop,
    lines_rx: mpsc::Receiver<String>,
}

impl Subscriber {
    fn start(port: u16, filter: &str) -> Subscriber {
        let mut command = Command::new("mosquitto_sub");
        command
            .args(["-h", "127.0.0.1", "-p", &port.to_string(), "-q", "1"])
            .args(["-t", filter, "-F", "%r %t %p"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null());
        let mut subscriber = KillOnDrop::spawn(command).expect("mosquitto_sub runs");
        let stdout = subscriber.0.stdout.take().expect("piped stdout");
        let (lines_tx, lines_rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if lines_tx.send(line).is_err() {
                    break;
                }
            }
        });
        Subscriber {
            _child: subscriber,
            lines_rx,
        }
    }

    /// Waits for a line satisfying `wanted`, returning it; None after `timeout`.
    fn wait_for(&self, timeout: Duration, wanted: impl Fn(&str) -> bool) -> Option<String> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.checked_duration_since(Instant::now())?;
            match self.lines_rx.recv_timeout(left) {
                Ok(line) if wanted(&line) => return Some(line),
                Ok(_) => continue,
                Err(_) => return None,
            }
        }
    }
}

#[test]
fn embedded_broker_keeps_and_clears_retained_messages() {
    let port = free_port();
    let broker = rtu2mqtt_demo::broker::start(port).expect("the embedded broker starts");
    assert_eq!(broker.url(), format!("mqtt://127.0.0.1:{port}"));

    mosquitto_pub(port, &["-r", "-t", "plant/test/kept", "-m", "42"]);
    mosquitto_pub(port, &["-r", "-t", "plant/test/cleared", "-m", "ON"]);
    let both = collect_for(port, "plant/test/#", 2);
    let mut sorted = both.clone();
    sorted.sort();
    assert_eq!(
        sorted,
        vec!["1 plant/test/cleared ON", "1 plant/test/kept 42"],
        "a new subscriber sees both retained messages with the retain flag"
    );

    // A retained empty message clears, exactly as the gateway clears a handled command.
    mosquitto_pub(port, &["-r", "-n", "-t", "plant/test/cleared"]);
    assert_eq!(
        collect_for(port, "plant/test/#", 2),
        vec!["1 plant/test/kept 42"]
    );
}

#[test]
fn embedded_broker_forwards_live_messages() {
    let port = free_port();
    rtu2mqtt_demo::broker::start(port).expect("the embedded broker starts");
    // The retained marker proves the subscription is in place before the live publish.
    mosquitto_pub(port, &["-r", "-t", "plant/live/ready", "-m", "yes"]);
    let subscriber = Subscriber::start(port, "plant/live/#");
    subscriber
        .wait_for(Duration::from_secs(10), |line| line.contains("ready"))
        .expect("the retained marker arrives");
    mosquitto_pub(port, &["-t", "plant/dust_collector/gear/set", "-m", "8"]);
    mosquitto_pub(port, &["-t", "plant/live/value", "-m", "12.34"]);
    let line = subscriber
        .wait_for(Duration::from_secs(10), |line| line.contains("value"))
        .expect("the live message arrives");
    assert_eq!(line, "0 plant/live/value 12.34");
}

/// Every `plant/<device>/<field>` the seed plant must publish: all fields of the three built-in
/// profiles.
fn expected_topics() -> Vec<String> {
    let mut topics = Vec::new();
    for (device, profile) in [
        ("dust_collector", "ruiwan-dust-collector"),
        ("air_shower", "lixian-air-shower"),
        ("valve", "wuzhou-valve"),
    ] {
        let profile = rtu2mqtt_profile::registry::built_in(profile).expect("built-in profile");
        for field in profile.fields() {
            topics.push(format!("plant/{device}/{}", field.name));
        }
    }
    topics
}

/// A running `rtu2mqtt-demo --log`, its output drained in the background; SIGKILLed on drop
/// if a test failed before stopping it.
struct Demo {
    child: KillOnDrop,
    stdout_rx: mpsc::Receiver<String>,
    stderr: std::thread::JoinHandle<String>,
}

impl Demo {
    fn start(args: &[&str]) -> Demo {
        let mut command = Command::new(crate::DEMO);
        command
            .arg("--log")
            .args(args)
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut demo = KillOnDrop::spawn(command).expect("the rtu2mqtt-demo binary runs");
        let stdout = demo.0.stdout.take().expect("piped stdout");
        let mut stderr = demo.0.stderr.take().expect("piped stderr");
        let (stdout_tx, stdout_rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if stdout_tx.send(line).is_err() {
                    break;
                }
            }
        });
        let stderr = std::thread::spawn(move || {
            let mut text = String::new();
            let _ = stderr.read_to_string(&mut text);
            text
        });
        Demo {
            child: demo,
            stdout_rx,
            stderr,
        }
    }

    /// SIGINT, then the exit status and everything the demo printed.
    fn interrupt(mut self) -> (std::process::ExitStatus, String, String) {
        kill(self.child.pid(), Signal::SIGINT).expect("SIGINT delivered");
        let deadline = Instant::now() + Duration::from_secs(30);
        let status = loop {
            if let Some(status) = self.child.0.try_wait().expect("wait") {
                break status;
            }
            assert!(Instant::now() < deadline, "the demo did not stop on SIGINT");
            std::thread::sleep(Duration::from_millis(50));
        };
        let stdout: Vec<String> = self.stdout_rx.try_iter().collect();
        (
            status,
            stdout.join("\n"),
            self.stderr.join().unwrap_or_default(),
        )
    }
}

/// Waits until `port` answers an MQTT CONNECT.
fn wait_for_broker(port: u16) {
    let address = SocketAddr::from(([127, 0, 0, 1], port));
    let deadline = Instant::now() + Duration::from_secs(30);
    while rtu2mqtt_demo::broker::mqtt_handshake(address).is_err() {
        assert!(Instant::now() < deadline, "no broker on {port}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The latest payload per topic, from `<retain> <topic> <payload>` lines.
struct Plant {
    subscriber: Subscriber,
    latest: HashMap<String, String>,
}

impl Plant {
    fn watch(port: u16) -> Plant {
        Plant {
            subscriber: Subscriber::start(port, "plant/#"),
            latest: HashMap::new(),
        }
    }

    /// Reads messages until `done(latest)` holds; false after `timeout`.
    fn until(
        &mut self,
        timeout: Duration,
        done: impl Fn(&HashMap<String, String>) -> bool,
    ) -> bool {
        let deadline = Instant::now() + timeout;
        while !done(&self.latest) {
            let Some(left) = deadline.checked_duration_since(Instant::now()) else {
                return false;
            };
            if let Ok(line) = self.subscriber.lines_rx.recv_timeout(left) {
                let mut parts = line.splitn(3, ' ');
                let (_retain, topic) = (parts.next(), parts.next().unwrap_or_default());
                let payload = parts.next().unwrap_or_default();
                self.latest.insert(topic.to_string(), payload.to_string());
            }
        }
        true
    }

    fn is(&mut self, topic: &str, value: &str) -> bool {
        let (topic, value) = (topic.to_string(), value.to_string());
        self.until(Duration::from_secs(30), move |latest| {
            latest.get(&topic) == Some(&value)
        })
    }

    fn outcome(&mut self, field_topic: &str) -> String {
        let topic = format!("{field_topic}/result");
        let wanted = topic.clone();
        assert!(
            self.until(Duration::from_secs(60), move |latest| latest
                .contains_key(&wanted)),
            "no result on {topic}"
        );
        let json: serde_json::Value =
            serde_json::from_str(&self.latest[&topic]).expect("a JSON result");
        json["outcome"].as_str().unwrap_or_default().to_string()
    }
}

/// The plant publishes every field, takes commands, and stops on SIGINT: the common part of the
/// demo tests, against whatever broker is on `port`.
fn exercise_the_plant(demo: Demo, port: u16) -> String {
    wait_for_broker(port);
    let started = Instant::now();
    let mut plant = Plant::watch(port);
    let expected = expected_topics();
    assert!(expected.len() >= 60, "{} fields", expected.len());
    let all = expected.clone();
    let complete = plant.until(Duration::from_secs(60), move |latest| {
        all.iter().all(|topic| latest.contains_key(topic))
    });
    let missing: Vec<&String> = expected
        .iter()
        .filter(|topic| !plant.latest.contains_key(*topic))
        .collect();
    assert!(complete, "never published: {missing:?}");
    eprintln!(
        "all {} fields published {:.1}s after the broker came up",
        expected.len(),
        started.elapsed().as_secs_f64()
    );
    for (device, status) in [
        ("dust_collector", "online"),
        ("air_shower", "online"),
        ("valve", "online"),
    ] {
        assert!(plant.is(&format!("plant/{device}/availability"), status));
    }

    // The demo switches the dust collector on, so a new gear is applied, not just acknowledged.
    mosquitto_pub(port, &["-t", "plant/dust_collector/gear/set", "-m", "8"]);
    assert_eq!(plant.outcome("plant/dust_collector/gear"), "applied");
    assert!(plant.is("plant/dust_collector/gear", "8"));

    // The emergency stop opens both automatic doors.
    assert!(plant.is("plant/air_shower/front_door_closed", "ON"));
    mosquitto_pub(
        port,
        &["-t", "plant/air_shower/emergency_stop/set", "-m", "ON"],
    );
    assert_eq!(plant.outcome("plant/air_shower/emergency_stop"), "applied");
    assert!(plant.is("plant/air_shower/emergency_stop", "ON"));
    assert!(plant.is("plant/air_shower/front_door_closed", "OFF"));
    assert!(plant.is("plant/air_shower/rear_door_closed", "OFF"));

    // The valve travels to a commanded opening.
    mosquitto_pub(port, &["-t", "plant/valve/opening/set", "-m", "40"]);
    assert_eq!(plant.outcome("plant/valve/opening"), "applied");
    assert!(plant.is("plant/valve/opening", "40"));

    // An invalid command is rejected before the bus.
    plant.latest.remove("plant/dust_collector/gear/result");
    mosquitto_pub(port, &["-t", "plant/dust_collector/gear/set", "-m", "11"]);
    assert_eq!(plant.outcome("plant/dust_collector/gear"), "rejected");
    assert_eq!(plant.latest["plant/dust_collector/gear"], "8");

    let (status, stdout, stderr) = demo.interrupt();
    assert!(status.success(), "exit {status:?}\n{stdout}\n{stderr}");
    assert!(stdout.contains("dust_collector/gear = 8"), "{stdout}");
    assert!(stdout.contains("rtu2mqtt-demo stopped"), "{stdout}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    // The valve's line runs with the device's even parity settings, which a pty ignores.
    assert!(stderr.contains("parity"), "{stderr}");
    stdout
}

#[test]
fn demo_publishes_the_whole_plant_and_obeys_commands() {
    let port = free_port();
    let demo = Demo::start(&["--port", &port.to_string()]);
    let stdout = exercise_the_plant(demo, port);
    assert!(stdout.contains("(embedded broker)"), "{stdout}");
}

#[test]
fn demo_uses_a_broker_already_on_its_port() {
    let mosquitto = support::Mosquitto::start();
    let demo = Demo::start(&["--port", &mosquitto.port.to_string()]);
    let stdout = exercise_the_plant(demo, mosquitto.port);
    assert!(stdout.contains("(existing broker)"), "{stdout}");
}

#[test]
fn demo_uses_the_broker_given() {
    let mosquitto = support::Mosquitto::start();
    let demo = Demo::start(&["--broker", &mosquitto.url()]);
    let stdout = exercise_the_plant(demo, mosquitto.port);
    assert!(stdout.contains("(--broker)"), "{stdout}");
}

#[test]
fn demo_leaves_nothing_retained_on_a_broker_it_did_not_start() {
    let mosquitto = support::Mosquitto::start();
    let port = mosquitto.port;
    // Somebody else's retained topics, which the demo must leave alone.
    let foreign = [
        ("plant/boiler/temperature", "21.5"),
        ("plant/gateway/edge-1/status", "offline"),
        ("homeassistant/device/edge-1_boiler/config", "{}"),
    ];
    for (topic, payload) in foreign {
        mosquitto_pub(port, &["-r", "-t", topic, "-m", payload]);
    }
    let demo = Demo::start(&["--broker", &mosquitto.url()]);
    let mut plant = Plant::watch(port);
    let expected = expected_topics();
    assert!(
        plant.until(Duration::from_secs(60), move |latest| expected
            .iter()
            .all(|topic| latest.contains_key(topic))),
        "the plant was never fully published"
    );
    mosquitto_pub(port, &["-t", "plant/dust_collector/gear/set", "-m", "8"]);
    assert_eq!(plant.outcome("plant/dust_collector/gear"), "applied");
    let discovery = collect_for(port, "homeassistant/device/+/config", 2);
    assert!(
        discovery
            .iter()
            .any(|line| line.starts_with("1 homeassistant/device/rtu2mqtt-demo_valve/config ")),
        "{discovery:?}"
    );

    let (status, stdout, stderr) = demo.interrupt();
    assert!(status.success(), "exit {status:?}\n{stdout}\n{stderr}");
    assert!(
        stdout.contains("Cleared the ") && stdout.contains("retained topics the demo used"),
        "{stdout}"
    );
    let mut left = collect_for(port, "#", 2);
    left.sort();
    let mut wanted: Vec<String> = foreign
        .iter()
        .map(|(topic, payload)| format!("1 {topic} {payload}"))
        .collect();
    wanted.sort();
    assert_eq!(left, wanted, "retained after the demo stopped");
}
