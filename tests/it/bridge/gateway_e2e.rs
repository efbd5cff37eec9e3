//! End to end: the gateway (`run_gateway`) between the simulated seed plant on pty lines and a
//! real mosquitto, driven by a real MQTT client exactly as a user would with mosquitto_pub and
//! mosquitto_sub. Frames are checked byte for byte in the simulators' journals.

use crate::support;

use std::time::Duration;

use rtu2mqtt::config::Config;
use rtu2mqtt_sim::{self as sim, SeedPlant};
use support::hex::{self, writes};
use support::{Gateway, Mosquitto, PlantBench, PlantConfig, TestClient};

/// Generous bounds for a busy 2-core machine: they only fail when something is broken.
const ANSWER: Duration = Duration::from_secs(15);
const DUST: u8 = 1;
const SHOWER: u8 = 0x81;
const VALVE: u8 = 1;

/// Air shower coils (docs/devices.md §3).
const COIL_EMERGENCY_STOP: usize = 0;
const COIL_BREEZE: usize = 4;

fn plant_config(broker: &Mosquitto, plant: &SeedPlant, client_id: &str, extra: &str) -> String {
    PlantConfig {
        gateway: &format!("stats_interval = \"1s\"\n{extra}"),
        explicit_serial: true,
        line_keys: "retries = 1\noffline_after = 2",
        dust_collector_keys: "poll_interval = \"1s\"",
        ..PlantConfig::default()
    }
    .text(broker, plant, client_id)
}

/// Validated as a user's file would be, then polled faster than the profiles' minimums so the
/// suite stays short (the simulators do not mind).
fn fast(text: &str) -> Config {
    support::fast_config(text)
}

/// The plant, a broker, the gateway and an observer of `plant/#`; `extra`: more `[gateway]`
/// keys; `prepare` sets the simulated devices up before the gateway starts.
async fn start_with(name: &str, extra: &str, prepare: impl FnOnce(&SeedPlant)) -> PlantBench {
    let extra = extra.to_string();
    PlantBench::setup(name)
        .prepare(prepare)
        .config(move |broker, plant, client_id| plant_config(broker, plant, client_id, &extra))
        .start()
        .await
}

async fn start(name: &str) -> PlantBench {
    start_with(name, "", |_| {}).await
}

fn frames(line: &sim::VirtualLine) -> Vec<Vec<u8>> {
    line.journal().frames()
}

fn assert_sent(frames: &[Vec<u8>], golden: &str) {
    let seen: Vec<String> = frames.iter().map(|f| hex::encode(f)).collect();
    assert!(
        seen.iter().any(|f| f == golden),
        "frame {golden} not sent; sent: {seen:#?}"
    );
}

