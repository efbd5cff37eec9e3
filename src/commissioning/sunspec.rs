//! `rtu2mqtt sunspec`: finds a SunSpec device's map on a serial port or over TCP, walks its
//! model chain and writes a profile for it. The "SunS" marker is looked for at 40000, 0 and
//! 50000; from there each model's `ID` and `L` lead to the next, up to the end marker
//! (`ID` 0xFFFF). What was found (manufacturer, model, serial and version from model 1; every
//! model with its id, address and length) goes to standard error; the profile
//! (`profile::sunspec::write_profile`) to `--output` or standard output.
//!
//! Read functions only (FC03): this module never builds a write request.

use std::fmt::Write as _;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context as _};

use super::target::Target;
use crate::cli::{parse_parity, SunspecArgs};
use rtu2mqtt_modbus::link::Link;
use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_modbus::{Request, SlaveId, Transact};
use rtu2mqtt_profile::sunspec::{self, Chain, FoundModel, LineChoice};

/// More models than any device carries: a chain longer than this loops or is garbage.
const MAX_MODELS: usize = 64;

/// Reads `quantity` holding registers; an exception or a transport error is a plain error.
async fn read(
    link: &mut Link,
    address: SlaveId,
    start: u16,
    quantity: u16,
    timeout: Duration,
) -> anyhow::Result<Vec<u16>> {
    let request = Request::ReadHoldingRegisters { start, quantity };
    match link.transact(address, &request, timeout).await {
        Ok(Ok(response)) => match response.registers() {
            Some(words) if words.len() == usize::from(quantity) => Ok(words.to_vec()),
            _ => bail!("the answer to FC03 {start} ×{quantity} has the wrong shape"),
        },
        Ok(Err(code)) => bail!("FC03 {start} ×{quantity}: device answered {code}"),
        Err(error) => bail!("FC03 {start} ×{quantity}: {error}"),
    }
}

/// The base holding "SunS", trying 40000, 0 and 50000 in turn.
async fn find_base(link: &mut Link, address: SlaveId, timeout: Duration) -> anyhow::Result<u16> {
    let mut tried = Vec::new();
    for base in sunspec::BASES {
        match read(link, address, base, 2, timeout).await {
            Ok(words) if words == sunspec::MARKER => return Ok(base),
            Ok(words) => tried.push(format!("{base}: {:04X} {:04X}", words[0], words[1])),
            Err(error) => tried.push(format!("{base}: {error}")),
        }
    }
    bail!(
        "no SunSpec marker \"SunS\" at address {address} ({})",
        tried.join("; ")
    )
}

/// The model chain from `base` to the end marker, and model 1's identity.
async fn walk(
    link: &mut Link,
    address: SlaveId,
    base: u16,
    timeout: Duration,
) -> anyhow::Result<Chain> {
    let mut chain = Chain {
        base,
        ..Chain::default()
    };
    let mut at = u32::from(base) + 2;
    loop {
        let here = u16::try_from(at)
            .ok()
            .filter(|a| *a < u16::MAX)
            .with_context(|| format!("the model chain runs past register 65535 at {at}"))?;
        let header = read(link, address, here, 2, timeout).await?;
        let (id, length) = (header[0], header[1]);
        if id == sunspec::END_ID {
            break;
        }
        if chain.models.len() == MAX_MODELS {
            bail!("more than {MAX_MODELS} models without an end marker");
        }
        chain.models.push(FoundModel {
            id,
            address: here,
            length,
        });
        at += 2 + u32::from(length);
    }
    if let Some(common) = chain.models.iter().find(|m| m.id == 1).cloned() {
        let def = sunspec::model(1).context("model 1 missing from the SunSpec table")?;
        let length = common.length.min(125);
        let words = read(link, address, common.body(), length, timeout).await?;
        let text = |point: &str| -> String {
            let Some(def_point) = def.points.iter().find(|p| p.name == point) else {
                return String::new();
            };
            let from = def.offset_of(point).map_or(0, |o| usize::from(o) - 2);
            let to = (from + usize::from(def_point.size)).min(words.len());
            words
                .get(from..to)
                .map(sunspec::text_of)
                .unwrap_or_default()
        };
        chain.manufacturer = text("Mn");
        chain.model = text("Md");
        chain.serial = text("SN");
        chain.version = text("Vr");
    }
    Ok(chain)
}

/// What `sunspec` prints on standard error.
pub fn report(address: SlaveId, chain: &Chain) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "SunSpec map at address {address}, base {} (\"SunS\" at {}–{})",
        chain.base,
        chain.base,
        chain.base + 1
    );
    let _ = writeln!(out, "  manufacturer  {}", chain.manufacturer);
    let _ = writeln!(out, "  model         {}", chain.model);
    let _ = writeln!(out, "  serial        {}", chain.serial);
    let _ = writeln!(out, "  version       {}", chain.version);
    let _ = writeln!(out, "  models:");
    for found in &chain.models {
        let described = match sunspec::model(found.id) {
            Some(def) => match def.repeats(found.length) {
                Some(0) => def.label.clone(),
                Some(n) => format!("{}, {n} × {}", def.label, def_group(def)),
                None => format!("{}: length does not fit the model, not read", def.label),
            },
            None => "unknown model, not read".to_string(),
        };
        let _ = writeln!(
            out,
            "    {:>5}  at {:<5}  length {:<4} {described}",
            found.id, found.address, found.length
        );
    }
    out
}

fn def_group(def: &sunspec::Model) -> String {
    def.repeating
        .as_ref()
        .map_or_else(String::new, |g| g.name.clone())
}

fn parity_name(parity: Parity) -> &'static str {
    match parity {
        Parity::None => "none",
        Parity::Even => "even",
        Parity::Odd => "odd",
    }
}

pub fn sunspec(args: &SunspecArgs) -> anyhow::Result<ExitCode> {
    let parity = parse_parity(&args.parity)?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the runtime")?;
    let chain = runtime.block_on(async {
        // The serial stream registers with the runtime's reactor: opened inside it.
        let target = Target::of(args.link.port.as_deref(), args.link.url.as_deref())?;
        let mut link = target.open(args.baud, parity).await?;
        let base = find_base(&mut link, args.address, args.timeout).await?;
        walk(&mut link, args.address, base, args.timeout).await
    })?;
    eprint!("{}", report(args.address, &chain));
    let profile = sunspec::write_profile(
        &chain,
        &LineChoice {
            baud: args.baud,
            parity: parity_name(parity),
            address: args.address,
        },
    );
    match &args.output {
        Some(path) => {
            std::fs::write(path, &profile)
                .with_context(|| format!("writing {}", path.display()))?;
            eprintln!("profile written to {}", path.display());
        }
        None => {
            use std::io::Write as _;
            // A closed pipe (`rtu2mqtt sunspec … | head`) is not an error worth a panic.
            let _ = std::io::stdout().lock().write_all(profile.as_bytes());
        }
    }
    Ok(ExitCode::SUCCESS)
}
