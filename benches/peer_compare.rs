//! rtu2mqtt beside the C++ gateway mqmgateway, in one run against one simulated device: the
//! same pseudo-terminal at 9600 8N1 whose answers are released byte by byte at the character
//! rate, one 6-register block polled back to back, 40 writes of a holding register through
//! MQTT in a 30 s window. The gateways take turns on the line (which one goes first alternates
//! from round to round); each runs as its own process against a real mosquitto.
//!
//! Printed for each gateway: its CPU in % of one core (utime + stime from /proc/<pid>/stat over
//! the window), transactions/s (from the simulator's journal), CPU per transaction (also round
//! by round), its CPU as a ratio to the simulator's (this process: the simulator and the bench's
//! two MQTT clients, the same for both gateways), anonymous memory and PSS
//! (/proc/<pid>/smaps_rollup), the idle gap before a request against t3.5 (also round by round)
//! and the requests sent sooner; and command → new value on MQTT
//! p50 / p95 beside its bound, from the frames' lengths at 9600: rtu2mqtt's `…/result` comes
//! after a read-back (bound: the transaction in flight, the write and its echo, the read-back
//! and its answer, with t3.5 before each frame), mqmgateway's `state` carries the value it
//! wrote as soon as the write's echo came (bound: in flight, the write and its echo).
//!
//! mqmgateway is found through `MQMGATEWAY=/path/to/modmqttd` (`scripts/build-peer` builds
//! one); without it the bench measures rtu2mqtt alone and says so. Another build of rtu2mqtt is
//! measured with `PEER_COMPARE_GATEWAY=/path/to/rtu2mqtt`, and one more beside it in the same
//! run (a build before a change) with `PEER_COMPARE_BASELINE=/path/to/rtu2mqtt`. Rounds: 3, or
//! `PEER_COMPARE_ROUNDS`; each figure is the median over them with the range beside it.
//! Prints figures; asserts nothing. Run: `MQMGATEWAY=… cargo bench --bench peer_compare`
//! (about 40 s per gateway and round after the build).

mod block_device;
mod gateway_process;
use rtu2mqtt_testkit as support;
mod wire_bench;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use block_device::{
    command_window, millis, ms_f, over_rounds, profile_text, spawn_line, transaction_wire_time,
    wire_figures, BenchLine, ResultAfter, Window, Wire, Writes, BAUD,
};
use gateway_process::GatewayProcess;
use rtu2mqtt_modbus::timing::LineTiming;
use rtu2mqtt_profile::Profile;
use rtu2mqtt_sim::Pace;
use rumqttc::QoS;
use support::{Mosquitto, PacedPymodbus};
use wire_bench::{command_client, percentile, timed_subscriber, EIGHT_N_ONE};

const WARM_UP: Duration = Duration::from_secs(5);
const WINDOW: Duration = Duration::from_secs(30);
const COMMANDS: u32 = 40;
/// The line's rest between two gateways: the one stopped has let go of the port.
const SETTLE: Duration = Duration::from_secs(1);
const DEFAULT_ROUNDS: usize = 3;

/// The kinds of gateway measured.
#[derive(Clone, Copy, PartialEq)]
enum Gateway {
    Rtu2mqtt,
    Mqmgateway,
}

impl Gateway {
    fn command_topic(self) -> &'static str {
        match self {
            Gateway::Rtu2mqtt => "plant/block/setpoint/set",
            Gateway::Mqmgateway => "peer/block/set",
        }
    }

    /// What a command's outcome is published after: rtu2mqtt reads the register back,
    /// mqmgateway publishes the value it wrote once the write's echo came.
    fn result_after(self) -> ResultAfter {
        match self {
            Gateway::Rtu2mqtt => ResultAfter::ReadBack,
            Gateway::Mqmgateway => ResultAfter::Echo,
        }
    }

    /// What a command's outcome is seen by: rtu2mqtt's result, mqmgateway's changed state.
    fn result_topic(self) -> &'static str {
        match self {
            Gateway::Rtu2mqtt => "plant/block/setpoint/result",
            Gateway::Mqmgateway => "peer/block/state",
        }
    }
}

