//! A served line (`[lines.serve]`) end to end: pymodbus clients (an implementation not written
//! here, `tests/interop/modbus_share_client.py`) against the gateway's Modbus TCP server while
//! the gateway polls the simulated seed plant on ptys and takes MQTT commands from mosquitto.
//! Frames are checked byte for byte in the simulator's journal.

use crate::support;

use std::time::{Duration, Instant};

use serde_json::{json, Value as Json};

use rtu2mqtt::bus::serve::places::PLACE_WAIT;
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_sim::{self as sim, SeedPlant};
use support::{free_port, hex, Mosquitto, PlantBench, PlantConfig};

/// Generous bounds for a busy 2-core machine: they only fail when something is broken.
const ANSWER: Duration = Duration::from_secs(15);
const CLIENT: &str = "modbus_share_client.py";
const DUST: u8 = 1;
const SHOWER: u8 = 0x81;

/// The seed plant's configuration with the line of `device` served as `serve` says.
fn served_config(
    broker: &Mosquitto,
    plant: &SeedPlant,
    client_id: &str,
    serve: &str,
    device: &str,
) -> String {
    let text = PlantConfig {
        gateway: "stats_interval = \"1s\"",
        explicit_serial: true,
        line_keys: "retries = 1\noffline_after = 2",
        ..PlantConfig::default()
    }
    .text(broker, plant, client_id);
    let first_device = format!("[[lines.devices]]\nname = \"{device}\"");
    assert!(text.contains(&first_device));
    text.replacen(
        &first_device,
        &format!("[lines.serve]\n{serve}\n\n{first_device}"),
        1,
    )
}

/// The plant bench with one line served to Modbus TCP clients on `port`.
struct Harness {
    base: PlantBench,
    port: u16,
    /// The served line.
    line: &'static str,
}

impl Harness {
    /// The seed plant with line-a (dust collector, air shower) served.
    async fn start(name: &str, serve: &str) -> Harness {
        Harness::start_serving(name, serve, "dust_collector").await
    }

    /// The seed plant with the line of `device` served.
    async fn start_serving(name: &str, serve: &str, device: &str) -> Harness {
        Harness::start_with(name, serve, device, false).await
    }

    /// The seed plant with the line of `device` served; its configuration read from a file
    /// that the bench reloads when `reloadable`.
    async fn start_with(name: &str, serve: &str, device: &str, reloadable: bool) -> Harness {
        Harness::start_edited(name, serve, device, reloadable, |text| text).await
    }

    /// [`Harness::start_with`], the configuration text passed through `edit` first.
    async fn start_edited(
        name: &str,
        serve: &str,
        device: &str,
        reloadable: bool,
        edit: impl Fn(String) -> String,
    ) -> Harness {
        let port = free_port();
        let serve = if serve.contains("listen") {
            serve.replace("{port}", &port.to_string())
        } else {
            format!("listen = \"modbus-tcp://127.0.0.1:{port}\"\n{serve}")
        };
        let mut setup = PlantBench::setup(name)
            .prepare(|plant| sim::lock(&plant.dust_collector).set_power(true))
            .config(|broker, plant, client_id| {
                edit(served_config(broker, plant, client_id, &serve, device))
            });
        if reloadable {
            setup = setup.reloadable();
        }
        Harness {
            base: setup.start().await,
            port,
            line: if device == "valve" {
                "line-b"
            } else {
                "line-a"
            },
        }
    }

    /// Runs `ops` in one pymodbus client; one JSON answer per op.
    async fn client(&self, ops: Json) -> Vec<Json> {
        self.python(CLIENT, &[], &ops, Duration::from_secs(60))
            .await
    }

    /// Runs the pymodbus `script` of tests/interop against the server (`HOST PORT ARGS… OPS`);
    /// one JSON value per line it prints.
    async fn python<T: serde::de::DeserializeOwned>(
        &self,
        script: &str,
        args: &[String],
        ops: &Json,
        limit: Duration,
    ) -> Vec<T> {
        let mut all = vec!["127.0.0.1".to_string(), self.port.to_string()];
        all.extend_from_slice(args);
        all.push(ops.to_string());
        support::pymodbus::run_client(script, &all, limit)
            .await
            .lines()
            .map(|line| serde_json::from_str(line).expect("one JSON value per line"))
            .collect()
    }

    fn frames(&self) -> Vec<String> {
        self.base
            .plant
            .line_a
            .journal()
            .frames()
            .iter()
            .map(|frame| hex::encode(frame))
            .collect()
    }

    /// The next statistics document whose figures of the served line satisfy `accept`.
    async fn line_stats(&mut self, accept: impl Fn(&Json) -> bool) -> Json {
        let topic = format!("plant/gateway/{}/stats/{}", self.base.client_id, self.line);
        self.base
            .observer
            .wait_for(&topic, ANSWER, |m| accept(&m.json()))
            .await
            .json()
    }
}

/// Latencies of `count` reads of the dust collector's block over a plain Modbus TCP socket.
async fn timed_reads(port: u16, count: u16) -> Vec<Duration> {
    let mut stream = tokio::net::TcpStream::connect(("127.0.0.1", port))
        .await
        .unwrap();
    stream.set_nodelay(true).unwrap();
    timed_reads_on(&mut stream, count).await
}

/// A read of the dust collector's block in Modbus TCP, transaction `transaction`.
fn block_read(transaction: u16) -> Vec<u8> {
    let mut request = transaction.to_be_bytes().to_vec();
    request.extend(hex::decode("00 00 00 06 01 03 10 00 00 06"));
    request
}

/// Latencies of `count` reads of the dust collector's block on `stream`, one at a time.
async fn timed_reads_on(stream: &mut tokio::net::TcpStream, count: u16) -> Vec<Duration> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut latencies = Vec::new();
    for transaction in 0..count {
        let sent = Instant::now();
        stream.write_all(&block_read(transaction)).await.unwrap();
        let mut answer = [0u8; 21];
        tokio::time::timeout(ANSWER, stream.read_exact(&mut answer))
            .await
            .expect("an answer in time")
            .unwrap();
        latencies.push(sent.elapsed());
        assert_eq!(answer[..2], transaction.to_be_bytes(), "{answer:?}");
        assert_eq!(answer[7..9], [0x03, 12], "{answer:?}");
    }
    latencies
}

/// Asserts that every request after the first on a 9600 8N1 line came after t3.5 of silence.
fn assert_t3_5_kept(records: &[sim::RequestRecord]) {
    let t3_5 = LineTiming::new(
        9600,
        CharFormat {
            data_bits: 8,
            parity: Parity::None,
            stop_bits: 1,
        },
    )
    .t3_5;
    for (i, record) in records.iter().enumerate().skip(1) {
        let silence = record.silence_before.unwrap_or_default();
        assert!(
            silence >= t3_5,
            "request {i} ({}) after {silence:?} of silence (t3.5 is {t3_5:?})",
            hex::encode(&record.frame)
        );
    }
}

fn mean(latencies: &[Duration]) -> Duration {
    latencies.iter().sum::<Duration>() / latencies.len().max(1) as u32
}

