//! The line task over real pseudo-terminals with the simulated seed devices: every block read
//! and matching the simulators' state, timeouts, noise that never yields a wrong value, a
//! silent device going offline and coming back without starving its neighbour, commands
//! overtaking queued polls, read-modify-write keeping the dust collector's internal bits, the
//! valve's exception-02 fallback and settle window, and a port that disappears and comes back.
//!
//! Timing assertions only go in safe directions with generous bounds: the machine running the
//! tests is small and busy.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::mpsc;

use rtu2mqtt::bus::scheduler::BUSY_LIMIT;
use rtu2mqtt::bus::{
    spawn_line, Command, CommandFailure, CommandOutcome, DeviceSpec, LineEvent, LineHandle,
    LineSpec,
};
use rtu2mqtt_modbus::serial::transport::SerialSettings;
use rtu2mqtt_modbus::timing::{CharFormat, Parity};
use rtu2mqtt_profile::{registry, CommandPlan, DeviceState, Profile, Value};
use rtu2mqtt_sim::{
    self as sim, air_shower, share, AirShower, DustCollector, Faults, Occurrence, ServeOptions,
    SharedDevice, SimDevice, Valve, VirtualLine,
};
use tokio_util::sync::CancellationToken;

const AIR_SHOWER_TOML: &str = include_str!("../../../config/profiles/lixian-air-shower.toml");

fn built_in(name: &str) -> Arc<Profile> {
    Arc::new(registry::built_in(name).unwrap())
}

/// The air shower profile without its minimum poll interval and start-up delay, so a test can
/// poll it back to back.
fn fast_air_shower() -> Arc<Profile> {
    let text = AIR_SHOWER_TOML
        .replace(
            "min_poll_interval = \"500ms\"",
            "min_poll_interval = \"1ms\"",
        )
        .replace("startup_delay = \"1s\"", "startup_delay = \"0s\"");
    assert!(text.contains("min_poll_interval = \"1ms\""));
    Arc::new(Profile::from_toml(&text, "fast air shower").unwrap())
}

fn device(name: &str, profile: Arc<Profile>, address: u8, poll_ms: u64) -> DeviceSpec {
    DeviceSpec {
        name: name.into(),
        address,
        profile,
        poll_interval: Duration::from_millis(poll_ms),
        publish: Default::default(),
    }
}

fn line_spec(name: &str, line: &VirtualLine, parity: Parity, devices: Vec<DeviceSpec>) -> LineSpec {
    LineSpec {
        name: name.into(),
        serial: SerialSettings {
            path: line.path().to_string_lossy().into_owned(),
            baud: 9600,
            format: CharFormat {
                data_bits: 8,
                parity,
                stop_bits: 1,
            },
            rs485: None,
        },
        transport: rtu2mqtt::bus::Transport::Serial,
        response_timeout: None,
        retries: 1,
        offline_after: 3,
        echo: false,
        broadcast_turnaround: Duration::from_millis(100),
        byte_timeout: None,
        recorders: Default::default(),
        console: false,
        serve: None,
        devices,
    }
}

/// (when, device, values) of one Values event.
type ValuesSeen = (Instant, String, Vec<(String, Value)>);

/// A running line and everything it reported.
struct Running {
    handle: LineHandle,
    task: tokio::task::JoinHandle<()>,
    trigger: CancellationToken,
    events_rx: mpsc::Receiver<LineEvent>,
    latest: HashMap<String, DeviceState>,
    /// Every Values event.
    values: Vec<ValuesSeen>,
    /// (when, device, online) of every Availability event.
    availability: Vec<(Instant, String, bool)>,
    /// Outcomes of finished commands by id, until taken by `wait_reply`.
    finished: HashMap<u64, CommandOutcome>,
    next_id: u64,
}

impl Running {
    fn start(spec: LineSpec) -> Self {
        let (events_tx, events_rx) = mpsc::channel(1024);
        let token = CancellationToken::new();
        let trigger = token.clone();
        let (handle, task) = spawn_line(spec, events_tx, token);
        Running {
            handle,
            task,
            trigger,
            events_rx,
            latest: HashMap::new(),
            values: Vec::new(),
            availability: Vec::new(),
            finished: HashMap::new(),
            next_id: 0,
        }
    }

