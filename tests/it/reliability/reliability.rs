//! The reliability suite: the whole gateway between the simulated seed plant and a real
//! mosquitto, one fault per test, each test asserting a bound on the figure a plant cares about
//! (time to `offline`, time to recover, wrong values counted on the broker against the
//! simulators' truth, writes counted by the simulators, outcomes counted on the broker) and
//! printing the figure it measured (`figure F…:` lines, shown with `--nocapture`).
//!
//! Faults that other suites already measure end to end (retained commands across restarts,
//! floods, client-id clashes, crashes) are not repeated here; docs/reliability.md maps them.
//! The bounds are generous for a busy 2-core machine: they catch regressions, the printed
//! figure is the measurement.

use crate::support;

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

use rtu2mqtt::bus::stats::LineStats;
use rtu2mqtt_sim::{self as sim, air_shower, Faults, Occurrence, SeedPlant};
use support::{PlantBench, PlantConfig, TestClient};

/// How long any single expected message may take before the test fails.
const ANSWER: Duration = Duration::from_secs(15);
const DUST: u8 = 1;
const SHOWER: u8 = 0x81;

/// Fields whose value the simulators keep still unless a command changes them: any other
/// value published for them under a fault is a wrong value.
const STILL_FIELDS: [&str; 12] = [
    "dust_collector/power",
    "dust_collector/gear",
    "dust_collector/pulse_interval",
    "dust_collector/pulse_duration",
    "dust_collector/fan_alarm",
    "dust_collector/filter_alarm",
    "air_shower/front_door_lock",
    "air_shower/rear_door_lock",
    "air_shower/tunnel_extension",
    "air_shower/buzzer",
    "air_shower/light",
    "air_shower/hepa_filter_expired",
];

/// The plant, a broker, the gateway (retries 1, offline after 2 failed polls, 150 ms response
/// timeout, polled every 300 ms) and an observer subscribed to `plant/#`.
/// The plant bench as `<name>-gw` with `gateway_keys`, one retry and offline after two
/// failures; the air shower's door lock, tunnel extension and filter alarm on, the dust
/// collector running.
async fn start(name: &str, gateway_keys: &str) -> PlantBench {
    on_plant(name, gateway_keys, || {
        SeedPlant::spawn(false).expect("seed plant")
    })
    .await
}

/// Like [`start`] on a plant built by `make_plant`.
async fn on_plant(
    name: &str,
    gateway_keys: &str,
    make_plant: impl FnOnce() -> SeedPlant,
) -> PlantBench {
    PlantBench::setup(name)
        .plant(make_plant)
        .prepare(|plant| {
            let mut shower = sim::lock(&plant.air_shower);
            for coil in [
                air_shower::FRONT_DOOR_LOCK,
                air_shower::TUNNEL_EXTENSION,
                air_shower::HEPA_FILTER_EXPIRED,
            ] {
                shower.set_coil(coil, true);
            }
            drop(shower);
            sim::lock(&plant.dust_collector).set_power(true);
        })
        .config(|broker, plant, client_id| {
            PlantConfig {
                gateway: gateway_keys,
                explicit_serial: true,
                line_keys: "retries = 1\noffline_after = 2",
                ..PlantConfig::default()
            }
            .text(broker, plant, client_id)
        })
        .start()
        .await
}

/// A bench with `faults` on the dust collector's answers (line A), set once the still
/// fields' truth and line A's statistics from before them are taken (both returned with
/// the bench).
async fn with_dust_collector_fault(
    name: &str,
    faults: Faults,
) -> (PlantBench, BTreeMap<String, String>, LineStats) {
    let mut bench = start(name, "").await;
    let truth = bench.still_truth().await;
    let before = bench.line_stats(0);
    bench.plant.line_a.faults().set(Faults {
        target: Some(DUST),
        ..faults
    });
    (bench, truth, before)
}

