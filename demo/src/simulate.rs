//! `rtu2mqtt-demo simulate`: one simulated device or a seed plant line on a serial port (a socat pty
//! or a real adapter for bench tests) or behind a TCP port (`--listen tcp://…` or
//! `modbus-tcp://…`). The three seed devices by their profile names, the device library's by
//! theirs (`eastron-sdm120`, `sunspec-inverter`, … from their register maps); any other profile
//! (built-in name or file) as a generic device built from its read blocks. Logs every request;
//! Ctrl-C stops.

use std::future::Future;
use std::path::Path;
use std::pin::Pin;
use std::process::ExitCode;
use tokio_util::sync::CancellationToken;

use anyhow::{bail, Context};

use crate::cli::SimulateArgs;
use rtu2mqtt::cli::parse_parity;
use rtu2mqtt_modbus::timing::Parity;
use rtu2mqtt_sim::faults::FaultHandle;
use rtu2mqtt_sim::{
    share, AirShower, AsyncSerial, DustCollector, Journal, ServeOptions, SharedDevice, Valve,
};

/// The simulated device for `profile` at `address` (the profile's usual address if None).
pub fn device_for_profile(profile: &str, address: Option<u8>) -> anyhow::Result<SharedDevice> {
    Ok(match profile {
        "ruiwan-dust-collector" => share(DustCollector::new(address.unwrap_or(1))).1,
        "wuzhou-valve" => {
            let address = address.unwrap_or(1);
            if !(1..=253).contains(&address) {
                bail!("the valve takes addresses 1–253, not {address}");
            }
            share(Valve::new(address)).1
        }
        "lixian-air-shower" => {
            if address.is_some_and(|a| a != rtu2mqtt_sim::air_shower::ADDRESS) {
                bail!("the air shower's address is fixed at 0x81");
            }
            share(AirShower::new()).1
        }
        other => match rtu2mqtt_sim::library::device(other) {
            Some(library) => share(library.map.device(address.unwrap_or(1))).1,
            None => generic_device(other, address)?,
        },
    })
}

fn generic_device(profile: &str, address: Option<u8>) -> anyhow::Result<SharedDevice> {
    let profile = rtu2mqtt_profile::registry::load(profile, None)
        .with_context(|| format!("loading profile `{profile}`"))?;
    let address = address
        .or(profile.default_address())
        .unwrap_or(*profile.limits().address_range.start());
    if !profile.limits().address_range.contains(&address) {
        bail!(
            "address {address} is outside the profile's range {:?}",
            profile.limits().address_range
        );
    }
    Ok(share(rtu2mqtt_sim::GenericDevice::from_profile(&profile, address)).1)
}

/// The devices `simulate` serves: one profile's device, or a seed plant line.
fn devices_for(args: &SimulateArgs) -> anyhow::Result<Vec<SharedDevice>> {
    match (&args.seed_line, &args.profile) {
        (Some(line), _) => match line.to_ascii_lowercase().as_str() {
            "a" => Ok(vec![
                share(DustCollector::new(1)).1,
                share(AirShower::new()).1,
            ]),
            "b" => Ok(vec![share(Valve::new(1)).1]),
            other => bail!("seed line `{other}`: expected a or b"),
        },
        (None, Some(profile)) => Ok(vec![device_for_profile(profile, args.address)?]),
        (None, None) => bail!("give --profile or --seed-line"),
    }
}

pub fn simulate(args: &SimulateArgs) -> anyhow::Result<ExitCode> {
    let parity = parse_parity(&args.parity)?;
    let devices = devices_for(args)?;
    let options = ServeOptions::new(args.baud, parity).pacing(args.pace);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the runtime")?;
    runtime.block_on(async move {
        let shutdown = CancellationToken::new();
        let trigger = shutdown.clone();
        let (journal, served): (Journal, Pin<Box<dyn Future<Output = anyhow::Result<()>>>>) =
            match (&args.listen, &args.port) {
                (Some(url), _) => {
                    let Some((protocol, address)) = rtu2mqtt_sim::tcp::Protocol::parse_url(url) else {
                        bail!("--listen `{url}`: expected tcp://HOST:PORT or modbus-tcp://HOST:PORT");
                    };
                    let mut simulator =
                        rtu2mqtt_sim::TcpSimulator::bind(address, protocol, options, devices)
                            .await
                            .with_context(|| format!("listening on {url}"))?;
                    tracing::info!(url = %simulator.url(), baud = args.baud, %parity, "simulating");
                    let journal = simulator.journal().clone();
                    let stopper = simulator.stopper();
                    let shutdown = shutdown;
                    let served = async move {
                        tokio::select! {
                            _ = simulator.wait() => {}
                            _ = shutdown.cancelled() => stopper.cancel(),
                        }
                        Ok(())
                    };
                    (journal, Box::pin(served))
                }
                (None, Some(port)) => {
                    let stream = open_port(port, args.baud, parity)?;
                    tracing::info!(
                        port = %port.display(), baud = args.baud, %parity, pace = %args.pace,
                        "simulating"
                    );
                    let journal = Journal::new();
                    let served = rtu2mqtt_sim::serve(stream, options, devices, FaultHandle::default(), journal.clone(), shutdown);
                    let label = port.display().to_string();
                    (journal, Box::pin(async move { served.await.with_context(|| format!("serving {label}")) }))
                }
                (None, None) => bail!("give --port or --listen"),
            };
        tokio::spawn(async move {
            if tokio::signal::ctrl_c().await.is_ok() {
                trigger.cancel();
            }
        });
        tokio::pin!(served);
        // Log each request as it comes, while serving.
        let mut ticker = tokio::time::interval(std::time::Duration::from_millis(100));
        let result = loop {
            tokio::select! {
                result = &mut served => break result,
                _ = ticker.tick() => {
                    for record in journal.drain_requests() {
                        tracing::info!(
                            request = %rtu2mqtt_modbus::codec::hex(&record.frame),
                            answer = %record.answer.as_deref().map(rtu2mqtt_modbus::codec::hex).unwrap_or_else(|| "-".into()),
                            crc_ok = record.crc_ok,
                            "frame"
                        );
                    }
                }
            }
        };
        result?;
        tracing::info!("simulator stopped");
        Ok(ExitCode::SUCCESS)
    })
}

/// Opens `port` with the line's settings. A pseudo-terminal that refuses the parity setting is
/// used anyway with a warning (ptys carry no parity); a real port must accept it.
fn open_port(port: &Path, baud: u32, parity: Parity) -> anyhow::Result<AsyncSerial> {
    let path = port.to_string_lossy().into_owned();
    let builder = |parity: Parity| {
        mio_serial::new(path.clone(), baud)
            .data_bits(mio_serial::DataBits::Eight)
            .stop_bits(mio_serial::StopBits::One)
            .parity(match parity {
                Parity::None => mio_serial::Parity::None,
                Parity::Even => mio_serial::Parity::Even,
                Parity::Odd => mio_serial::Parity::Odd,
            })
    };
    match AsyncSerial::open(&builder(parity)) {
        Ok(stream) => Ok(stream),
        Err(error) if parity != Parity::None && is_pty(port) => {
            tracing::warn!(%error, "the pseudo-terminal refuses parity; running without (ptys carry none)");
            AsyncSerial::open(&builder(Parity::None)).with_context(|| format!("opening {path}"))
        }
        Err(error) => Err(error).with_context(|| format!("opening {path}")),
    }
}

fn is_pty(port: &Path) -> bool {
    std::fs::canonicalize(port)
        .map(|real| real.starts_with("/dev/pts"))
        .unwrap_or(false)
}
