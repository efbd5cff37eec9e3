//! What registering the serial port for read interest alone saves (`serial::transport` of
//! rtu2mqtt-modbus), against `tokio_serial::SerialStream`, which registers the same mio-serial
//! port for read and write interest.
//!
//! The same RTU transactions both ways: a read of the dust collector's 6-register block (an
//! 8-byte request, a 17-byte answer) at 9600 8N1 over a pseudo-terminal, answered by the
//! simulator, which releases the answer byte by byte at the wire's character rate
//! (`Pace::Bytes`), with at least t3.5 of silence before each request. Each
//! transport runs in a process of its own (this bench started again as a child), on a
//! current_thread runtime, so that its figures are its own and not the simulator's: our `Port`
//! writes the frame (`write_frame`) and reads the answer with deadlines (`read_until`);
//! tokio-serial does the same `write_all` and `read` with the same deadlines.
//!
//! Printed per transaction, for each transport: CPU (utime + stime of the child process from
//! `getrusage`, µs) and the share of it the runtime was busy (tokio's
//! `worker_total_busy_duration`, wall time, so a loaded machine's preemptions inflate it),
//! wake-ups (tokio's `worker_park_count`: each park of the runtime's thread in `epoll_wait`
//! ends in one), context switches, the transaction's time (request written → last answer byte
//! read, p50 and p95), and, when `strace` is installed, the system calls per transaction and
//! how often `epoll_wait` returned with write readiness alone (`strace -f` of two child runs of
//! different lengths, the difference divided by the difference of their transactions, so that
//! opening and setting up count for nothing). Each figure is the median over the rounds, with
//! the range; the comparison is the median of the rounds' differences (the two transports of
//! one round ran back to back, under the same load), with how many rounds went each way.
//!
//! Rounds: 7, or `TRANSPORT_INTEREST_ROUNDS`; transactions per round and transport: 300, or
//! `TRANSPORT_INTEREST_TRANSACTIONS`. Which transport goes first alternates from round to round.
//! Prints figures; asserts nothing. Run: `cargo bench --bench transport_interest` (about 3 min
//! after the build; docs/performance.md, "Read interest alone").

mod wire_bench;

use std::collections::BTreeMap;
use std::io;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

use anyhow::{bail, Context};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::Instant;

use rtu2mqtt_modbus::codec::{self, Answer};
use rtu2mqtt_modbus::serial::transport::{Port, SerialSettings};
use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_modbus::{Request, SlaveId};
use rtu2mqtt_sim::{share, DustCollector, Pace, ServeOptions, VirtualLine};
use wire_bench::percentile;

const BAUD: u32 = 9600;
const EIGHT_N_ONE: CharFormat = CharFormat {
    data_bits: 8,
    parity: Parity::None,
    stop_bits: 1,
};
const DEVICE: SlaveId = 1;
/// The dust collector's whole block: status, gear, PV, SV and two more words.
const READ_BLOCK: Request = Request::ReadHoldingRegisters {
    start: 0x1000,
    quantity: 6,
};
/// Transactions before the measured ones: the port and the runtime settle.
const WARM_UP: usize = 10;
/// How long one answer is awaited: its wire time is 18 ms.
const ANSWER_TIMEOUT: Duration = Duration::from_millis(200);
const DEFAULT_ROUNDS: usize = 7;
const DEFAULT_TRANSACTIONS: usize = 300;
/// The shorter of the two runs under strace; the longer one has this many more transactions.
const STRACE_BASE: usize = 50;
const STRACE_EXTRA: usize = 100;

/// The environment that makes this bench a child: the transport to measure, the port, how many.
const CHILD_TRANSPORT: &str = "TRANSPORT_INTEREST_CHILD";
const CHILD_PORT: &str = "TRANSPORT_INTEREST_PORT";
const CHILD_TRANSACTIONS: &str = "TRANSPORT_INTEREST_COUNT";

/// The two transports measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Transport {
    /// rtu2mqtt-modbus's `Port`: read interest alone.
    Ours,
    /// `tokio_serial::SerialStream`: read and write interest.
    TokioSerial,
}