fn outcome(result: &serde_json::Value) -> &str {
    result["outcome"].as_str().unwrap_or("")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_field_of_the_seed_devices_is_published_with_its_value() {
    let mut h = start_with("fields", "json_view = true", |plant| {
        let mut dust = sim::lock(&plant.dust_collector);
        dust.set_power(true);
        drop(dust);
        sim::lock(&plant.air_shower).set_coil(8, true);
        sim::lock(&plant.valve).set_opening(40);
    })
    .await;
    // A late subscriber sees the retained state of every field of every device.
    h.observer.settle(Duration::from_secs(2)).await;
    let mut late = TestClient::connect(h.broker.port, "fields-late").await;
    late.subscribe("plant/+/+").await;
    late.settle(Duration::from_secs(2)).await;
    let config = fast(&plant_config(&h.broker, &h.plant, "x", ""));
    for line in &config.lines {
        for device in &line.devices {
            for field in device.profile.fields() {
                let topic = format!("plant/{}/{}", device.name, field.name);
                let messages = late.on(&topic);
                // Fields whose raw data cannot be valid in the simulator would be absent; the
                // seed simulators produce valid data for all of them.
                assert!(!messages.is_empty(), "{topic} not published");
                // The first copy comes from the broker's retained store; later live updates of
                // a changing value (fan speed) arrive without the flag.
                assert!(messages[0].retain, "{topic} not retained");
            }
        }
    }
    let value = |topic: &str| late.on(topic).last().map(|m| m.text()).unwrap_or_default();
    let (gear, interval, duration) = {
        let dust = sim::lock(&h.plant.dust_collector);
        (dust.gear(), dust.pulse_interval(), dust.pulse_duration())
    };
    assert_eq!(value("plant/dust_collector/power"), "ON");
    assert_eq!(value("plant/dust_collector/pulse_cleaning"), "OFF");
    assert_eq!(value("plant/dust_collector/gear"), gear.to_string());
    assert_eq!(
        value("plant/dust_collector/pulse_interval"),
        interval.to_string()
    );
    assert_eq!(
        value("plant/dust_collector/pulse_duration"),
        duration.to_string()
    );
    assert_eq!(value("plant/dust_collector/fan_alarm"), "OFF");
    let coils = sim::lock(&h.plant.air_shower).coils();
    let on_off = |on: bool| if on { "ON" } else { "OFF" };
    for (coil, field) in [
        (0, "emergency_stop"),
        (1, "front_door_lock"),
        (2, "rear_door_lock"),
        (3, "strong_wind"),
        (4, "breeze"),
        (8, "light"),
        (9, "buzzer"),
        (16, "front_door_closed"),
        (17, "rear_door_closed"),
    ] {
        assert_eq!(
            value(&format!("plant/air_shower/{field}")),
            on_off(coils[coil]),
            "{field}"
        );
    }
    assert_eq!(value("plant/air_shower/light"), "ON");
    let opening = sim::lock(&h.plant.valve).opening();
    assert_eq!(value("plant/valve/opening"), opening.to_string());
    assert_eq!(value("plant/valve/mode"), "manual");
    // The JSON view: every value of a device in one retained object, typed.
    let view = h
        .observer
        .wait_for("plant/valve", ANSWER, |m| {
            // Early views hold the blocks read so far; wait for the live block too.
            m.json()["opening"].is_number() && m.json()["jammed"].is_boolean()
        })
        .await;
    let view = view.json();
    assert_eq!(view["opening"], u64::from(opening), "{view}");
    assert_eq!(view["mode"], "manual", "{view}");
    assert_eq!(view["jammed"], false, "{view}");
    // The gateway itself: its readiness hook shows both lines and a live, connected bridge.
    let running = &h.gateway.as_ref().unwrap().running;
    assert_eq!(running.lines.len(), 2);
    assert!(*running.bridge.connected.borrow());
    assert!(running.bridge.heartbeat.borrow().elapsed() < Duration::from_secs(5));
    h.wait_text(&format!("plant/gateway/{}/status", h.client_id), "online")
        .await;
    // Statistics go out every second, a summary and one document per line; a later line
    // document counts the polls.
    let stats_topic = format!("plant/gateway/{}/stats", h.client_id);
    h.observer
        .wait_for(&format!("{stats_topic}/line-a"), ANSWER, |m| {
            m.json()["transactions"].as_u64().unwrap_or(0) > 0
        })
        .await;
    let stats = h.observer.next_on(&stats_topic, ANSWER).await.json();
    assert_eq!(stats["devices_total"], 3, "{stats}");
    assert_eq!(stats["lines_total"], 2, "{stats}");
    let line_b = h
        .observer
        .next_on(&format!("{stats_topic}/line-b"), ANSWER)
        .await
        .json();
    assert!(line_b["devices"]["valve"].is_object(), "{line_b}");
    h.stop_gateway().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gear_8_goes_out_as_the_golden_frame_and_is_applied() {
    let dir = tempfile::tempdir().unwrap();
    let frame_log = dir.path().join("frames.log");
    let extra = format!("frame_log = \"{}\"", frame_log.display());
    let mut h = start_with("gear8", &extra, |plant| {
        sim::lock(&plant.dust_collector).set_power(true);
    })
    .await;
    h.wait_text("plant/dust_collector/power", "ON").await;
    let result = h.command("dust_collector", "gear", b"8").await;
    assert_eq!(result["outcome"], "applied", "{result}");
    assert_eq!(result["value"], "8");
    assert_sent(&frames(&h.plant.line_a), "01 06 10 02 00 08 2D 0C");
    assert_eq!(sim::lock(&h.plant.dust_collector).gear(), 8);
    h.wait_text("plant/dust_collector/gear", "8").await;
    h.stop_gateway().await;
    // The frame log holds the write with its line, timestamp and direction.
    let log = std::fs::read_to_string(&frame_log).unwrap();
    assert!(
        log.lines()
            .any(|record| record.starts_with("line-a ") && record.ends_with(" tx 0106100200082D0C")),
        "{log}"
    );
    assert!(log.lines().any(|record| record.starts_with("line-b ")));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gear_3_in_standby_is_not_applied() {
    let mut h = start_with("standby", "", |plant| {
        let mut dust = sim::lock(&plant.dust_collector);
        dust.set_power(false);
    })
    .await;
    h.wait_text("plant/dust_collector/power", "OFF").await;
    // The simulator starts at gear 3: ask for another gear so the read-back can differ.
    let result = h.command("dust_collector", "gear", b"5").await;
    assert_eq!(result["outcome"], "not_applied", "{result}");
    assert!(!result["detail"].as_str().unwrap_or("").is_empty());
    assert!(!writes(&frames(&h.plant.line_a), DUST).is_empty());
    assert_eq!(sim::lock(&h.plant.dust_collector).gear(), 3);
    h.stop_gateway().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn air_shower_commands_respect_the_coil_rules() {
    let mut h = start("shower").await;
    h.wait_text("plant/air_shower/light", "OFF").await;

    // Light ON with all coils off: the document's frame.
    let result = h.command("air_shower", "light", b"ON").await;
    assert_eq!(result["outcome"], "applied", "{result}");
    assert_sent(&frames(&h.plant.line_a), "81 0F 00 00 00 0C 02 00 01 45 B6");

    // Strong wind while breeze is on: rejected, nothing written.
    sim::lock(&h.plant.air_shower).set_coil(COIL_BREEZE, true);
    h.wait_text("plant/air_shower/breeze", "ON").await;
    h.plant.line_a.journal().clear();
    let result = h.command("air_shower", "strong_wind", b"ON").await;
    assert_eq!(result["outcome"], "rejected", "{result}");
    assert!(
        result["detail"].as_str().unwrap_or("").contains("breeze"),
        "{result}"
    );
    assert_eq!(
        writes(&frames(&h.plant.line_a), SHOWER),
        Vec::<String>::new()
    );
    sim::lock(&h.plant.air_shower).set_coil(COIL_BREEZE, false);
    h.wait_text("plant/air_shower/breeze", "OFF").await;

    // An active emergency stop survives switching the light.
    sim::lock(&h.plant.air_shower).set_emergency_stop(true);
    h.wait_text("plant/air_shower/emergency_stop", "ON").await;
    let result = h.command("air_shower", "light", b"OFF").await;
    assert_eq!(result["outcome"], "applied", "{result}");
    assert!(sim::lock(&h.plant.air_shower).emergency_stop());
    let coils = sim::lock(&h.plant.air_shower).coils();
    assert!(coils[COIL_EMERGENCY_STOP]);
    h.stop_gateway().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn valve_setpoint_lands_as_packed_bcd() {
    let mut h = start("valve").await;
    let result = h.command("valve", "setpoint", b"45.67").await;
    assert_eq!(result["outcome"], "applied", "{result}");
    let (integer, fraction) = {
        let valve = sim::lock(&h.plant.valve);
        (valve.register(0xB2), valve.register(0xB3))
    };
    assert_eq!(integer, Some(0x0045));
    assert_eq!(fraction, Some(0x0067));
    h.wait_text("plant/valve/setpoint", "45.67").await;
    h.stop_gateway().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_retained_command_runs_once_is_cleared_and_is_not_replayed() {
    let mut h = start_with("retained", "", |plant| {
        sim::lock(&plant.dust_collector).set_power(true);
    })
    .await;
    h.wait_text("plant/dust_collector/power", "ON").await;
    h.observer
        .publish("plant/dust_collector/gear/set", b"7".to_vec(), true)
        .await;
    let result = h.result("dust_collector", "gear").await;
    assert_eq!(outcome(&result), "applied", "{result}");
    // The gateway clears it: an empty retained message on the same topic.
    h.observer
        .wait_for("plant/dust_collector/gear/set", ANSWER, |m| {
            m.payload.is_empty()
        })
        .await;
    let mut late = TestClient::connect(h.broker.port, "retained-late").await;
    late.subscribe("plant/dust_collector/gear/set").await;
    late.settle(Duration::from_secs(1)).await;
    assert!(late.on("plant/dust_collector/gear/set").is_empty());

    // A restart writes nothing.
    h.stop_gateway().await;
    h.plant.line_a.journal().clear();
    h.start_gateway().await;
    h.wait_new_text("plant/dust_collector/availability", "online")
        .await;
    h.observer.settle(Duration::from_secs(2)).await;
    assert_eq!(writes(&frames(&h.plant.line_a), DUST), Vec::<String>::new());
    assert!(h.observer.on("plant/dust_collector/gear/result").is_empty());
    h.stop_gateway().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_retained_command_waiting_at_start_runs_exactly_once() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap();
    sim::lock(&plant.dust_collector).set_power(true);
    let sender = TestClient::connect(broker.port, "f25-sender").await;
    sender
        .publish(
            "plant/dust_collector/pulse_interval/set",
            b"12".to_vec(),
            true,
        )
        .await;
    // The broker holds it before any gateway runs: a client subscribing after the publish was
    // routed gets it from the retained store. (A subscription racing the publish may see it
    // live first, without the retain flag; the second subscriber settles that.)
    let mut first_look = TestClient::connect(broker.port, "f25-first-look").await;
    first_look
        .subscribe("plant/dust_collector/pulse_interval/set")
        .await;
    first_look
        .wait_for("plant/dust_collector/pulse_interval/set", ANSWER, |m| {
            m.text() == "12"
        })
        .await;
    let mut observer = TestClient::connect(broker.port, "f25-observer").await;
    observer.subscribe("plant/#").await;
    observer
        .wait_for("plant/dust_collector/pulse_interval/set", ANSWER, |m| {
            m.retain && m.text() == "12"
        })
        .await;
    observer.forget();
    for round in 0..2 {
        let gateway = Gateway::start(fast(&plant_config(&broker, &plant, "f25-gw", ""))).await;
        observer
            .wait_for("plant/dust_collector/availability", ANSWER, |m| {
                m.text() == "online"
            })
            .await;
        if round == 0 {
            let result = observer
                .next_on("plant/dust_collector/pulse_interval/result", ANSWER)
                .await
                .json();
            assert_eq!(outcome(&result), "applied", "{result}");
        }
        observer.settle(Duration::from_secs(2)).await;
        gateway.stop().await;
    }
    let writes = writes(&plant.line_a.journal().frames(), DUST);
    assert_eq!(writes.len(), 1, "{writes:?}");
    assert_eq!(sim::lock(&plant.dust_collector).pulse_interval(), 12);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_device_goes_offline_and_its_command_runs_when_it_returns() {
    let mut h = start_with("silent", "command_ttl = \"60s\"", |plant| {
        sim::lock(&plant.dust_collector).set_power(true);
    })
    .await;
    h.observer.drain();
    h.observer
        .received
        .retain(|m| m.topic != "plant/air_shower/availability");
    h.plant.line_a.faults().silence(DUST, true);
    let went = std::time::Instant::now();
    h.wait_new_text("plant/dust_collector/availability", "offline")
        .await;
    // Bounded: offline_after × (retries + 1) × timeout plus scheduling slack.
    eprintln!(
        "figure: silent device reported offline after {:?}",
        went.elapsed()
    );
    assert!(
        went.elapsed() < Duration::from_secs(10),
        "{:?}",
        went.elapsed()
    );
    // The air shower on the same line stays online.
    assert!(h
        .observer
        .on("plant/air_shower/availability")
        .iter()
        .all(|m| m.text() == "online"));

    h.observer
        .publish("plant/dust_collector/gear/set", b"4".to_vec(), false)
        .await;
    h.observer
        .publish("plant/dust_collector/gear/set", b"6".to_vec(), false)
        .await;
    // The older one is superseded while waiting.
    let first = h.result("dust_collector", "gear").await;
    assert_eq!(first["value"], "4");
    assert_eq!(outcome(&first), "superseded", "{first}");
    assert!(first["detail"]
        .as_str()
        .unwrap_or("")
        .contains("superseded"));
    h.observer.settle(Duration::from_secs(1)).await;
    assert!(h.observer.on("plant/dust_collector/gear/result").is_empty());

    h.plant.line_a.faults().silence(DUST, false);
    h.wait_new_text("plant/dust_collector/availability", "online")
        .await;
    let result = h.result("dust_collector", "gear").await;
    assert_eq!(result["value"], "6");
    assert_eq!(outcome(&result), "applied", "{result}");
    assert_eq!(sim::lock(&h.plant.dust_collector).gear(), 6);
    h.stop_gateway().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_command_for_a_device_offline_past_its_time_to_live_expires() {
    let mut h = start_with("ttl", "command_ttl = \"2s\"", |_| {}).await;
    h.plant.line_b.faults().silence(VALVE, true);
    h.wait_new_text("plant/valve/availability", "offline").await;
    h.observer
        .publish("plant/valve/opening/set", b"30".to_vec(), true)
        .await;
    let result = h.result("valve", "opening").await;
    assert_eq!(outcome(&result), "expired", "{result}");
    assert!(
        result["detail"].as_str().unwrap_or("").contains("offline"),
        "{result}"
    );
    h.observer
        .wait_for("plant/valve/opening/set", ANSWER, |m| m.payload.is_empty())
        .await;
    assert_eq!(
        writes(&frames(&h.plant.line_b), VALVE),
        Vec::<String>::new()
    );
    h.stop_gateway().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_broker_killed_and_restarted_gets_the_state_back_and_commands_work() {
    let mut h = start_with("brokerkill", "", |plant| {
        sim::lock(&plant.dust_collector).set_power(true);
    })
    .await;
    h.wait_text("plant/dust_collector/power", "ON").await;
    h.broker.kill();
    // Polling goes on meanwhile.
    let polled = h.plant.line_a.journal().request_count();
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert!(h.plant.line_a.journal().request_count() > polled);
    sim::lock(&h.plant.dust_collector).set_power(false);
    tokio::time::sleep(Duration::from_secs(1)).await;
    h.broker.restart();
    let back = std::time::Instant::now();

    // A fresh subscriber on the restarted broker (no persistence) sees the current state.
    let mut fresh = TestClient::connect(h.broker.port, "brokerkill-fresh").await;
    fresh.subscribe("plant/#").await;
    fresh
        .wait_for("plant/dust_collector/power", ANSWER, |m| m.text() == "OFF")
        .await;
    fresh
        .wait_for(
            &format!("plant/gateway/{}/status", h.client_id),
            ANSWER,
            |m| m.text() == "online",
        )
        .await;
    fresh
        .wait_for("plant/valve/availability", ANSWER, |m| m.text() == "online")
        .await;
    eprintln!(
        "figure: state and status back {:?} after the broker restart",
        back.elapsed()
    );
    // Subscriptions were restored: commands work again.
    fresh
        .publish("plant/dust_collector/power/set", b"ON".to_vec(), false)
        .await;
    let result = fresh
        .next_on("plant/dust_collector/power/result", ANSWER)
        .await
        .json();
    assert_eq!(outcome(&result), "applied", "{result}");
    eprintln!(
        "figure: a command applied {:?} after the broker restart",
        back.elapsed()
    );
    assert!(sim::lock(&h.plant.dust_collector).power());
    h.stop_gateway().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_payloads_are_rejected_without_a_frame() {
    let mut h = start_with("bad", "max_payload = 64", |plant| {
        sim::lock(&plant.dust_collector).set_power(true);
    })
    .await;
    h.wait_text("plant/dust_collector/power", "ON").await;
    h.observer.settle(Duration::from_millis(500)).await;
    h.plant.line_a.journal().clear();
    let huge = vec![b'9'; 5000];
    let cases: Vec<(&str, &str, Vec<u8>, &str)> = vec![
        ("dust_collector", "gear", vec![0xff, 0xfe, 0x41], "UTF-8"),
        ("dust_collector", "gear", huge, "limit"),
        ("dust_collector", "gear", b"banana".to_vec(), ""),
        ("dust_collector", "gear", b"11".to_vec(), ""),
        ("dust_collector", "gear", b"2.5".to_vec(), ""),
        ("dust_collector", "gear", b"NaN".to_vec(), ""),
        ("dust_collector", "fan_speed", b"100".to_vec(), "read-only"),
        (
            "dust_collector",
            "no_such_field",
            b"1".to_vec(),
            "unknown field",
        ),
        ("air_shower", "light", b"maybe".to_vec(), ""),
        ("valve", "setpoint", b"12.345.6".to_vec(), ""),
    ];
    for (device, field, payload, reason) in cases {
        let result = h.command(device, field, &payload).await;
        assert_eq!(outcome(&result), "rejected", "{device}/{field}: {result}");
        let detail = result["detail"].as_str().unwrap_or("");
        assert!(!detail.is_empty(), "{result}");
        assert!(detail.contains(reason), "{device}/{field}: {result}");
    }
    // `value` is the payload exactly as sent, untrimmed, control characters included.
    let result = h.command("dust_collector", "gear", b" banana\r\n").await;
    assert_eq!(outcome(&result), "rejected", "{result}");
    assert_eq!(result["value"], " banana\r\n", "{result}");
    // A retained payload far over the limit (but under the client's packet bound) is
    // rejected and cleared, so it does not come back after every reconnect.
    h.observer
        .publish(
            "plant/dust_collector/pulse_interval/set",
            vec![b'7'; 300_000],
            true,
        )
        .await;
    let result = h.result("dust_collector", "pulse_interval").await;
    assert_eq!(outcome(&result), "rejected", "{result}");
    h.observer
        .wait_for("plant/dust_collector/pulse_interval/set", ANSWER, |m| {
            m.payload.is_empty()
        })
        .await;
    // A command for a device that is not configured is rejected, naming the configured ones;
    // a topic that is not of our shape gets nothing back. Nothing happens on the lines.
    h.observer
        .publish("plant/intruder/gear/set", b"1".to_vec(), false)
        .await;
    h.observer
        .publish("plant/dust_collector/gear/set/x", b"1".to_vec(), false)
        .await;
    let unknown = h.result("intruder", "gear").await;
    assert_eq!(outcome(&unknown), "rejected", "{unknown}");
    let detail = unknown["detail"].as_str().unwrap_or_default();
    assert!(
        detail.contains("dust_collector") && detail.contains("valve"),
        "{detail}"
    );
    h.observer.settle(Duration::from_secs(1)).await;
    assert!(h
        .observer
        .on("plant/dust_collector/gear/set/x/result")
        .is_empty());
    assert!(
        h.observer.on("plant/intruder/gear/result").is_empty(),
        "one result"
    );
    for writes_on in [
        writes(&frames(&h.plant.line_a), DUST),
        writes(&frames(&h.plant.line_a), SHOWER),
        writes(&frames(&h.plant.line_b), VALVE),
    ] {
        assert_eq!(writes_on, Vec::<String>::new());
    }
    // Still alive and obeying.
    let result = h.command("dust_collector", "gear", b"9").await;
    assert_eq!(outcome(&result), "applied", "{result}");
    h.stop_gateway().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_clean_stop_announces_offline() {
    let mut h = start("stop").await;
    let status = format!("plant/gateway/{}/status", h.client_id);
    h.wait_text(&status, "online").await;
    h.observer.drain();
    h.observer.forget();
    h.stop_gateway().await;
    h.wait_text(&status, "offline").await;
    for device in ["dust_collector", "air_shower", "valve"] {
        h.wait_text(&format!("plant/{device}/availability"), "offline")
            .await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connects_over_tls_with_a_client_certificate_and_a_password_file() {
    let (broker, tls_port, certs) = Mosquitto::start_tls();
    let plant = SeedPlant::spawn(false).unwrap();
    let mut observer = TestClient::connect(broker.port, "tls-observer").await;
    observer.subscribe("plant/#").await;
    let dir = certs.path().display();
    let text = plant_config(&broker, &plant, "tls-gw", "").replace(
        &format!("url = \"{}\"", broker.url()),
        &format!(
            "url = \"mqtts://127.0.0.1:{tls_port}\"\nusername = \"gateway\"\n\
                 password_file = \"{dir}/password\"\nca_file = \"{dir}/ca.crt\"\n\
                 cert_file = \"{dir}/client.crt\"\nkey_file = \"{dir}/client.key\""
        ),
    );
    let config = fast(&text);
    assert!(config.mqtt.tls.is_some());
    assert_eq!(config.mqtt.password.as_deref(), Some("s3cret"));
    let gateway = Gateway::start(config).await;
    observer
        .wait_for("plant/gateway/tls-gw/status", ANSWER, |m| {
            m.text() == "online"
        })
        .await;
    observer
        .wait_for("plant/valve/availability", ANSWER, |m| m.text() == "online")
        .await;
    gateway.stop().await;
    // The broker saw the gateway log in with its user name (on the TLS listener: it is the
    // only one the configuration names).
    let log = broker.log();
    assert!(
        log.lines()
            .any(|line| line.contains("as tls-gw") && line.contains("u'gateway'")),
        "no authenticated connection of the gateway in the broker log:\n{log}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn polling_runs_while_the_broker_is_down_at_start_and_state_follows_it() {
    let mut broker = Mosquitto::not_started();
    let plant = SeedPlant::spawn(false).unwrap();
    sim::lock(&plant.dust_collector).set_power(true);
    let metrics_port = support::free_port();
    let extra = format!("metrics_listen = \"127.0.0.1:{metrics_port}\"");
    let gateway = Gateway::start(fast(&plant_config(&broker, &plant, "late-gw", &extra))).await;
    // No broker: the lines poll all the same.
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert!(plant.line_a.journal().request_count() > 3);
    assert!(plant.line_b.journal().request_count() > 3);
    assert!(!*gateway.running.bridge.connected.borrow());
    // Change a value while MQTT is away: the cached latest value is what gets published.
    sim::lock(&plant.dust_collector).set_power(false);
    tokio::time::sleep(Duration::from_secs(1)).await;

    // The Prometheus endpoint answers meanwhile.
    let metrics = http_get(metrics_port, "/metrics").await;
    assert!(metrics.starts_with("HTTP/1.1 200"), "{metrics}");
    assert!(metrics.contains("rtu2mqtt_mqtt_connected 0"), "{metrics}");
    assert!(metrics.contains("line=\"line-a\""), "{metrics}");

    broker.restart();
    let mut observer = TestClient::connect(broker.port, "late-observer").await;
    observer.subscribe("plant/#").await;
    // Within the back-off schedule (capped at 30 s; a few seconds this early).
    observer
        .wait_for("plant/gateway/late-gw/status", ANSWER * 3, |m| {
            m.text() == "online"
        })
        .await;
    observer
        .wait_for("plant/dust_collector/power", ANSWER, |m| m.text() == "OFF")
        .await;
    observer
        .wait_for("plant/valve/availability", ANSWER, |m| m.text() == "online")
        .await;
    let metrics = http_get(metrics_port, "/metrics").await;
    assert!(metrics.contains("rtu2mqtt_mqtt_connected 1"), "{metrics}");
    gateway.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn home_assistant_discovery_is_sent_repeated_and_cleaned_up() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).unwrap();
    let mut observer = TestClient::connect(broker.port, "ha-observer").await;
    observer.subscribe("homeassistant/#").await;
    // A config this gateway left behind for a device no longer configured.
    let stale = serde_json::json!({
        "dev": {"ids": ["ha-gw_old_pump"], "name": "old pump", "via_device": "ha-gw"},
        "o": {"name": "rtu2mqtt"},
        "cmps": {}
    });
    observer
        .publish(
            "homeassistant/device/ha-gw_old_pump/config",
            stale.to_string(),
            true,
        )
        .await;
    let text =
        plant_config(&broker, &plant, "ha-gw", "").replace("discovery = false", "discovery = true");
    let gateway = Gateway::start(fast(&text)).await;
    let valve_topic = "homeassistant/device/ha-gw_valve/config";
    let config = observer.next_on(valve_topic, ANSWER).await;
    // Retained: a client that comes later (Home Assistant after a restart) gets it too.
    let mut late = TestClient::connect(broker.port, "ha-late").await;
    late.subscribe(valve_topic).await;
    assert!(late.next_on(valve_topic, ANSWER).await.retain);
    let document = config.json();
    assert_eq!(document["dev"]["via_device"], "ha-gw", "{document}");
    assert!(document["cmps"]["opening"].is_object(), "{document}");
    observer
        .next_on("homeassistant/device/ha-gw_gateway/config", ANSWER)
        .await;
    // The stale one is removed.
    observer
        .wait_for("homeassistant/device/ha-gw_old_pump/config", ANSWER, |m| {
            m.payload.is_empty()
        })
        .await;
    // Home Assistant restarts: discovery follows within its re-announce delay.
    observer.drain();
    observer.forget();
    observer
        .publish("homeassistant/status", b"online".to_vec(), false)
        .await;
    observer.next_on(valve_topic, ANSWER).await;
    gateway.stop().await;
}

/// A plain HTTP/1.1 GET on 127.0.0.1, the whole response as text.
async fn http_get(port: u16, path: &str) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut stream = tokio::net::TcpStream::connect(("127.0.0.1", port))
        .await
        .unwrap();
    stream
        .write_all(format!("GET {path} HTTP/1.1\r\nHost: test\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut response = String::new();
    stream.read_to_string(&mut response).await.unwrap();
    response
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_command_flood_is_bounded_and_the_newest_command_wins() {
    let mut h = start_with("flood", "", |plant| {
        sim::lock(&plant.dust_collector).set_power(true);
    })
    .await;
    h.wait_text("plant/dust_collector/power", "ON").await;
    h.observer.settle(Duration::from_millis(500)).await;
    h.observer.forget();
    h.plant.line_a.journal().clear();
    const COMMANDS: usize = 200;
    let flood_started = std::time::Instant::now();
    for index in 0..COMMANDS {
        // Ends on 7; consecutive commands always differ.
        let gear = (index + 7) % 10 + 1;
        h.observer
            .publish(
                "plant/dust_collector/gear/set",
                gear.to_string().into_bytes(),
                false,
            )
            .await;
    }
    let last = h
        .observer
        .wait_for("plant/dust_collector/gear/result", ANSWER * 2, |m| {
            m.json()["value"] == "7" && m.json()["outcome"] != "superseded"
        })
        .await
        .json();
    assert_eq!(outcome(&last), "applied", "{last}");
    eprintln!(
        "figure: {COMMANDS} commands settled in {:?}",
        flood_started.elapsed()
    );
    assert_eq!(sim::lock(&h.plant.dust_collector).gear(), 7);
    h.observer.settle(Duration::from_secs(1)).await;
    let results = h.observer.on("plant/dust_collector/gear/result");
    // Every command has exactly one result: run, or superseded while it waited.
    assert_eq!(results.len() + 1, COMMANDS);
    assert!(results
        .iter()
        .all(|m| ["applied", "superseded"].contains(&outcome(&m.json()))));
    // Newest wins: far fewer writes than commands, and the line kept polling the air shower.
    let frames = frames(&h.plant.line_a);
    let gear_writes = writes(&frames, DUST).len();
    assert!(gear_writes < COMMANDS / 2, "{gear_writes} writes");
    assert!(frames.iter().any(|f| f[0] == SHOWER));
    assert!(h
        .observer
        .on("plant/air_shower/availability")
        .iter()
        .all(|m| m.text() == "online"));
    h.stop_gateway().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_gateways_with_one_client_id_do_not_storm_the_broker() {
    let broker = Mosquitto::start();
    let plant_one = SeedPlant::spawn(false).unwrap();
    let plant_two = SeedPlant::spawn(false).unwrap();
    let one = Gateway::start(fast(&plant_config(&broker, &plant_one, "twin-gw", ""))).await;
    let two = Gateway::start(fast(&plant_config(&broker, &plant_two, "twin-gw", ""))).await;
    let watched = Duration::from_secs(10);
    tokio::time::sleep(watched).await;
    let connects = broker
        .log()
        .lines()
        .filter(|line| line.contains("New client connected") && line.contains("as twin-gw"))
        .count();
    eprintln!("figure: {connects} connections of two same-id gateways in {watched:?}");
    // Each takeover kicks the other out: without back-off this is hundreds per second.
    assert!(connects >= 2, "{connects}");
    assert!(connects <= 20, "{connects} connections in {watched:?}");
    one.stop().await;
    two.stop().await;
}
