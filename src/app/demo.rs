//! `rtu2mqtt demo`: the seed plant with no hardware.

mod view;

use std::process::ExitCode;

pub fn demo(broker: Option<String>, port: u16, log: bool) -> anyhow::Result<ExitCode> {
    todo!("demo helper")
}