impl Transport {
    fn name(self) -> &'static str {
        match self {
            Transport::Ours => "ours",
            Transport::TokioSerial => "tokio-serial",
        }
    }

    fn from_name(name: &str) -> Option<Self> {
        [Transport::Ours, Transport::TokioSerial]
            .into_iter()
            .find(|transport| transport.name() == name)
    }

    fn label(self) -> &'static str {
        match self {
            Transport::Ours => "rtu2mqtt-modbus Port (read interest)",
            Transport::TokioSerial => "tokio-serial SerialStream (read + write interest)",
        }
    }
}

fn main() -> anyhow::Result<()> {
    if let Ok(name) = std::env::var(CHILD_TRANSPORT) {
        return child(&name);
    }
    let rounds = env_count("TRANSPORT_INTEREST_ROUNDS", DEFAULT_ROUNDS)?;
    let transactions = env_count("TRANSPORT_INTEREST_TRANSACTIONS", DEFAULT_TRANSACTIONS)?;
    // The simulator's runtime: this process serves the line, the children use it.
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()?;
    let _entered = runtime.enter();
    let (_dust, dust) = share(DustCollector::new(DEVICE));
    let line = VirtualLine::spawn(
        ServeOptions::new(BAUD, Parity::None).pacing(Pace::Bytes),
        vec![dust],
    )?;
    let port = line.path();
    println!(
        "{rounds} rounds of {transactions} transactions per transport: FC03 of 6 registers at \
         {BAUD} 8N1 on {} (byte-paced simulator)",
        port.display()
    );

    let mut runs: Vec<(Transport, Vec<ChildFigures>)> = vec![
        (Transport::Ours, Vec::new()),
        (Transport::TokioSerial, Vec::new()),
    ];
    for round in 0..rounds {
        let order = if round % 2 == 0 { [0, 1] } else { [1, 0] };
        for index in order {
            let (transport, figures) = &mut runs[index];
            figures.push(run_child(*transport, &port, transactions, None)?);
        }
    }
    let traced = strace_available();
    for (transport, figures) in &runs {
        println!("\n{}", transport.label());
        print_figures(figures);
        if traced {
            let syscalls = syscalls_per_transaction(*transport, &port)?;
            let each: Vec<String> = syscalls
                .by_name
                .iter()
                .map(|(name, calls)| format!("{name} {calls:.1}"))
                .collect();
            println!(
                "  system calls per transaction (strace -f -c): {:.1}: {}",
                syscalls.total,
                each.join(", ")
            );
            println!(
                "  epoll_wait returns with write readiness alone per transaction (strace): {:.2}",
                write_alone_wake_ups(*transport, &port)?
            );
        }
    }
    if !traced {
        println!("\nstrace not found: system calls not counted");
    }
    let [(_, ours), (_, theirs)] = &runs[..] else {
        bail!("two transports measured");
    };
    compare(ours, theirs);
    Ok(())
}

/// A positive count from the environment, or `default`.
fn env_count(name: &str, default: usize) -> anyhow::Result<usize> {
    match std::env::var(name) {
        Ok(text) => text
            .parse()
            .ok()
            .filter(|count| *count > 0)
            .with_context(|| format!("{name}={text:?} is no positive count")),
        Err(_) => Ok(default),
    }
}

/// What one child reports of its measured transactions.
#[derive(Debug, Clone, Default)]
struct ChildFigures {
    transactions: usize,
    failed: usize,
    cpu: Duration,
    voluntary_switches: u64,
    involuntary_switches: u64,
    /// Times the runtime's thread parked waiting for events (tokio's `worker_park_count`):
    /// each park ends in a wake-up.
    parks: u64,
    /// Time the runtime's thread spent running tasks and handling events (tokio's
    /// `worker_total_busy_duration`), the user-space share of the work.
    busy: Duration,
    p50: Duration,
    p95: Duration,
}

impl ChildFigures {
    fn cpu_per_transaction_us(&self) -> f64 {
        self.cpu.as_secs_f64() * 1e6 / self.transactions.max(1) as f64
    }