/// One gateway measured: what kind it is, its name in the table, its binary.
struct Contender {
    gateway: Gateway,
    name: &'static str,
    binary: PathBuf,
}

/// This build's rtu2mqtt (or `PEER_COMPARE_GATEWAY`), another build of it beside it when
/// `PEER_COMPARE_BASELINE` names one, and mqmgateway when `MQMGATEWAY` names it.
fn contenders() -> anyhow::Result<Vec<Contender>> {
    let mut contenders = vec![Contender {
        gateway: Gateway::Rtu2mqtt,
        name: "rtu2mqtt",
        binary: std::env::var_os("PEER_COMPARE_GATEWAY").map_or_else(
            || PathBuf::from(env!("CARGO_BIN_EXE_rtu2mqtt")),
            PathBuf::from,
        ),
    }];
    let others = [
        (
            "PEER_COMPARE_BASELINE",
            Gateway::Rtu2mqtt,
            "rtu2mqtt baseline",
        ),
        ("MQMGATEWAY", Gateway::Mqmgateway, "mqmgateway"),
    ];
    for (variable, gateway, name) in others {
        let Some(binary) = std::env::var_os(variable).map(PathBuf::from) else {
            continue;
        };
        anyhow::ensure!(
            binary.is_file(),
            "{variable}={} is not a file",
            binary.display()
        );
        contenders.push(Contender {
            gateway,
            name,
            binary,
        });
    }
    Ok(contenders)
}

/// One gateway's turn on the line.
struct Turn {
    window: Window,
    wire: Wire,
}

/// The simulators every gateway is measured on, in the same run.
struct Simulator {
    name: &'static str,
    line: Box<dyn BenchLine>,
}

/// The project's own simulator, and pymodbus's RTU server behind a byte pacer unless
/// `PEER_COMPARE_PYMODBUS=0` (or pymodbus cannot be started: then it says why).
fn simulators(profile: &Profile) -> anyhow::Result<Vec<Simulator>> {
    let mut simulators = vec![Simulator {
        name: "project's simulator",
        line: Box::new(spawn_line(profile, 1, Pace::Bytes)?),
    }];
    if std::env::var("PEER_COMPARE_PYMODBUS").as_deref() == Ok("0") {
        return Ok(simulators);
    }
    match PacedPymodbus::spawn(BAUD, 6) {
        Ok(line) => simulators.push(Simulator {
            name: "pymodbus, paced",
            line: Box::new(line),
        }),
        Err(error) => eprintln!("pymodbus's RTU server not measured: {error:#}"),
    }
    Ok(simulators)
}

fn main() -> anyhow::Result<()> {
    let contenders = contenders()?;
    let runtime = wire_bench::runtime()?;
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir()?;
    let profile_path = dir.path().join("block.toml");
    let profile_text = profile_text();
    std::fs::write(&profile_path, &profile_text)?;
    let profile = Profile::from_toml(&profile_text, "block")
        .map_err(|e| anyhow::anyhow!("bench profile: {e:?}"))?;
    let rounds = std::env::var("PEER_COMPARE_ROUNDS")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .filter(|n| *n > 0)
        .unwrap_or(DEFAULT_ROUNDS);
    // The project's simulator runs on the bench's runtime.
    let simulators = runtime.block_on(async { simulators(&profile) })?;
    // turns[simulator][gateway]: every round's turn.
    let mut turns: Vec<Vec<Vec<Turn>>> = simulators
        .iter()
        .map(|_| contenders.iter().map(|_| Vec::new()).collect())
        .collect();
    runtime.block_on(async {
        let mut turn_number = 0;
        for round in 0..rounds {
            for (simulator, sim_turns) in simulators.iter().zip(turns.iter_mut()) {
                let mut order: Vec<usize> = (0..contenders.len()).collect();
                if round % 2 == 1 {
                    order.reverse();
                }
                for index in order {
                    let Some((contender, list)) =
                        contenders.get(index).zip(sim_turns.get_mut(index))
                    else {
                        continue;
                    };
                    eprintln!(
                        "round {} of {rounds}, {}: {}",
                        round + 1,
                        simulator.name,
                        contender.name
                    );
                    let turn = take_turn(
                        contender,
                        &broker,
                        dir.path(),
                        &profile_path,
                        simulator.line.as_ref(),
                        turn_number,
                    )
                    .await?;
                    turn_number += 1;
                    list.push(turn);
                    tokio::time::sleep(SETTLE).await;
                }
            }
        }
        anyhow::Ok(())
    })?;
    header(&contenders, rounds);
    for (simulator, turns) in simulators.iter().zip(&turns) {
        report(simulator.name, &contenders, turns);
    }
    footer();
    Ok(())
}

