//! The end-to-end test harness every integration test and benchmark of the workspace shares.
//!
//! - This file: a real mosquitto on a free loopback port ([`Mosquitto`]: temporary config,
//!   killed on drop, restartable on the same port), a small rumqttc client that records what it
//!   receives ([`TestClient`]), and the gateway over the simulated seed plant ([`PlantConfig`],
//!   [`Gateway`]: its configuration, started and stopped by a test).
//! - [`plant_bench`]: the broker + plant + gateway bench most end-to-end tests stand on
//!   ([`PlantBench`]).
//! - [`child`]: the workspace's binaries as child processes, killed and reaped on drop.
//! - [`command`]: a command's refusal by a profile, for asserting the same words as the gateway.
//! - [`hex`]: frames as hex text.
//! - [`pysparkplug`]: the Sparkplug B decoder written by others, run through Python.

pub mod child;
pub mod command;
pub mod hex;
pub mod plant_bench;
pub mod pysparkplug;

pub use plant_bench::{PlantBench, PlantSetup, PLANT_ANSWER, SEED_DEVICES};

use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use child::KillOnDrop;
use rtu2mqtt::app::{run_gateway, Hooks, Running};
use rtu2mqtt::config::Config;
use rtu2mqtt_sim::SeedPlant;
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

pub const MOSQUITTO: &str = "/usr/sbin/mosquitto";

/// A mosquitto broker owned by a test.
pub struct Mosquitto {
    pub port: u16,
    /// More listeners and settings (after the anonymous loopback listener on `port`).
    extra: String,
    child: Option<KillOnDrop>,
    dir: tempfile::TempDir,
}

impl Mosquitto {
    /// Starts a broker on a free 127.0.0.1 port and waits until it accepts connections.
    pub fn start() -> Mosquitto {
        Mosquitto::start_with(String::new())
    }

    /// Like [`start`] with more configuration; listeners it adds must use
    /// `per_listener_settings`-style settings of their own.
    pub fn start_with(extra: String) -> Mosquitto {
        let port = free_port();
        let dir = tempfile::tempdir().expect("temp dir");
        let mut broker = Mosquitto {
            port,
            extra,
            child: None,
            dir,
        };
        broker.launch();
        broker
    }

    /// A broker that is not running yet (its port chosen): start it with [`restart`].
    pub fn not_started() -> Mosquitto {
        Mosquitto {
            port: free_port(),
            extra: String::new(),
            child: None,
            dir: tempfile::tempdir().expect("temp dir"),
        }
    }

