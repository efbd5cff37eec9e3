//! `rtu2mqtt run` gives the kernel back the pages of code that only its start-up ran
//! (`[gateway] release_startup_code_after`), measured from outside in `/proc/<pid>/smaps`: the
//! resident pages of the executable shrink once the time has passed, and the gateway goes on
//! working with its code paged back in on use (a command is applied and its state published).

use crate::support;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use rtu2mqtt::sim::{self, SeedPlant};
use support::child::{self, KillOnDrop};
use support::{Mosquitto, PlantConfig, TestClient};

/// Generous bounds for a busy machine: they only fail when something is broken.
const ANSWER: Duration = Duration::from_secs(15);
/// The gateway's settle time in this test.
const RELEASE_AFTER: Duration = Duration::from_secs(10);

/// `rtu2mqtt run` as its own process; killed on drop.
struct Daemon {
    child: KillOnDrop,
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
            .env("RUST_LOG", "warn");
        let child = KillOnDrop::spawn(command).expect("rtu2mqtt run starts");
        Daemon { child, _dir: dir }
    }

    /// Resident KiB of the executable's own mappings (its code and constants).
    fn executable_rss_kib(&self) -> u64 {
        let pid = self.child.id();
        let exe: PathBuf = std::fs::read_link(format!("/proc/{pid}/exe")).expect("exe link");
        let exe = exe.to_string_lossy().into_owned();
        let smaps = std::fs::read_to_string(format!("/proc/{pid}/smaps")).expect("smaps");
        let mut in_exe = false;
        let mut total = 0;
        for line in smaps.lines() {
            let first = line.split_whitespace().next().unwrap_or_default();
            if first.contains('-') && first.chars().all(|c| c.is_ascii_hexdigit() || c == '-') {
                in_exe = line.split_whitespace().nth(5) == Some(exe.as_str());
            } else if in_exe && first == "Rss:" {
                total += line
                    .split_whitespace()
                    .nth(1)
                    .and_then(|kib| kib.parse::<u64>().ok())
                    .unwrap_or(0);
            }
        }
        total
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn start_up_code_goes_back_to_the_kernel_and_the_gateway_works_on() {
    let broker = Mosquitto::start();
    let plant = SeedPlant::spawn(false).expect("seed plant on ptys");
    sim::lock(&plant.dust_collector).set_power(true);
    let mut client = TestClient::connect(broker.port, "startup-pages-observer").await;
    client.subscribe("plant/#").await;
    let gateway = format!(
        "release_startup_code_after = \"{}s\"",
        RELEASE_AFTER.as_secs()
    );
    let config = PlantConfig {
        gateway: &gateway,
        discovery: true,
        ..PlantConfig::default()
    }
    .text(&broker, &plant, "startup-pages-gw");
    let daemon = Daemon::spawn(&config);
    let started = Instant::now();

    for device in ["dust_collector", "air_shower", "valve"] {
        client
            .wait_for(&format!("plant/{device}/availability"), ANSWER, |m| {
                m.text() == "online"
            })
            .await;
    }
    let settled = daemon.executable_rss_kib();
    eprintln!(
        "online after {:?}; executable resident {settled} KiB",
        started.elapsed()
    );
    assert!(
        started.elapsed() < RELEASE_AFTER,
        "the plant came online too late to measure before the release"
    );

    // After the release the executable's resident pages are what the running loops touch
    // again: far fewer than start-up left behind.
    tokio::time::sleep_until((started + RELEASE_AFTER).into()).await;
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut lowest = settled;
    while Instant::now() < deadline && lowest * 2 >= settled {
        lowest = lowest.min(daemon.executable_rss_kib());
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    eprintln!("after the release: {lowest} KiB");
    assert!(
        lowest * 2 < settled,
        "the executable's resident pages went from {settled} KiB to {lowest} KiB at best; \
         expected under half"
    );

    // The gateway works on: a command goes to the wire and its state comes back.
    client.drain();
    client
        .publish("plant/dust_collector/gear/set", "8", false)
        .await;
    client
        .wait_for("plant/dust_collector/gear/result", ANSWER, |m| {
            m.json()["outcome"] == "applied"
        })
        .await;
    client
        .wait_for("plant/dust_collector/gear", ANSWER, |m| m.text() == "8")
        .await;
    assert_eq!(sim::lock(&plant.dust_collector).gear(), 8);
}