    fn record(&mut self, event: LineEvent) {
        let now = Instant::now();
        match event {
            LineEvent::Values { device, values, .. } => {
                let state = self.latest.entry(device.clone()).or_default();
                for (field, value) in &values {
                    state.insert(field.clone(), value.clone());
                }
                self.values.push((now, device, values));
            }
            LineEvent::Availability { device, online } => {
                self.availability.push((now, device, online))
            }
            LineEvent::CommandFinished { id, outcome, .. } => {
                self.finished.insert(id, outcome);
            }
            // These lines are not served: no client writes.
            LineEvent::ClientWriteFinished { .. } | LineEvent::Written { .. } => {}
        }
    }

    /// Records events until `done` holds or `timeout` passes; returns whether it held.
    async fn until(&mut self, timeout: Duration, done: impl Fn(&Running) -> bool) -> bool {
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            if done(self) {
                return true;
            }
            // Statistics change without an event (an unchanged answer sends none), so both
            // wake the check.
            tokio::select! {
                event = self.events_rx.recv() => match event {
                    Some(event) => self.record(event),
                    None => return done(self),
                },
                changed = self.handle.stats_rx.changed() => {
                    if changed.is_err() {
                        return done(self);
                    }
                }
                () = tokio::time::sleep_until(deadline) => return done(self),
            }
        }
    }

    /// Records events for `duration`.
    async fn run_for(&mut self, duration: Duration) {
        self.until(duration, |_| false).await;
    }

    fn text(&self, device: &str, field: &str) -> Option<String> {
        self.latest
            .get(device)
            .and_then(|state| state.get(field))
            .map(Value::to_text)
    }

    fn values_of(&self, device: &str) -> usize {
        self.values.iter().filter(|v| v.1 == device).count()
    }

    /// Answered polls of `device` so far, from the line's statistics. A poll whose answer
    /// equals the last one sends no values (nothing changed), so Values events do not count
    /// polls.
    fn polls_ok(&self, device: &str) -> u64 {
        self.handle
            .stats_rx
            .borrow()
            .devices
            .iter()
            .find(|d| d.name == device)
            .map_or(0, |d| d.polls_ok)
    }

    fn went(&self, device: &str, online: bool) -> usize {
        self.availability
            .iter()
            .filter(|a| a.1 == device && a.2 == online)
            .count()
    }

    async fn command(&mut self, device: &str, field: &str, text: &str) -> CommandOutcome {
        let profile_state = self.latest.get(device).cloned().unwrap_or_default();
        let plan = self
            .profile_of(device)
            .plan_command(field, text, &profile_state)
            .unwrap();
        self.send(device, plan).await
    }

    /// Hands `plan` to the line as a command for `device` and waits for its outcome.
    async fn send(&mut self, device: &str, plan: CommandPlan) -> CommandOutcome {
        self.next_id += 1;
        let id = self.next_id;
        self.handle
            .command_tx
            .send(Command {
                id,
                device: device.into(),
                plan,
            })
            .await
            .unwrap();
        self.wait_reply(id).await
    }

    /// Records events until `device` has published values once; fails the test when that
    /// takes longer than `timeout`.
    async fn wait_for_values(&mut self, device: &str, timeout: Duration) {
        assert!(
            self.until(timeout, |r| r.values_of(device) >= 1).await,
            "no values from {device} in {timeout:?}"
        );
    }

    /// Records events until the line reports the end of command `id`.
    async fn wait_reply(&mut self, id: u64) -> CommandOutcome {
        let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
        loop {
            if let Some(outcome) = self.finished.remove(&id) {
                return outcome;
            }
            tokio::select! {
                event = self.events_rx.recv() => match event {
                    Some(event) => self.record(event),
                    None => panic!("line ended"),
                },
                () = tokio::time::sleep_until(deadline) => panic!("no command outcome in 30 s"),
            }
        }
    }

    fn profile_of(&self, device: &str) -> Arc<Profile> {
        PROFILES.with(|p| p.borrow().get(device).cloned().unwrap())
    }

    async fn stop(self) {
        self.trigger.cancel();
        tokio::time::timeout(Duration::from_secs(5), self.task)
            .await
            .expect("the line stops within 5 s")
            .unwrap();
    }
}

thread_local! {
    static PROFILES: std::cell::RefCell<HashMap<String, Arc<Profile>>> =
        std::cell::RefCell::new(HashMap::new());
}

fn remember_profiles(devices: &[DeviceSpec]) {
    PROFILES.with(|p| {
        for d in devices {
            p.borrow_mut().insert(d.name.clone(), d.profile.clone());
        }
    });
}

fn start(name: &str, line: &VirtualLine, parity: Parity, devices: Vec<DeviceSpec>) -> Running {
    remember_profiles(&devices);
    Running::start(line_spec(name, line, parity, devices))
}

