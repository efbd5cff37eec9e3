//! Messages larger than the gateway reads, sent by a real mosquitto to the gateway binary run as
//! a child process (so that its memory is its own, read from `/proc/<pid>/smaps_rollup`): a
//! 64 MiB command and a 64 MiB retained Home Assistant config cost the gateway no more memory
//! than a small one, the connection comes back, the log says what happened, and a command
//! sent afterwards gets its result.

use crate::support;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use rtu2mqtt_sim::{self as sim, SeedPlant};
use support::child::{self, KillOnDrop};
use support::{Mosquitto, PlantConfig, TestClient};

/// Generous bound for a busy 2-core machine: it only runs out when something is broken.
const ANSWER: Duration = Duration::from_secs(30);
/// The payload sent: far past anything the gateway needs to read.
const BIG: usize = 64 * 1024 * 1024;
/// What the gateway's anonymous memory must stay under, before, during and after.
const MEMORY_BOUND_KIB: u64 = 30 * 1024;
const GEAR_SET: &str = "plant/dust_collector/gear/set";
const GEAR_RESULT: &str = "plant/dust_collector/gear/result";

/// A field of `/proc/<pid>/<file>` in KiB (`Anonymous:` of `smaps_rollup`, `VmHWM:` of
/// `status`); 0 once the process is gone.
fn proc_kib(pid: u32, file: &str, field: &str) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/{file}"))
        .unwrap_or_default()
        .lines()
        .find_map(|line| line.strip_prefix(field))
        .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or(0)
}

fn anonymous_kib(pid: u32) -> u64 {
    proc_kib(pid, "smaps_rollup", "Anonymous:")
}

/// The most anonymous memory the process had at any sample, sampled every millisecond on a
/// thread of its own until dropped.
struct PeakSampler {
    peak: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl PeakSampler {
    fn start(pid: u32) -> PeakSampler {
        let peak = Arc::new(AtomicU64::new(anonymous_kib(pid)));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (peak, stop) = (Arc::clone(&peak), Arc::clone(&stop));
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    peak.fetch_max(anonymous_kib(pid), Ordering::Relaxed);
                    std::thread::sleep(Duration::from_millis(1));
                }
            })
        };
        PeakSampler {
            peak,
            stop,
            thread: Some(thread),
        }
    }

    fn peak_kib(&self) -> u64 {
        self.peak.load(Ordering::Relaxed)
    }
}

impl Drop for PeakSampler {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// The broker, the seed plant and the gateway binary with Home Assistant discovery on, its
/// log in `dir`.
struct Bench {
    broker: Mosquitto,
    _plant: SeedPlant,
    gateway: KillOnDrop,
    dir: tempfile::TempDir,
    observer: TestClient,
}

impl Bench {
    async fn start(client_id: &str) -> Bench {
        let broker = Mosquitto::start();
        let plant = SeedPlant::spawn(false).expect("the seed plant starts");
        sim::lock(&plant.dust_collector).set_power(true);
        let dir = tempfile::tempdir().expect("temp dir");
        let text = PlantConfig {
            discovery: true,
            ..PlantConfig::default()
        }
        .text(&broker, &plant, client_id);
        let config = dir.path().join("config.toml");
        std::fs::write(&config, text).expect("write config");
        let mut command = child::gateway_run(&config);
        command
            .env("RTU2MQTT__HEALTH__STATUS_FILE", dir.path().join("health"))
            .env("RUST_LOG", "info")
            .stderr(
                std::fs::File::create(dir.path().join("gateway.log"))
                    .map(Stdio::from)
                    .unwrap_or_else(|_| Stdio::null()),
            );
        let gateway = KillOnDrop::spawn(command).expect("rtu2mqtt run starts");
        // Only the topics this test reads: a subscriber to the big message would be cut too.
        let mut observer = TestClient::connect(broker.port, &format!("{client_id}-observer")).await;
        observer.subscribe(GEAR_RESULT).await;
        observer
            .subscribe("plant/dust_collector/availability")
            .await;
        let mut bench = Bench {
            broker,
            _plant: plant,
            gateway,
            dir,
            observer,
        };
        bench
            .observer
            .wait_for("plant/dust_collector/availability", ANSWER, |m| {
                m.text() == "online"
            })
            .await;
        bench
    }

    fn pid(&self) -> u32 {
        self.gateway.id()
    }

    fn log(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("gateway.log")).unwrap_or_default()
    }

