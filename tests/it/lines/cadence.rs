//! Per-block cadence end to end: the gateway (`run_gateway`) polls a simulated device built
//! from a profile with fast, slow, own-period and `once` blocks on a pty, behind a real
//! mosquitto. The simulator's journal counts every read frame: a `once` block is read exactly
//! once at start, again after a command writing into it (from MQTT, or from a Modbus TCP client
//! of the served line, under `profile` and `raw` access alike), and
//! `<prefix>/<device>/refresh` reads every block once; a retained refresh is cleared and reads
//! nothing.

use crate::support;

use std::path::Path;
use std::time::{Duration, Instant};

use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_profile::Profile;
use rtu2mqtt_sim::{self as sim, share, GenericDevice, ServeOptions, VirtualLine};
use support::{Gateway, Mosquitto, TestClient};

/// Generous bound for a busy 2-core machine: it only runs out when something is broken.
const ANSWER: Duration = Duration::from_secs(15);
const ADDRESS: u8 = 5;

/// A meter with one block of each cadence (`check`'s test shows its plan). Its `nameplate`
/// block is read once; its `modbus_address` is a setting written into that block.
pub const PROFILE: &str = r#"
[device]
name = "cadence-meter"
manufacturer = "Test"
model = "C1"

[line]
min_poll_interval = "100ms"

[[blocks]]
name = "power"
function = 4
start = 0x0000
count = 2

[[blocks]]
name = "voltage"
function = 4
start = 0x0010
count = 2
poll = "250ms"

[[blocks]]
name = "energy"
function = 4
start = 0x0100
count = 2
poll = "15s"

[[blocks]]
name = "setup"
function = 3
start = 0x0300
count = 1
poll = "slow"

[[blocks]]
name = "nameplate"
function = 3
start = 0x0200
count = 2
poll = "once"

[[fields]]
name = "power"
block = "power"
offset = 0
codec = { type = "u16" }

[[fields]]
name = "voltage"
block = "voltage"
offset = 0
codec = { type = "u16" }

[[fields]]
name = "energy"
block = "energy"
offset = 0
codec = { type = "u16" }

[[fields]]
name = "ct_ratio"
block = "setup"
offset = 0
codec = { type = "u16" }

[[fields]]
name = "serial"
block = "nameplate"
offset = 0
codec = { type = "u16" }

[[fields]]
name = "modbus_address"
block = "nameplate"
offset = 1
codec = { type = "u16" }
range = [1, 247]
write = { function = 6, address = 0x0201 }
"#;

/// The blocks as (function, start), in the profile's order.
const POWER: (u8, u16) = (4, 0x0000);
const ENERGY: (u8, u16) = (4, 0x0100);
const SETUP: (u8, u16) = (3, 0x0300);
const NAMEPLATE: (u8, u16) = (3, 0x0200);

/// The meter's configuration; `serve`: the body of a `[lines.serve]` table, or empty.
fn config(broker: &Mosquitto, line: &VirtualLine, profile: &Path, serve: &str) -> String {
    let serve = if serve.is_empty() {
        String::new()
    } else {
        format!("[lines.serve]\n{serve}\n")
    };
    format!(
        r#"
[mqtt]
url = "{url}"
client_id = "cadence-gw"
prefix = "plant"

[[lines]]
name = "line-m"
port = "{port}"
baud = 9600
parity = "none"
response_timeout = "150ms"
retries = 1
{serve}
[[lines.devices]]
name = "meter"
profile = "{profile}"
address = {ADDRESS}
poll_interval = "300ms"
"#,
        url = broker.url(),
        port = line.path().display(),
        profile = profile.display(),
    )
}

/// Reads of each block the simulator saw: power, energy, setup, nameplate (the 250 ms
/// voltage block only keeps the line busy).
fn reads(line: &VirtualLine) -> [usize; 4] {
    let frames = line.journal().frames();
    [POWER, ENERGY, SETUP, NAMEPLATE].map(|(function, start)| {
        let [high, low] = start.to_be_bytes();
        frames
            .iter()
            .filter(|frame| frame.len() == 8 && frame[..4] == [ADDRESS, function, high, low])
            .count()
    })
}