/// What these tests read from the plant bench beyond what every bench offers.
trait Reliability {
    async fn time_until_availability(&mut self, device: &str, text: &'static str) -> Duration;
    fn line_stats(&self, index: usize) -> LineStats;
    async fn still_truth(&mut self) -> BTreeMap<String, String>;
    fn count_against(&self, truth: &BTreeMap<String, String>) -> (usize, Vec<String>);
}

impl Reliability for PlantBench {
    /// Waits for a change of `device`'s availability to `text` published from now on, and
    /// returns how long it took.
    async fn time_until_availability(&mut self, device: &str, text: &'static str) -> Duration {
        let since = Instant::now();
        self.observer
            .wait_for_new(&format!("plant/{device}/availability"), ANSWER, |m| {
                m.text() == text
            })
            .await;
        since.elapsed()
    }

    /// The statistics of line `index` (0: line-a, 1: line-b) as the gateway counts them.
    fn line_stats(&self, index: usize) -> LineStats {
        let gateway = self.gateway.as_ref().expect("gateway running");
        let stats = gateway.running.lines[index].stats_rx.borrow().clone();
        stats
    }

    /// The value of every still field as published so far (the last one each), after checking
    /// it against the simulators: what the rest of the test holds the broker to.
    async fn still_truth(&mut self) -> BTreeMap<String, String> {
        let (gear, interval, duration) = {
            let dust = sim::lock(&self.plant.dust_collector);
            (dust.gear(), dust.pulse_interval(), dust.pulse_duration())
        };
        let coils = sim::lock(&self.plant.air_shower).coils();
        let on_off = |on: bool| if on { "ON" } else { "OFF" }.to_string();
        let expected: BTreeMap<&str, String> = [
            ("dust_collector/power", "ON".to_string()),
            ("dust_collector/gear", gear.to_string()),
            ("dust_collector/pulse_interval", interval.to_string()),
            ("dust_collector/pulse_duration", duration.to_string()),
            (
                "air_shower/front_door_lock",
                on_off(coils[air_shower::FRONT_DOOR_LOCK]),
            ),
            ("air_shower/light", on_off(coils[air_shower::LIGHT])),
            (
                "air_shower/hepa_filter_expired",
                on_off(coils[air_shower::HEPA_FILTER_EXPIRED]),
            ),
        ]
        .into_iter()
        .collect();
        let mut truth = BTreeMap::new();
        for field in STILL_FIELDS {
            let topic = format!("plant/{field}");
            let message = self.observer.next_on(&topic, ANSWER).await;
            if let Some(value) = expected.get(field) {
                assert_eq!(&message.text(), value, "{topic} at start");
            }
            truth.insert(topic, message.text());
        }
        self.observer.settle(Duration::from_millis(300)).await;
        self.observer.forget();
        truth
    }

    /// Values published on still fields since the last `forget`: (how many, the wrong ones).
    fn count_against(&self, truth: &BTreeMap<String, String>) -> (usize, Vec<String>) {
        let mut seen = 0;
        let mut wrong = Vec::new();
        for message in &self.observer.received {
            if let Some(value) = truth.get(&message.topic) {
                seen += 1;
                if &message.text() != value {
                    wrong.push(format!("{} = {}", message.topic, message.text()));
                }
            }
        }
        (seen, wrong)
    }
}

fn device_stats<'a>(stats: &'a LineStats, name: &str) -> &'a rtu2mqtt::bus::stats::DeviceStats {
    stats
        .devices
        .iter()
        .find(|d| d.name == name)
        .unwrap_or_else(|| panic!("no statistics for {name}"))
}