    /// Waits until the gateway's log holds `text` `count` times, at most `limit`; the log.
    async fn logged_within(&self, text: &str, count: usize, limit: Duration) -> String {
        let deadline = Instant::now() + limit;
        loop {
            let log = self.log();
            if log.matches(text).count() >= count || Instant::now() >= deadline {
                return log;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Waits until the gateway's log holds `text` `count` times.
    async fn logged(&self, text: &str, count: usize) -> String {
        let deadline = Instant::now() + ANSWER;
        loop {
            let log = self.log();
            if log.matches(text).count() >= count {
                return log;
            }
            assert!(
                Instant::now() < deadline,
                "the gateway never logged {text:?} {count} time(s):\n{log}"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Sends a `BIG` payload on `topic` with mosquitto_pub (QoS 1), from a file in `dir`.
    async fn publish_big(&self, topic: &str, retain: bool) {
        let file = big_file(self.dir.path());
        let mut command = Command::new("mosquitto_pub");
        command
            .args(["-h", "127.0.0.1", "-p", &self.broker.port.to_string()])
            .args(["-i", "big-sender", "-q", "1", "-t", topic, "-f"])
            .arg(&file);
        if retain {
            command.arg("-r");
        }
        let output = child::output(command, ANSWER)
            .await
            .expect("mosquitto_pub ran");
        assert!(
            output.status.success(),
            "mosquitto_pub: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        let _ = std::fs::remove_file(file);
    }

    /// A gear command after it all: the gateway still takes commands and answers them.
    async fn command_still_works(&mut self) -> serde_json::Value {
        self.observer.drain();
        self.observer.forget();
        let deadline = Instant::now() + ANSWER;
        loop {
            self.observer.publish(GEAR_SET, "3", false).await;
            let result = self
                .observer
                .try_wait_for(GEAR_RESULT, Duration::from_secs(5), |_| true)
                .await;
            if let Some(result) = result {
                return result.json();
            }
            // Sent while the gateway was reconnecting: it was not subscribed yet.
            assert!(
                Instant::now() < deadline,
                "no result for a command:\n{}",
                self.log()
            );
        }
    }
}

/// A file of `BIG` bytes (a JSON-ish text, as a careless sender would make) in `dir`.
fn big_file(dir: &Path) -> PathBuf {
    let path = dir.join("big.payload");
    std::fs::write(&path, vec![b'7'; BIG]).expect("write the big payload");
    path
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_64_mib_command_costs_no_memory_and_the_gateway_carries_on() {
    let mut bench = Bench::start("big-cmd").await;
    let pid = bench.pid();
    let before = anonymous_kib(pid);
    let hwm_before = proc_kib(pid, "status", "VmHWM:");
    let sampler = PeakSampler::start(pid);

    bench.publish_big(GEAR_SET, false).await;
    // The gateway has had it: it connected again after refusing it, or it took it in.
    bench
        .logged_within("MQTT connected", 2, Duration::from_secs(10))
        .await;
    let peak = sampler.peak_kib();
    drop(sampler);
    let hwm_growth = proc_kib(pid, "status", "VmHWM:").saturating_sub(hwm_before);
    println!(
        "figure: a {} MiB command: anonymous memory {before} KiB before, peak {peak} KiB; \
         VmHWM grew {hwm_growth} KiB",
        BIG >> 20
    );
    assert!(
        peak < MEMORY_BOUND_KIB,
        "anonymous memory peaked at {peak} KiB"
    );
    assert!(hwm_growth < MEMORY_BOUND_KIB, "VmHWM grew {hwm_growth} KiB");
    let log = bench.logged("MQTT connected", 2).await;
    assert!(
        log.contains("larger than the gateway reads"),
        "the log says what happened:\n{log}"
    );

    let result = bench.command_still_works().await;
    assert_eq!(result["outcome"], "applied", "{result}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_64_mib_retained_config_costs_no_memory_and_its_subscription_is_left_out() {
    let mut bench = Bench::start("big-cfg").await;
    let pid = bench.pid();
    let before = anonymous_kib(pid);
    let hwm_before = proc_kib(pid, "status", "VmHWM:");
    let sampler = PeakSampler::start(pid);

    // Retained on a topic of Home Assistant's that the gateway subscribes to (to find its own
    // earlier configs): it comes once live and again with every subscription.
    bench
        .publish_big("homeassistant/device/x/config", true)
        .await;
    // The gateway has had it: its subscription was left out, or it took it in.
    bench
        .logged_within(
            "is left out of the subscriptions",
            1,
            Duration::from_secs(15),
        )
        .await;
    let peak = sampler.peak_kib();
    drop(sampler);
    let hwm_growth = proc_kib(pid, "status", "VmHWM:").saturating_sub(hwm_before);
    println!(
        "figure: a {} MiB retained config: anonymous memory {before} KiB before, peak {peak} \
         KiB; VmHWM grew {hwm_growth} KiB",
        BIG >> 20
    );
    assert!(
        peak < MEMORY_BOUND_KIB,
        "anonymous memory peaked at {peak} KiB"
    );
    assert!(hwm_growth < MEMORY_BOUND_KIB, "VmHWM grew {hwm_growth} KiB");
    let log = bench.logged("is left out of the subscriptions", 1).await;
    assert!(
        log.contains("homeassistant/device/+/config"),
        "the log names the subscription:\n{log}"
    );
    // The connection after that one stays.
    let connected = log.matches("MQTT connected").count();
    bench.logged("MQTT connected", connected + 1).await;

    let result = bench.command_still_works().await;
    assert_eq!(result["outcome"], "applied", "{result}");
    // And the connection stays up: no connection lost after the command.
    let log = bench.log();
    let after = log
        .rsplit("is left out of the subscriptions")
        .next()
        .unwrap_or_default();
    assert!(
        after.matches("MQTT connection lost").count() <= 1,
        "the connection keeps being cut:\n{log}"
    );
}
