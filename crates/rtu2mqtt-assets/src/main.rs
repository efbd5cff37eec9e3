//! `rtu2mqtt-assets DIR`: writes rtu2mqtt's manual pages (`DIR/man/*.1`) and shell completions
//! (`DIR/completions/`) for the package build, and lists what it wrote.

use std::path::PathBuf;
use std::process::ExitCode;

fn main() -> ExitCode {
    let mut args = std::env::args_os().skip(1);
    let (Some(dir), None) = (args.next(), args.next()) else {
        eprintln!("usage: rtu2mqtt-assets DIR");
        return ExitCode::from(2);
    };
    match rtu2mqtt_assets::write_all(&PathBuf::from(&dir)) {
        Ok(written) => {
            for path in written {
                println!("{}", path.display());
            }
            ExitCode::SUCCESS
        }
        Err(error) => {
            eprintln!("rtu2mqtt-assets: {}: {error}", PathBuf::from(dir).display());
            ExitCode::FAILURE
        }
    }
}