/// A virtual line at 9600 baud serving `simulated`, and the line task polling `devices` on it.
fn start_on_new_line(
    name: &str,
    parity: Parity,
    simulated: Vec<SharedDevice>,
    devices: Vec<DeviceSpec>,
) -> (VirtualLine, Running) {
    let line = VirtualLine::spawn(ServeOptions::new(9600, parity), simulated).unwrap();
    let running = start(name, &line, parity, devices);
    (line, running)
}

/// A lone valve at address 1, polled every second on a new 9600 8E1 line, once its first
/// values are in.
async fn valve_with_values(name: &str, valve: SharedDevice) -> (VirtualLine, Running) {
    let (line, mut running) = start_on_new_line(
        name,
        Parity::Even,
        vec![valve],
        vec![device("valve", built_in("wuzhou-valve"), 1, 1000)],
    );
    running
        .wait_for_values("valve", Duration::from_secs(15))
        .await;
    (line, running)
}

/// The dust collector at address 1 and `others` on line-a (9600 8N1), all polled every second,
/// once the dust collector's first values are in.
async fn dust_collector_with_values(
    dust: SharedDevice,
    others: Vec<DeviceSpec>,
) -> (VirtualLine, Running) {
    let devices = std::iter::once(device(
        "dust_collector",
        built_in("ruiwan-dust-collector"),
        1,
        1000,
    ))
    .chain(others)
    .collect();
    let (line, mut running) = start_on_new_line("line-a", Parity::None, vec![dust], devices);
    running
        .wait_for_values("dust_collector", Duration::from_secs(15))
        .await;
    (line, running)
}

fn has_all_fields(running: &Running, device: &str, profile: &Profile) -> bool {
    running
        .latest
        .get(device)
        .is_some_and(|state| profile.fields().iter().all(|f| state.contains_key(&f.name)))
}

fn on_off(on: bool) -> String {
    if on { "ON" } else { "OFF" }.to_string()
}