/// F1: a device that stops answering goes `offline` within offline_after × (retries + 1) ×
/// timeout plus its polls; the other device on its line stays online; it comes back on the
/// first answered probe.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn f1_a_silent_device_goes_offline_and_comes_back_in_bounded_time() {
    let mut bench = start("rel-f1", "").await;
    bench.observer.settle(Duration::from_millis(500)).await;
    bench.observer.forget();
    bench.plant.line_a.faults().silence(DUST, true);
    let offline = bench
        .time_until_availability("dust_collector", "offline")
        .await;
    eprintln!("figure F1: silent device offline after {offline:?}");
    // 2 failed polls × 2 attempts × 150 ms, plus the waits between the device's polls.
    assert!(
        offline < Duration::from_secs(8),
        "offline after {offline:?}"
    );
    tokio::time::sleep(Duration::from_millis(500)).await;
    bench.observer.drain();
    assert!(
        bench
            .observer
            .on("plant/air_shower/availability")
            .iter()
            .all(|m| m.text() == "online"),
        "the air shower on the same line went offline: {:?} {:?}",
        bench.observer.on("plant/air_shower/availability"),
        device_stats(&bench.line_stats(0), "air_shower")
    );

    bench.plant.line_a.faults().silence(DUST, false);
    let online = bench
        .time_until_availability("dust_collector", "online")
        .await;
    eprintln!("figure F1: answering again → online after {online:?}");
    // Probes back off 1 s, 2 s, …: after a short outage the next probe is at most 2 s away.
    assert!(online < Duration::from_secs(8), "online after {online:?}");
    bench.stop().await;
}

/// A plant whose line A is served behind a stable link in `directory`, so that it can be
/// unplugged and replugged under a new pty while the configuration keeps its path.
fn plant_with_linked_line_a(directory: &std::path::Path) -> SeedPlant {
    let plant = SeedPlant::spawn(false).expect("seed plant");
    let line_a = sim::VirtualLine::with_link(
        sim::ServeOptions::new(9600, rtu2mqtt_modbus::timing::Parity::None),
        plant.line_a.devices().to_vec(),
        &directory.join("ttyRS485-A"),
    )
    .expect("linked line A");
    SeedPlant { line_a, ..plant }
}

/// F13/F14: the adapter of line A is unplugged (both pty ends closed): every device on it goes
/// `offline`, line B carries on; replugged under a new pty behind the same link, the port is
/// reopened and the devices come back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn f13_an_unplugged_port_takes_its_devices_offline_and_a_replug_brings_them_back() {
    let directory = tempfile::tempdir().expect("temp dir");
    let mut bench = on_plant("rel-f13", "", || plant_with_linked_line_a(directory.path())).await;
    bench.observer.settle(Duration::from_millis(500)).await;
    bench.observer.forget();

    let unplugged = Instant::now();
    bench.plant.line_a.unplug().await;
    bench.wait_availability("dust_collector", "offline").await;
    bench.wait_availability("air_shower", "offline").await;
    let offline = unplugged.elapsed();
    eprintln!("figure F13: port unplugged → its devices offline after {offline:?}");
    assert!(
        offline < Duration::from_secs(5),
        "offline after {offline:?}"
    );

    // The outage lasts a while: the reopen attempts back off instead of spinning.
    let failures_then = bench.line_stats(0).port_failures;
    tokio::time::sleep(Duration::from_secs(3)).await;
    let attempts = bench.line_stats(0).port_failures - failures_then;
    eprintln!("figure F13: {attempts} reopen attempts in 3 s of outage");
    assert!(attempts <= 8, "{attempts} reopen attempts in 3 s");
    bench.observer.drain();
    assert!(
        bench
            .observer
            .on("plant/valve/availability")
            .iter()
            .all(|m| m.text() == "online"),
        "the valve on the other line went offline"
    );

    bench.observer.forget();
    bench.plant.line_a.replug().await.expect("replug");
    let replugged = Instant::now();
    bench.wait_availability("dust_collector", "online").await;
    bench.wait_availability("air_shower", "online").await;
    let online = replugged.elapsed();
    eprintln!("figure F14: replugged under a new pty → devices online after {online:?}");
    // Reopen back-off at most 3 s, then one poll.
    assert!(online < Duration::from_secs(8), "online after {online:?}");
    bench.stop().await;
}

