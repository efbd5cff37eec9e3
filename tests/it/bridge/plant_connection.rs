//! The MQTT connection at plant scale, on a real mosquitto: a gateway with 1,000
//! `modbus-tcp://` lines (each to a closed loopback port, so every line is retried and every
//! device is offline, at no cost) publishes a statistics summary and one document per line,
//! each well within the packet limit, as are its Home Assistant gateway documents (one per
//! line); one more device, whose profile has so many fields that its discovery document is
//! larger than the limit, has that document refused alone and counted while its availability
//! goes out; and the connection stays up all along (no `offline` on the gateway status, one
//! connect, no disconnect).

use crate::support;

use std::collections::HashMap;
use std::time::{Duration, Instant};

use rtu2mqtt::bridge::driver::connection::MAX_OUTGOING_PACKET;
use support::{free_port, Gateway, Mosquitto, TestClient};

const LINES: usize = 1_000;
/// Fields of the big device: its discovery document is several times the packet limit.
const BIG_FIELDS: usize = 2_400;
const CLIENT_ID: &str = "scale-gw";
/// Generous bound for a busy 2-core machine: it only runs out when something is broken.
const ANSWER: Duration = Duration::from_secs(15);
/// Every discovery document of the thousand lines and their devices, announced in turns.
const ANNOUNCED: Duration = Duration::from_secs(40);

/// A profile of `BIG_FIELDS` holding registers, one `u16` field each, in blocks of 120.
fn big_profile() -> String {
    let mut text = String::from(
        r#"
[device]
name = "big-meter"
manufacturer = "Test"
model = "A meter with very many registers"

[line]
baud = 9600
address_range = [1, 247]
default_address = 1
max_read_registers = 120
"#,
    );
    let blocks = BIG_FIELDS.div_ceil(120);
    for block in 0..blocks {
        text.push_str(&format!(
            "\n[[blocks]]\nname = \"b{block}\"\nfunction = 3\nstart = {}\ncount = 120\npoll = \"fast\"\n",
            block * 120
        ));
    }
    for field in 0..BIG_FIELDS {
        text.push_str(&format!(
            "\n[[fields]]\nname = \"register_{field:04}\"\nblock = \"b{}\"\noffset = {}\ncodec = {{ type = \"u16\" }}\n",
            field / 120,
            field % 120
        ));
    }
    text
}

/// `LINES` Modbus TCP lines, one device each, every one to `closed_port` on its own loopback
/// address, and one more line with the big device (`big_profile` at `big_profile_path`);
/// statistics every second, discovery on.
fn config_text(broker: &Mosquitto, closed_port: u16, big_profile_path: &str) -> String {
    let mut text = format!(
        r#"
[mqtt]
url = "{broker}"
client_id = "{CLIENT_ID}"
prefix = "plant"
discovery = true

[gateway]
stats_interval = "1s"
"#,
        broker = broker.url()
    );
    for index in 0..LINES {
        let host = format!("127.0.{}.{}", index / 250, index % 250 + 1);
        let line = format!("line-{index:04}");
        let device = format!("meter_{index:04}");
        text.push_str(&line_text(
            &line,
            &host,
            closed_port,
            &device,
            "ruiwan-dust-collector",
        ));
    }
    text.push_str(&line_text(
        "line-big",
        "127.0.4.1",
        closed_port,
        "big_meter",
        big_profile_path,
    ));
    text
}

