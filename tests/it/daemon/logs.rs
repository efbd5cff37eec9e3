//! What `rtu2mqtt run` writes to stderr when stderr is no terminal (the journal, a file, a
//! pipe): plain text without ANSI escape codes, and without our own timestamp when systemd's
//! `JOURNAL_STREAM` says the journal stamps the lines.

use std::io::Read;
use std::process::Stdio;
use std::time::Duration;

use nix::sys::signal::{kill, Signal};

use crate::support::child::{self, KillOnDrop};
use crate::support::free_port;

/// Runs the daemon for a moment on a line whose port does not exist and a broker that does
/// not answer (both are logged at once), stops it with SIGTERM and returns its stderr.
fn daemon_stderr(extra_env: &[(&str, &str)]) -> String {
    let dir = tempfile::tempdir().expect("temp dir");
    let closed_port = free_port();
    let config = format!(
        r#"
[mqtt]
url = "mqtt://127.0.0.1:{closed_port}"
client_id = "log-test"

[[lines]]
name = "line-a"
port = "{missing}"

[[lines.devices]]
name = "dust_collector"
profile = "ruiwan-dust-collector"
address = 1
"#,
        missing = dir.path().join("no-such-port").display()
    );
    let config_path = dir.path().join("config.toml");
    std::fs::write(&config_path, config).expect("write config");
    let mut command = child::gateway_run(&config_path);
    command
        .env("RTU2MQTT__HEALTH__STATUS_FILE", dir.path().join("health"))
        .env_remove("NO_COLOR")
        .env_remove("JOURNAL_STREAM")
        .env_remove("RTU2MQTT_LOG_FORMAT")
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped());
    for (key, value) in extra_env {
        command.env(key, value);
    }
    let mut daemon = KillOnDrop::spawn(command).expect("rtu2mqtt run starts");
    std::thread::sleep(Duration::from_millis(2500));
    kill(daemon.pid(), Signal::SIGTERM).expect("SIGTERM");
    let mut stderr = String::new();
    daemon
        .0
        .stderr
        .take()
        .expect("piped stderr")
        .read_to_string(&mut stderr)
        .expect("read stderr");
    stderr
}

#[test]
fn logs_to_a_pipe_are_plain_text() {
    let stderr = daemon_stderr(&[]);
    assert!(
        stderr.contains("ERROR") || stderr.contains("WARN"),
        "the missing port and the closed broker are logged: {stderr}"
    );
    assert!(
        !stderr.contains('\u{1b}'),
        "ANSI escape codes in a log that is no terminal: {stderr:?}"
    );
    let first = stderr.lines().next().unwrap_or_default();
    assert!(
        first.starts_with(|c: char| c.is_ascii_digit()),
        "a line of a plain log starts with its timestamp: {first:?}"
    );
}

#[test]
fn under_the_journal_lines_carry_no_timestamp_of_their_own() {
    let stderr = daemon_stderr(&[("JOURNAL_STREAM", "8:4242")]);
    assert!(!stderr.contains('\u{1b}'), "{stderr:?}");
    let first = stderr.lines().next().unwrap_or_default();
    assert!(
        first.trim_start().starts_with("INFO")
            || first.trim_start().starts_with("WARN")
            || first.trim_start().starts_with("ERROR"),
        "the journal line starts with its level: {first:?}"
    );
}
