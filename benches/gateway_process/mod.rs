//! The gateway binary as a process of its own for the benches, and what /proc says about it:
//! CPU time, memory, bytes written to disk.

// Each bench compiles this module as its own and uses a part of it.
#![allow(dead_code)]

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// `name:` in a /proc file of `key: value` lines, the first number (0 when absent).
pub fn proc_field(text: &str, name: &str) -> u64 {
    text.lines()
        .find(|line| line.starts_with(name))
        .and_then(|line| line.split_whitespace().nth(1))
        .and_then(|value| value.parse::<u64>().ok())
        .unwrap_or(0)
}

/// User and system CPU time so far of `/proc/<pid>` (`self` for this process).
pub fn cpu_time_of(pid: &str) -> anyhow::Result<Duration> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))?;
    // The command name may hold spaces: the fields after it start behind the last ')'.
    let after_name = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest)
        .ok_or_else(|| anyhow::anyhow!("unreadable /proc stat"))?;
    let fields: Vec<&str> = after_name.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the line, 12 and 13 after the name.
    let ticks: u64 = fields
        .get(11..13)
        .ok_or_else(|| anyhow::anyhow!("short /proc stat"))?
        .iter()
        .map(|field| field.parse::<u64>().unwrap_or(0))
        .sum();
    // SAFETY: sysconf takes no pointers.
    let per_second = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as u64;
    Ok(Duration::from_secs_f64(ticks as f64 / per_second as f64))
}

/// What the gateway's memory costs the box: anonymous memory two ways, and PSS.
#[derive(Debug, Default, Clone, Copy)]
pub struct Memory {
    /// RssAnon from /proc/<pid>/status: heap and stacks resident.
    pub rss_anon_kib: u64,
    /// Private_Dirty from /proc/<pid>/smaps_rollup: pages only this process has written.
    pub private_dirty_kib: u64,
    /// Anonymous from /proc/<pid>/smaps_rollup: resident anonymous pages (heap, stacks).
    pub anonymous_kib: u64,
    /// Pss from /proc/<pid>/smaps_rollup: resident pages, shared ones divided among users.
    pub pss_kib: u64,
    pub threads: u64,
}

impl Memory {
    /// The higher of each figure.
    pub fn max(self, other: Memory) -> Memory {
        Memory {
            rss_anon_kib: self.rss_anon_kib.max(other.rss_anon_kib),
            private_dirty_kib: self.private_dirty_kib.max(other.private_dirty_kib),
            anonymous_kib: self.anonymous_kib.max(other.anonymous_kib),
            pss_kib: self.pss_kib.max(other.pss_kib),
            threads: self.threads.max(other.threads),
        }
    }
}

/// A gateway as its own process (`rtu2mqtt run --config <config>`, or another gateway's command),
/// stopped (SIGTERM, then SIGKILL after 5 s) when dropped.
pub struct GatewayProcess {
    child: Child,
}

impl GatewayProcess {
    pub fn start(binary: &Path, config: &Path, log: &str) -> anyhow::Result<GatewayProcess> {
        let mut command = Command::new(binary);
        command
            .arg("run")
            .arg("--config")
            .arg(config)
            .env("RUST_LOG", log);
        GatewayProcess::spawn(command)
    }

    /// Any gateway's `command`, its standard input and output closed, its errors on ours.
    pub fn spawn(mut command: Command) -> anyhow::Result<GatewayProcess> {
        let child = command
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()?;
        Ok(GatewayProcess { child })
    }

    /// The text of `/proc/<pid>/<file>`.
    pub fn proc(&self, file: &str) -> anyhow::Result<String> {
        Ok(std::fs::read_to_string(format!(
            "/proc/{}/{file}",
            self.child.id()
        ))?)
    }

    /// User and system CPU time so far (/proc/<pid>/stat, utime + stime).
    pub fn cpu_time(&self) -> anyhow::Result<Duration> {
        cpu_time_of(&self.child.id().to_string())
    }

    pub fn memory(&self) -> anyhow::Result<Memory> {
        let status = self.proc("status")?;
        let rollup = self.proc("smaps_rollup")?;
        Ok(Memory {
            rss_anon_kib: proc_field(&status, "RssAnon:"),
            private_dirty_kib: proc_field(&rollup, "Private_Dirty:"),
            anonymous_kib: proc_field(&rollup, "Anonymous:"),
            pss_kib: proc_field(&rollup, "Pss:"),
            threads: proc_field(&status, "Threads:"),
        })
    }

    /// Bytes this process caused to be written to the block layer (/proc/<pid>/io).
    pub fn write_bytes(&self) -> anyhow::Result<u64> {
        Ok(proc_field(&self.proc("io")?, "write_bytes:"))
    }

    pub fn stop(&mut self) {
        let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
        let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for GatewayProcess {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.stop();
        }
    }
}
