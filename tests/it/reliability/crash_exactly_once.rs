//! Crashes at every step of a command's life: the gateway binary runs as a child process
//! while this test owns the simulated seed plant (on ptys, so the devices outlive the
//! gateway) and a real mosquitto. A retained command is sent, the gateway is killed with
//! SIGKILL at one step (received, cleared and queued, written, result published), restarted,
//! and the simulator's own counters say what happened: a momentary action (the air shower's
//! voice prompt) ran at most once; a state command (`gear = 9`) leaves the device in the state
//! asked for, and no retained command is left to replay.

use crate::support;

use std::process::Stdio;
use std::time::{Duration, Instant};

use rtu2mqtt_sim as sim;
use support::child::{self, KillOnDrop};
use support::{PlantBench, PlantConfig, TestClient};

/// Generous bound for a busy 2-core machine: it only runs out when something is broken.
const ANSWER: Duration = Duration::from_secs(15);
const VOICE_SET: &str = "plant/air_shower/voice_start/set";
const VOICE_RESULT: &str = "plant/air_shower/voice_start/result";
const GEAR_SET: &str = "plant/dust_collector/gear/set";
const GEAR_RESULT: &str = "plant/dust_collector/gear/result";

/// Where a command's life is cut short.
#[derive(Debug, Clone, Copy)]
enum KillAt {
    /// As soon as the command is published.
    Received,
    /// When the gateway's clearing of the command reaches the broker (an action is queued
    /// for its line right after).
    Cleared,
    /// When the device has seen the write.
    Written,
    /// When the outcome is on the broker.
    ResultPublished,
}

/// The plant bench without a gateway in the test's runtime: the gateway is `rtu2mqtt run`, a
/// child process the test kills; its configuration, status file and log live in `dir`.
struct Bench {
    base: PlantBench,
    dir: tempfile::TempDir,
}

impl Bench {
    fn spawn_gateway(&self) -> KillOnDrop {
        let config = self.dir.path().join("config.toml");
        let text =
            PlantConfig::default().text(&self.base.broker, &self.base.plant, &self.base.client_id);
        std::fs::write(&config, text).expect("write config");
        let mut command = child::gateway_run(&config);
        command
            .env(
                "RTU2MQTT__HEALTH__STATUS_FILE",
                self.dir.path().join("health"),
            )
            .env("RUST_LOG", "warn")
            .stderr(
                std::fs::File::create(self.dir.path().join("gateway.log"))
                    .map(Stdio::from)
                    .unwrap_or_else(|_| Stdio::null()),
            );
        KillOnDrop::spawn(command).expect("rtu2mqtt run starts")
    }

    /// Starts the gateway and waits until both seed devices on line-a are online again.
    async fn start_gateway(&mut self) -> KillOnDrop {
        self.base.observer.drain();
        self.base.observer.forget();
        let daemon = self.spawn_gateway();
        for device in ["dust_collector", "air_shower"] {
            let topic = format!("plant/{device}/availability");
            let online = self
                .base
                .observer
                .try_wait_for(&topic, ANSWER, |m| m.text() == "online")
                .await;
            if online.is_none() {
                let log = std::fs::read_to_string(self.dir.path().join("gateway.log"));
                panic!("{device} not online; the gateway said: {log:?}");
            }
        }
        daemon
    }

    fn voice_presses(&self) -> u32 {
        sim::lock(&self.base.plant.air_shower).voice_presses()[0]
    }

    fn gear(&self) -> u16 {
        sim::lock(&self.base.plant.dust_collector).gear()
    }

    /// Waits (polling the simulator every millisecond) until `done` holds.
    async fn until(&self, what: &str, done: impl Fn(&Bench) -> bool) {
        let deadline = Instant::now() + ANSWER;
        while !done(self) {
            assert!(Instant::now() < deadline, "never happened: {what}");
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    }

    /// Kills `daemon` at `at` for the command on `set` (answered on `result`); `effect` says
    /// the device has seen the write.
    async fn kill_at(
        &mut self,
        daemon: KillOnDrop,
        at: KillAt,
        set: &str,
        result: &str,
        effect: impl Fn(&Bench) -> bool,
    ) {
        match at {
            KillAt::Received => {}
            KillAt::Cleared => {
                self.base
                    .observer
                    .wait_for(set, ANSWER, |m| m.payload.is_empty())
                    .await;
            }
            KillAt::Written => self.until("the write", effect).await,
            KillAt::ResultPublished => {
                self.base.observer.next_on(result, ANSWER).await;
            }
        }
        drop(daemon);
    }

    /// The retained message on `topic` as a new subscriber gets it.
    async fn retained(&self, topic: &str) -> Option<String> {
        let mut client = TestClient::connect(self.base.broker.port, "crash-late").await;
        client.subscribe(topic).await;
        client.settle(Duration::from_millis(300)).await;
        client.on(topic).iter().find(|m| m.retain).map(|m| m.text())
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_action_runs_at_most_once_and_each_state_is_reached_whatever_the_crash() {
    let base = PlantBench::setup("crash")
        .prepare(|plant| sim::lock(&plant.dust_collector).set_power(true))
        .without_gateway()
        .start()
        .await;
    let sender = TestClient::connect(base.broker.port, "crash-sender").await;
    let mut bench = Bench {
        base,
        dir: tempfile::tempdir().expect("temp dir"),
    };
    let mut daemon = bench.start_gateway().await;

    // A momentary action: at most once, whatever the step the gateway dies at.
    for at in [
        KillAt::Received,
        KillAt::Cleared,
        KillAt::Written,
        KillAt::ResultPublished,
    ] {
        let before = bench.voice_presses();
        bench.base.observer.drain();
        bench.base.observer.forget();
        sender.publish(VOICE_SET, "PRESS", true).await;
        bench
            .kill_at(daemon, at, VOICE_SET, VOICE_RESULT, move |b| {
                b.voice_presses() > before
            })
            .await;
        let after_kill = bench.voice_presses() - before;
        daemon = bench.start_gateway().await;
        // Time for a replay to show, were there one.
        tokio::time::sleep(Duration::from_secs(2)).await;
        let presses = bench.voice_presses() - before;
        eprintln!("figure: killed at {at:?}: {after_kill} press(es) before, {presses} in all");
        assert!(presses <= 1, "killed at {at:?}: pressed {presses} times");
        if matches!(at, KillAt::Written | KillAt::ResultPublished) {
            assert_eq!(presses, 1, "killed at {at:?}");
        }
        assert_eq!(bench.retained(VOICE_SET).await, None, "killed at {at:?}");
    }

    // A state command: idempotent, so it may run again; it leaves the state asked for.
    for (at, gear) in [
        (KillAt::Received, 9),
        (KillAt::Written, 4),
        (KillAt::ResultPublished, 9),
    ] {
        bench.base.observer.drain();
        bench.base.observer.forget();
        sender.publish(GEAR_SET, gear.to_string(), true).await;
        bench
            .kill_at(daemon, at, GEAR_SET, GEAR_RESULT, move |b| b.gear() == gear)
            .await;
        daemon = bench.start_gateway().await;
        let state = "plant/dust_collector/gear";
        let text = gear.to_string();
        bench
            .base
            .observer
            .wait_for(state, ANSWER, move |m| m.text() == text)
            .await;
        assert_eq!(bench.gear(), gear, "killed at {at:?}");
        // The retained command is gone once it has its outcome (at once, or after the replay).
        let deadline = Instant::now() + ANSWER;
        while bench.retained(GEAR_SET).await.is_some() {
            assert!(
                Instant::now() < deadline,
                "killed at {at:?}: still retained"
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }
    drop(daemon);
}