#[tokio::test(flavor = "current_thread")]
async fn reads_every_block_of_the_three_devices() {
    let (dust, dust_shared) = share(DustCollector::new(1));
    let (shower, shower_shared) = share(AirShower::new());
    let (valve, valve_shared) = share(Valve::new(1));
    sim::lock(&dust).set_power(true);
    sim::lock(&shower).set_coil(air_shower::LIGHT, true);
    sim::lock(&shower).set_coil(air_shower::PHOTO_SENSOR_2, true);
    sim::lock(&valve).set_opening(42);
    let line_a = VirtualLine::spawn(
        ServeOptions::new(9600, Parity::None),
        vec![dust_shared, shower_shared],
    )
    .unwrap();
    let line_b =
        VirtualLine::spawn(ServeOptions::new(9600, Parity::Even), vec![valve_shared]).unwrap();

    let dust_profile = built_in("ruiwan-dust-collector");
    let shower_profile = built_in("lixian-air-shower");
    let valve_profile = built_in("wuzhou-valve");
    let mut a = start(
        "line-a",
        &line_a,
        Parity::None,
        vec![
            device("dust_collector", dust_profile.clone(), 1, 1000),
            device("air_shower", shower_profile.clone(), 0x81, 1000),
        ],
    );
    let mut b = start(
        "line-b",
        &line_b,
        Parity::Even,
        vec![device("valve", valve_profile.clone(), 1, 1000)],
    );

    let complete_a = a
        .until(Duration::from_secs(20), |r| {
            has_all_fields(r, "dust_collector", &dust_profile)
                && has_all_fields(r, "air_shower", &shower_profile)
        })
        .await;
    let complete_b = b
        .until(Duration::from_secs(20), |r| {
            has_all_fields(r, "valve", &valve_profile)
        })
        .await;
    assert!(complete_a, "line A values: {:?}", a.latest);
    assert!(
        a.until(Duration::from_secs(10), |r| r.values_of("dust_collector")
            >= 3)
            .await
    );
    assert!(complete_b, "line B values: {:?}", b.latest);
    assert_eq!(a.went("dust_collector", true), 1);
    assert_eq!(a.went("air_shower", true), 1);
    assert_eq!(b.went("valve", true), 1);

    {
        let dust = sim::lock(&dust);
        assert_eq!(
            a.text("dust_collector", "power"),
            Some(on_off(dust.power()))
        );
        assert_eq!(
            a.text("dust_collector", "gear"),
            Some(dust.gear().to_string())
        );
        assert_eq!(
            a.text("dust_collector", "pulse_interval"),
            Some(dust.pulse_interval().to_string())
        );
        assert_eq!(
            a.text("dust_collector", "pulse_duration"),
            Some(dust.pulse_duration().to_string())
        );
    }
    let coils = sim::lock(&shower).coils();
    for (field, coil) in [
        ("light", air_shower::LIGHT),
        ("front_door_lock", air_shower::FRONT_DOOR_LOCK),
        ("front_door_closed", air_shower::FRONT_DOOR_CLOSED),
        ("photo_sensor_2", air_shower::PHOTO_SENSOR_2),
        ("emergency_stop", air_shower::EMERGENCY_STOP),
    ] {
        assert_eq!(
            a.text("air_shower", field),
            Some(on_off(coils[coil])),
            "{field}"
        );
    }
    assert_eq!(b.text("valve", "opening"), Some("42".to_string()));
    assert_eq!(b.text("valve", "motor"), Some("stopped".to_string()));
    assert_eq!(b.text("valve", "setpoint"), Some("120.00".to_string()));

    // The dust collector was left alone for its 3 s start-up delay and then polled no faster
    // than once a second.
    let dust_frames: Vec<_> = line_a
        .journal()
        .requests()
        .into_iter()
        .filter(|r| r.frame.first() == Some(&1))
        .collect();
    assert!(dust_frames.len() >= 2);
    for pair in dust_frames.windows(2) {
        let gap = pair[1].arrived - pair[0].arrived;
        assert!(
            gap >= Duration::from_millis(900),
            "dust collector polled after {gap:?}"
        );
    }
    let stats = a.handle.stats_rx.borrow().clone();
    assert!(stats.port_open);
    assert!(stats.transactions >= 3);
    assert!(stats.bus_load > 0.0 && stats.bus_load < 1.0);
    a.stop().await;
    b.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn noise_never_yields_a_wrong_value() {
    let (shower, shower_shared) = share(AirShower::new());
    {
        let mut shower = sim::lock(&shower);
        for coil in [
            air_shower::FRONT_DOOR_LOCK,
            air_shower::TUNNEL_EXTENSION,
            air_shower::BUZZER,
            air_shower::PHOTO_SENSOR_1,
            air_shower::HEPA_FILTER_EXPIRED,
        ] {
            shower.set_coil(coil, true);
        }
    }
    let line = VirtualLine::spawn(
        ServeOptions::new(9600, Parity::None).paced(true),
        vec![shower_shared],
    )
    .unwrap();
    line.faults().set(Faults {
        corrupt_crc: Occurrence::probability(0.15),
        truncate: Occurrence::probability(0.15),
        truncate_bytes: 2,
        garbage_before: Occurrence::probability(0.15),
        garbage_bytes: 5,
        wrong_address: Occurrence::probability(0.1),
        wrong_address_value: 9,
        idle_garbage_every: Some(Duration::from_millis(300)),
        ..Faults::default()
    });
    let profile = fast_air_shower();
    let mut running = start(
        "noisy",
        &line,
        Parity::None,
        vec![device("air_shower", profile, 0x81, 0)],
    );
    let enough = running
        .until(Duration::from_secs(30), |r| r.polls_ok("air_shower") >= 60)
        .await;
    assert!(
        enough,
        "only {} polls delivered",
        running.polls_ok("air_shower")
    );
    // Every value the line sent is checked below; a wrong one would differ from the last
    // answer, so it would have been sent.
    assert!(running.values_of("air_shower") >= 1);
    let coils = sim::lock(&shower).coils();
    let expected: HashMap<&str, String> = [
        ("front_door_lock", air_shower::FRONT_DOOR_LOCK),
        ("rear_door_lock", air_shower::REAR_DOOR_LOCK),
        ("tunnel_extension", air_shower::TUNNEL_EXTENSION),
        ("buzzer", air_shower::BUZZER),
        ("light", air_shower::LIGHT),
        ("photo_sensor_1", air_shower::PHOTO_SENSOR_1),
        ("hepa_filter_expired", air_shower::HEPA_FILTER_EXPIRED),
        ("prefilter_expired", air_shower::PREFILTER_EXPIRED),
    ]
    .into_iter()
    .map(|(field, coil)| (field, on_off(coils[coil])))
    .collect();
    for (_, _, values) in &running.values {
        for (field, value) in values {
            if let Some(want) = expected.get(field.as_str()) {
                assert_eq!(&value.to_text(), want, "{field} from a noisy line");
            }
        }
    }
    let stats = running.handle.stats_rx.borrow().clone();
    let device = &stats.devices[0];
    assert!(
        device.crc_errors + device.bad_answers + device.timeouts > 0,
        "the faults never struck: {device:?}"
    );
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn an_unchanged_answer_sends_nothing_and_a_change_is_sent() {
    let (shower, shower_shared) = share(AirShower::new());
    let (_line, mut running) = start_on_new_line(
        "unchanged",
        Parity::None,
        vec![shower_shared],
        vec![device("air_shower", fast_air_shower(), 0x81, 0)],
    );
    assert!(
        running
            .until(Duration::from_secs(20), |r| r.polls_ok("air_shower") >= 10)
            .await
    );
    // Ten answers, one set of values: the answer never changed.
    assert_eq!(running.values_of("air_shower"), 1);
    assert_eq!(running.text("air_shower", "light").as_deref(), Some("OFF"));

    assert!(sim::lock(&shower).set_coil(air_shower::LIGHT, true));
    assert!(
        running
            .until(Duration::from_secs(10), |r| r
                .text("air_shower", "light")
                .as_deref()
                == Some("ON"))
            .await,
        "the change was never sent"
    );
    assert_eq!(running.values_of("air_shower"), 2);
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn busy_answers_are_retried_and_never_take_the_device_offline() {
    let (_shower, shower_shared) = share(AirShower::new());
    let line =
        VirtualLine::spawn(ServeOptions::new(9600, Parity::None), vec![shower_shared]).unwrap();
    // The longest run of busy answers that still counts as a device that is there; a random
    // pattern would sometimes reach the limit and make the outcome a matter of luck.
    let streak = BUSY_LIMIT - 1;
    let busy_streak = Faults {
        exception: Occurrence::next(streak),
        exception_code: Some(rtu2mqtt_modbus::ExceptionCode::ServerDeviceBusy),
        ..Faults::default()
    };
    line.faults().set(busy_streak.clone());
    let mut spec = line_spec(
        "busy",
        &line,
        Parity::None,
        vec![device("air_shower", fast_air_shower(), 0x81, 0)],
    );
    spec.offline_after = 1;
    remember_profiles(&spec.devices);
    let mut running = Running::start(spec);
    let exceptions = |r: &Running| r.handle.stats_rx.borrow().devices[0].exceptions;
    assert!(
        running
            .until(Duration::from_secs(20), |r| r.polls_ok("air_shower") >= 10)
            .await
    );
    assert_eq!(exceptions(&running), u64::from(streak));
    // An answer ends the streak: a second one right after is again not an outage.
    line.faults().set(busy_streak);
    let answered = running.polls_ok("air_shower");
    assert!(
        running
            .until(Duration::from_secs(20), |r| r.polls_ok("air_shower")
                >= answered + 10)
            .await
    );
    assert_eq!(exceptions(&running), 2 * u64::from(streak));
    assert_eq!(running.went("air_shower", false), 0);
    assert_eq!(running.went("air_shower", true), 1);
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn a_silent_device_times_out_goes_offline_and_comes_back_without_starving_the_other() {
    let (_dust, dust_shared) = share(DustCollector::new(1));
    let (_shower, shower_shared) = share(AirShower::new());
    let (line, mut running) = start_on_new_line(
        "line-a",
        Parity::None,
        vec![dust_shared, shower_shared],
        vec![
            device("dust_collector", built_in("ruiwan-dust-collector"), 1, 1000),
            device("air_shower", built_in("lixian-air-shower"), 0x81, 500),
        ],
    );
    assert!(
        running
            .until(Duration::from_secs(15), |r| r.went("dust_collector", true)
                == 1)
            .await
    );
    let shower_polls = |r: &Running| r.handle.stats_rx.borrow().devices[1].polls_ok;

    line.faults().silence(1, true);
    let silenced_at = Instant::now();
    let before = shower_polls(&running);
    assert!(
        running
            .until(Duration::from_secs(20), |r| r.went("dust_collector", false)
                == 1)
            .await,
        "the silent dust collector never went offline"
    );
    // Offline after three failed polls (1 s apart, each at most two timeouts long).
    assert!(silenced_at.elapsed() < Duration::from_secs(10));
    // Keep the dust collector dead for a while: it is only probed now.
    running.run_for(Duration::from_secs(4)).await;
    let dead_for = silenced_at.elapsed().as_secs_f64();
    let during = shower_polls(&running) - before;
    // The air shower polls every 500 ms: it must keep most of its rate (at least 60 %).
    let rate = during as f64 / dead_for;
    assert!(
        rate >= 1.2,
        "air shower polled {rate:.2}/s while the dust collector was dead"
    );
    let dust_stats = running.handle.stats_rx.borrow().devices[0].clone();
    assert!(dust_stats.timeouts >= 3, "{dust_stats:?}");
    assert!(!dust_stats.online);

    line.faults().silence(1, false);
    let revived_at = Instant::now();
    assert!(
        running
            .until(Duration::from_secs(20), |r| r.went("dust_collector", true)
                == 2)
            .await,
        "the dust collector never came back"
    );
    // Values are sent again after the comeback.
    let back = running.availability.last().map(|a| a.0).unwrap();
    assert!(
        running
            .until(Duration::from_secs(5), |r| r
                .values
                .iter()
                .any(|v| v.1 == "dust_collector" && v.0 >= back))
            .await
    );
    assert!(revived_at.elapsed() < Duration::from_secs(20));
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn a_command_overtakes_queued_polls() {
    let (shower, shower_shared) = share(AirShower::new());
    let line = VirtualLine::spawn(
        ServeOptions::new(9600, Parity::None).paced(true),
        vec![shower_shared],
    )
    .unwrap();
    let profile = fast_air_shower();
    let mut running = start(
        "busy-line",
        &line,
        Parity::None,
        vec![device("air_shower", profile.clone(), 0x81, 0)],
    );
    assert!(
        running
            .until(Duration::from_secs(10), |r| r.values_of("air_shower") >= 1
                && r.polls_ok("air_shower") >= 5)
            .await
    );
    let state = running.latest.get("air_shower").cloned().unwrap();
    let plan = profile.plan_command("light", "ON", &state).unwrap();
    let reads_before = plan.reads_before().len();
    let sent_after = line.journal().request_count();
    let outcome = running.send("air_shower", plan).await;
    assert!(
        matches!(outcome, CommandOutcome::Applied { .. }),
        "{outcome:?}"
    );
    assert!(sim::lock(&shower).coils()[air_shower::LIGHT]);
    let frames = line.journal().frames();
    let write_at = frames
        .iter()
        .skip(sent_after)
        .position(|frame| frame.get(1) == Some(&0x0F))
        .expect("the write is on the wire");
    // At most the transaction in flight when the command arrived, then the command's own
    // reads, then its write: no queued poll in between.
    assert!(
        write_at <= 1 + reads_before,
        "{write_at} frames before the write, {reads_before} of them the command's reads"
    );
    let stats = running.handle.stats_rx.borrow().clone();
    assert_eq!(stats.commands, 1);
    assert!(stats.last_command_latency.is_some());
    // Polled back to back: the line measured its own time between transactions.
    assert!(stats.turnaround_mean.is_some());
    assert!(stats.turnaround_worst >= stats.turnaround_mean);
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn read_modify_write_keeps_the_dust_collectors_internal_bits() {
    let (dust, dust_shared) = share(DustCollector::new(1));
    sim::lock(&dust).set_internal_bits(0x2040);
    sim::lock(&dust).set_alarms(0x0002);
    let internal_and_alarms = sim::lock(&dust).status_word() & !0x0300;
    let (_line, mut running) = dust_collector_with_values(dust_shared, vec![]).await;
    let outcome = running.command("dust_collector", "power", "ON").await;
    assert!(
        matches!(outcome, CommandOutcome::Applied { .. }),
        "{outcome:?}"
    );
    let outcome = running
        .command("dust_collector", "pulse_cleaning", "ON")
        .await;
    assert!(
        matches!(outcome, CommandOutcome::Applied { .. }),
        "{outcome:?}"
    );
    {
        let dust = sim::lock(&dust);
        assert!(dust.power());
        assert!(dust.pulse_cleaning());
        assert_eq!(dust.status_word() & !0x0300, internal_and_alarms);
        assert_eq!(dust.violations(), Vec::<String>::new());
    }
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn the_valve_falls_back_to_small_reads_after_exception_02_and_remembers() {
    let (valve, valve_shared) = share(Valve::new(1));
    sim::lock(&valve).set_drift(false);
    let profile = built_in("wuzhou-valve");
    let (line, mut running) = start_on_new_line(
        "line-b",
        Parity::Even,
        vec![valve_shared],
        vec![device("valve", profile.clone(), 1, 500)],
    );
    assert!(
        running
            .until(Duration::from_secs(20), |r| {
                has_all_fields(r, "valve", &profile) && r.polls_ok("valve") >= 12
            })
            .await,
        "valve values: {:?}",
        running.latest.get("valve")
    );
    let merged: Vec<(usize, &rtu2mqtt_profile::ReadBlock)> = profile
        .read_blocks()
        .iter()
        .enumerate()
        .filter(|(_, block)| block.used_runs.len() > 1)
        .collect();
    assert!(
        !merged.is_empty(),
        "the valve profile merges neighbouring fields"
    );
    let frames = line.journal().frames();
    for (_, block) in merged {
        let rtu2mqtt_modbus::Request::ReadHoldingRegisters { start, quantity } = block.request
        else {
            continue;
        };
        let head = [
            1,
            3,
            (start >> 8) as u8,
            start as u8,
            (quantity >> 8) as u8,
            quantity as u8,
        ];
        let tries = frames.iter().filter(|f| f.starts_with(&head)).count();
        assert!(
            tries <= 1,
            "block {} was sent {tries} times although the valve refused it",
            block.name
        );
    }
    assert_eq!(running.went("valve", false), 0);
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn a_valve_opening_command_settles_before_it_is_applied() {
    let (valve, valve_shared) = share(Valve::new(1));
    sim::lock(&valve).set_speed(20.0);
    let (_line, mut running) = valve_with_values("line-b", valve_shared).await;
    let started = Instant::now();
    let outcome = running.command("valve", "opening", "60").await;
    assert!(
        matches!(outcome, CommandOutcome::Applied { .. }),
        "{outcome:?}"
    );
    // 30 % → 60 % at 20 %/s takes about 1.5 s: the first read-back cannot have confirmed it.
    assert!(started.elapsed() >= Duration::from_millis(1000));
    assert_eq!(sim::lock(&valve).opening(), 60);
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn a_jammed_valve_is_not_applied_as_soon_as_its_motor_reports_stopped() {
    let (valve, valve_shared) = share(Valve::new(1));
    sim::lock(&valve).set_jammed(true);
    let (_line, mut running) = valve_with_values("line-jam", valve_shared).await;
    let reached = sim::lock(&valve).opening();
    let started = Instant::now();
    let outcome = running.command("valve", "opening", "90").await;
    let CommandOutcome::NotApplied { detail } = &outcome else {
        panic!("a jammed valve gave {outcome:?}");
    };
    assert!(
        detail.contains(&format!("opening reads {reached} after writing 90")),
        "{detail}"
    );
    assert!(detail.contains("motor reads stopped"), "{detail}");
    // Judged on the stopped motor, not by waiting out the 60 s settle window.
    assert!(
        started.elapsed() < Duration::from_secs(30),
        "took {:?}",
        started.elapsed()
    );
    assert_eq!(sim::lock(&valve).opening(), reached);
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn the_port_disappearing_and_coming_back_is_reopened() {
    let directory = tempfile::tempdir().unwrap();
    let link = directory.path().join("ttyRS485");
    let (_shower, shower_shared) = share(AirShower::new());
    let mut line = VirtualLine::with_link(
        ServeOptions::new(9600, Parity::None),
        vec![shower_shared],
        &link,
    )
    .unwrap();
    let mut running = start(
        "unplugged",
        &line,
        Parity::None,
        vec![device("air_shower", fast_air_shower(), 0x81, 100)],
    );
    assert!(
        running
            .until(Duration::from_secs(10), |r| r.values_of("air_shower") >= 1
                && r.polls_ok("air_shower") >= 3)
            .await
    );
    line.unplug().await;
    assert!(
        running
            .until(Duration::from_secs(10), |r| r.went("air_shower", false)
                == 1)
            .await,
        "no offline event after the unplug"
    );
    let failures_then = running.handle.stats_rx.borrow().port_failures;
    running.run_for(Duration::from_secs(3)).await;
    let stats = running.handle.stats_rx.borrow().clone();
    assert!(!stats.port_open);
    // Back-off 100 ms doubling to 3 s: a handful of attempts in 3 s, not a spin.
    let attempts = stats.port_failures - failures_then;
    assert!(attempts <= 8, "{attempts} open attempts in 3 s");
    // A command meanwhile fails at once instead of waiting for the port.
    let state = running.latest.get("air_shower").cloned().unwrap();
    let plan = fast_air_shower()
        .plan_command("light", "ON", &state)
        .unwrap();
    let outcome = running.send("air_shower", plan).await;
    assert!(
        matches!(outcome, CommandOutcome::Failed { .. }),
        "{outcome:?}"
    );

    line.replug().await.unwrap();
    let replugged = Instant::now();
    assert!(
        running
            .until(Duration::from_secs(10), |r| r.went("air_shower", true) == 2)
            .await,
        "not back online after the replug"
    );
    assert!(replugged.elapsed() < Duration::from_secs(10));
    // Polled again, and its values sent again although they did not change: the line
    // forgot its last answers when the device went offline.
    let values_before = running.values_of("air_shower");
    let polls_before = running.polls_ok("air_shower");
    assert!(
        running
            .until(Duration::from_secs(5), |r| r.values_of("air_shower")
                > values_before
                && r.polls_ok("air_shower") > polls_before + 2)
            .await
    );
    assert!(running.handle.stats_rx.borrow().port_open);
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn statistics_heartbeat_keeps_coming_while_idle() {
    let (_shower, shower_shared) = share(AirShower::new());
    let (_line, mut running) = start_on_new_line(
        "idle",
        Parity::None,
        vec![shower_shared],
        vec![device(
            "air_shower",
            built_in("lixian-air-shower"),
            0x81,
            60_000,
        )],
    );
    running.run_for(Duration::from_millis(2500)).await;
    let first = running.handle.stats_rx.borrow().heartbeat;
    running.run_for(Duration::from_millis(2500)).await;
    let second = running.handle.stats_rx.borrow().heartbeat;
    assert!(second > first, "no heartbeat while the line was idle");
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn a_broadcast_command_is_sent_without_waiting_for_an_answer_and_keeps_the_turnaround() {
    let (dust, dust_shared) = share(DustCollector::new(1));
    sim::lock(&dust).set_power(true);
    let broadcast = device(
        "every_dust_collector",
        built_in("ruiwan-dust-collector"),
        0,
        1000,
    );
    let (line, mut running) = dust_collector_with_values(dust_shared, vec![broadcast]).await;
    let before = line.journal().request_count();
    let wanted = if sim::lock(&dust).gear() == 7 {
        "8"
    } else {
        "7"
    };
    let outcome = running
        .command("every_dust_collector", "gear", wanted)
        .await;
    assert!(
        matches!(outcome, CommandOutcome::Applied { .. }),
        "{outcome:?}"
    );
    assert_eq!(sim::lock(&dust).gear().to_string(), wanted);
    // The next poll waits out the broadcast's turnaround (100 ms here).
    assert!(
        running
            .until(Duration::from_secs(5), |_| line.journal().request_count()
                >= before + 2)
            .await
    );
    let records = line.journal().requests();
    let broadcast = &records[before];
    assert_eq!(broadcast.frame[0], 0);
    assert!(broadcast.answer.is_none());
    let next = &records[before + 1];
    assert!(next.arrived - broadcast.arrived >= Duration::from_millis(100));
    // No device named by address 0 is ever polled or reported.
    assert!(records
        .iter()
        .all(|r| r.frame[0] != 0 || r.frame[1] == 0x06));
    assert_eq!(running.values_of("every_dust_collector"), 0);
    running.stop().await;
}

#[tokio::test(flavor = "current_thread")]
async fn commands_fail_with_the_exception_code_or_after_the_retries() {
    let (shower, shower_shared) = share(AirShower::new());
    let (line, mut running) = start_on_new_line(
        "line-a",
        Parity::None,
        vec![shower_shared],
        vec![device("air_shower", fast_air_shower(), 0x81, 200)],
    );
    running
        .wait_for_values("air_shower", Duration::from_secs(10))
        .await;
    line.faults().set(Faults {
        exception: Occurrence::ALWAYS,
        exception_code: Some(rtu2mqtt_modbus::ExceptionCode::ServerDeviceFailure),
        ..Faults::default()
    });
    let writes_before = line.journal().writes_to(air_shower::ADDRESS);
    match running.command("air_shower", "light", "ON").await {
        CommandOutcome::Failed { cause } => {
            let detail = cause.to_string();
            assert!(detail.contains("04"), "{detail}");
            // The device's exception stays its own answer, apart from transport failures.
            assert_eq!(
                cause,
                CommandFailure::Exception(rtu2mqtt_modbus::ExceptionCode::ServerDeviceFailure)
            );
        }
        other => panic!("expected a failure, got {other:?}"),
    }
    line.faults().clear();
    line.faults().silence(air_shower::ADDRESS, true);
    match running.command("air_shower", "light", "ON").await {
        CommandOutcome::Failed { cause } => {
            let detail = cause.to_string();
            assert!(detail.contains("no answer"), "{detail}");
            assert!(
                matches!(
                    cause,
                    CommandFailure::NoAnswer(rtu2mqtt_modbus::Error::Timeout(_))
                ),
                "{cause:?}"
            );
        }
        other => panic!("expected a failure, got {other:?}"),
    }
    // The read-modify-write never got its fresh read: nothing was written.
    assert_eq!(line.journal().writes_to(air_shower::ADDRESS), writes_before);
    assert!(!sim::lock(&shower).coils()[air_shower::LIGHT]);
    running.stop().await;
}