/// Waits until `accept` holds for the reads the simulator saw.
async fn wait_reads(line: &VirtualLine, accept: impl Fn([usize; 4]) -> bool) -> [usize; 4] {
    let deadline = Instant::now() + ANSWER;
    loop {
        let seen = reads(line);
        if accept(seen) {
            return seen;
        }
        assert!(Instant::now() < deadline, "reads seen: {seen:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn once_blocks_are_read_at_start_after_a_write_and_on_refresh_and_a_retained_refresh_is_cleared(
) {
    let dir = tempfile::tempdir().unwrap();
    let profile_path = dir.path().join("cadence-meter.toml");
    std::fs::write(&profile_path, PROFILE).unwrap();
    let profile = Profile::from_toml(PROFILE, "cadence-meter.toml").unwrap();
    let (meter, shared) = share(GenericDevice::from_profile(&profile, ADDRESS));
    sim::lock(&meter).set_holding(0x0200, 4711);
    let line = VirtualLine::spawn(ServeOptions::new(9600, Parity::None), vec![shared]).unwrap();
    let broker = Mosquitto::start();

    // A stale refresh waits in the broker's retained store before the gateway starts.
    let sender = TestClient::connect(broker.port, "cadence-sender").await;
    sender
        .publish("plant/meter/refresh", b"stale".to_vec(), true)
        .await;
    let mut look = TestClient::connect(broker.port, "cadence-look").await;
    look.subscribe("plant/meter/refresh").await;
    look.wait_for("plant/meter/refresh", ANSWER, |m| m.retain)
        .await;
    let mut observer = TestClient::connect(broker.port, "cadence-observer").await;
    observer.subscribe("plant/#").await;

    let text = config(&broker, &line, &profile_path, "");
    let config = rtu2mqtt::config::from_str(&text, dir.path()).expect("valid configuration");
    let gateway = Gateway::start(config).await;
    observer
        .wait_for("plant/meter/availability", ANSWER, |m| m.text() == "online")
        .await;
    observer
        .wait_for("plant/meter/serial", ANSWER, |m| m.text() == "4711")
        .await;
    // The gateway clears the retained refresh (an empty retained message) ...
    observer
        .wait_for("plant/meter/refresh", ANSWER, |m| m.payload.is_empty())
        .await;
    // ... and reads nothing for it: after a few fast polls, every block but the fast one has
    // been read once, at start.
    let started = wait_reads(&line, |[power, ..]| power >= 5).await;
    assert_eq!(
        started[1..],
        [1, 1, 1],
        "energy, setup, nameplate: {started:?}"
    );
    let mut late = TestClient::connect(broker.port, "cadence-late").await;
    late.subscribe("plant/meter/refresh").await;
    late.settle(Duration::from_millis(500)).await;
    assert!(
        late.on("plant/meter/refresh").is_empty(),
        "still retained: {:?}",
        late.on("plant/meter/refresh")
    );
    let steady = wait_reads(&line, |[power, ..]| power >= started[0] + 3).await;
    assert_eq!(
        steady[1..],
        [1, 1, 1],
        "a once block is read once: {steady:?}"
    );

    // A live refresh reads every block once and publishes what changed.
    sim::lock(&meter).set_holding(0x0200, 4712);
    observer
        .publish("plant/meter/refresh", b"now".to_vec(), false)
        .await;
    observer
        .wait_for("plant/meter/serial", ANSWER, |m| m.text() == "4712")
        .await;
    let refreshed = wait_reads(&line, |seen| seen[3] >= 2).await;
    let after = wait_reads(&line, |[power, ..]| power >= refreshed[0] + 3).await;
    assert_eq!(after[1..], [2, 2, 2], "one read of every block: {after:?}");

    // A command writing into the once block: the block is read again (by its slot), and
    // then no more.
    observer
        .publish("plant/meter/modbus_address/set", b"17".to_vec(), false)
        .await;
    let result = observer
        .next_on("plant/meter/modbus_address/result", ANSWER)
        .await
        .json();
    assert_eq!(result["outcome"], "applied", "{result}");
    observer
        .wait_for("plant/meter/modbus_address", ANSWER, |m| m.text() == "17")
        .await;
    let written = reads(&line);
    assert!(written[3] > after[3], "{after:?} → {written:?}");
    assert_eq!(written[1..3], [2, 2], "other blocks untouched: {written:?}");
    let calm = wait_reads(&line, |[power, ..]| power >= written[0] + 4).await;
    assert_eq!(
        calm[1..],
        written[1..],
        "nothing more in steady state: {calm:?}"
    );
    assert_eq!(sim::lock(&meter).holding(0x0201), Some(17));

    gateway.stop().await;
}

/// A Modbus TCP client (pymodbus, `tests/interop/modbus_share_client.py`) writes into the
/// `once` block through the served line: the block is read again and the new value published.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_served_clients_write_into_a_once_block_has_it_read_again() {
    for access in ["profile", "raw"] {
        let dir = tempfile::tempdir().unwrap();
        let profile_path = dir.path().join("cadence-meter.toml");
        std::fs::write(&profile_path, PROFILE).unwrap();
        let profile = Profile::from_toml(PROFILE, "cadence-meter.toml").unwrap();
        let (meter, shared) = share(GenericDevice::from_profile(&profile, ADDRESS));
        let line = VirtualLine::spawn(ServeOptions::new(9600, Parity::None), vec![shared]).unwrap();
        let broker = Mosquitto::start();
        let mut observer = TestClient::connect(broker.port, "cadence-served-observer").await;
        observer.subscribe("plant/#").await;
        let port = support::free_port();
        let serve = format!("listen = \"modbus-tcp://127.0.0.1:{port}\"\naccess = \"{access}\"");
        let text = config(&broker, &line, &profile_path, &serve);
        let config = rtu2mqtt::config::from_str(&text, dir.path()).expect("valid configuration");
        let gateway = Gateway::start(config).await;
        observer
            .wait_for("plant/meter/availability", ANSWER, |m| m.text() == "online")
            .await;
        let started = wait_reads(&line, |[power, ..]| power >= 4).await;
        assert_eq!(started[1..], [1, 1, 1], "{access}: {started:?}");

        let answers = modbus_client(port, &format!("[[\"write\", {ADDRESS}, 513, 23]]")).await;
        assert_eq!(answers.trim(), r#"{"written": true}"#, "{access}");
        observer
            .wait_for("plant/meter/modbus_address", ANSWER, |m| m.text() == "23")
            .await;
        let written = wait_reads(&line, |seen| seen[3] >= 2).await;
        let calm = wait_reads(&line, |[power, ..]| power >= written[0] + 4).await;
        assert_eq!(
            calm[1..3],
            [1, 1],
            "{access}: other blocks untouched: {calm:?}"
        );
        assert_eq!(calm[3], written[3], "{access}: then no more: {calm:?}");
        assert_eq!(sim::lock(&meter).holding(0x0201), Some(23));
        gateway.stop().await;
    }
}

/// Runs `ops` in one pymodbus client against the served line on `port`; its output.
async fn modbus_client(port: u16, ops: &str) -> String {
    let args = ["127.0.0.1", &port.to_string(), ops];
    support::pymodbus::run_client("modbus_share_client.py", &args, Duration::from_secs(60)).await
}
