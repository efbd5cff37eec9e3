//! The scan itself: every setting and address probed in turn, each device found identified,\nand the table and the configuration to copy printed.

use super::super::read::read_request;
use super::super::target::Target;
use super::identities;
use crate::cli::{parse_parity, ScanArgs};
use crate::config::suggestion::{Candidates, LinkPlace};
use anyhow::{bail, Context as _};
use rtu2mqtt_modbus::link::Link;
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_modbus::{Error as LinkError, WireCounters};
use rtu2mqtt_modbus::{ExceptionCode, Request, SlaveId, Transact};
use rtu2mqtt_profile::identify::Identity;
use std::fmt::Write as _;
use std::process::ExitCode;
use std::time::{Duration, Instant};

/// What one address answered at one serial setting.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Found {
    pub address: SlaveId,
    pub baud: u32,
    pub parity: Parity,
    /// One entry per read function probed: `FC03 ok`, `FC03 exception 02 (…)`, ….
    pub answers: Vec<String>,
    /// What it said it is, asked the first time a device answered at this address.
    pub identity: Option<Identity>,
}

/// Parses `1-247`, `1,2,0x81` or a mix of both.
pub fn parse_addresses(text: &str) -> anyhow::Result<Vec<SlaveId>> {
    crate::cli::parse_addresses(text).map_err(anyhow::Error::msg)
}

/// `8N1`, `8E1`: the character format a scan tries (8 data bits, 1 stop bit).
fn format_name(parity: Parity) -> CharFormat {
    CharFormat {
        data_bits: 8,
        parity,
        stop_bits: 1,
    }
}

/// How long a freshly opened line may take to fall silent before the first probe.
const OPENING_PATIENCE: Duration = Duration::from_secs(2);
/// Bytes of the probe request (address, function, start, count, CRC).
const PROBE_REQUEST_LEN: usize = 8;
/// The least a probe waits for an answer to start: a device may take a few milliseconds to
/// decide, and a USB adapter hands bytes over in latency-timer batches.
const QUICK_WAIT_FLOOR: Duration = Duration::from_millis(20);
/// A device answers within a few character times of the request's end (plus t3.5).
const ANSWER_START_CHARS: u32 = 4;

/// How long a probe on a serial port waits for an answer to start before the address counts
/// as silent. A UART's drain takes the request's wire time before the wait begins; a pty's
/// does not, so the wait covers the request's wire time too, then t3.5 and a few character
/// times, and never less than the floor.
pub fn quick_wait(timing: &LineTiming) -> Duration {
    QUICK_WAIT_FLOOR.max(
        timing.frame_time(PROBE_REQUEST_LEN) + timing.t3_5 + timing.char_time * ANSWER_START_CHARS,
    )
}

/// What the master heard that answered none of its probes: late answers (its own
/// attribution: bytes after a timeout, or a frame from the address that timed out last) and
/// frames for other addresses (a late answer that came only after a further probe had
/// timed out, or an answer garbled at another setting).
fn unclaimed(counters: WireCounters) -> (u64, u64) {
    (counters.late_answers, counters.wrong_address)
}

/// How a probe went.
enum Probe {
    Answered(String),
    Garbled(String),
    Silent,
}

async fn probe(
    master: &mut Link,
    address: SlaveId,
    request: &Request,
    timeout: Duration,
) -> anyhow::Result<Probe> {
    let function = request.function().value();
    Ok(match master.transact(address, request, timeout).await {
        Ok(Ok(_)) => Probe::Answered(format!("FC{function:02} ok")),
        // A Modbus TCP gateway's answer in the device's place: nothing answered there.
        Ok(Err(ExceptionCode::GatewayPathUnavailable))
        | Ok(Err(ExceptionCode::GatewayTargetFailedToRespond)) => Probe::Silent,
        Ok(Err(code)) => Probe::Answered(format!("FC{function:02} {code}")),
        Err(LinkError::Timeout(_)) => Probe::Silent,
        Err(LinkError::PortGone(fault)) => return Err(fault).context("serial port"),
        Err(other) => Probe::Garbled(other.to_string()),
    })
}