async fn take_turn(
    contender: &Contender,
    broker: &Mosquitto,
    dir: &Path,
    profile_path: &Path,
    line: &dyn BenchLine,
    turn: usize,
) -> anyhow::Result<Turn> {
    let gateway = contender.gateway;
    let mut process = match gateway {
        Gateway::Mqmgateway => {
            let config = dir.join(format!("peer-{turn}.yaml"));
            std::fs::write(&config, peer_config(broker, line, turn))?;
            let mut command = Command::new(&contender.binary);
            command.arg(format!("--config={}", config.display()));
            GatewayProcess::spawn(command)?
        }
        Gateway::Rtu2mqtt => {
            let config = dir.join(format!("rtu2mqtt-{turn}.toml"));
            std::fs::write(&config, rtu2mqtt_config(broker, line, profile_path, turn))?;
            GatewayProcess::start(&contender.binary, &config, "warn")?
        }
    };
    // Client ids of their own per turn: the previous turn's clients may still be connected.
    let (_subscriber, mut results) = timed_subscriber(
        broker.port,
        gateway.result_topic(),
        &format!("peer-compare-results-{turn}"),
        QoS::AtMostOnce,
    )
    .await?;
    let client = command_client(broker.port, &format!("peer-compare-commands-{turn}")).await;
    tokio::time::sleep(WARM_UP).await;
    let window = command_window(
        &process,
        line,
        &client,
        Writes {
            topic: gateway.command_topic(),
            first_value: 1000 + 100 * (turn % 500) as u16,
            count: COMMANDS,
        },
        &mut results,
        WINDOW,
    )
    .await?;
    process.stop();
    let _ = client.disconnect().await;
    let wire = wire_figures(
        &window.records,
        window.wall,
        None,
        &window.published,
        &window.results,
        gateway.result_after(),
    );
    Ok(Turn { window, wire })
}

/// rtu2mqtt: the line and the bench device (`block`) polled back to back.
fn rtu2mqtt_config(
    broker: &Mosquitto,
    line: &dyn BenchLine,
    profile: &Path,
    turn: usize,
) -> String {
    format!(
        "[mqtt]\nurl = \"{url}\"\nclient_id = \"peer-compare-{turn}\"\n\n\
         [health]\nstatus_file = \"\"\n\n\
         [[lines]]\nname = \"line\"\nport = \"{port}\"\nbaud = {BAUD}\nparity = \"none\"\n\n\
         [[lines.devices]]\nname = \"block\"\nprofile = \"{profile}\"\naddress = 1\n\
         poll_interval = \"0s\"\n",
        url = broker.url(),
        port = line.path().display(),
        profile = profile.display(),
    )
}

/// mqmgateway: the same line and block, polled back to back (`refresh: 0ms`), its state the
/// six registers as one JSON array, published on change; the first register writable through
/// `peer/block/set` (FC06). Its log at `warning`, as rtu2mqtt's.
fn peer_config(broker: &Mosquitto, line: &dyn BenchLine, turn: usize) -> String {
    format!(
        "modmqttd:\n  log_level: warning\n\
         modbus:\n  networks:\n    - name: line\n      device: {port}\n      baud: {BAUD}\n\
         \x20     parity: N\n      data_bit: 8\n      stop_bit: 1\n      response_timeout: 500ms\n\
         mqtt:\n  client_id: peer-compare-{turn}\n  refresh: 0ms\n  broker:\n\
         \x20   host: 127.0.0.1\n    port: {broker_port}\n  objects:\n\
         \x20   - topic: peer/block\n      network: line\n      slave: 1\n      state:\n\
         \x20       register: 1\n        register_type: holding\n        count: 6\n\
         \x20     commands:\n        - name: set\n          register: 1\n\
         \x20         register_type: holding\n",
        port = line.path().display(),
        broker_port = broker.port,
    )
}

