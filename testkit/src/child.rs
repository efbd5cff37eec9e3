//! Child processes of the tests: the gateway binary's `run` command line, a command's output
//! awaited on the blocking pool within a time limit (async tests have no tokio process driver:
//! the gateway is built without it), and a child killed and reaped on drop, which every test
//! that starts a process holds.

use std::os::unix::process::CommandExt as _;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

/// A binary of the workspace, built by `cargo test` beside the test executable that runs
/// (`target/<profile>/<name>`, the test being in `target/<profile>/deps/`).
pub fn binary(name: &str) -> PathBuf {
    let test = std::env::current_exe().expect("the test executable's path");
    let profile_dir = test
        .parent()
        .and_then(Path::parent)
        .expect("the test executable lies in target/<profile>/deps");
    let path = profile_dir.join(name);
    assert!(
        path.exists(),
        "{} is not built: run the tests with `cargo test` at the workspace root",
        path.display()
    );
    path
}

/// The gateway binary under test.
pub fn gateway_binary() -> PathBuf {
    binary("rtu2mqtt")
}

/// `rtu2mqtt run --config <config>` with stdin and stdout closed and stderr discarded; the
/// caller adds its environment and, to read the log, where stderr goes.
pub fn gateway_run(config: &Path) -> Command {
    let mut command = Command::new(gateway_binary());
    command
        .args(["run", "--config"])
        .arg(config)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    command
}

/// Starts `command` holding none of this process's descriptors beyond stdin, stdout and
/// stderr. Every test shares this process: a child forked while another test's pty was being
/// opened (before its ends are marked close-on-exec) would keep that pty's ends, and its
/// lock, for as long as it runs, so an unplugged line stays open and a plugged one cannot be
/// locked by the gateway.
fn spawn_clean(command: &mut Command) -> std::io::Result<Child> {
    // SAFETY: the closure runs in the forked child before exec and makes one
    // async-signal-safe system call that only closes that child's own descriptors.
    unsafe {
        command.pre_exec(|| {
            // An old kernel without close_range leaves the child as std would have.
            let _ = libc::syscall(libc::SYS_close_range, 3, libc::c_uint::MAX, 0);
            Ok(())
        });
    }
    command.spawn()
}

/// Runs `command` to its end and returns what it printed; a child still running after `limit`
/// is killed and the result is a `TimedOut` error (a hung child fails its test, never hangs it).
pub async fn output(mut command: Command, limit: Duration) -> std::io::Result<Output> {
    command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let child = spawn_clean(&mut command)?;
    let pid = Pid::from_raw(child.id() as i32);
    let mut waiting = tokio::task::spawn_blocking(move || child.wait_with_output());
    let finished = match tokio::time::timeout(limit, &mut waiting).await {
        Ok(finished) => finished,
        Err(_elapsed) => {
            let _ = kill(pid, Signal::SIGKILL);
            let _ = waiting.await;
            return Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                format!("{command:?} still ran after {limit:?}"),
            ));
        }
    };
    finished.map_err(std::io::Error::other)?
}

/// A child process killed (SIGKILL, which also ends a stopped one) and reaped when this is
/// dropped, so a failing test leaves no process behind.
pub struct KillOnDrop(pub Child);

impl KillOnDrop {
    /// Spawns `command` (holding no descriptor of the tests beyond its standard streams).
    pub fn spawn(mut command: Command) -> std::io::Result<Self> {
        spawn_clean(&mut command).map(KillOnDrop)
    }

    pub fn id(&self) -> u32 {
        self.0.id()
    }

    /// The process id, for signals.
    pub fn pid(&self) -> Pid {
        Pid::from_raw(self.0.id() as i32)
    }

    /// Whether it has not exited yet.
    pub fn is_running(&mut self) -> bool {
        matches!(self.0.try_wait(), Ok(None))
    }
}

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