/// The valve's `measured_1` registers (integer and fraction, packed BCD, read every cycle): the
/// test changes them while faults run, so that values keep being published and each can be
/// checked.
const VALVE_MEASURED_1: u16 = sim::valve::REG_MEASURED_1;
const VALVE_MEASURED_1_FRACTION: u16 = sim::valve::REG_MEASURED_1 + 1;
const MEASURED_TOPIC: &str = "plant/valve/measured_1";

/// Sets the valve's first measured value to 100, 101, 102 … every `every` until `stop`
/// fires; returns every value it set.
fn keep_changing_the_measured_value(
    plant: &SeedPlant,
    every: Duration,
) -> (
    tokio::sync::oneshot::Sender<()>,
    tokio::task::JoinHandle<BTreeSet<u32>>,
) {
    let valve = plant.valve.clone();
    // The simulator lets measured values drift on their own; the test owns them here.
    sim::lock(&valve).set_drift(false);
    let (stop_tx, mut stop_rx) = tokio::sync::oneshot::channel();
    let task = tokio::spawn(async move {
        let mut set = BTreeSet::new();
        let mut value = 100;
        loop {
            if let Some(raw) = rtu2mqtt_profile::bcd::encode(value, 4) {
                let mut valve = sim::lock(&valve);
                if valve.set_register(VALVE_MEASURED_1_FRACTION, 0)
                    && valve.set_register(VALVE_MEASURED_1, raw)
                {
                    set.insert(u32::from(value));
                }
            }
            value += 1;
            tokio::select! {
                _ = &mut stop_rx => return set,
                () = tokio::time::sleep(every) => {}
            }
        }
    });
    (stop_tx, task)
}

/// F3/F4/F5: answers with flipped CRC bits, cut short or preceded by garbage, at a rate of
/// 10 % each on both lines, and garbage on the idle line: the faults are counted and retried,
/// and no value published on the broker differs from the simulators' truth (still fields, and
/// a valve value the test keeps changing).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn f3_f4_f5_broken_answers_never_publish_a_wrong_value() {
    let mut bench = start("rel-f3", "").await;
    let truth = bench.still_truth().await;
    let before = [bench.line_stats(0), bench.line_stats(1)];
    let faults = Faults {
        corrupt_crc: Occurrence::probability(0.1),
        truncate: Occurrence::probability(0.1),
        truncate_bytes: 2,
        garbage_before: Occurrence::probability(0.1),
        garbage_bytes: 4,
        idle_garbage_every: Some(Duration::from_millis(700)),
        ..Faults::default()
    };
    let (stop, changer) =
        keep_changing_the_measured_value(&bench.plant, Duration::from_millis(400));
    bench.plant.line_a.faults().set(faults.clone());
    bench.plant.line_b.faults().set(faults);
    tokio::time::sleep(Duration::from_secs(10)).await;
    bench.plant.line_a.faults().clear();
    bench.plant.line_b.faults().clear();
    let _ = stop.send(());
    let measured = changer.await.expect("measured value changer");
    bench.observer.settle(Duration::from_millis(500)).await;

    let after = [bench.line_stats(0), bench.line_stats(1)];
    let (still_seen, mut wrong) = bench.count_against(&truth);
    let measured_values: Vec<String> = bench
        .observer
        .on(MEASURED_TOPIC)
        .iter()
        .map(|m| m.text())
        .collect();
    for text in &measured_values {
        let right = text
            .parse::<f64>()
            .is_ok_and(|v| v.fract() == 0.0 && measured.contains(&(v as u32)));
        if !right {
            wrong.push(format!("{MEASURED_TOPIC} = {text}"));
        }
    }
    let delta = |count: fn(&LineStats) -> u64| -> u64 {
        (0..2).map(|i| count(&after[i]) - count(&before[i])).sum()
    };
    let polls_ok: u64 = ["dust_collector", "air_shower"]
        .iter()
        .map(|d| device_stats(&after[0], d).polls_ok - device_stats(&before[0], d).polls_ok)
        .sum::<u64>()
        + (device_stats(&after[1], "valve").polls_ok - device_stats(&before[1], "valve").polls_ok);
    let crc = delta(|s| s.crc_errors);
    let truncated = delta(|s| s.truncated);
    let stray = delta(|s| s.stray_bytes);
    let transactions = delta(|s| s.transactions);
    let seen = still_seen + measured_values.len();
    eprintln!(
        "figure F3-F5: {transactions} transactions, {polls_ok} good polls, {crc} CRC errors, \
         {truncated} truncated, {stray} stray bytes; {seen} values published ({} of a \
         changing one), {} wrong",
        measured_values.len(),
        wrong.len()
    );
    assert!(wrong.is_empty(), "wrong values published: {wrong:?}");
    assert!(
        measured_values.len() >= 5,
        "only {} changing values published: {measured_values:?}",
        measured_values.len()
    );
    assert!(
        crc > 0 && truncated + stray > 0,
        "faults not counted: crc {crc}, truncated {truncated}, stray {stray}"
    );
    assert!(polls_ok >= 20, "only {polls_ok} good polls in 10 s");
    bench.stop().await;
}

