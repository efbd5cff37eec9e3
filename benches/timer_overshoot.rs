//! How late the line's precise sleep returns, against a plain tokio sleep: 200 waits of 1–4 ms
//! (the range of the line's t3.5 silences and turnarounds) on a current_thread runtime. Prints
//! figures; asserts nothing (that the sleep never returns early is a unit test of
//! `rtu::clock`).
//!
//! Run: `cargo bench --bench timer_overshoot` (about 1 s).

use std::time::Duration;

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
    Ok(())
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
