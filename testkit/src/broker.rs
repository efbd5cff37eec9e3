//! A real mosquitto owned by a test: a free loopback port, a temporary configuration, killed on
//! drop, restartable on the same port; for a bench's long run, one that keeps its sessions
//! across a restart ([`Mosquitto::start_durable`]).

use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::child::KillOnDrop;

pub const MOSQUITTO: &str = "/usr/sbin/mosquitto";

/// A mosquitto broker owned by a test.
pub struct Mosquitto {
    pub port: u16,
    /// More listeners and settings (after the anonymous loopback listener on `port`).
    extra: String,
    /// Persistence on and a log of errors and warnings only ([`Mosquitto::start_durable`]).
    durable: bool,
    child: Option<KillOnDrop>,
    dir: tempfile::TempDir,
}

impl Mosquitto {
    /// Starts a broker on a free 127.0.0.1 port and waits until it accepts connections.
    pub fn start() -> Mosquitto {
        Mosquitto::start_with(String::new())
    }

    /// Like [`Mosquitto::start`] with more configuration; listeners it adds must use
    /// `per_listener_settings`-style settings of their own.
    pub fn start_with(extra: String) -> Mosquitto {
        let port = free_port();
        let dir = tempfile::tempdir().expect("temp dir");
        let mut broker = Mosquitto {
            port,
            extra,
            durable: false,
            child: None,
            dir,
        };
        broker.launch();
        broker
    }

    /// A broker with persistence, so that a subscriber's session and the messages queued for it
    /// outlive a [`Mosquitto::stop`] and [`Mosquitto::restart`], and whose log holds errors and
    /// warnings alone: a plant-scale run publishes far too much to log every message.
    pub fn start_durable() -> Mosquitto {
        let mut broker = Mosquitto {
            port: free_port(),
            extra: String::new(),
            durable: true,
            child: None,
            dir: tempfile::tempdir().expect("temp dir"),
        };
        broker.launch();
        broker
    }

    /// A broker that is not running yet (its port chosen): start it with [`Mosquitto::restart`].
    pub fn not_started() -> Mosquitto {
        Mosquitto {
            port: free_port(),
            extra: String::new(),
            durable: false,
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
        let (persistence, log_types) = if self.durable {
            (
                format!(
                    "persistence true\npersistence_location {}/\nautosave_interval 0\n\
                     max_queued_messages 10000000\n",
                    self.dir.path().display()
                ),
                "log_type error\nlog_type warning\n",
            )
        } else {
            ("persistence false\n".to_string(), "log_type all\n")
        };
        let config = format!(
            "per_listener_settings true\n{persistence}\
             log_dest file {}\n{log_types}listener {} 127.0.0.1\nallow_anonymous true\n{}",
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
            // A durable broker writes its database there too.
            let mode = if self.durable { 0o777 } else { 0o755 };
            let _ =
                std::fs::set_permissions(self.dir.path(), std::fs::Permissions::from_mode(mode));
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

    /// SIGTERM, on which mosquitto saves its sessions (see [`Mosquitto::start_durable`]), then
    /// waits up to 20 s for the process to end before killing it.
    pub fn stop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = nix::sys::signal::kill(child.pid(), nix::sys::signal::Signal::SIGTERM);
            let deadline = Instant::now() + Duration::from_secs(20);
            while child.is_running() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(20));
            }
        }
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