/// One `modbus-tcp://` line to `host:port` with one device of `profile` at address 1.
fn line_text(line: &str, host: &str, port: u16, device: &str, profile: &str) -> String {
    format!(
        r#"
[[lines]]
name = "{line}"
url = "modbus-tcp://{host}:{port}"
response_timeout = "200ms"

[[lines.devices]]
name = "{device}"
profile = "{profile}"
address = 1
"#
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_thousand_lines_keep_the_connection_up_and_every_document_within_the_limit() {
    let broker = Mosquitto::start();
    // Bound, then closed: nothing listens there.
    let closed_port = free_port();
    let mut observer = TestClient::connect(broker.port, "scale-observer").await;
    observer.subscribe("plant/gateway/#").await;
    observer.subscribe("plant/big_meter/availability").await;
    observer.subscribe("homeassistant/device/#").await;
    let dir = tempfile::tempdir().expect("temp dir");
    let profile_path = dir.path().join("big-meter.toml");
    std::fs::write(&profile_path, big_profile()).expect("write the profile");
    let text = config_text(&broker, closed_port, &profile_path.display().to_string());
    let gateway = Gateway::start(support::fast_config(&text)).await;
    let started = Instant::now();

    let status = format!("plant/gateway/{CLIENT_ID}/status");
    let summary_topic = format!("plant/gateway/{CLIENT_ID}/stats");
    observer
        .wait_for(&status, ANSWER, |m| m.text() == "online")
        .await;

    // Every line's document arrives, and each is small; together they are what one document
    // would have been.
    let mut line_documents: HashMap<String, usize> = HashMap::new();
    let mut statuses = Vec::new();
    let mut discovery: HashMap<String, usize> = HashMap::new();
    let mut big_meter_availability = None;
    let line_prefix = format!("{summary_topic}/");
    let gateway_documents = |discovery: &HashMap<String, usize>| {
        discovery
            .keys()
            .filter(|topic| topic.starts_with(&format!("homeassistant/device/{CLIENT_ID}_gateway")))
            .count()
    };
    // Discovery documents go out at a bounded rate (50 every 250 ms at most), the devices'
    // before the lines': about ten seconds for these 2,002.
    let deadline = tokio::time::Instant::now() + ANNOUNCED;
    while line_documents.len() < LINES + 1 || gateway_documents(&discovery) < 1 + LINES + 1 {
        assert!(
            tokio::time::Instant::now() < deadline,
            "{} line documents of {LINES} and {} of the gateway's discovery documents within \
             {ANNOUNCED:?}",
            line_documents.len(),
            gateway_documents(&discovery)
        );
        observer.settle(Duration::from_millis(200)).await;
        for message in observer.received.drain(..) {
            if message.topic == status {
                statuses.push(message.text());
            }
            if message.topic == "plant/big_meter/availability" {
                big_meter_availability = Some(message.text());
            }
            if message.topic.starts_with("homeassistant/") {
                discovery.insert(message.topic.clone(), message.payload.len());
                continue;
            }
            if let Some(line) = message.topic.strip_prefix(&line_prefix) {
                let document = message.json();
                assert_eq!(document["line"], line, "{document}");
                assert_eq!(
                    document["devices"].as_object().map(|d| d.len()),
                    Some(1),
                    "{document}"
                );
                line_documents.insert(line.to_string(), message.payload.len());
            }
        }
    }
    let largest_line = line_documents.values().copied().max().unwrap_or(0);
    let all_lines: usize = line_documents.values().sum();
    assert!(
        largest_line < MAX_OUTGOING_PACKET / 100,
        "{largest_line} bytes"
    );
    assert!(
        all_lines > MAX_OUTGOING_PACKET,
        "one document would not fit: {all_lines} bytes"
    );

    // Home Assistant: the gateway's document and one per line, each small; every device's
    // but the big one's, which alone was refused.
    let largest_discovery = discovery.values().copied().max().unwrap_or(0);
    assert!(
        largest_discovery < MAX_OUTGOING_PACKET,
        "{largest_discovery} bytes"
    );
    assert_eq!(
        gateway_documents(&discovery),
        1 + LINES + 1,
        "the gateway's and its lines'"
    );
    assert!(discovery.contains_key(&format!(
        "homeassistant/device/{CLIENT_ID}_meter_0999/config"
    )));
    assert!(!discovery.contains_key(&format!(
        "homeassistant/device/{CLIENT_ID}_big_meter/config"
    )));
    // The big device itself is there all the same.
    let availability = match big_meter_availability {
        Some(word) => word,
        None => observer
            .wait_for("plant/big_meter/availability", ANSWER, |_| true)
            .await
            .text(),
    };
    assert_eq!(availability, "offline");

    // A summary after the gateway has had time to trip over anything too large: still the
    // first connection, and the oversized document was refused alone, once.
    let summary = observer
        .wait_for(&summary_topic, ANSWER, |m| {
            m.json()["uptime_seconds"].as_u64().unwrap_or(0) >= 3
        })
        .await;
    let figures = summary.json();
    assert!(
        summary.payload.len() < 4096,
        "{} bytes",
        summary.payload.len()
    );
    assert_eq!(figures["lines_total"], LINES + 1, "{figures}");
    assert_eq!(figures["devices_total"], LINES + 1, "{figures}");
    assert_eq!(figures["mqtt"]["connected"], true, "{figures}");
    assert_eq!(figures["mqtt"]["connects"], 1, "{figures}");
    assert_eq!(figures["mqtt"]["disconnects"], 0, "{figures}");
    assert_eq!(figures["mqtt"]["oversized_refused"], 1, "{figures}");
    eprintln!(
        "{LINES} lines: summary {} bytes, largest line document {largest_line} bytes, \
         all line documents {all_lines} bytes, largest discovery document \
         {largest_discovery} bytes, after {:?}",
        summary.payload.len(),
        started.elapsed()
    );
    // The gateway's status never went to its Will.
    observer.settle(Duration::from_millis(300)).await;
    statuses.extend(observer.on(&status).iter().map(|m| m.text()));
    assert!(
        statuses.iter().all(|text| text == "online"),
        "the connection went down: {statuses:?}"
    );
    gateway.stop().await;
}