    fn switches_per_transaction(&self) -> f64 {
        self.voluntary_switches as f64 / self.transactions.max(1) as f64
    }

    fn parks_per_transaction(&self) -> f64 {
        self.parks as f64 / self.transactions.max(1) as f64
    }

    fn busy_per_transaction_us(&self) -> f64 {
        self.busy.as_secs_f64() * 1e6 / self.transactions.max(1) as f64
    }

    fn to_line(&self) -> String {
        format!(
            "transactions={} failed={} cpu_us={} nvcsw={} nivcsw={} parks={} busy_us={} \
             p50_us={} p95_us={}",
            self.transactions,
            self.failed,
            self.cpu.as_micros(),
            self.voluntary_switches,
            self.involuntary_switches,
            self.parks,
            self.busy.as_micros(),
            self.p50.as_micros(),
            self.p95.as_micros()
        )
    }

    fn from_line(line: &str) -> anyhow::Result<Self> {
        let mut figures = ChildFigures::default();
        for pair in line.split_whitespace() {
            let (key, value) = pair
                .split_once('=')
                .with_context(|| format!("{pair:?} in {line:?}"))?;
            let number: u64 = value.parse().with_context(|| format!("{pair:?}"))?;
            match key {
                "transactions" => figures.transactions = usize::try_from(number)?,
                "failed" => figures.failed = usize::try_from(number)?,
                "cpu_us" => figures.cpu = Duration::from_micros(number),
                "nvcsw" => figures.voluntary_switches = number,
                "nivcsw" => figures.involuntary_switches = number,
                "parks" => figures.parks = number,
                "busy_us" => figures.busy = Duration::from_micros(number),
                "p50_us" => figures.p50 = Duration::from_micros(number),
                "p95_us" => figures.p95 = Duration::from_micros(number),
                _ => bail!("unknown figure {key:?} in {line:?}"),
            }
        }
        Ok(figures)
    }
}

/// How a child runs under strace, writing to a file.
#[derive(Debug, Clone, Copy)]
enum Trace {
    /// `strace -f -c`: the calls of each system call.
    Summary,
    /// Every `epoll_wait` with the events it returned.
    EpollEvents,
}

/// Runs one child on `port` for `transactions`, under `strace` writing to `trace`'s file
/// when given.
fn run_child(
    transport: Transport,
    port: &Path,
    transactions: usize,
    trace: Option<(Trace, &Path)>,
) -> anyhow::Result<ChildFigures> {
    let bench = std::env::current_exe()?;
    let mut command = match trace {
        Some((trace, file)) => {
            let mut strace = Command::new("strace");
            match trace {
                Trace::Summary => strace.args(["-f", "-c", "-U", "calls,name"]),
                Trace::EpollEvents => {
                    strace.args(["-f", "-e", "trace=epoll_wait,epoll_pwait,epoll_pwait2"])
                }
            };
            strace.arg("-o").arg(file).arg(&bench);
            strace
        }
        None => Command::new(&bench),
    };
    let output = command
        .env(CHILD_TRANSPORT, transport.name())
        .env(CHILD_PORT, port)
        .env(CHILD_TRANSACTIONS, transactions.to_string())
        .output()
        .with_context(|| format!("starting the {} child", transport.name()))?;
    let stdout = String::from_utf8_lossy(&output.stdout);
    if !output.status.success() {
        bail!(
            "the {} child failed ({}): {}{}",
            transport.name(),
            output.status,
            stdout,
            String::from_utf8_lossy(&output.stderr)
        );
    }
    let line = stdout
        .lines()
        .last()
        .with_context(|| format!("the {} child printed nothing", transport.name()))?;
    ChildFigures::from_line(line)
}

/// System calls per transaction, from two traced runs of different lengths: all of them, and
/// each by name.
struct Syscalls {
    total: f64,
    by_name: Vec<(String, f64)>,
}

fn strace_available() -> bool {
    Command::new("strace")
        .arg("-V")
        .output()
        .is_ok_and(|output| output.status.success())
}