fn row(figure: &str, values: &[String], note: &str) {
    let mut text = format!("{figure:<46}");
    for value in values {
        text += &format!(" {value:>26}");
    }
    println!("{text}   {note}");
}

/// One figure of every gateway's turns, each the median over its rounds.
fn per_gateway(
    turns: &[Vec<Turn>],
    figure: impl Fn(&Turn) -> f64 + Copy,
    show: fn(f64) -> String,
) -> Vec<String> {
    turns
        .iter()
        .map(|turns| over_rounds(turns.iter().map(figure), show))
        .collect()
}

/// One figure of every gateway, each round's in the order the rounds ran.
fn per_round(
    turns: &[Vec<Turn>],
    figure: impl Fn(&Turn) -> f64 + Copy,
    show: fn(f64) -> String,
) -> Vec<String> {
    turns
        .iter()
        .map(|turns| {
            let shown: Vec<String> = turns.iter().map(|turn| show(figure(turn))).collect();
            shown.join(" / ")
        })
        .collect()
}

/// `p50 / p95` of one latency list of every gateway, each over its rounds.
fn latency_pairs(turns: &[Vec<Turn>], list: fn(&Wire) -> &Vec<Duration>) -> Vec<String> {
    turns
        .iter()
        .map(|turns| {
            let at = |p: usize| {
                over_rounds(
                    turns
                        .iter()
                        .filter(|turn| !list(&turn.wire).is_empty())
                        .map(|turn| millis(percentile(list(&turn.wire), p))),
                    ms_f,
                )
            };
            format!("{} / {}", at(50), at(95))
        })
        .collect()
}

fn header(contenders: &[Contender], rounds: usize) {
    println!();
    for contender in contenders {
        println!("{}: {}", contender.name, contender.binary.display());
    }
    if !contenders
        .iter()
        .any(|contender| contender.gateway == Gateway::Mqmgateway)
    {
        println!(
            "mqmgateway: not measured (MQMGATEWAY unset; scripts/build-peer builds it): \
             rtu2mqtt alone"
        );
    }
    println!(
        "one simulated device, 9600 8N1, answers released byte by byte; one 6-register block \
         polled back to back, {COMMANDS} commands in {} s per turn; {rounds} round(s), each \
         figure the median over them (lowest–highest)",
        WINDOW.as_secs()
    );
}

fn footer() {
    println!(
        "\nCPU from /proc/<pid>/stat (utime + stime) over each window; memory at its end; \
         transactions and the wire from the simulator's journal (the pymodbus pacer's: where it \
         saw a request's first byte, when it handed an answer's last byte over)"
    );
}