/// F6: the dust collector's answers come back (half of them) under the air shower's address
/// on the same line: they are ignored and counted, nothing is stored under the air shower,
/// and no wrong value reaches the broker.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn f6_a_rogue_answer_from_another_address_is_never_stored() {
    let (mut bench, truth, before) = with_dust_collector_fault(
        "rel-f6",
        Faults {
            wrong_address: Occurrence::probability(0.5),
            wrong_address_value: SHOWER,
            ..Faults::default()
        },
    )
    .await;
    tokio::time::sleep(Duration::from_secs(8)).await;
    bench.plant.line_a.faults().clear();
    bench.observer.settle(Duration::from_millis(500)).await;

    let after = bench.line_stats(0);
    let (seen, wrong) = bench.count_against(&truth);
    let rogue = after.wrong_address - before.wrong_address;
    let dust_polls = device_stats(&after, "dust_collector").polls_ok
        - device_stats(&before, "dust_collector").polls_ok;
    let unexpected = after.unexpected_answers - before.unexpected_answers;
    eprintln!(
        "figure F6: {rogue} answers from the wrong address ({unexpected} unexpected answers), \
         {dust_polls} good polls of the device meanwhile; {seen} values published on still \
         fields, {} wrong",
        wrong.len()
    );
    assert!(wrong.is_empty(), "wrong values published: {wrong:?}");
    assert!(
        rogue + unexpected > 0,
        "no rogue answer counted: wrong address {rogue}, unexpected {unexpected}"
    );
    bench.stop().await;
}

/// F2: every dust collector answer arrives 1.3 × the response timeout late. A late answer is
/// never taken for the next request's answer (not even the retry of the same request), so the
/// device goes `offline` rather than being fed stale bytes; the air shower on the same line
/// keeps its values right; on time again, the device is back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn f2_a_late_answer_is_never_taken_for_the_next_one() {
    let (mut bench, truth, before) = with_dust_collector_fault(
        "rel-f2",
        Faults {
            delay: Duration::from_millis(150).mul_f64(1.3),
            ..Faults::default()
        },
    )
    .await;
    let offline = bench
        .time_until_availability("dust_collector", "offline")
        .await;
    tokio::time::sleep(Duration::from_secs(2)).await;
    bench.plant.line_a.faults().clear();
    let online = bench
        .time_until_availability("dust_collector", "online")
        .await;
    bench.observer.settle(Duration::from_millis(500)).await;

    let after = bench.line_stats(0);
    let late = after.late_answers - before.late_answers;
    let (seen, wrong) = bench.count_against(&truth);
    eprintln!(
        "figure F2: answers 1.3× late → offline after {offline:?}, {late} late answers \
         counted, {seen} values published on still fields, {} wrong; on time again → online \
         after {online:?}",
        wrong.len()
    );
    assert!(wrong.is_empty(), "wrong values published: {wrong:?}");
    assert!(late > 0, "no late answer counted");
    assert!(
        offline < Duration::from_secs(8),
        "offline after {offline:?}"
    );
    assert!(online < Duration::from_secs(8), "online after {online:?}");
    assert!(
        bench
            .observer
            .on("plant/air_shower/availability")
            .iter()
            .all(|m| m.text() == "online"),
        "the air shower went offline"
    );
    bench.stop().await;
}