/// What `trace` wrote of a short and a long child run (`STRACE_EXTRA` transactions apart),
/// each read by `read`: their difference is what the extra transactions cost.
fn traced_runs<T>(
    transport: Transport,
    port: &Path,
    trace: Trace,
    read: impl Fn(&str) -> anyhow::Result<T>,
) -> anyhow::Result<(T, T)> {
    let directory = tempfile::tempdir()?;
    let run = |transactions: usize| -> anyhow::Result<T> {
        let file = directory.path().join(format!("trace-{transactions}"));
        run_child(transport, port, transactions, Some((trace, &file)))?;
        read(&std::fs::read_to_string(&file)?)
    };
    Ok((run(STRACE_BASE)?, run(STRACE_BASE + STRACE_EXTRA)?))
}

fn syscalls_per_transaction(transport: Transport, port: &Path) -> anyhow::Result<Syscalls> {
    let (short, long) = traced_runs(transport, port, Trace::Summary, strace_counts)?;
    let per_transaction = |name: &str| {
        let calls = |counts: &BTreeMap<String, u64>| counts.get(name).copied().unwrap_or(0) as f64;
        (calls(&long) - calls(&short)) / STRACE_EXTRA as f64
    };
    let by_name = long
        .keys()
        .filter(|name| *name != "total")
        .map(|name| (name.clone(), per_transaction(name)))
        .filter(|(_, calls)| *calls >= 0.05)
        .collect();
    Ok(Syscalls {
        total: per_transaction("total"),
        by_name,
    })
}

/// Returns of `epoll_wait` per transaction that carried write readiness alone (a wake-up for
/// nothing: no task waits to write), from two traced runs of different lengths.
fn write_alone_wake_ups(transport: Transport, port: &Path) -> anyhow::Result<f64> {
    let write_alone = |returns: &str| -> anyhow::Result<f64> {
        Ok(returns
            .lines()
            .filter(|line| line.contains("EPOLLOUT") && !line.contains("EPOLLIN"))
            .count() as f64)
    };
    let (short, long) = traced_runs(transport, port, Trace::EpollEvents, write_alone)?;
    Ok((long - short) / STRACE_EXTRA as f64)
}

/// The calls of each system call (and `total`) from a `strace -c -U calls,name` summary.
fn strace_counts(summary: &str) -> anyhow::Result<BTreeMap<String, u64>> {
    let mut counts = BTreeMap::new();
    for line in summary.lines() {
        let mut columns = line.split_whitespace();
        let (Some(calls), Some(name)) = (columns.next(), columns.next()) else {
            continue;
        };
        if let Ok(calls) = calls.parse::<u64>() {
            counts.insert(name.to_string(), calls);
        }
    }
    if !counts.contains_key("total") {
        bail!("no total in the strace summary:\n{summary}");
    }
    Ok(counts)
}

/// The median and range of `figure` over the rounds.
fn spread(figures: &[ChildFigures], figure: impl Fn(&ChildFigures) -> f64) -> (f64, f64, f64) {
    let mut values: Vec<f64> = figures.iter().map(figure).collect();
    values.sort_by(f64::total_cmp);
    let median = values.get(values.len() / 2).copied().unwrap_or_default();
    let low = values.first().copied().unwrap_or_default();
    let high = values.last().copied().unwrap_or_default();
    (median, low, high)
}

/// A printed figure: its name, its unit and how it is read from a child's figures.
type FigureRow = (&'static str, &'static str, fn(&ChildFigures) -> f64);

