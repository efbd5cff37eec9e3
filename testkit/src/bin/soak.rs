//! `soak DURATION [OUT_DIR] [SEED]`: the gateway under an hour (or any time) of chaos, see
//! `rtu2mqtt_testkit::soak`. Exits 1 when a check fails. The gateway binary is the `rtu2mqtt`
//! beside this one.

use std::path::PathBuf;
use std::process::ExitCode;

use rtu2mqtt_testkit::soak::{run, Options};

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(duration) = args
        .first()
        .and_then(|text| humantime::parse_duration(text).ok())
    else {
        eprintln!("usage: soak DURATION [OUT_DIR] [SEED]   (DURATION as 2m, 1h)");
        return ExitCode::from(2);
    };
    let out_dir = args
        .get(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("rtu2mqtt-soak"));
    let seed = args
        .get(2)
        .and_then(|text| text.parse().ok())
        .unwrap_or_else(rand::random);
    let daemon = std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(|dir| dir.join("rtu2mqtt")));
    let Some(daemon) = daemon.filter(|path| path.exists()) else {
        eprintln!("the rtu2mqtt binary is not beside this one: build it first (scripts/soak does)");
        return ExitCode::from(2);
    };
    let options = Options {
        duration,
        daemon,
        out_dir,
        seed,
    };
    eprintln!("soak: {options:?}");
    match run(&options).await {
        Ok(report) => {
            println!("{report}");
            if report.passed() {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            }
        }
        Err(error) => {
            eprintln!("soak could not run: {error:#}");
            ExitCode::FAILURE
        }
    }
}