/// F17/F18: the broker is killed (no persistence: everything retained is lost) and started
/// again. The gateway reconnects, subscribes again and republishes status, availability and
/// state; a retained command published on the new broker while the gateway is still away is
/// applied once it is back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn f17_a_restarted_broker_gets_the_state_back_and_a_waiting_command_runs() {
    let mut bench = start("rel-f17", "").await;
    let truth = bench.still_truth().await;
    let gear_before = sim::lock(&bench.plant.dust_collector).gear();
    let gear_wanted = if gear_before == 6 { 7 } else { 6 };
    bench.broker.kill();
    tokio::time::sleep(Duration::from_secs(2)).await;
    bench.broker.restart();
    let back = Instant::now();

    let mut fresh = TestClient::connect(bench.broker.port, "rel-f17-fresh").await;
    fresh
        .publish(
            "plant/dust_collector/gear/set",
            gear_wanted.to_string(),
            true,
        )
        .await;
    fresh.subscribe("plant/#").await;
    fresh
        .wait_for(
            &format!("plant/gateway/{}/status", bench.client_id),
            ANSWER,
            |m| m.text() == "online",
        )
        .await;
    for device in ["dust_collector", "air_shower", "valve"] {
        fresh
            .wait_for(&format!("plant/{device}/availability"), ANSWER, |m| {
                m.text() == "online"
            })
            .await;
    }
    let status_back = back.elapsed();
    for (topic, value) in &truth {
        if topic.ends_with("/gear") {
            continue;
        }
        let value = value.clone();
        fresh
            .wait_for(topic, ANSWER, move |m| m.text() == value)
            .await;
    }
    let state_back = back.elapsed();
    let result = fresh
        .next_on("plant/dust_collector/gear/result", ANSWER)
        .await
        .json();
    let applied = back.elapsed();
    assert_eq!(result["outcome"], "applied", "{result}");
    fresh
        .wait_for("plant/dust_collector/gear/set", ANSWER, |m| {
            m.payload.is_empty()
        })
        .await;
    eprintln!(
        "figure F17: after the broker restart, status and availability back in \
         {status_back:?}, every state value in {state_back:?}, the waiting retained command \
         applied in {applied:?}"
    );
    assert_eq!(sim::lock(&bench.plant.dust_collector).gear(), gear_wanted);
    let writes = bench.plant.line_a.journal().writes_to(DUST);
    assert_eq!(writes, 1, "{writes} writes for one retained command");
    assert!(
        applied < Duration::from_secs(10),
        "applied after {applied:?}"
    );
    bench.stop().await;
}