fn print_figures(figures: &[ChildFigures]) {
    let failed: usize = figures.iter().map(|f| f.failed).sum();
    let done: usize = figures.iter().map(|f| f.transactions).sum();
    let rows: [FigureRow; 7] = [
        (
            "CPU per transaction",
            " µs",
            ChildFigures::cpu_per_transaction_us,
        ),
        (
            "  of it the runtime busy (tokio worker_total_busy_duration)",
            " µs",
            ChildFigures::busy_per_transaction_us,
        ),
        (
            "wake-ups per transaction (tokio worker_park_count)",
            "",
            ChildFigures::parks_per_transaction,
        ),
        (
            "voluntary context switches per transaction",
            "",
            ChildFigures::switches_per_transaction,
        ),
        ("involuntary context switches per transaction", "", |f| {
            f.involuntary_switches as f64 / f.transactions.max(1) as f64
        }),
        ("transaction time p50", " ms", |f| f.p50.as_secs_f64() * 1e3),
        ("transaction time p95", " ms", |f| f.p95.as_secs_f64() * 1e3),
    ];
    for (name, unit, figure) in rows {
        let (median, low, high) = spread(figures, figure);
        println!("  {name}: {median:.2}{unit} (rounds {low:.2}–{high:.2})");
    }
    println!("  failed transactions: {failed} of {done}");
}

fn compare(ours: &[ChildFigures], theirs: &[ChildFigures]) {
    // Paired by round: the two ran one after the other, under the same load.
    let paired = |figure: fn(&ChildFigures) -> f64| {
        let mut differences: Vec<f64> = ours
            .iter()
            .zip(theirs)
            .map(|(ours, theirs)| figure(ours) - figure(theirs))
            .collect();
        differences.sort_by(f64::total_cmp);
        let median = differences
            .get(differences.len() / 2)
            .copied()
            .unwrap_or_default();
        let lower = differences.iter().filter(|d| **d < 0.0).count();
        (median, lower, differences.len())
    };
    println!("\nread interest alone against read + write, the median of the rounds' differences:");
    let (cpu, lower, rounds) = paired(ChildFigures::cpu_per_transaction_us);
    println!("  CPU per transaction {cpu:+.2} µs (lower in {lower} of {rounds} rounds)");
    let (busy, lower, _) = paired(ChildFigures::busy_per_transaction_us);
    println!("  runtime busy per transaction {busy:+.2} µs (lower in {lower} of {rounds} rounds)");
    let (parks, lower, _) = paired(ChildFigures::parks_per_transaction);
    println!("  wake-ups per transaction {parks:+.2} (fewer in {lower} of {rounds} rounds)");
    let (p50, _, _) = paired(|f| f.p50.as_secs_f64() * 1e3);
    let (p95, _, _) = paired(|f| f.p95.as_secs_f64() * 1e3);
    println!("  transaction time p50 {p50:+.3} ms, p95 {p95:+.3} ms");
}

/// The child: measures `transactions` through one transport and prints its figures as one line.
fn child(name: &str) -> anyhow::Result<()> {
    let transport =
        Transport::from_name(name).with_context(|| format!("unknown transport {name:?}"))?;
    let port = std::env::var(CHILD_PORT).with_context(|| format!("{CHILD_PORT} not set"))?;
    let transactions = env_count(CHILD_TRANSACTIONS, DEFAULT_TRANSACTIONS)?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let figures = runtime.block_on(async {
        let mut link = Link::open(transport, &port)?;
        measure(&mut link, transactions).await
    })?;
    println!("{}", figures.to_line());
    Ok(())
}

/// One of the two transports, open.
enum Link {
    Ours(Port),
    TokioSerial(tokio_serial::SerialStream),
}

impl Link {
    fn open(transport: Transport, path: &str) -> anyhow::Result<Self> {
        Ok(match transport {
            Transport::Ours => Link::Ours(Port::open(&SerialSettings {
                path: path.to_string(),
                baud: BAUD,
                format: EIGHT_N_ONE,
                rs485: None,
            })?),
            Transport::TokioSerial => {
                use tokio_serial::SerialPortBuilderExt;
                Link::TokioSerial(tokio_serial::new(path, BAUD).open_native_async()?)
            }
        })
    }