    /// A loopback TLS listener on its own port that wants a client certificate signed by the
    /// test CA and a user name and password (`gateway` / `s3cret`), beside the plain
    /// anonymous one. Returns the broker, the TLS port and the directory with `ca.crt`,
    /// `client.crt`, `client.key` and `password` (mode 0600).
    pub fn start_tls() -> (Mosquitto, u16, tempfile::TempDir) {
        let certs = tempfile::tempdir().expect("temp dir");
        let dir = certs.path();
        std::fs::write(
            dir.join("server.ext"),
            "subjectAltName=DNS:localhost,IP:127.0.0.1\n",
        )
        .unwrap();
        std::fs::write(dir.join("client.ext"), "extendedKeyUsage=clientAuth\n").unwrap();
        let openssl = |args: &[&str]| {
            let status = Command::new("openssl")
                .args(args)
                .current_dir(dir)
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .expect("run openssl");
            assert!(status.success(), "openssl {args:?} failed");
        };
        openssl(&[
            "req",
            "-x509",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-keyout",
            "ca.key",
            "-out",
            "ca.crt",
            "-days",
            "2",
            "-subj",
            "/CN=rtu2mqtt-test-ca",
        ]);
        for (name, ext) in [("server", "server.ext"), ("client", "client.ext")] {
            openssl(&[
                "req",
                "-newkey",
                "rsa:2048",
                "-nodes",
                "-keyout",
                &format!("{name}.key"),
                "-out",
                &format!("{name}.csr"),
                "-subj",
                &format!("/CN={name}"),
            ]);
            openssl(&[
                "x509",
                "-req",
                "-in",
                &format!("{name}.csr"),
                "-CA",
                "ca.crt",
                "-CAkey",
                "ca.key",
                "-CAcreateserial",
                "-out",
                &format!("{name}.crt"),
                "-days",
                "2",
                "-extfile",
                ext,
            ]);
        }
        let passwd = dir.join("mosquitto.passwd");
        let status = Command::new("mosquitto_passwd")
            .args(["-c", "-b"])
            .arg(&passwd)
            .args(["gateway", "s3cret"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .expect("run mosquitto_passwd");
        assert!(status.success());
        std::fs::write(dir.join("password"), "s3cret\n").unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(dir.join("password"), std::fs::Permissions::from_mode(0o600))
            .unwrap();
        // mosquitto drops root privileges: let it read the broker's files.
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o755)).unwrap();
        for file in ["ca.crt", "server.crt", "server.key", "mosquitto.passwd"] {
            std::fs::set_permissions(dir.join(file), std::fs::Permissions::from_mode(0o644))
                .unwrap();
        }
        let tls_port = free_port();
        let extra = format!(
            "listener {tls_port} 127.0.0.1\nallow_anonymous false\npassword_file {passwd}\n\
             cafile {ca}\ncertfile {cert}\nkeyfile {key}\nrequire_certificate true\n",
            passwd = passwd.display(),
            ca = dir.join("ca.crt").display(),
            cert = dir.join("server.crt").display(),
            key = dir.join("server.key").display(),
        );
        (Mosquitto::start_with(extra), tls_port, certs)
    }

    pub fn url(&self) -> String {
        format!("mqtt://127.0.0.1:{}", self.port)
    }

    fn config_path(&self) -> PathBuf {
        self.dir.path().join("mosquitto.conf")
    }

    fn launch(&mut self) {
        let config = format!(
            "per_listener_settings true\npersistence false\n\
             log_dest file {}\nlog_type all\nlistener {} 127.0.0.1\nallow_anonymous true\n{}",
            self.dir.path().join("mosquitto.log").display(),
            self.port,
            self.extra
        );
        std::fs::write(self.config_path(), config).expect("write mosquitto.conf");
        // mosquitto drops root privileges before it opens its log: let it write there.
        {
            use std::os::unix::fs::PermissionsExt;
            let log = self.dir.path().join("mosquitto.log");
            let _ = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(&log);
            let _ = std::fs::set_permissions(&log, std::fs::Permissions::from_mode(0o666));
            let _ =
                std::fs::set_permissions(self.dir.path(), std::fs::Permissions::from_mode(0o755));
        }
        let mut command = Command::new(MOSQUITTO);
        command
            .arg("-c")
            .arg(self.config_path())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        self.child = Some(KillOnDrop::spawn(command).expect("start mosquitto"));
        let deadline = Instant::now() + Duration::from_secs(10);
        while TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            assert!(Instant::now() < deadline, "mosquitto did not start");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// SIGKILL: no Will for anyone, retained messages gone (no persistence).
    pub fn kill(&mut self) {
        self.child = None;
    }

    /// Stops (SIGSTOP) or continues (SIGCONT) the broker process: a broker that stops
    /// answering while its sockets stay open.
    pub fn signal(&self, signal: nix::sys::signal::Signal) {
        if let Some(child) = &self.child {
            nix::sys::signal::kill(child.pid(), signal).expect("signal mosquitto");
        }
    }

    /// Starts again on the same port.
    pub fn restart(&mut self) {
        self.kill();
        self.launch();
    }

    /// The broker's log so far (for failure messages).
    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("mosquitto.log")).unwrap_or_default()
    }
}