fn exception(code: u8) -> Json {
    json!({ "exception": code })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn profile_access_reads_the_devices_and_writes_only_what_the_profile_allows() {
    let mut h = Harness::start("serve-profile", "access = \"profile\"").await;

    // Reads equal the device's registers: the words the device put on the wire for that
    // read (the fan spins up, so the table moves between reads).
    h.base.plant.line_a.journal().clear();
    let answers = h
        .client(json!([
            ["read", DUST, 0x1000, 6],
            ["read", DUST, 0x1001, 1]
        ]))
        .await;
    let answered: Vec<Json> =
        register_answers(&h.base.plant.line_a, &[DUST, 0x03, 0x10, 0x00, 0x00, 0x06]);
    assert!(
        answered.contains(&answers[0]),
        "{answers:?} not in {answered:?}"
    );
    let gear = sim::lock(&h.base.plant.dust_collector).gear();
    assert_eq!(answers[0]["registers"][1], gear, "{answers:?}");
    assert_eq!(answers[1], json!({ "registers": [gear] }), "{answers:?}");

    // A gear write lands on the line byte for byte and on MQTT.
    h.base.plant.line_a.journal().clear();
    let answers = h.client(json!([["write", DUST, 0x1002, 8]])).await;
    assert_eq!(answers, vec![json!({ "written": true })]);
    assert!(
        h.frames().contains(&"01 06 10 02 00 08 2D 0C".to_string()),
        "{:?}",
        h.frames()
    );
    assert_eq!(sim::lock(&h.base.plant.dust_collector).gear(), 8);
    h.base
        .observer
        .wait_for("plant/dust_collector/gear", ANSWER, |m| m.text() == "8")
        .await;
    let result = h
        .base
        .observer
        .next_on("plant/dust_collector/gear/result", ANSWER)
        .await
        .json();
    assert_eq!(result["outcome"], "applied", "{result}");
    assert_eq!(result["value"], "8", "{result}");

    // Gear 11, the read-only fan speed, a read outside the blocks and an unknown unit are
    // refused with no frame on the line.
    h.base.plant.line_a.journal().clear();
    let answers = h
        .client(json!([
            ["write", DUST, 0x1002, 11],
            ["write", DUST, 0x1008, 100],
            ["read", DUST, 0x2000, 1],
            ["read", 5, 0x1000, 6],
        ]))
        .await;
    assert_eq!(
        answers,
        vec![exception(3), exception(2), exception(2), exception(0x0A)]
    );
    let writes: Vec<String> = h
        .frames()
        .into_iter()
        .filter(|frame| !frame.starts_with("01 03") && !frame.starts_with("81 01"))
        .collect();
    assert!(writes.is_empty(), "frames besides polls: {writes:?}");
    assert_eq!(sim::lock(&h.base.plant.dust_collector).gear(), 8);

    // A configured device that does not answer: 0x0B after the timeout and retries.
    h.base.plant.line_a.faults().silence(SHOWER, true);
    let answers = h.client(json!([["coils", SHOWER, 0, 3]])).await;
    assert_eq!(answers, vec![exception(0x0B)]);

    // A statistics document published before the last request counted it: the wait is for
    // one that has every request.
    let stats = h
        .line_stats(|line| line["client_requests"].as_u64().unwrap_or(0) >= 8)
        .await;
    assert_eq!(stats["client_refusals"], 4, "{stats}");
    h.base.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn read_only_access_refuses_every_write_with_exception_01() {
    let h = Harness::start("serve-ro", "access = \"read-only\"").await;
    h.base.plant.line_a.journal().clear();
    let answers = h
        .client(json!([
            ["write", DUST, 0x1002, 8],
            ["read", DUST, 0x1000, 6]
        ]))
        .await;
    assert_eq!(answers[0], exception(1));
    assert!(answers[1]["registers"].is_array(), "{answers:?}");
    assert!(
        h.frames().iter().all(|frame| !frame.starts_with("01 06")),
        "{:?}",
        h.frames()
    );
    h.base.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_clients_and_mqtt_commands_share_the_line_without_a_request_inside_t3_5() {
    let mut h = Harness::start("serve-three", "access = \"profile\"").await;
    let idle = timed_reads(h.port, 20).await;
    h.base.plant.line_a.journal().clear();
    let started = Instant::now();
    let reads = json!(vec![json!(["read", DUST, 0x1000, 6]); 15]);
    let commands = async {
        for gear in [4, 5, 6] {
            h.base
                .observer
                .publish("plant/dust_collector/gear/set", gear.to_string(), false)
                .await;
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    };
    let (first, second, third, busy, ()) = tokio::join!(
        h.client(reads.clone()),
        h.client(reads.clone()),
        h.client(reads.clone()),
        timed_reads(h.port, 20),
        commands
    );
    let elapsed = started.elapsed();
    for answers in [&first, &second, &third] {
        assert_eq!(answers.len(), 15);
        for answer in answers {
            assert_eq!(
                answer["registers"].as_array().map(Vec::len),
                Some(6),
                "{answer}"
            );
        }
    }
    // The last command wins on the device, and polls went on between the clients' reads.
    let deadline = Instant::now() + ANSWER;
    while sim::lock(&h.base.plant.dust_collector).gear() != 6 && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(sim::lock(&h.base.plant.dust_collector).gear(), 6);
    let records = h.base.plant.line_a.journal().requests();
    assert!(
        records.iter().any(|r| r.frame.starts_with(&[SHOWER, 0x01])),
        "the air shower was never polled while the clients read"
    );
    assert_t3_5_kept(&records);
    let stats = h
        .line_stats(|line| line["client_requests"].as_u64().unwrap_or(0) >= 65)
        .await;
    assert_eq!(stats["client_refusals"], 0, "{stats}");
    let wire: Duration = records
        .iter()
        .filter_map(|r| {
            let answered = r.answer_timing?.handed_over;
            Some(answered.saturating_duration_since(r.arrived))
        })
        .sum();
    eprintln!(
        "figure: client read latency idle {:?} (worst {:?}), busy with three clients and MQTT \
         commands {:?} (worst {:?}); {} requests on the line in {elapsed:?}, requests to \
         answers {:.0} % of it",
        mean(&idle),
        idle.iter().max().copied().unwrap_or_default(),
        mean(&busy),
        busy.iter().max().copied().unwrap_or_default(),
        records.len(),
        wire.as_secs_f64() / elapsed.as_secs_f64() * 100.0
    );
    h.base.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_cache_answers_reads_of_a_young_poll_without_the_bus() {
    let mut h = Harness::start("serve-cache", "cache = \"5s\"").await;
    // A first poll of the block is in the cache once the device is online.
    let block = [DUST, 0x03, 0x10, 0x00, 0x00, 0x06];
    let on_line = |h: &Harness| {
        h.base
            .plant
            .line_a
            .journal()
            .frames()
            .iter()
            .filter(|frame| frame.starts_with(&block))
            .count()
    };
    let before = on_line(&h);
    let started = Instant::now();
    let reads = json!(vec![json!(["read", DUST, 0x1000, 6]); 30]);
    let answers = h.client(reads).await;
    let polls_meanwhile = on_line(&h) - before;
    // Every answer is one the device itself gave a poll, word for word.
    let polled: Vec<Json> = register_answers(&h.base.plant.line_a, &block);
    for answer in &answers {
        assert!(polled.contains(answer), "{answer} was never polled");
    }
    // Polls run every 300 ms: whatever reached the line in that time was polls, not the
    // thirty reads.
    let polls_due = started.elapsed().as_millis() / 300 + 2;
    assert!(
        (polls_meanwhile as u128) <= polls_due,
        "{polls_meanwhile} block reads on the line in {:?} for 30 client reads",
        started.elapsed()
    );
    let stats = h
        .line_stats(|line| line["cache_hits"].as_u64().unwrap_or(0) >= 25)
        .await;
    eprintln!(
        "figure: cache {} hits of {} client requests; {polls_meanwhile} block reads on the \
         line meanwhile",
        stats["cache_hits"], stats["client_requests"]
    );
    assert!(
        stats["client_requests"].as_u64().unwrap_or(0) >= 30,
        "{stats}"
    );
    h.base.stop().await;
}

/// The register words of the device's answers on `line` to requests that start with
/// `request`, as a client's read result (`{"registers": [...]}`), in the order given.
fn register_answers(line: &sim::VirtualLine, request: &[u8]) -> Vec<Json> {
    line.journal()
        .requests()
        .iter()
        .filter(|r| r.frame.starts_with(request))
        .filter_map(|r| r.answer.as_ref())
        .filter(|answer| answer.get(1) == Some(&0x03))
        .map(|answer| {
            let count = usize::from(answer[2]);
            let words: Vec<u16> = answer[3..3 + count]
                .chunks(2)
                .map(|pair| u16::from_be_bytes([pair[0], pair[1]]))
                .collect();
            json!({ "registers": words })
        })
        .collect()
}

/// The device's answers on `line` to a poll that starts with `request`, once there is one.
async fn polled_answers(line: &sim::VirtualLine, request: &[u8]) -> Vec<Json> {
    let deadline = Instant::now() + ANSWER;
    loop {
        let answers = register_answers(line, request);
        if !answers.is_empty() {
            return answers;
        }
        assert!(
            Instant::now() < deadline,
            "{} was never polled",
            hex::encode(request)
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_cache_cuts_a_part_from_a_block_the_valve_reads_linearly() {
    const VALVE: u8 = 1;
    let mut h = Harness::start_serving("serve-linear", "cache = \"1h\"", "valve").await;
    // The identity block (0x00–0x0A, every register mapped) is polled whole once at start.
    let identity = [VALVE, 0x03, 0x00, 0x00, 0x00, 0x0B];
    let polled = polled_answers(&h.base.plant.line_b, &identity).await;
    let words = polled[0]["registers"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    assert_eq!(words.len(), 11, "{polled:?}");

    // Two parts of it (serial number; versions and baud code) come from the poll: no frame.
    h.base.plant.line_b.journal().clear();
    let parts = json!([["read", VALVE, 0x01, 7], ["read", VALVE, 0x08, 3]]);
    let cached = h.client(parts.clone()).await;
    assert_eq!(cached[0], json!({ "registers": words[1..8] }), "{cached:?}");
    assert_eq!(
        cached[1],
        json!({ "registers": words[8..11] }),
        "{cached:?}"
    );
    let on_the_line = |h: &Harness| -> Vec<String> {
        h.base
            .plant
            .line_b
            .journal()
            .frames()
            .iter()
            .filter(|frame| frame.starts_with(&[VALVE, 0x03, 0x00]) && frame[3] < 0x0B)
            .filter(|frame| !frame.starts_with(&identity))
            .map(|frame| hex::encode(frame))
            .collect()
    };
    assert!(on_the_line(&h).is_empty(), "{:?}", on_the_line(&h));
    let stats = h
        .line_stats(|line| line["cache_hits"].as_u64().unwrap_or(0) >= 2)
        .await;
    assert_eq!(stats["cache_hits"], 2, "{stats}");

    // A command slot makes the cache forget the valve: the same parts now go to the device,
    // whose answers on the wire are the words the cache gave.
    h.base
        .observer
        .publish("plant/valve/mode/set", "manual".to_string(), false)
        .await;
    h.base
        .observer
        .next_on("plant/valve/mode/result", ANSWER)
        .await;
    h.base.plant.line_b.journal().clear();
    let read = h.client(parts).await;
    assert_eq!(read, cached);
    assert_eq!(
        on_the_line(&h),
        ["01 03 00 01 00 07 55 C8", "01 03 00 08 00 03 84 09"]
    );
    let wire: Vec<Json> = [
        [VALVE, 0x03, 0x00, 0x01, 0x00, 0x07],
        [VALVE, 0x03, 0x00, 0x08, 0x00, 0x03],
    ]
    .iter()
    .flat_map(|request| register_answers(&h.base.plant.line_b, request))
    .collect();
    assert_eq!(wire, cached);
    h.base.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_part_of_the_dust_collectors_block_always_goes_to_the_device() {
    let mut h = Harness::start("serve-offset", "cache = \"1h\"").await;
    let block = [DUST, 0x03, 0x10, 0x00, 0x00, 0x06];
    polled_answers(&h.base.plant.line_a, &block).await;
    h.base.plant.line_a.journal().clear();
    let answers = h
        .client(json!([
            ["read", DUST, 0x1000, 6],
            ["read", DUST, 0x1001, 2]
        ]))
        .await;
    // The whole block from the cache, its part from the device: its frame is on the line
    // and the client got the device's own answer to it.
    let part = [DUST, 0x03, 0x10, 0x01, 0x00, 0x02];
    let from_device = register_answers(&h.base.plant.line_a, &part);
    assert_eq!(from_device, [answers[1].clone()], "{answers:?}");
    let stats = h
        .line_stats(|line| line["client_requests"].as_u64().unwrap_or(0) >= 2)
        .await;
    assert_eq!(stats["cache_hits"], 1, "{stats}");
    h.base.stop().await;
}

/// Reads until the server closes the connection (Ok) or `limit` passes (Err).
async fn closed_within(stream: &mut tokio::net::TcpStream, limit: Duration) -> Result<(), String> {
    use tokio::io::AsyncReadExt;
    let mut buf = [0u8; 64];
    match tokio::time::timeout(limit, stream.read(&mut buf)).await {
        Ok(Ok(0)) | Ok(Err(_)) => Ok(()),
        Ok(Ok(n)) => Err(format!("answered {}", hex::encode(&buf[..n]))),
        Err(_) => Err(format!("still open after {limit:?}")),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_closes_that_client_and_disturbs_no_one_else() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpStream;
    let h = Harness::start("serve-bad", "max_clients = 3").await;
    let address = format!("127.0.0.1:{}", h.port);
    let connect = || TcpStream::connect(address.clone());

    // An unknown function code (65, user-defined): exception 01 for that transaction, the
    // connection stays; a known one without its data (43 with no MEI type): exception 03.
    let mut stream = connect().await.unwrap();
    for (request, expected) in [
        ("00 07 00 00 00 02 01 41", "00 07 00 00 00 03 01 C1 01"),
        ("00 08 00 00 00 02 01 2B", "00 08 00 00 00 03 01 AB 03"),
    ] {
        stream.write_all(&hex::decode(request)).await.unwrap();
        let mut answer = [0u8; 9];
        tokio::time::timeout(ANSWER, stream.read_exact(&mut answer))
            .await
            .expect("an answer")
            .unwrap();
        assert_eq!(hex::encode(&answer), expected);
    }

    // A protocol id that is not Modbus and a length no PDU has: closed at once.
    for header in [
        "00 01 00 05 00 06 01 03 10 00 00 06",
        "00 01 00 00 01 2C 01 03",
    ] {
        let mut stream = connect().await.unwrap();
        stream.write_all(&hex::decode(header)).await.unwrap();
        assert_eq!(
            closed_within(&mut stream, Duration::from_secs(2)).await,
            Ok(()),
            "{header}"
        );
    }
    // A torn header, and a length that promises more than comes: closed after the patience.
    for torn in ["00 01 00", "00 01 00 00 00 0A 01 03 10 00 00 06"] {
        let mut stream = connect().await.unwrap();
        stream.write_all(&hex::decode(torn)).await.unwrap();
        assert_eq!(
            closed_within(&mut stream, Duration::from_secs(5)).await,
            Ok(()),
            "{torn}"
        );
    }

    // More connections than max_clients, every one of which has completed a request: the
    // extra one waits for a place and is closed when none comes free.
    let mut kept: Vec<TcpStream> = vec![connect().await.unwrap(), connect().await.unwrap()];
    for stream in &mut kept {
        timed_reads_on(stream, 1).await;
    }
    let mut extra = connect().await.unwrap();
    assert_eq!(
        closed_within(&mut extra, PLACE_WAIT + Duration::from_secs(2)).await,
        Ok(())
    );
    // An idle connection without a request gives its place to a newcomer after its grace.
    drop(kept.pop());
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut idle = connect().await.unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    let newcomer = h.client(json!([["read", DUST, 0x1000, 6]])).await;
    assert_eq!(newcomer[0]["registers"].as_array().map(Vec::len), Some(6));
    assert_eq!(
        closed_within(&mut idle, Duration::from_secs(2)).await,
        Ok(())
    );
    let _kept = kept;
    drop(_kept);
    drop(stream);
    tokio::time::sleep(Duration::from_millis(200)).await;

    // Nothing of it reached the line, and the next client is served.
    let reads = h.client(json!([["read", DUST, 0x1000, 6]])).await;
    assert_eq!(reads[0]["registers"].as_array().map(Vec::len), Some(6));
    let garbage = h.base.plant.line_a.journal().discarded_bytes();
    assert_eq!(garbage, 0);
    h.base.stop().await;
}

/// Requests the flooding client writes without waiting for an answer.
const FLOOD: u16 = 1000;

/// The answers to `count` Modbus TCP requests on `stream`: (transaction, PDU).
async fn mbap_answers(
    stream: &mut (impl tokio::io::AsyncRead + Unpin),
    count: u16,
) -> Vec<(u16, Vec<u8>)> {
    use tokio::io::AsyncReadExt;
    let mut answers = Vec::new();
    for _ in 0..count {
        let mut header = [0u8; 7];
        tokio::time::timeout(ANSWER, stream.read_exact(&mut header))
            .await
            .expect("an answer in time")
            .unwrap();
        let length = usize::from(u16::from_be_bytes([header[4], header[5]]));
        let mut pdu = vec![0u8; length.saturating_sub(1)];
        tokio::time::timeout(ANSWER, stream.read_exact(&mut pdu))
            .await
            .expect("the rest of an answer in time")
            .unwrap();
        answers.push((u16::from_be_bytes([header[0], header[1]]), pdu));
    }
    answers
}

/// The longest time between two polls of the air shower in `records`.
fn longest_shower_gap(records: &[sim::RequestRecord]) -> Duration {
    let polls: Vec<Instant> = records
        .iter()
        .filter(|r| r.frame.starts_with(&[SHOWER, 0x01]))
        .map(|r| r.arrived)
        .collect();
    polls
        .windows(2)
        .map(|pair| pair[1].saturating_duration_since(pair[0]))
        .max()
        .unwrap_or(Duration::MAX)
}

/// Asserts that a polite client's reads (`latencies`) and the air shower's polls in `records`
/// kept their service beside a bad client, t3.5 kept: the worst read and the longest poll gap.
fn assert_others_kept_their_service(
    latencies: &[Duration],
    records: &[sim::RequestRecord],
) -> (Duration, Duration) {
    let worst = latencies.iter().max().copied().unwrap_or_default();
    assert!(worst < Duration::from_secs(2), "a read took {worst:?}");
    let gap = longest_shower_gap(records);
    assert!(
        gap < Duration::from_secs(2),
        "the air shower went {gap:?} unpolled"
    );
    assert_t3_5_kept(records);
    (worst, gap)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flooding_client_gets_busy_answers_while_others_and_the_polls_keep_their_turns() {
    use tokio::io::AsyncWriteExt;
    let mut h = Harness::start("serve-flood", "cache = \"0s\"").await;
    h.base.plant.line_a.journal().clear();
    let started = Instant::now();
    let flood = async {
        let stream = tokio::net::TcpStream::connect(("127.0.0.1", h.port))
            .await
            .unwrap();
        let (mut reading, mut writing) = stream.into_split();
        let requests: Vec<u8> = (0..FLOOD).flat_map(block_read).collect();
        let write = async { writing.write_all(&requests).await.unwrap() };
        let ((), answers) = tokio::join!(write, mbap_answers(&mut reading, FLOOD));
        answers
    };
    let reads = json!(vec![json!(["read", DUST, 0x1000, 6]); 10]);
    let (flooded, polite, timed) = tokio::join!(flood, h.client(reads), timed_reads(h.port, 20));
    let elapsed = started.elapsed();
    let records = h.base.plant.line_a.journal().requests();

    // Every request of the flood is answered, in order: the device's block or 06 (busy).
    let transactions: Vec<u16> = flooded.iter().map(|(t, _)| *t).collect();
    assert_eq!(transactions, (0..FLOOD).collect::<Vec<_>>());
    let busy = flooded
        .iter()
        .filter(|(_, pdu)| pdu == &[0x83, 0x06])
        .count();
    let read = flooded
        .iter()
        .filter(|(_, pdu)| pdu.len() == 14 && pdu[..2] == [0x03, 12])
        .count();
    assert_eq!(busy + read, usize::from(FLOOD), "{flooded:?}");
    assert!(busy > 0 && read > 0, "{read} read, {busy} busy");

    // The others were served beside it, with bounded latency; the polls kept their cadence.
    assert_eq!(polite.len(), 10);
    for answer in &polite {
        assert_eq!(
            answer["registers"].as_array().map(Vec::len),
            Some(6),
            "{answer}"
        );
    }
    let (worst, gap) = assert_others_kept_their_service(&timed, &records);
    let stats = h
        .line_stats(|line| line["client_busy"].as_u64().unwrap_or(0) >= busy as u64)
        .await;
    eprintln!(
        "figure: flood of {FLOOD} pipelined reads: {read} read on the line, {busy} answered busy \
         (06), in {elapsed:?}; a polite client's read meanwhile {:?} on average (worst \
         {worst:?}); the air shower's longest poll gap {gap:?}; stats {stats}",
        mean(&timed)
    );
    h.base.stop().await;
}

/// Anonymous memory of this process (the gateway runs in it), in KiB.
fn rss_anon_kib() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|line| line.strip_prefix("RssAnon:"))
        .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or(0)
}

/// Writes reads of the dust collector's block on `stream` as fast as it takes them and never
/// reads an answer, until a write fails (the server closed the connection) or `limit`
/// passes: the bytes written and the time until the failure.
async fn write_without_reading(
    stream: &mut tokio::net::TcpStream,
    limit: Duration,
) -> Result<(usize, Duration), String> {
    use tokio::io::AsyncWriteExt;
    // Whole requests, written from where the last write stopped: frames stay whole.
    let requests: Vec<u8> = (0..64).flat_map(block_read).collect();
    let started = Instant::now();
    let mut written = 0usize;
    while started.elapsed() < limit {
        let offset = written % requests.len();
        let write = stream.write(&requests[offset..]);
        match tokio::time::timeout(Duration::from_millis(200), write).await {
            Ok(Ok(0)) | Ok(Err(_)) => return Ok((written, started.elapsed())),
            Ok(Ok(n)) => written += n,
            Err(_) => {}
        }
    }
    Err(format!(
        "still open after {limit:?}, {written} bytes written"
    ))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_never_reads_is_closed_and_its_place_freed_while_others_are_served() {
    use tokio::net::TcpStream;
    let h = Harness::start("serve-deaf", "cache = \"0s\"\nmax_clients = 2").await;
    let memory_before = rss_anon_kib();
    let mut polite = TcpStream::connect(("127.0.0.1", h.port)).await.unwrap();
    polite.set_nodelay(true).unwrap();
    // A small receive buffer: it fills in seconds (a default one takes minutes of answers,
    // and costs the line no more than any client's turn meanwhile).
    let deaf_socket = tokio::net::TcpSocket::new_v4().unwrap();
    deaf_socket.set_recv_buffer_size(4096).unwrap();
    let mut deaf = deaf_socket
        .connect(([127, 0, 0, 1], h.port).into())
        .await
        .unwrap();
    // Both places are taken by clients that have completed a request: a third client
    // waits for a place and is turned away.
    timed_reads_on(&mut polite, 1).await;
    {
        use tokio::io::AsyncWriteExt;
        deaf.write_all(&block_read(0)).await.unwrap();
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    let mut third = TcpStream::connect(("127.0.0.1", h.port)).await.unwrap();
    assert_eq!(
        closed_within(&mut third, PLACE_WAIT + Duration::from_secs(2)).await,
        Ok(())
    );
    h.base.plant.line_a.journal().clear();
    let deafness = async {
        let outcome = write_without_reading(&mut deaf, Duration::from_secs(90)).await;
        (outcome, rss_anon_kib())
    };
    let (((written, closed_after), memory_during), latencies) = {
        let ((outcome, memory), latencies) =
            tokio::join!(deafness, timed_reads_on(&mut polite, 40));
        (
            (outcome.expect("the server closed the deaf client"), memory),
            latencies,
        )
    };
    let records = h.base.plant.line_a.journal().requests();
    let (worst, gap) = assert_others_kept_their_service(&latencies, &records);
    // Its place is free again: a new client is served while the polite one stays connected.
    let reads = h.client(json!([["read", DUST, 0x1000, 6]])).await;
    assert_eq!(reads[0]["registers"].as_array().map(Vec::len), Some(6));
    let grown = memory_during.saturating_sub(memory_before);
    eprintln!(
        "figure: a client that never reads: closed after {closed_after:?} having written \
         {written} bytes; this process's anonymous memory grew {grown} KiB meanwhile; a polite \
         client's read {:?} on average (worst {worst:?}); the air shower's longest poll gap {gap:?}",
        mean(&latencies)
    );
    assert!(
        written < 64 << 20,
        "{written} bytes taken from a client that never reads"
    );
    assert!(grown < 64 << 10, "memory grew {grown} KiB");
    h.base.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtu_over_tcp_with_raw_access_passes_any_unit_to_the_line() {
    use rtu2mqtt_modbus::{codec, Request};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let serve = "listen = \"tcp://127.0.0.1:{port}\"\naccess = \"raw\"";
    let h = Harness::start("serve-rtu", serve).await;
    let mut stream = tokio::net::TcpStream::connect(("127.0.0.1", h.port))
        .await
        .unwrap();
    let block = Request::ReadHoldingRegisters {
        start: 0x1000,
        quantity: 6,
    };

    // The dust collector's block, in RTU frames with their CRC.
    let frame = codec::encode_request(DUST, &block).unwrap();
    stream.write_all(&frame).await.unwrap();
    let mut answer = [0u8; 17];
    tokio::time::timeout(ANSWER, stream.read_exact(&mut answer))
        .await
        .expect("an answer in time")
        .unwrap();
    let decoded = codec::decode_answer(DUST, &block, &answer).expect("a valid RTU answer");
    assert!(
        matches!(decoded, codec::Answer::Normal(ref r) if r.registers().map(<[u16]>::len) == Some(6)),
        "{decoded:?}"
    );

    // A unit not on the line goes to the line as asked, and gets 0x0B when nothing answers.
    h.base.plant.line_a.journal().clear();
    let frame = codec::encode_request(5, &block).unwrap();
    stream.write_all(&frame).await.unwrap();
    let mut answer = [0u8; 5];
    tokio::time::timeout(ANSWER, stream.read_exact(&mut answer))
        .await
        .expect("an answer in time")
        .unwrap();
    assert_eq!(answer[..3], [5, 0x83, 0x0B], "{}", hex::encode(&answer));
    assert!(
        h.base.plant.line_a.journal().frames().contains(&frame),
        "{:?}",
        h.frames()
    );
    h.base.stop().await;
}

/// The broadcast turnaround of line-a in the broadcast tests: long, so that an answer that
/// waited for it cannot pass for one given at once.
const TURNAROUND: Duration = Duration::from_secs(1);

/// line-a served as `serve`, with a broadcast turnaround of [`TURNAROUND`].
async fn broadcast_harness(name: &str, serve: &str) -> Harness {
    Harness::start_edited(name, serve, "dust_collector", false, |text| {
        text.replacen(
            "response_timeout = \"150ms\"\n",
            &format!(
                "response_timeout = \"150ms\"\nbroadcast_turnaround = \"{}ms\"\n",
                TURNAROUND.as_millis()
            ),
            1,
        )
    })
    .await
}

/// How much earlier than the turnaround the next frame may seem to arrive: the simulator
/// stamps a frame when it reads its first byte, a little late at times under load.
const STAMP_SLACK: Duration = Duration::from_millis(20);

/// The frames line-a heard that are `frame` (spaced hex), with when each arrived, and the
/// frame heard next after each.
fn heard(h: &Harness, frame: &str) -> Vec<(Instant, Option<Instant>)> {
    let requests = h.base.plant.line_a.journal().requests();
    requests
        .iter()
        .enumerate()
        .filter(|(_, record)| hex::encode(&record.frame) == frame)
        .map(|(at, record)| {
            (
                record.arrived,
                requests.get(at + 1).map(|next| next.arrived),
            )
        })
        .collect()
}

/// Waits until line-a has heard frames for longer than the turnaround after `since`, so that
/// what a broadcast was followed by is in the journal.
async fn line_went_on(h: &Harness, since: Instant) {
    let deadline = Instant::now() + ANSWER;
    while !h
        .base
        .plant
        .line_a
        .journal()
        .requests()
        .iter()
        .any(|record| record.arrived > since + TURNAROUND + Duration::from_millis(200))
    {
        assert!(
            Instant::now() < deadline,
            "line-a went quiet: {:?}",
            h.frames()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_clients_broadcast_goes_out_once_and_is_answered_at_once() {
    use rtu2mqtt_modbus::tcp::mbap;
    use rtu2mqtt_modbus::{codec, Request, Response};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let h = broadcast_harness("serve-broadcast", "access = \"raw\"").await;
    h.base.plant.line_a.journal().clear();

    // The dust collector's gear (0x1002 in its vendor's FC06 table) set to 9 on every device
    // of the line, over a plain Modbus TCP socket: the line retries unanswered requests once.
    let write = Request::WriteSingleRegister {
        address: 0x1002,
        value: 9,
    };
    let mut stream = tokio::net::TcpStream::connect(("127.0.0.1", h.port))
        .await
        .unwrap();
    let asked = Instant::now();
    stream
        .write_all(&mbap::encode_request(7, 0, &write).unwrap())
        .await
        .unwrap();
    // The MBAP header, then as many bytes as it says follow.
    let mut answer = vec![0u8; 7];
    tokio::time::timeout(ANSWER, stream.read_exact(&mut answer))
        .await
        .expect("an answer in time")
        .unwrap();
    let rest = usize::from(u16::from_be_bytes([answer[4], answer[5]])).saturating_sub(1);
    answer.resize(7 + rest, 0);
    tokio::time::timeout(ANSWER, stream.read_exact(&mut answer[7..]))
        .await
        .expect("the whole answer in time")
        .unwrap();
    let waited = asked.elapsed();
    // The echo, as an answered write gets it, long before the turnaround is over.
    let echo = Response::WriteSingleRegister {
        address: 0x1002,
        value: 9,
    };
    let expected = mbap::rtu_to_adu(7, &codec::encode_answer(0, &echo)).unwrap();
    assert_eq!(hex::encode(&answer), hex::encode(&expected));
    assert!(waited < TURNAROUND / 2, "answered after {waited:?}");
    println!("broadcast answered after {waited:?} (turnaround {TURNAROUND:?})");

    // pymodbus, writing 8 the same way, hears that it was written.
    let answers = h.client(json!([["write", 0, 0x1002, 8]])).await;
    assert_eq!(answers, [json!({"written": true})]);

    // Each went out once, and the line was quiet for the turnaround after each.
    line_went_on(&h, Instant::now()).await;
    for frame in ["00 06 10 02 00 09 ED 1D", "00 06 10 02 00 08 2C DD"] {
        let heard = heard(&h, frame);
        assert_eq!(heard.len(), 1, "{frame} on the wire: {:?}", h.frames());
        let (at, next) = heard[0];
        let next = next.expect("the line went on");
        assert!(
            next - at >= TURNAROUND - STAMP_SLACK,
            "{frame} followed after {:?}",
            next - at
        );
    }
    h.base.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broadcast_over_rtu_over_tcp_goes_out_once_and_gets_no_answer() {
    use rtu2mqtt_modbus::{codec, Request};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let serve = "listen = \"tcp://127.0.0.1:{port}\"\naccess = \"raw\"";
    let h = broadcast_harness("serve-rtu-broadcast", serve).await;
    h.base.plant.line_a.journal().clear();
    let mut stream = tokio::net::TcpStream::connect(("127.0.0.1", h.port))
        .await
        .unwrap();

    // A broadcast and right behind it a read of the dust collector's block, as an RTU master
    // sends them: on the serial line nothing answers the broadcast, so the first bytes back
    // are the read's answer.
    let broadcast = hex::decode("00 06 10 02 00 09 ED 1D");
    let block = Request::ReadHoldingRegisters {
        start: 0x1000,
        quantity: 6,
    };
    stream.write_all(&broadcast).await.unwrap();
    stream
        .write_all(&codec::encode_request(DUST, &block).unwrap())
        .await
        .unwrap();
    let mut answer = [0u8; 17];
    tokio::time::timeout(ANSWER, stream.read_exact(&mut answer))
        .await
        .expect("an answer in time")
        .unwrap();
    let decoded = codec::decode_answer(DUST, &block, &answer);
    assert!(
        matches!(decoded, Ok(codec::Answer::Normal(_))),
        "{}: {decoded:?}",
        hex::encode(&answer)
    );
    line_went_on(&h, Instant::now()).await;
    let heard = heard(&h, "00 06 10 02 00 09 ED 1D");
    assert_eq!(heard.len(), 1, "{:?}", h.frames());
    let (at, next) = heard[0];
    assert!(
        next.is_some_and(|next| next - at >= TURNAROUND - STAMP_SLACK),
        "{:?}",
        h.frames()
    );
    // Nothing more comes on the connection.
    let mut more = [0u8; 1];
    let late = tokio::time::timeout(Duration::from_millis(500), stream.read(&mut more)).await;
    assert!(late.is_err(), "bytes after the read's answer: {more:?}");
    h.base.stop().await;
}

const PIPELINE_CLIENT: &str = "modbus_pipeline_client.py";

impl Harness {
    /// Runs `rounds` rounds of `ops` pipelined by pymodbus's framer on one connection,
    /// `pause` apart; one list of answers per round.
    async fn pipelined(&self, rounds: u32, pause: Duration, ops: Json) -> Vec<Vec<Json>> {
        let args = [rounds.to_string(), pause.as_millis().to_string()];
        self.python(PIPELINE_CLIENT, &args, &ops, Duration::from_secs(120))
            .await
    }
}

/// The frames on `line` that start with `prefix`, with when they arrived at the device.
fn frames_starting(line: &sim::VirtualLine, prefix: &[u8]) -> Vec<(Instant, String)> {
    line.journal()
        .requests()
        .iter()
        .filter(|record| record.frame.starts_with(prefix))
        .map(|record| (record.arrived, hex::encode(&record.frame)))
        .collect()
}

/// The gaps between consecutive frames of `frames`.
fn gaps(frames: &[(Instant, String)]) -> Vec<Duration> {
    frames
        .windows(2)
        .map(|pair| pair[1].0.saturating_duration_since(pair[0].0))
        .collect()
}

/// Counts the answers of `rounds` that are `answer`.
fn count_of(rounds: &[Vec<Json>], answer: &Json) -> usize {
    rounds.iter().flatten().filter(|a| *a == answer).count()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pipelined_gear_writes_keep_the_gear_write_interval_on_the_wire() {
    let mut h = Harness::start("serve-gear-interval", "access = \"profile\"").await;
    h.base.plant.line_a.journal().clear();
    // Eight gear writes at once, every 250 ms for 3.5 s: the gear is written at most once a
    // second (`min_write_interval = "1s"`), every other write is answered 06 at once.
    let writes = json!((3..=10)
        .map(|gear| json!(["write", DUST, 0x1002, gear]))
        .collect::<Vec<_>>());
    let started = Instant::now();
    let rounds = h.pipelined(14, Duration::from_millis(250), writes).await;
    let elapsed = started.elapsed();
    let on_wire = frames_starting(&h.base.plant.line_a, &[DUST, 0x06, 0x10, 0x02]);
    let gaps = gaps(&on_wire);
    eprintln!(
        "figure: 8 pipelined gear writes every 250 ms for {elapsed:?}: {} written, {} answered 06; \
         on the wire {} gear writes, gaps {gaps:?}",
        count_of(&rounds, &json!({ "written": true })),
        count_of(&rounds, &exception(6)),
        on_wire.len(),
    );
    assert_eq!(rounds.len(), 14);
    for answers in &rounds {
        assert_eq!(answers.len(), 8, "{answers:?}");
        let written = answers.iter().filter(|a| a["written"] == true).count();
        assert!(
            written <= 1,
            "more than one gear write in a round: {answers:?}"
        );
        for answer in answers {
            assert!(
                answer["written"] == true || *answer == exception(6),
                "{answers:?}"
            );
        }
    }
    assert_eq!(
        on_wire.len(),
        count_of(&rounds, &json!({ "written": true })),
        "{on_wire:?}"
    );
    assert!(on_wire.len() >= 3, "{on_wire:?}");
    for gap in &gaps {
        assert!(
            *gap >= Duration::from_secs(1),
            "gear writes {gap:?} apart: {on_wire:?}"
        );
    }
    let stats = h
        .line_stats(|line| line["client_busy"].as_u64().unwrap_or(0) >= 100)
        .await;
    assert_eq!(stats["client_refusals"], 0, "{stats}");
    h.base.stop().await;
}

/// The valve's setpoint `value` (whole units) as the two packed-BCD registers a client writes
/// at 0xB2.
fn setpoint_registers(value: u16) -> Json {
    let bcd = value.to_string().chars().fold(0u16, |word, digit| {
        (word << 4) | digit.to_digit(10).unwrap_or(0) as u16
    });
    json!([bcd, 0])
}

const VALVE: u8 = 1;
/// The valve's setpoint writes on the wire: FC06 at 0xB2 (and 0xB3).
const SETPOINT_WRITE: [u8; 4] = [VALVE, 0x06, 0x00, 0xB2];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pipelined_setpoint_writes_keep_the_setpoint_write_interval_on_the_wire() {
    let h =
        Harness::start_serving("serve-setpoint-interval", "access = \"profile\"", "valve").await;
    h.base.plant.line_b.journal().clear();
    // Eight setpoint writes at once, every second for 12 s: the valve's EEPROM setpoint is
    // written at most once in 10 s.
    let writes = json!((0..8)
        .map(|n| json!(["write_registers", VALVE, 0xB2, setpoint_registers(40 + n)]))
        .collect::<Vec<_>>());
    let started = Instant::now();
    let rounds = h.pipelined(13, Duration::from_secs(1), writes).await;
    let elapsed = started.elapsed();
    let on_wire = frames_starting(&h.base.plant.line_b, &SETPOINT_WRITE);
    let gaps = gaps(&on_wire);
    let written = count_of(&rounds, &json!({ "written": true }));
    eprintln!(
        "figure: 8 pipelined setpoint writes every second for {elapsed:?}: {written} written, {} \
         answered 06; on the wire {} setpoint writes (FC06 at 0xB2), gaps {gaps:?}",
        count_of(&rounds, &exception(6)),
        on_wire.len(),
    );
    assert_eq!(written, 2, "{rounds:?}");
    assert_eq!(count_of(&rounds, &exception(6)), 13 * 8 - 2, "{rounds:?}");
    assert_eq!(on_wire.len(), 2, "{on_wire:?}");
    assert!(gaps[0] >= Duration::from_secs(10), "{on_wire:?}");
    // Each write is the setpoint's two registers, nothing more.
    let fractions = frames_starting(&h.base.plant.line_b, &[VALVE, 0x06, 0x00, 0xB3]);
    assert_eq!(fractions.len(), 2, "{fractions:?}");
    h.base.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_write_then_a_command_and_the_reverse_keep_the_write_interval() {
    let mut h =
        Harness::start_serving("serve-mixed-interval", "access = \"profile\"", "valve").await;
    h.base.plant.line_b.journal().clear();
    // A client writes the setpoint; an MQTT command for it a second later waits for the
    // interval, then runs.
    let answers = h
        .client(json!([[
            "write_registers",
            VALVE,
            0xB2,
            setpoint_registers(41)
        ]]))
        .await;
    assert_eq!(answers, vec![json!({ "written": true })]);
    tokio::time::sleep(Duration::from_secs(1)).await;
    h.base
        .observer
        .publish("plant/valve/setpoint/set", "42".to_string(), false)
        .await;
    let result = h
        .base
        .observer
        .wait_for(
            "plant/valve/setpoint/result",
            Duration::from_secs(30),
            |m| m.json()["value"] == "42",
        )
        .await
        .json();
    assert_eq!(result["outcome"], "applied", "{result}");
    let on_wire = frames_starting(&h.base.plant.line_b, &SETPOINT_WRITE);
    assert_eq!(on_wire.len(), 2, "{on_wire:?}");
    let client_then_command = on_wire[1].0 - on_wire[0].0;
    assert!(
        client_then_command >= Duration::from_secs(10),
        "{on_wire:?}"
    );

    // The reverse: a client's write a second after the command's is answered 06 at once,
    // and nothing reaches the valve.
    tokio::time::sleep(Duration::from_secs(1)).await;
    let asked = Instant::now();
    let answers = h
        .client(json!([[
            "write_registers",
            VALVE,
            0xB2,
            setpoint_registers(43)
        ]]))
        .await;
    let answered_in = asked.elapsed();
    assert_eq!(answers, vec![exception(6)]);
    tokio::time::sleep(Duration::from_millis(500)).await;
    let after = frames_starting(&h.base.plant.line_b, &SETPOINT_WRITE);
    assert_eq!(after.len(), 2, "{after:?}");
    // Once the interval is over, the client's write goes through.
    let free_at = on_wire[1].0 + Duration::from_secs(10);
    tokio::time::sleep(
        free_at.saturating_duration_since(Instant::now()) + Duration::from_millis(500),
    )
    .await;
    let answers = h
        .client(json!([[
            "write_registers",
            VALVE,
            0xB2,
            setpoint_registers(43)
        ]]))
        .await;
    assert_eq!(answers, vec![json!({ "written": true })]);
    let last = frames_starting(&h.base.plant.line_b, &SETPOINT_WRITE);
    assert_eq!(last.len(), 3, "{last:?}");
    assert!(last[2].0 - last[1].0 >= Duration::from_secs(10), "{last:?}");
    eprintln!(
        "figure: client write then MQTT command 1 s later: written {client_then_command:?} apart \
         on the wire; a client write 1 s after the command: 06 in {answered_in:?} (pymodbus \
         connection included); the next write {:?} after the command's",
        last[2].0 - last[1].0
    );
    h.base.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_vendors_whole_frames_land_on_the_wire_as_the_vendor_documents_them() {
    let h = Harness::start("serve-vendor-frames", "access = \"profile\"").await;
    h.base.plant.line_a.journal().clear();
    // The air shower: light and buzzer on, the rest 0 (the voice buttons not pressed, the
    // emergency stop left alone).
    let light_and_buzzer = [0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 0, 0];
    let answers = h
        .client(json!([["write_coils", SHOWER, 0, light_and_buzzer]]))
        .await;
    assert_eq!(answers, vec![json!({ "written": true })]);
    let writes: Vec<String> = h
        .frames()
        .into_iter()
        .filter(|frame| frame.starts_with("81 0F"))
        .collect();
    assert_eq!(writes, ["81 0F 00 00 00 0C 02 00 03 C4 77"]);
    let coils = sim::lock(&h.base.plant.air_shower).coils();
    assert!(coils[8] && coils[9], "{coils:?}");
    assert!(!coils[0], "the emergency stop was touched: {coils:?}");

    // The dust collector's FC10 example: power on, pulse cleaning on, gear 5, PV 2, SV 10.
    // The status word's internal bits ("internal use, writing forbidden") are written back as
    // the device holds them: on a device that holds none, the frame is the vendor's.
    sim::lock(&h.base.plant.dust_collector).set_internal_bits(0);
    h.base.plant.line_a.journal().clear();
    let answers = h
        .client(json!([[
            "write_registers",
            DUST,
            0x1000,
            [0x0300, 5, 2, 10]
        ]]))
        .await;
    assert_eq!(answers, vec![json!({ "written": true })]);
    let writes: Vec<String> = h
        .frames()
        .into_iter()
        .filter(|frame| frame.starts_with("01 10") || frame.starts_with("01 06"))
        .collect();
    assert_eq!(
        writes,
        ["01 10 10 00 00 04 08 03 00 00 05 00 02 00 0A 25 38"]
    );
    assert_eq!(sim::lock(&h.base.plant.dust_collector).gear(), 5);
    // The simulator's own internal bits (0x2040) stay as they are.
    sim::lock(&h.base.plant.dust_collector).set_internal_bits(0x2040);
    tokio::time::sleep(Duration::from_secs(2)).await;
    h.base.plant.line_a.journal().clear();
    let answers = h
        .client(json!([[
            "write_registers",
            DUST,
            0x1000,
            [0x0300, 5, 2, 10]
        ]]))
        .await;
    assert_eq!(answers, vec![json!({ "written": true })]);
    let writes: Vec<String> = h
        .frames()
        .into_iter()
        .filter(|frame| frame.starts_with("01 10"))
        .collect();
    assert_eq!(
        writes,
        ["01 10 10 00 00 04 08 23 40 00 05 00 02 00 0A 66 E4"]
    );
    h.base.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn seven_slow_connections_do_not_keep_a_fresh_client_out() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpStream;
    let mut h = Harness::start("serve-slowloris", "max_clients = 8").await;
    // One client that has completed a request keeps its place throughout.
    let mut settled = TcpStream::connect(("127.0.0.1", h.port)).await.unwrap();
    settled.set_nodelay(true).unwrap();
    timed_reads_on(&mut settled, 1).await;

    // Seven connections sending a request one byte a second, reconnecting when closed.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let reconnections = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let slow: Vec<_> = (0..7)
        .map(|_| {
            let (stop, reconnections, port) = (stop.clone(), reconnections.clone(), h.port);
            tokio::spawn(async move {
                use std::sync::atomic::Ordering::Relaxed;
                while !stop.load(Relaxed) {
                    let Ok(mut stream) = TcpStream::connect(("127.0.0.1", port)).await else {
                        tokio::time::sleep(Duration::from_millis(10)).await;
                        continue;
                    };
                    reconnections.fetch_add(1, Relaxed);
                    let request = block_read(7);
                    let mut buf = [0u8; 64];
                    for byte in request.iter().cycle() {
                        if stop.load(Relaxed) {
                            return;
                        }
                        tokio::select! {
                            read = stream.read(&mut buf) => {
                                if matches!(read, Ok(0) | Err(_)) { break; }
                            }
                            () = tokio::time::sleep(Duration::from_secs(1)) => {
                                if stream.write_all(&[*byte]).await.is_err() { break; }
                            }
                        }
                    }
                }
            })
        })
        .collect();
    // Every place is taken now.
    tokio::time::sleep(Duration::from_secs(2)).await;

    // Fresh pymodbus clients, one after another for 20 s: every one is served.
    let mut served = 0;
    let mut waits = Vec::new();
    let until = Instant::now() + Duration::from_secs(20);
    let mut fresh = 0;
    while Instant::now() < until {
        fresh += 1;
        let asked = Instant::now();
        let answers = h.client(json!([["read", DUST, 0x1000, 6]])).await;
        waits.push(asked.elapsed());
        if answers[0]["registers"].as_array().map(Vec::len) == Some(6) {
            served += 1;
        }
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    // The settled client still has its place.
    timed_reads_on(&mut settled, 1).await;
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    for task in slow {
        task.abort();
    }
    let stats = h
        .line_stats(|line| line["client_evicted"].as_u64().unwrap_or(0) >= 1)
        .await;
    eprintln!(
        "figure: max_clients = 8, one settled client and 7 connections sending a byte a second \
         ({} connections in all): {served} of {fresh} fresh pymodbus clients served in 20 s, \
         each in {:?} on average (worst {:?}, connection and wait for a place included); \
         client_evicted {}",
        reconnections.load(std::sync::atomic::Ordering::Relaxed),
        mean(&waits),
        waits.iter().max().copied().unwrap_or_default(),
        stats["client_evicted"]
    );
    assert_eq!(served, fresh);
    assert!(fresh >= 8, "{fresh}");
    h.base.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_write_interval_survives_a_reload_that_restarts_the_line() {
    let h = Harness::start_with(
        "serve-reload-interval",
        "access = \"profile\"",
        "valve",
        true,
    )
    .await;
    h.base.plant.line_b.journal().clear();
    let answers = h
        .client(json!([[
            "write_registers",
            VALVE,
            0xB2,
            setpoint_registers(44)
        ]]))
        .await;
    assert_eq!(answers, vec![json!({ "written": true })]);
    let written = frames_starting(&h.base.plant.line_b, &SETPOINT_WRITE);
    assert_eq!(written.len(), 1, "{written:?}");
    // The file polls every second where the running configuration polled every 300 ms: the
    // reload restarts both lines, and line-b's new task polls at the new cadence.
    let Some((reload, _dir)) = &h.base.reload else {
        panic!("started reloadable")
    };
    reload.send(()).await.unwrap();
    let opening = [VALVE, 0x03, 0x00, 0x74];
    let deadline = Instant::now() + ANSWER;
    loop {
        let polls = frames_starting(&h.base.plant.line_b, &opening);
        let slow = gaps(&polls[polls.len().saturating_sub(3)..])
            .iter()
            .all(|gap| *gap >= Duration::from_millis(900));
        if polls.len() >= 3 && slow {
            break;
        }
        assert!(Instant::now() < deadline, "line-b not restarted: {polls:?}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // The new line task keeps the interval the old one started.
    assert!(written[0].0.elapsed() < Duration::from_secs(9));
    let answers = h
        .client(json!([[
            "write_registers",
            VALVE,
            0xB2,
            setpoint_registers(45)
        ]]))
        .await;
    assert_eq!(answers, vec![exception(6)]);
    assert_eq!(
        frames_starting(&h.base.plant.line_b, &SETPOINT_WRITE).len(),
        1
    );
    h.base.stop().await;
}