fn report(simulator: &str, contenders: &[Contender], turns: &[Vec<Turn>]) {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    println!();
    println!("== on the {simulator}");
    let names: Vec<String> = contenders.iter().map(|c| c.name.to_string()).collect();
    row("figure", &names, "");
    let wire_limit = 1.0 / transaction_wire_time().as_secs_f64();
    row(
        "transactions/s",
        &per_gateway(
            turns,
            |t| t.window.transactions_per_second(),
            |v| format!("{v:.1}"),
        ),
        &format!("wire limit {wire_limit:.1}"),
    );
    row(
        "gateway CPU, % of one core",
        &per_gateway(
            turns,
            |t| t.window.gateway_cpu_percent(),
            |v| format!("{v:.2} %"),
        ),
        "",
    );
    let cpu_per_transaction =
        |t: &Turn| t.window.gateway_cpu.as_secs_f64() * 1e6 / t.window.records.len().max(1) as f64;
    row(
        "CPU per transaction",
        &per_gateway(turns, cpu_per_transaction, |v| format!("{v:.0} µs")),
        "",
    );
    row(
        "  round by round (µs)",
        &per_round(turns, cpu_per_transaction, |v| format!("{v:.0}")),
        "the gateways' turns of a round run one after the other",
    );
    row(
        "simulator CPU (with this process), % of one core",
        &per_gateway(
            turns,
            |t| t.window.simulator_cpu_percent(),
            |v| format!("{v:.2} %"),
        ),
        "",
    );
    row(
        "gateway CPU ÷ simulator CPU",
        &per_gateway(
            turns,
            |t| t.window.gateway_cpu_percent() / t.window.simulator_cpu_percent().max(f64::EPSILON),
            |v| format!("{v:.2}"),
        ),
        "same simulator, same run",
    );
    let mib = |kib: u64| kib as f64 / 1024.0;
    row(
        "anonymous memory (Private_Dirty)",
        &per_gateway(
            turns,
            |t| mib(t.window.memory.private_dirty_kib),
            |v| format!("{v:.2} MiB"),
        ),
        "smaps_rollup",
    );
    row(
        "anonymous memory (RssAnon)",
        &per_gateway(
            turns,
            |t| mib(t.window.memory.rss_anon_kib),
            |v| format!("{v:.2} MiB"),
        ),
        "status",
    );
    row(
        "PSS",
        &per_gateway(
            turns,
            |t| mib(t.window.memory.pss_kib),
            |v| format!("{v:.2} MiB"),
        ),
        "smaps_rollup",
    );
    row(
        "threads",
        &per_gateway(
            turns,
            |t| t.window.memory.threads as f64,
            |v| format!("{v:.0}"),
        ),
        "",
    );
    row(
        "idle gap before a request p50",
        &per_gateway(turns, |t| millis(t.wire.gap_p50), ms_f),
        &format!("t3.5 = {}", ms_f(millis(timing.t3_5))),
    );
    row(
        "  round by round (ms)",
        &per_round(turns, |t| millis(t.wire.gap_p50), |v| format!("{v:.2}")),
        "",
    );
    row(
        "bus efficiency",
        &per_gateway(turns, |t| t.wire.efficiency, |v| format!("{v:.3}")),
        "wire time + 2 × t3.5 per transaction ÷ wall",
    );
    row(
        "bus efficiency, the device's own answer times",
        &per_gateway(
            turns,
            |t| t.wire.efficiency_device_times,
            |v| format!("{v:.3}"),
        ),
        "request start → answer end + t3.5, ÷ wall",
    );
    row(
        "device turnaround p50",
        &per_gateway(turns, |t| millis(t.wire.device_turnaround_p50), ms_f),
        "request end → answer start: the simulator's",
    );
    let early: Vec<String> = turns
        .iter()
        .map(|turns| {
            let early: usize = turns.iter().map(|t| t.wire.early).sum();
            let all: usize = turns.iter().map(|t| t.window.records.len()).sum();
            format!("{early} of {all}")
        })
        .collect();
    row("requests sooner than t3.5, all rounds", &early, "");
    let seen: Vec<String> = turns
        .iter()
        .map(|turns| {
            let seen: usize = turns.iter().map(|t| t.wire.to_result.len()).sum();
            format!("{seen} of {}", COMMANDS as usize * turns.len())
        })
        .collect();
    row("commands whose new value was seen", &seen, "");
    row(
        "command → new value on MQTT p50 / p95",
        &latency_pairs(turns, |w| &w.to_result),
        "rtu2mqtt: …/result; mqmgateway: state",
    );
    row(
        "  its bound p50 / p95",
        &latency_pairs(turns, |w| &w.to_result_bound),
        "rtu2mqtt: in flight + write + read-back; mqmgateway: in flight + write",
    );
    row(
        "  later than its bound p50 / p95",
        &latency_pairs(turns, |w| &w.result_over_bound),
        "target ≤ 4 ms / ≤ 5 ms",
    );
    row(
        "  later than the bound as answers were delivered",
        &latency_pairs(turns, |w| &w.result_over_delivered),
        "the gateway's own share",
    );
    row(
        "  of which: write on the wire later than its bound",
        &latency_pairs(turns, |w| &w.to_wire_over_bound),
        "the command's way to the line, and t3.5's overshoot",
    );
    row(
        "  write echo end → next request at device",
        &latency_pairs(turns, |w| &w.echo_to_read_back),
        &format!("t3.5 = {} at best", ms_f(millis(timing.t3_5))),
    );
    row(
        "  read-back answer end → on MQTT",
        &latency_pairs(turns, |w| &w.read_back_to_result),
        "line → bridge → broker → subscriber",
    );
}