/// A port nobody listens on right now.
pub fn free_port() -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind a free port");
    listener.local_addr().expect("local address").port()
}

/// One message as a subscriber saw it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Message {
    pub topic: String,
    pub payload: Vec<u8>,
    pub retain: bool,
}

impl Message {
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.payload).into_owned()
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.payload).unwrap_or(serde_json::Value::Null)
    }
}

enum ClientEvent {
    Message(Message),
    SubAck,
}

/// A test's MQTT client: subscribe, publish, wait for messages.
pub struct TestClient {
    pub client: AsyncClient,
    rx: mpsc::UnboundedReceiver<ClientEvent>,
    /// Everything received so far, in order.
    pub received: Vec<Message>,
    task: tokio::task::JoinHandle<()>,
}

impl TestClient {
    /// Connects (clean session) and waits for the ConnAck.
    pub async fn connect(port: u16, id: &str) -> TestClient {
        let mut options = MqttOptions::new(id, "127.0.0.1", port);
        options.set_keep_alive(Duration::from_secs(5));
        options.set_max_packet_size(1024 * 1024, 1024 * 1024);
        let (client, mut eventloop) = AsyncClient::new(options, 100);
        let (tx, rx) = mpsc::unbounded_channel();
        let (connected_tx, connected_rx) = tokio::sync::oneshot::channel();
        let task = tokio::spawn(async move {
            let mut connected_tx = Some(connected_tx);
            loop {
                match eventloop.poll().await {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => {
                        if let Some(tx) = connected_tx.take() {
                            let _ = tx.send(());
                        }
                    }
                    Ok(Event::Incoming(Packet::Publish(publish))) => {
                        let message = Message {
                            topic: publish.topic.clone(),
                            payload: publish.payload.to_vec(),
                            retain: publish.retain,
                        };
                        if tx.send(ClientEvent::Message(message)).is_err() {
                            return;
                        }
                    }
                    Ok(Event::Incoming(Packet::SubAck(_))) => {
                        if tx.send(ClientEvent::SubAck).is_err() {
                            return;
                        }
                    }
                    Ok(_) => {}
                    Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
                }
            }
        });
        tokio::time::timeout(Duration::from_secs(10), connected_rx)
            .await
            .expect("test client connect timed out")
            .expect("test client event loop ended");
        TestClient {
            client,
            rx,
            received: Vec::new(),
            task,
        }
    }

    /// Subscribes and waits for the SubAck.
    pub async fn subscribe(&mut self, filter: &str) {
        self.client
            .subscribe(filter, QoS::AtLeastOnce)
            .await
            .expect("subscribe");
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        loop {
            match tokio::time::timeout_at(deadline, self.rx.recv()).await {
                Ok(Some(ClientEvent::SubAck)) => return,
                Ok(Some(ClientEvent::Message(message))) => self.received.push(message),
                _ => panic!("no SubAck for {filter}"),
            }
        }
    }

    pub async fn publish(&self, topic: &str, payload: impl Into<Vec<u8>>, retain: bool) {
        self.client
            .publish(topic, QoS::AtLeastOnce, retain, payload.into())
            .await
            .expect("publish");
    }

    /// Waits for the next message on `topic` that satisfies `accept` (messages received
    /// earlier are looked at first, from the oldest not yet taken).
    pub async fn wait_for(
        &mut self,
        topic: &str,
        timeout: Duration,
        accept: impl Fn(&Message) -> bool,
    ) -> Message {
        self.try_wait_for(topic, timeout, accept)
            .await
            .unwrap_or_else(|| {
                let seen: Vec<String> = self
                    .received
                    .iter()
                    .filter(|m| m.topic == topic)
                    .map(|m| m.text())
                    .collect();
                panic!("no matching message on {topic} within {timeout:?}; seen there: {seen:?}")
            })
    }

