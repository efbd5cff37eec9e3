//! The demo's live table in a real terminal: `rtu2mqtt-demo` runs inside tmux at 80×24 and at
//! 200×60 and the screen is read back as a user sees it (`tmux capture-pane`). The footer
//! ("Ctrl-C stops") is on the last row, every device's row is there with its status, no value
//! is cut off by the edge, the hints can be copied whole, a changed value is highlighted, and
//! Ctrl-C stops the demo. Each size's screen is saved under the target directory
//! (`demo-80x24.txt`, `demo-200x60.txt`). Needs tmux (`apt install tmux`).

use std::path::PathBuf;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use crate::support::free_port;

/// A tmux server of our own (its own socket), killed on drop.
struct Tmux {
    socket: String,
}

impl Tmux {
    fn run(&self, args: &[&str]) -> Output {
        Command::new("tmux")
            .args(["-L", &self.socket])
            .args(args)
            .output()
            .expect("tmux runs (apt install tmux)")
    }

    /// The visible screen, one string per row; with `escapes`, colours and attributes too.
    fn screen(&self, escapes: bool) -> Vec<String> {
        let mut args = vec!["capture-pane", "-p", "-t", "demo"];
        if escapes {
            args.push("-e");
        }
        let output = self.run(&args);
        String::from_utf8_lossy(&output.stdout)
            .lines()
            .map(str::to_string)
            .collect()
    }

