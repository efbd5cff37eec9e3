//! How late a sleeping line wakes up: the precise sleep against a plain tokio sleep, 200 waits
//! of 1–4 ms (the range of the line's t3.5 silences and turnarounds) on a current_thread
//! runtime; and a byte through a pseudo-terminal (the stand-in for a UART in the benches), from
//! the write on one side to its reader on the other, once for a reader that sleeps until the
//! reactor reports it (as the gateway and the simulators do) and once for one that keeps
//! reading. A simulated line's idle gap holds the second twice over (the gateway hears the
//! answer's last byte, the simulator the request's first) on top of t3.5. Prints figures;
//! asserts nothing (that the sleep never returns early is a unit test of `rtu::clock`).
//!
//! Run: `cargo bench --bench timer_overshoot` (about 4 s).

use std::os::fd::{AsRawFd, OwnedFd};
use std::time::Duration;

use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;
use tokio::time::Instant;

use rtu2mqtt_modbus::clock::sleep_until_precise;

const ROUNDS: u64 = 200;

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let (precise, plain) = runtime.block_on(measure());
    println!(
        "overshoot precise: median {:?} p99 {:?} max {:?}; tokio sleep: median {:?} p99 {:?} max {:?}",
        percentile(&precise, 50),
        percentile(&precise, 99),
        percentile(&precise, 100),
        percentile(&plain, 50),
        percentile(&plain, 99),
        percentile(&plain, 100),
    );
    for (reader, watching) in [
        ("sleeping on the reactor", false),
        ("reading all along", true),
    ] {
        let delays = runtime.block_on(byte_through_a_pty(watching))?;
        println!(
            "a byte through a pseudo-terminal, reader {reader}: median {:?} p90 {:?} p99 {:?}",
            percentile(&delays, 50),
            percentile(&delays, 90),
            percentile(&delays, 99),
        );
    }
    Ok(())
}

/// Sorted delays from the write of a byte on a pseudo-terminal's master to its read on the
/// other side, one byte every 4 ms from another thread; the reader waits on the runtime's
/// reactor, or (`watching`) reads again and again until the byte is there.
async fn byte_through_a_pty(watching: bool) -> anyhow::Result<Vec<Duration>> {
    let pty = nix::pty::openpty(None, None)?;
    for side in [&pty.master, &pty.slave] {
        let mut attributes = tcgetattr(side)?;
        cfmakeraw(&mut attributes);
        tcsetattr(side, SetArg::TCSANOW, &attributes)?;
    }
    fcntl(pty.slave.as_raw_fd(), FcntlArg::F_SETFL(OFlag::O_NONBLOCK))?;
    // SAFETY: the AsyncFd owns the descriptor, so it stays open and the same until the AsyncFd
    // is dropped.
    let reader = unsafe { AsyncFd::register_with_interest(pty.slave, Interest::READABLE) }
        .map_err(std::io::Error::from)?;
    let writer: OwnedFd = pty.master;
    let (sent, mut written_at) = tokio::sync::mpsc::unbounded_channel();
    // The next byte is written only once the reader has taken the last, so that every read
    // takes one byte.
    let (taken, next) = std::sync::mpsc::channel::<()>();
    let writing = std::thread::spawn(move || -> nix::Result<()> {
        for _ in 0..ROUNDS {
            std::thread::sleep(Duration::from_millis(4));
            let at = Instant::now();
            nix::unistd::write(&writer, b"x")?;
            if sent.send(at).is_err() || next.recv().is_err() {
                break;
            }
        }
        Ok(())
    });
    let mut delays = Vec::new();
    let mut byte = [0u8; 16];
    while delays.len() < ROUNDS as usize {
        let read_at = loop {
            if watching {
                if matches!(
                    nix::unistd::read(reader.get_ref().as_raw_fd(), &mut byte),
                    Ok(1..)
                ) {
                    break Instant::now();
                }
                std::hint::spin_loop();
                continue;
            }
            let mut ready = reader.readable().await?;
            // A read that would block clears the readiness (`Err`), and the reactor is asked
            // again.
            let read = ready.try_io(|fd| {
                nix::unistd::read(fd.get_ref().as_raw_fd(), &mut byte).map_err(std::io::Error::from)
            });
            match read {
                Ok(Ok(0)) => anyhow::bail!("the pseudo-terminal closed"),
                Ok(Ok(_)) => break Instant::now(),
                Ok(Err(error)) => return Err(error.into()),
                Err(_would_block) => {}
            }
        };
        let Some(at) = written_at.recv().await else {
            break;
        };
        delays.push(read_at.saturating_duration_since(at));
        if taken.send(()).is_err() {
            break;
        }
    }
    writing
        .join()
        .map_err(|_| anyhow::anyhow!("the writing thread panicked"))??;
    delays.sort();
    Ok(delays)
}

/// Sorted overshoots of the precise sleep and of tokio's, waits interleaved.
async fn measure() -> (Vec<Duration>, Vec<Duration>) {
    let mut precise = Vec::new();
    let mut plain = Vec::new();
    for round in 0..ROUNDS {
        let wait = Duration::from_micros(1000 + (round * 37) % 3000);
        let deadline = Instant::now() + wait;
        sleep_until_precise(deadline).await;
        precise.push(Instant::now() - deadline);
        let deadline = Instant::now() + wait;
        tokio::time::sleep_until(deadline).await;
        plain.push(Instant::now() - deadline);
    }
    precise.sort();
    plain.sort();
    (precise, plain)
}

/// The `percent`-th percentile of sorted figures (100: the worst).
fn percentile(sorted: &[Duration], percent: usize) -> Duration {
    let index = (sorted.len() * percent / 100).min(sorted.len().saturating_sub(1));
    sorted.get(index).copied().unwrap_or_default()
}