    /// Like [`wait_for`] but None on timeout.
    pub async fn try_wait_for(
        &mut self,
        topic: &str,
        timeout: Duration,
        accept: impl Fn(&Message) -> bool,
    ) -> Option<Message> {
        if let Some(index) = self
            .received
            .iter()
            .position(|m| m.topic == topic && accept(m))
        {
            return Some(self.received.remove(index));
        }
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            match tokio::time::timeout_at(deadline, self.rx.recv()).await {
                Ok(Some(ClientEvent::Message(message))) => {
                    if message.topic == topic && accept(&message) {
                        return Some(message);
                    }
                    self.received.push(message);
                }
                Ok(Some(ClientEvent::SubAck)) => {}
                _ => return None,
            }
        }
    }

    /// Like [`wait_for`], ignoring what arrived on `topic` before this call (a state change
    /// that has to happen from now on, not one seen at start-up).
    pub async fn wait_for_new(
        &mut self,
        topic: &str,
        timeout: Duration,
        accept: impl Fn(&Message) -> bool,
    ) -> Message {
        self.drain();
        self.received.retain(|m| m.topic != topic);
        self.wait_for(topic, timeout, accept).await
    }

    /// Moves whatever has arrived into `received` without waiting.
    pub fn drain(&mut self) {
        while let Ok(event) = self.rx.try_recv() {
            if let ClientEvent::Message(message) = event {
                self.received.push(message);
            }
        }
    }

    /// Waits for the next message on `topic`, whatever it says.
    pub async fn next_on(&mut self, topic: &str, timeout: Duration) -> Message {
        self.wait_for(topic, timeout, |_| true).await
    }

    /// Collects everything arriving for `duration` into `received`.
    pub async fn settle(&mut self, duration: Duration) {
        let deadline = tokio::time::Instant::now() + duration;
        while let Ok(Some(event)) = tokio::time::timeout_at(deadline, self.rx.recv()).await {
            if let ClientEvent::Message(message) = event {
                self.received.push(message);
            }
        }
    }

    /// Forgets what was received so far (after settling).
    pub fn forget(&mut self) {
        self.received.clear();
    }

    /// Messages received on `topic` (not yet taken by a wait).
    pub fn on(&self, topic: &str) -> Vec<&Message> {
        self.received.iter().filter(|m| m.topic == topic).collect()
    }
}

impl Drop for TestClient {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Generous bound for the gateway to get ready and to stop on a busy 2-core machine: it only
/// runs out when something is broken.
const GATEWAY_BOUND: Duration = Duration::from_secs(15);

/// The gateway configuration for the seed plant: line-a (dust collector at 1, air shower at
/// 0x81) and line-b (valve at 1, even parity), prefix `plant`, 150 ms response timeout. The
/// fields add what a test needs on top.
#[derive(Default)]
pub struct PlantConfig<'a> {
    /// `[mqtt] discovery`.
    pub discovery: bool,
    /// The body of a `[gateway]` table; no table when empty.
    pub gateway: &'a str,
    /// Writes `baud = 9600` on both lines and `parity = "none"` on line-a instead of leaving
    /// them to the profiles' defaults.
    pub explicit_serial: bool,
    /// More keys for both lines.
    pub line_keys: &'a str,
    /// More keys for the dust collector.
    pub dust_collector_keys: &'a str,
}