/// F17 with commands in flight: commands wait for a silent device while the broker is killed
/// and started again; each one gets exactly one outcome (the older ones per field
/// `superseded`, the newest `applied` once the device answers), and only the newest per field
/// is written.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn f17_every_command_gets_exactly_one_outcome_across_a_broker_restart() {
    let mut bench = start("rel-f17-outcomes", "command_ttl = \"60s\"").await;
    bench.observer.settle(Duration::from_millis(300)).await;
    bench.plant.line_a.faults().silence(DUST, true);
    bench
        .time_until_availability("dust_collector", "offline")
        .await;
    bench.plant.line_a.journal().clear();

    let commands: Vec<(&str, Vec<String>)> = vec![
        ("gear", ["4", "5", "6"].map(String::from).to_vec()),
        (
            "pulse_interval",
            ["11", "12", "13"].map(String::from).to_vec(),
        ),
        (
            "pulse_duration",
            ["21", "22", "23"].map(String::from).to_vec(),
        ),
    ];
    for (field, values) in &commands {
        for value in values {
            bench
                .observer
                .publish(
                    &format!("plant/dust_collector/{field}/set"),
                    value.clone(),
                    false,
                )
                .await;
        }
    }
    let mut outcomes: BTreeMap<(String, String), Vec<String>> = BTreeMap::new();
    let superseded_expected: usize = commands.iter().map(|(_, v)| v.len() - 1).sum();
    let deadline = Instant::now() + ANSWER;
    let collect = |bench: &mut PlantBench, outcomes: &mut BTreeMap<_, Vec<String>>| {
        bench.observer.drain();
        for message in std::mem::take(&mut bench.observer.received) {
            let Some(field) = message
                .topic
                .strip_prefix("plant/dust_collector/")
                .and_then(|rest| rest.strip_suffix("/result"))
            else {
                continue;
            };
            let result = message.json();
            let value = result["value"].as_str().unwrap_or("").to_string();
            let outcome = result["outcome"].as_str().unwrap_or("").to_string();
            outcomes
                .entry((field.to_string(), value))
                .or_default()
                .push(outcome);
        }
    };
    // The superseded ones are reported while the broker is still up.
    while outcomes.values().map(Vec::len).sum::<usize>() < superseded_expected {
        assert!(Instant::now() < deadline, "outcomes so far: {outcomes:?}");
        bench.observer.settle(Duration::from_millis(100)).await;
        collect(&mut bench, &mut outcomes);
    }

    bench.broker.kill();
    tokio::time::sleep(Duration::from_secs(1)).await;
    bench.broker.restart();
    let back = Instant::now();
    let mut fresh = TestClient::connect(bench.broker.port, "rel-f17-outcomes-fresh").await;
    fresh.subscribe("plant/#").await;
    fresh
        .wait_for(
            &format!("plant/gateway/{}/status", bench.client_id),
            ANSWER,
            |m| m.text() == "online",
        )
        .await;
    bench.observer = fresh;
    bench.plant.line_a.faults().silence(DUST, false);

    let total: usize = commands.iter().map(|(_, v)| v.len()).sum();
    let deadline = Instant::now() + ANSWER;
    while outcomes.values().map(Vec::len).sum::<usize>() < total && Instant::now() < deadline {
        bench.observer.settle(Duration::from_millis(100)).await;
        collect(&mut bench, &mut outcomes);
    }
    let all_done = back.elapsed();
    // Anything more arriving late would be a second outcome.
    bench.observer.settle(Duration::from_secs(1)).await;
    collect(&mut bench, &mut outcomes);

    let applied: BTreeSet<(String, String)> = commands
        .iter()
        .map(|(field, values)| (field.to_string(), values[values.len() - 1].clone()))
        .collect();
    for (field, values) in &commands {
        for value in values {
            let key = (field.to_string(), value.clone());
            let expected = if applied.contains(&key) {
                "applied"
            } else {
                "superseded"
            };
            assert_eq!(
                outcomes.get(&key).map(Vec::as_slice),
                Some([expected.to_string()].as_slice()),
                "{field} = {value}: outcomes {outcomes:?}"
            );
        }
    }
    assert_eq!(
        outcomes.len(),
        total,
        "outcomes for unknown commands: {outcomes:?}"
    );
    let writes = bench.plant.line_a.journal().writes_to(DUST);
    eprintln!(
        "figure F17: {total} commands across a broker restart → {} outcomes (one each), \
         {writes} writes on the device, all done {all_done:?} after the restart",
        outcomes.values().map(Vec::len).sum::<usize>()
    );
    // One write per field at most (the profile's settings frame may carry several fields).
    assert!(
        (1..=commands.len() as u32).contains(&writes),
        "{writes} writes"
    );
    let settings = {
        let dust = sim::lock(&bench.plant.dust_collector);
        (dust.gear(), dust.pulse_interval(), dust.pulse_duration())
    };
    assert_eq!(settings, (6, 13, 23));
    bench.stop().await;
}