    /// Writes `frame` and reads until `answer` holds `answer_len` bytes or `deadline` passes
    /// (`false`).
    async fn exchange(
        &mut self,
        frame: &[u8],
        answer: &mut Vec<u8>,
        answer_len: usize,
        deadline: Instant,
    ) -> io::Result<bool> {
        let mut buffer = [0u8; 256];
        match self {
            Link::Ours(port) => {
                port.write_frame(frame).await?;
                while answer.len() < answer_len {
                    match port.read_until(&mut buffer, deadline).await? {
                        Some((count, _seen)) => answer.extend_from_slice(&buffer[..count]),
                        None => return Ok(false),
                    }
                }
            }
            Link::TokioSerial(stream) => {
                stream.write_all(frame).await?;
                while answer.len() < answer_len {
                    match tokio::time::timeout_at(deadline, stream.read(&mut buffer)).await {
                        Err(_elapsed) => return Ok(false),
                        Ok(Ok(0)) => return Err(io::ErrorKind::UnexpectedEof.into()),
                        Ok(Ok(count)) => answer.extend_from_slice(&buffer[..count]),
                        Ok(Err(error)) => return Err(error),
                    }
                }
            }
        }
        Ok(true)
    }
}

/// CPU and context switches of this process so far.
fn usage() -> io::Result<(Duration, u64, u64)> {
    let mut usage = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the `struct rusage` it is given; on success it is initialised.
    let usage = unsafe {
        if libc::getrusage(libc::RUSAGE_SELF, usage.as_mut_ptr()) != 0 {
            return Err(io::Error::last_os_error());
        }
        usage.assume_init()
    };
    let micros = |time: libc::timeval| {
        Duration::from_secs(u64::try_from(time.tv_sec).unwrap_or_default())
            + Duration::from_micros(u64::try_from(time.tv_usec).unwrap_or_default())
    };
    Ok((
        micros(usage.ru_utime) + micros(usage.ru_stime),
        u64::try_from(usage.ru_nvcsw).unwrap_or_default(),
        u64::try_from(usage.ru_nivcsw).unwrap_or_default(),
    ))
}

/// The transactions, at least t3.5 after each answer's last byte (tokio's timer, the same for
/// both transports; it rounds up to the next millisecond).
async fn measure(link: &mut Link, transactions: usize) -> anyhow::Result<ChildFigures> {
    let timing = LineTiming::new(BAUD, EIGHT_N_ONE);
    let frame = codec::encode_request(DEVICE, &READ_BLOCK)?;
    let answer_len = READ_BLOCK.answer_len();
    let mut answer = Vec::with_capacity(answer_len);
    let mut times = Vec::with_capacity(transactions);
    let mut failed = 0;
    let mut quiet_at = Instant::now() + Duration::from_millis(50);
    let metrics = tokio::runtime::Handle::current().metrics();
    let mut start = usage()?;
    let mut start_parks = 0;
    let mut start_busy = Duration::ZERO;
    for index in 0..WARM_UP + transactions {
        if index == WARM_UP {
            start = usage()?;
            start_parks = metrics.worker_park_count(0);
            start_busy = metrics.worker_total_busy_duration(0);
        }
        tokio::time::sleep_until(quiet_at).await;
        answer.clear();
        let sent = Instant::now();
        let complete = link
            .exchange(&frame, &mut answer, answer_len, sent + ANSWER_TIMEOUT)
            .await?;
        let done = Instant::now();
        quiet_at = done + timing.t3_5;
        let heard = complete
            && matches!(
                codec::decode_answer(DEVICE, &READ_BLOCK, &answer),
                Ok(Answer::Normal(_))
            );
        if index >= WARM_UP {
            times.push(done - sent);
            if !heard {
                failed += 1;
            }
        }
        if !complete {
            // Whatever came late is the next transaction's noise: let the line fall silent.
            quiet_at = done + ANSWER_TIMEOUT;
        }
    }
    let end = usage()?;
    let metrics = tokio::runtime::Handle::current().metrics();
    let (parks, busy) = (
        metrics.worker_park_count(0),
        metrics.worker_total_busy_duration(0),
    );
    times.sort();
    Ok(ChildFigures {
        transactions,
        failed,
        cpu: end.0.saturating_sub(start.0),
        voluntary_switches: end.1.saturating_sub(start.1),
        involuntary_switches: end.2.saturating_sub(start.2),
        parks: parks.saturating_sub(start_parks),
        busy: busy.saturating_sub(start_busy),
        p50: percentile(&times, 50),
        p95: percentile(&times, 95),
    })
}