/// Probes `address` on `master`: FC03 (waiting `first_wait` for the answer to start), and
/// FC04/FC01 when FC03 was refused.
async fn probe_address(
    master: &mut Link,
    address: SlaveId,
    first_wait: Duration,
    timeout: Duration,
) -> anyhow::Result<(Vec<String>, Option<String>)> {
    let first = read_request(3, 0, 1)?;
    match probe(master, address, &first, first_wait).await? {
        Probe::Silent => Ok((Vec::new(), None)),
        Probe::Garbled(why) => Ok((Vec::new(), Some(why))),
        Probe::Answered(answer) => {
            let refused = !answer.ends_with(" ok");
            let mut answers = vec![answer];
            if refused {
                for function in [4, 1] {
                    if let Probe::Answered(more) =
                        probe(master, address, &read_request(function, 0, 1)?, timeout).await?
                    {
                        answers.push(more);
                    }
                }
            }
            Ok((answers, None))
        }
    }
}

pub fn scan(args: &ScanArgs) -> anyhow::Result<ExitCode> {
    let addresses = parse_addresses(&args.addresses)?;
    let candidates = candidates(args.profiles.as_deref())?;
    let parities = args
        .parity
        .iter()
        .map(|p| parse_parity(p))
        .collect::<anyhow::Result<Vec<_>>>()?;
    if args.baud.is_empty() || parities.is_empty() {
        bail!("nothing to scan: give at least one baud rate and one parity");
    }
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the runtime")?;
    let started = Instant::now();
    let (found, garbled, interrupted) = runtime.block_on(async {
        let mut found = Vec::new();
        let mut garbled = Vec::new();
        let ctrl_c = tokio::signal::ctrl_c();
        tokio::pin!(ctrl_c);
        let work = run_scan(args, &addresses, &parities, &mut found, &mut garbled);
        tokio::select! {
            result = work => result.map(|()| false),
            _ = &mut ctrl_c => Ok(true),
        }
        .map(|interrupted| (found, garbled, interrupted))
    })?;
    if interrupted {
        eprintln!("\nscan interrupted: partial results");
    }
    let target = Target::of(args.link.port.as_deref(), args.link.url.as_deref())?;
    let modbus_tcp = target.is_modbus_tcp()?;
    let through = if modbus_tcp {
        format!(
            "through the Modbus TCP gateway {}",
            args.link.url.as_deref().unwrap_or("")
        )
    } else {
        let settings = args.baud.len() * parities.len();
        format!(
            "at {settings} serial setting{}",
            if settings == 1 { "" } else { "s" }
        )
    };
    eprintln!(
        "scanned {} address{} {through} in {:.1} s",
        addresses.len(),
        if addresses.len() == 1 { "" } else { "es" },
        started.elapsed().as_secs_f64()
    );
    print!("{}", table(&found, modbus_tcp));
    if !garbled.is_empty() {
        println!("\ngarbled answers (something is there at another setting, or noise):");
        for line in &garbled {
            println!("  {line}");
        }
    }
    if !found.is_empty() {
        println!("\nwhat the devices say they are:");
        print!("{}", identities::table(&found, &candidates));
        let place = match target {
            Target::Port(path) => LinkPlace::Port(path.display().to_string()),
            Target::Url(url) => LinkPlace::Url(url.to_string()),
        };
        println!("\na configuration to copy (docs/configuration.md):\n");
        print!(
            "{}",
            identities::suggestion(&found, &candidates, &place, modbus_tcp)
        );
    }
    if let Some(profile) = &args.profile {
        if !interrupted {
            runtime.block_on(show_profile(args, profile, &found))?;
        }
    }
    Ok(if found.is_empty() {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

/// The built-in profiles and those in `directory` (every `*.toml` file), which a scan may
/// name for a device.
fn candidates(directory: Option<&std::path::Path>) -> anyhow::Result<Candidates> {
    let mut candidates = Candidates::built_in();
    let Some(directory) = directory else {
        return Ok(candidates);
    };
    let entries = std::fs::read_dir(directory)
        .with_context(|| format!("reading the profiles in {}", directory.display()))?;
    let mut paths: Vec<std::path::PathBuf> = entries
        .filter_map(|entry| entry.ok().map(|entry| entry.path()))
        .filter(|path| path.extension().is_some_and(|ext| ext == "toml"))
        .collect();
    paths.sort();
    for path in paths {
        match rtu2mqtt_profile::registry::load_file(&path) {
            Ok(profile) => candidates.add(profile, path.display().to_string()),
            Err(error) => eprintln!("skipping {}: {error}", path.display()),
        }
    }
    Ok(candidates)
}

async fn run_scan(
    args: &ScanArgs,
    addresses: &[SlaveId],
    parities: &[Parity],
    found: &mut Vec<Found>,
    garbled: &mut Vec<String>,
) -> anyhow::Result<()> {
    let target = Target::of(args.link.port.as_deref(), args.link.url.as_deref())?;
    // A Modbus TCP gateway has one serial setting, its own: probed once.
    let (bauds, parities) = if target.is_modbus_tcp()? {
        (
            &args.baud[..args.baud.len().min(1)],
            &parities[..parities.len().min(1)],
        )
    } else {
        (&args.baud[..], parities)
    };
    let settings = bauds.len() * parities.len();
    let serial = matches!(target, Target::Port(_));
    let mut setting_index = 0;
    for &baud in bauds {
        for &parity in parities {
            setting_index += 1;
            let mut master = target.open(baud, parity).await?;
            // A freshly opened line is first heard out for longer than a quick probe waits
            // (an answer from before may still be on it).
            // A line that never falls silent is probed all the same: the probes report what
            // they hear.
            if let Err(LinkError::PortGone(fault)) = master.wait_until_quiet(OPENING_PATIENCE).await
            {
                return Err(fault).context("serial port");
            }
            let quick = if serial {
                quick_wait(&LineTiming::new(baud, format_name(parity))).min(args.timeout)
            } else {
                args.timeout
            };
            // Addresses probed quickly and found silent, with when their probe ended: a late
            // answer heard since is one of theirs.
            let mut silent: Vec<(SlaveId, Instant)> = Vec::new();
            for (i, &address) in addresses.iter().enumerate() {
                eprint!(
                    "\rscanning {baud} {} ({setting_index}/{settings}): address {address} ({}/{}), {} found   ",
                    format_name(parity),
                    i + 1,
                    addresses.len(),
                    found.len()
                );
                let last = i + 1 == addresses.len();
                let first_wait = if last { args.timeout } else { quick };
                let (late_before, foreign_before) = unclaimed(master.counters());
                let mut outcome =
                    probe_address(&mut master, address, first_wait, args.timeout).await?;
                let (late_after, foreign_after) = unclaimed(master.counters());
                if late_after > late_before || foreign_after > foreign_before {
                    // Whoever answered late answered within the full timeout of its request:
                    // every address left silent since then is heard again with the full wait.
                    let since = Instant::now().checked_sub(args.timeout * 2);
                    for (previous, _) in silent
                        .drain(..)
                        .filter(|&(_, ended)| since.map_or(true, |since| ended >= since))
                    {
                        let again =
                            probe_address(&mut master, previous, args.timeout, args.timeout)
                                .await?;
                        if record(found, garbled, previous, baud, parity, again) {
                            identify_last(&mut master, found, args.timeout).await?;
                        }
                    }
                }
                if late_after > late_before && outcome.0.is_empty() && outcome.1.is_none() {
                    // A late answer came while this address was probed and may have collided
                    // with its answer: it is heard again with the full wait.
                    outcome =
                        probe_address(&mut master, address, args.timeout, args.timeout).await?;
                }
                if outcome.0.is_empty() && outcome.1.is_none() {
                    silent.push((address, Instant::now()));
                }
                if record(found, garbled, address, baud, parity, outcome) {
                    identify_last(&mut master, found, args.timeout).await?;
                }
            }
        }
    }
    eprintln!();
    Ok(())
}

/// Asks the device found last what it is, at the setting it was found at.
async fn identify_last(
    master: &mut Link,
    found: &mut [Found],
    timeout: Duration,
) -> anyhow::Result<()> {
    let Some(device) = found.last_mut() else {
        return Ok(());
    };
    let timing = LineTiming::new(device.baud, format_name(device.parity));
    let timeout = identities::identification_timeout(timeout, &timing);
    device.identity = Some(identities::identify(master, device.address, timeout).await?);
    Ok(())
}

/// Notes what one address answered (if anything) at one setting; true when a device answered
/// at an address where none had answered before (at any setting).
fn record(
    found: &mut Vec<Found>,
    garbled: &mut Vec<String>,
    address: SlaveId,
    baud: u32,
    parity: Parity,
    (answers, garble): (Vec<String>, Option<String>),
) -> bool {
    if let Some(why) = garble {
        garbled.push(format!(
            "address {address} ({address:#04x}) at {baud} {}: {why}",
            format_name(parity)
        ));
    }
    if answers.is_empty() {
        return false;
    }
    let first_here = !found.iter().any(|device| device.address == address);
    found.push(Found {
        address,
        baud,
        parity,
        answers,
        identity: None,
    });
    first_here
}

/// The table of what answered where (behind a Modbus TCP gateway the serial setting is the
/// gateway's own, not the scan's: it is left out).
pub fn table(found: &[Found], modbus_tcp: bool) -> String {
    let mut out = String::new();
    if found.is_empty() {
        out.push_str("no device answered\n");
        return out;
    }
    if modbus_tcp {
        out.push_str("address     answers\n");
        for device in found {
            let _ = writeln!(
                out,
                "{:>3} ({:#04x})  {}",
                device.address,
                device.address,
                device.answers.join("; ")
            );
        }
        return out;
    }
    out.push_str("address       baud  format  answers\n");
    for device in found {
        let _ = writeln!(
            out,
            "{:>3} ({:#04x})  {:>6}  {}     {}",
            device.address,
            device.address,
            device.baud,
            format_name(device.parity),
            device.answers.join("; ")
        );
    }
    out
}

/// Reads `profile`'s blocks at each address found (at the setting it was found at) and prints
/// the decoded fields.
async fn show_profile(args: &ScanArgs, name: &str, found: &[Found]) -> anyhow::Result<()> {
    let profile = rtu2mqtt_profile::registry::load(name, None)
        .with_context(|| format!("loading profile `{name}`"))?;
    for device in found {
        println!(
            "\n{} at address {} ({} {}):",
            profile.name(),
            device.address,
            device.baud,
            format_name(device.parity)
        );
        let target = Target::of(args.link.port.as_deref(), args.link.url.as_deref())?;
        let mut master = target.open(device.baud, device.parity).await?;
        for (index, block) in profile.read_blocks().iter().enumerate() {
            if !block.request.is_read() {
                continue;
            }
            match master
                .transact(
                    device.address,
                    &block.request,
                    args.timeout.max(Duration::from_millis(200)),
                )
                .await
            {
                Ok(Ok(response)) => {
                    for reading in profile.decode_block(index, &response) {
                        let value = match &reading.value {
                            Ok(value) => value.to_text(),
                            Err(error) => format!("({error})"),
                        };
                        println!("  {:<28} {value}", reading.field);
                    }
                }
                Ok(Err(code)) => println!("  block `{}`: device answered {code}", block.name),
                Err(error) => println!("  block `{}`: {error}", block.name),
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_parse() {
        assert_eq!(parse_addresses("1-3").unwrap(), vec![1, 2, 3]);
        assert_eq!(parse_addresses("1,2,0x81").unwrap(), vec![1, 2, 0x81]);
        assert_eq!(parse_addresses("5, 1-2").unwrap(), vec![5, 1, 2]);
        assert!(parse_addresses("0-3").is_err());
        assert!(parse_addresses("3-1").is_err());
        assert!(parse_addresses("x").is_err());
        assert!(parse_addresses("").is_err());
    }

    #[test]
    fn table_lists_each_find() {
        let found = [Found {
            address: 0x81,
            baud: 19200,
            parity: Parity::None,
            answers: vec!["FC01 ok".into()],
            identity: None,
        }];
        let text = table(&found, false);
        assert!(
            text.contains("129 (0x81)   19200  8N1     FC01 ok"),
            "{text}"
        );
        let behind_a_gateway = table(&found, true);
        assert_eq!(
            behind_a_gateway,
            "address     answers\n129 (0x81)  FC01 ok\n"
        );
    }
}