    /// Polls the screen until `done` holds; the last screen either way.
    fn wait_for(&self, timeout: Duration, done: impl Fn(&[String]) -> bool) -> (bool, Vec<String>) {
        let deadline = Instant::now() + timeout;
        loop {
            let screen = self.screen(false);
            if done(&screen) {
                return (true, screen);
            }
            if Instant::now() > deadline {
                return (false, screen);
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        let _ = self.run(&["kill-server"]);
    }
}

/// The fields the table shows for a device: all of them when `everything`, otherwise those
/// that are not settings or diagnostics.
fn shown_fields(profile: &str, everything: bool) -> Vec<String> {
    let profile = rtu2mqtt_profile::registry::built_in(profile).expect("built-in profile");
    profile
        .fields()
        .iter()
        .filter(|field| everything || field.ha.entity_category.is_none())
        .map(|field| field.name.clone())
        .collect()
}

const DEVICES: [(&str, &str); 3] = [
    ("dust_collector", "ruiwan-dust-collector"),
    ("air_shower", "lixian-air-shower"),
    ("valve", "wuzhou-valve"),
];

fn all_online(screen: &[String]) -> bool {
    DEVICES
        .iter()
        .all(|(device, _)| screen.iter().any(|row| row.starts_with(&format!("{device} [online]"))))
        // A field not published yet shows `name ·`.
        && !screen
            .iter()
            .any(|row| row.contains(" ·  ") || row.ends_with(" ·"))
}

/// `name value` for `field` somewhere on the screen, the value whole (followed by two blanks
/// or the end of the row).
fn shows_value(screen: &[String], field: &str) -> bool {
    screen.iter().any(|row| {
        let cells: Vec<&str> = row.trim().split("  ").map(str::trim).collect();
        cells.iter().any(|cell| {
            cell.split_once(' ')
                .is_some_and(|(name, value)| name == field && !value.is_empty())
        })
    })
}

fn save(name: &str, screen: &[String]) -> PathBuf {
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::write(&path, screen.join("\n") + "\n");
    path
}

fn check_the_screen(width: u16, height: u16) {
    let port = free_port();
    let tmux = Tmux {
        socket: format!(
            "rtu2mqtt-demo-screen-{}-{width}x{height}",
            std::process::id()
        ),
    };
    let demo = format!(
        "{} --port {port}; echo \"demo exited: $?\"; sleep 30",
        crate::DEMO
    );
    let started = tmux.run(&[
        "new-session",
        "-d",
        "-s",
        "demo",
        "-x",
        &width.to_string(),
        "-y",
        &height.to_string(),
        &demo,
    ]);
    assert!(
        started.status.success(),
        "tmux new-session: {}",
        String::from_utf8_lossy(&started.stderr)
    );

    // Before its first poll the dust collector (3 s start-up) is starting, not offline.
    let (seen, screen) = tmux.wait_for(Duration::from_secs(30), |screen| {
        screen.iter().any(|row| row.starts_with("rtu2mqtt-demo:"))
    });
    assert!(seen, "no table:\n{}", screen.join("\n"));
    assert!(
        !screen.iter().any(|row| row.contains("OFFLINE")),
        "{}",
        screen.join("\n")
    );

    let (online, screen) = tmux.wait_for(Duration::from_secs(60), all_online);
    assert!(online, "not all online:\n{}", screen.join("\n"));
    let saved = save(&format!("demo-{width}x{height}.txt"), &screen);
    eprintln!("screen saved to {}", saved.display());
    let text = screen.join("\n");

    assert_eq!(screen.len(), usize::from(height), "{text}");
    assert_eq!(
        screen.last().map(String::as_str),
        Some("Ctrl-C stops"),
        "{text}"
    );
    assert!(
        screen
            .iter()
            .all(|row| row.chars().count() <= usize::from(width)),
        "{text}"
    );
    let everything = width >= 200;
    for (device, profile) in DEVICES {
        for field in shown_fields(profile, everything) {
            assert!(
                shows_value(&screen, &field),
                "{device}/{field} not shown whole:\n{text}"
            );
        }
    }
    for hint in [
        format!("mosquitto_pub -p {port} -t plant/dust_collector/gear/set -m 8"),
        format!("mosquitto_pub -p {port} -t plant/air_shower/emergency_stop/set -m ON"),
        format!("mosquitto_pub -p {port} -t plant/valve/opening/set -m 40"),
    ] {
        assert!(
            screen
                .iter()
                .any(|row| row.trim_start().trim_start_matches("try: ") == hint),
            "hint `{hint}` not on a row of its own:\n{text}"
        );
    }
    assert!(text.contains("8E1"), "the line settings are cut:\n{text}");

    // A command: its outcome is listed and the new value highlighted for a moment.
    let sent = Command::new("mosquitto_pub")
        .args(["-h", "127.0.0.1", "-p", &port.to_string()])
        .args(["-t", "plant/dust_collector/gear/set", "-m", "8"])
        .status()
        .expect("mosquitto_pub runs (apt install mosquitto-clients)");
    assert!(sent.success());
    let (applied, screen) = tmux.wait_for(Duration::from_secs(30), |screen| {
        screen
            .iter()
            .any(|row| row.contains("dust_collector/gear ← 8: applied"))
    });
    assert!(applied, "no outcome:\n{}", screen.join("\n"));
    let marked = tmux
        .screen(true)
        .iter()
        .any(|row| row.contains("gear \u{1b}[7m8"));
    assert!(
        marked,
        "the new gear is not highlighted:\n{}",
        tmux.screen(true).join("\n")
    );
    assert_eq!(
        tmux.screen(false).last().map(String::as_str),
        Some("Ctrl-C stops")
    );

    let _ = tmux.run(&["send-keys", "-t", "demo", "C-c"]);
    let (stopped, screen) = tmux.wait_for(Duration::from_secs(30), |screen| {
        screen.iter().any(|row| row.starts_with("demo exited:"))
    });
    let text = screen.join("\n");
    assert!(stopped, "the demo did not stop on Ctrl-C:\n{text}");
    assert!(text.contains("demo exited: 0"), "{text}");
    assert!(text.contains("rtu2mqtt-demo stopped after"), "{text}");
}

#[test]
fn the_table_fits_80_by_24() {
    check_the_screen(80, 24);
}

#[test]
fn the_table_fits_200_by_60() {
    check_the_screen(200, 60);
}
