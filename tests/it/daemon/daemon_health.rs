//! `rtu2mqtt run` under a (simulated) service manager: it notifies `READY=1`, pings the
//! watchdog and keeps the status file fresh while its loops turn, goes silent and stale when the
//! process is frozen (`kill -STOP`, docs/reliability.md F26), recovers, and on SIGTERM says
//! `STOPPING=1`, removes the status file and exits 0. The seed plant is simulated on ptys; the
//! broker is a real mosquitto; the service manager is a Unix datagram socket in `NOTIFY_SOCKET`.

use crate::support;

use std::os::unix::net::UnixDatagram;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use nix::sys::signal::{kill, Signal};
use rtu2mqtt_sim::SeedPlant;
use support::child::{self, KillOnDrop};

/// The notifications received so far, one string per datagram.
fn drain(socket: &UnixDatagram) -> Vec<String> {
    let mut out = Vec::new();
    let mut buffer = [0u8; 4096];
    while let Ok(n) = socket.recv(&mut buffer) {
        out.push(String::from_utf8_lossy(&buffer[..n]).into_owned());
    }
    out
}

/// Waits for a notification containing `wanted`, keeping everything seen in `seen`.
fn wait_for_notification(
    socket: &UnixDatagram,
    seen: &mut Vec<String>,
    wanted: &str,
    timeout: Duration,
) -> bool {
    let deadline = Instant::now() + timeout;
    loop {
        seen.extend(drain(socket));
        if seen.iter().any(|n| n.lines().any(|line| line == wanted)) {
            return true;
        }
        if Instant::now() > deadline {
            return false;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// `rtu2mqtt health` on the status file; (healthy, what it printed).
fn health(status_file: &Path, max_age: &str) -> (bool, String) {
    let output = Command::new(child::gateway_binary())
        .args(["health", "--status-file"])
        .arg(status_file)
        .args(["--max-age", max_age])
        .output()
        .expect("rtu2mqtt health runs");
    (
        output.status.success(),
        String::from_utf8_lossy(&output.stdout).into_owned(),
    )
}

fn wait_for_health(status_file: &Path, max_age: &str, healthy: bool) -> String {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let (is_healthy, said) = health(status_file, max_age);
        if is_healthy == healthy {
            return said;
        }
        assert!(
            Instant::now() < deadline,
            "health never became {healthy}: {said}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn run_reports_readiness_liveness_and_stop() {
    let runtime = tokio::runtime::Runtime::new().expect("runtime");
    let _entered = runtime.enter();
    let plant = SeedPlant::spawn(false).expect("simulated plant");
    let mosquitto = support::Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");

    let example = include_str!("../../../config/rtu2mqtt.toml");
    let config = example
        .replace("/dev/ttyUSB0", &plant.line_a.path().to_string_lossy())
        .replace("/dev/ttyUSB1", &plant.line_b.path().to_string_lossy())
        .replace("mqtt://127.0.0.1:1883", &mosquitto.url());
    assert_ne!(config, example, "the example configuration changed shape");
    let config_path = dir.path().join("config.toml");
    std::fs::write(&config_path, config).expect("write config");

    let socket_path = dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).expect("notify socket");
    socket.set_nonblocking(true).expect("non-blocking");
    let status_file = dir.path().join("health");

    let mut command = child::gateway_run(&config_path);
    command
        .env("NOTIFY_SOCKET", &socket_path)
        .env("WATCHDOG_USEC", "3000000")
        .env("RTU2MQTT__HEALTH__STATUS_FILE", &status_file)
        .env("RUST_LOG", "warn");
    // Killed on drop even while frozen: SIGKILL ends a stopped process too.
    let daemon = KillOnDrop::spawn(command).expect("rtu2mqtt run starts");
    let pid = daemon.pid();
    let mut seen = Vec::new();

    assert!(
        wait_for_notification(&socket, &mut seen, "READY=1", Duration::from_secs(30)),
        "no READY=1: {seen:?}"
    );
    assert!(
        wait_for_notification(&socket, &mut seen, "WATCHDOG=1", Duration::from_secs(30)),
        "no WATCHDOG=1: {seen:?}"
    );
    let said = wait_for_health(&status_file, "10s", true);
    assert!(said.starts_with("healthy: 2 line(s) alive"), "{said}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&status_file).expect("status file"))
            .expect("JSON status");
    assert_eq!(report["healthy"], true);
    assert_eq!(report["lines"].as_array().map(Vec::len), Some(2));

    // Frozen: no pings, and the status file goes stale.
    kill(pid, Signal::SIGSTOP).expect("SIGSTOP");
    std::thread::sleep(Duration::from_millis(500));
    drain(&socket);
    let said = wait_for_health(&status_file, "2s", false);
    assert!(said.contains("old"), "{said}");
    let while_frozen = drain(&socket);
    assert!(
        while_frozen.iter().all(|n| !n.contains("WATCHDOG=1")),
        "{while_frozen:?}"
    );

    // Thawed: fresh again.
    kill(pid, Signal::SIGCONT).expect("SIGCONT");
    wait_for_health(&status_file, "10s", true);

    kill(pid, Signal::SIGTERM).expect("SIGTERM");
    let mut daemon = daemon;
    let deadline = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(status) = daemon.0.try_wait().expect("wait") {
            break status;
        }
        assert!(Instant::now() < deadline, "no stop within 20 s of SIGTERM");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "{status:?}");
    assert!(
        wait_for_notification(&socket, &mut seen, "STOPPING=1", Duration::from_secs(1)),
        "{seen:?}"
    );
    assert!(!status_file.exists(), "the status file outlived the daemon");
    let (healthy, said) = health(&status_file, "30s");
    assert!(!healthy && said.contains("cannot read"), "{said}");
    drop(plant);
}
