//! pymodbus, a Modbus implementation written by others, as the tests run it: the scripts of
//! `tests/interop/` as clients run to their end or as servers kept running, and snippets passed
//! to `python3 -c`. Every test that talks to pymodbus starts it here.

use std::ffi::OsStr;
use std::io::{BufRead as _, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use crate::broker::free_port;
use crate::child::{self, KillOnDrop};

/// The script `name` of the repository's `tests/interop/`.
pub fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/interop")
        .join(name)
}

/// `python3 tests/interop/<name>`, for the caller to give its arguments and streams.
pub fn command(name: &str) -> Command {
    let mut command = Command::new("python3");
    command.arg(script(name));
    command
}

/// Whether python3 can import pymodbus. In CI (`CI` set) a missing pymodbus fails the test:
/// there, the interoperability checks must run (`.ci/run` installs it).
pub fn available() -> bool {
    let available = Command::new("python3")
        .args(["-c", "import pymodbus"])
        .output()
        .is_ok_and(|output| output.status.success());
    if !available {
        assert!(
            std::env::var_os("CI").is_none(),
            "python3 with pymodbus is required in CI (pip install pymodbus)"
        );
        eprintln!("skipped: python3 with pymodbus is not installed (pip install pymodbus)");
    }
    available
}

/// Runs the client script `name` with `args` to its end (killed after `limit`) and returns what
/// it printed; a client that fails fails the test, with what it said.
pub async fn run_client<S: AsRef<OsStr>>(name: &str, args: &[S], limit: Duration) -> String {
    let mut client = command(name);
    client.args(args);
    let output = child::output(client, limit)
        .await
        .unwrap_or_else(|error| panic!("pymodbus client {name} did not run: {error}"));
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    assert!(
        output.status.success(),
        "pymodbus client {name} failed: {}\n{stdout}",
        String::from_utf8_lossy(&output.stderr)
    );
    stdout
}

/// Runs `code` with `python3 -c` and returns what it printed; a snippet that fails fails the
/// test, with what it said.
pub fn run_snippet(code: &str) -> Vec<u8> {
    let output = Command::new("python3")
        .args(["-c", code])
        .output()
        .expect("python3 runs");
    assert!(
        output.status.success(),
        "pymodbus: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    output.stdout
}

/// The server script `name` on a free loopback port (`name 127.0.0.1 PORT`), once it has
/// printed `listening`; it is killed when the returned child is dropped.
pub async fn server(name: &str) -> (KillOnDrop, u16) {
    let port = free_port();
    let mut command = command(name);
    command
        .args(["127.0.0.1", &port.to_string()])
        .stdout(Stdio::piped())
        .stderr(Stdio::null());
    let mut server = KillOnDrop::spawn(command).expect("python3 runs");
    let stdout = server
        .0
        .stdout
        .take()
        .expect("the server's stdout is piped");
    let ready = tokio::task::spawn_blocking(move || {
        let mut line = String::new();
        BufReader::new(stdout).read_line(&mut line).ok();
        line
    })
    .await
    .expect("the server's first line is read");
    assert_eq!(ready.trim(), "listening", "pymodbus server did not start");
    (server, port)
}
