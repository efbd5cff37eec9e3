//! Two minutes of the soak run that `scripts/soak` runs for an hour (docs/reliability.md): the
//! gateway binary over the seed plant and 100 Modbus TCP devices, with line server clients,
//! MQTT commands, broker outages, a device drop-out, SIGHUP reloads and a journal outage; every
//! end check must pass.

use std::time::Duration;

use crate::support;
use support::soak::{run, Options};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_minutes_of_chaos_pass_every_end_check() {
    let dir = tempfile::tempdir().expect("out dir");
    let options = Options {
        duration: Duration::from_secs(120),
        daemon: support::child::gateway_binary(),
        out_dir: dir.path().join("soak"),
        seed: rand::random(),
    };
    let report = run(&options).await.expect("the soak run");
    println!("{report}");
    assert!(report.passed(), "{report}");
    let figures = std::fs::read_to_string(dir.path().join("soak/samples.csv")).unwrap_or_default();
    assert!(
        figures.lines().count() > 40,
        "sampled every 2 s:\n{figures}"
    );
}