impl PlantConfig<'_> {
    /// The configuration text for `plant` behind `broker`, connecting as `client_id`.
    pub fn text(&self, broker: &Mosquitto, plant: &SeedPlant, client_id: &str) -> String {
        let gateway = if self.gateway.is_empty() {
            String::new()
        } else {
            format!("\n[gateway]\n{}\n", self.gateway)
        };
        let (line_a_serial, line_b_serial) = if self.explicit_serial {
            ("baud = 9600\nparity = \"none\"\n", "baud = 9600\n")
        } else {
            ("", "")
        };
        let line_keys = with_newline(self.line_keys);
        format!(
            r#"
[mqtt]
url = "{url}"
client_id = "{client_id}"
prefix = "plant"
discovery = {discovery}
{gateway}
[[lines]]
name = "line-a"
port = "{line_a}"
{line_a_serial}response_timeout = "150ms"
{line_keys}
[[lines.devices]]
name = "dust_collector"
profile = "ruiwan-dust-collector"
address = 1
{dust_collector_keys}
[[lines.devices]]
name = "air_shower"
profile = "lixian-air-shower"
address = 0x81

[[lines]]
name = "line-b"
port = "{line_b}"
{line_b_serial}parity = "even"
response_timeout = "150ms"
{line_keys}
[[lines.devices]]
name = "valve"
profile = "wuzhou-valve"
address = 1
"#,
            url = broker.url(),
            discovery = self.discovery,
            line_a = plant.line_a.path().display(),
            line_b = plant.line_b.path().display(),
            dust_collector_keys = with_newline(self.dust_collector_keys),
        )
    }
}

/// `keys` as lines of a table: followed by a newline unless empty.
fn with_newline(keys: &str) -> String {
    if keys.is_empty() {
        String::new()
    } else {
        format!("{keys}\n")
    }
}

/// The gateway (`run_gateway`) running in a task of the test's runtime.
pub struct Gateway {
    trigger: CancellationToken,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
    pub running: Running,
}

impl Gateway {
    /// Starts the gateway and waits until it is ready.
    pub async fn start(config: Config) -> Gateway {
        let shutdown = CancellationToken::new();
        let trigger = shutdown.clone();
        let (ready_tx, ready_rx) = tokio::sync::oneshot::channel();
        let hooks = Hooks {
            ready_tx: Some(ready_tx),
            ..Hooks::default()
        };
        let task = tokio::spawn(run_gateway(config, shutdown, hooks));
        let running = tokio::time::timeout(GATEWAY_BOUND, ready_rx)
            .await
            .expect("gateway not ready in time")
            .expect("gateway ended before it was ready");
        Gateway {
            trigger,
            task,
            running,
        }
    }

    /// Starts the gateway as [`Gateway::start`] does, reloading `path` whenever the returned
    /// sender sends (as SIGHUP does for `run`).
    pub async fn start_reloadable(
        config: Config,
        path: std::path::PathBuf,
    ) -> (Gateway, tokio::sync::mpsc::Sender<()>) {
        let shutdown = CancellationToken::new();
        let trigger = shutdown.clone();
        let (ready_tx, ready_rx) = tokio::sync::oneshot::channel();
        let (reload_tx, requests) = tokio::sync::mpsc::channel(1);
        let hooks = Hooks {
            ready_tx: Some(ready_tx),
            reload: Some(rtu2mqtt::app::reload::ReloadSource { path, requests }),
        };
        let task = tokio::spawn(run_gateway(config, shutdown, hooks));
        let running = tokio::time::timeout(GATEWAY_BOUND, ready_rx)
            .await
            .expect("gateway not ready in time")
            .expect("gateway ended before it was ready");
        let gateway = Gateway {
            trigger,
            task,
            running,
        };
        (gateway, reload_tx)
    }

    /// Asks the gateway to stop and waits until it has ended cleanly.
    pub async fn stop(self) {
        self.trigger.cancel();
        tokio::time::timeout(GATEWAY_BOUND, self.task)
            .await
            .expect("gateway did not stop in time")
            .expect("gateway task panicked")
            .expect("gateway failed");
    }
}

/// `text` validated as a user's file would be, then polled faster than the profiles' minimums
/// (every 300 ms) so tests stay short (the simulators do not mind).
pub fn fast_config(text: &str) -> Config {
    let mut config =
        rtu2mqtt::config::from_str(text, std::path::Path::new(".")).expect("valid configuration");
    for line in &mut config.lines {
        for device in &mut line.devices {
            device.poll_interval = Duration::from_millis(300);
        }
    }
    config
}
