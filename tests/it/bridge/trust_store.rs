//! `mqtts://` without `ca_file` verifies the broker against the system's trust store, and only
//! against it; `ca_file` overrides the store. The gateway runs as its own process whose "system
//! store" is a bundle given in `SSL_CERT_FILE` (which rustls-native-certs honours instead of the
//! distribution's), so nothing on the machine is changed. The broker is a real mosquitto with a
//! TLS listener whose certificate an openssl-made test CA signed.

use crate::support::child::{self, KillOnDrop};
use crate::support::{free_port, Mosquitto, TestClient};

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

/// Long enough for a connection that would succeed (the first attempt is at once).
const CONNECT_WAIT: Duration = Duration::from_secs(15);

/// A CA of its own in `dir` (`<name>.crt`), unrelated to the broker's.
fn other_ca(dir: &Path, name: &str) -> std::path::PathBuf {
    let status = Command::new("openssl")
        .args([
            "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
        ])
        .args([
            "-keyout",
            &format!("{name}.key"),
            "-out",
            &format!("{name}.crt"),
        ])
        .args(["-subj", &format!("/CN={name}")])
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .expect("run openssl");
    assert!(status.success(), "openssl made no CA");
    dir.join(format!("{name}.crt"))
}

/// The gateway `client_id` on the TLS listener of `tls_port` (client certificate and password
/// from `certs`), with `ca_file` when given, its system store being `store`; its log goes to
/// `log`. Its one line leads nowhere: only the MQTT connection matters here.
fn start_gateway(
    work: &Path,
    certs: &Path,
    tls_port: u16,
    client_id: &str,
    ca_file: Option<&Path>,
    store: &Path,
) -> (KillOnDrop, std::path::PathBuf) {
    let certs = certs.display();
    let ca_line = ca_file.map_or(String::new(), |ca| {
        format!("ca_file = \"{}\"\n", ca.display())
    });
    let config = format!(
        "[mqtt]\nurl = \"mqtts://localhost:{tls_port}\"\nclient_id = \"{client_id}\"\n\
         prefix = \"plant\"\nusername = \"gateway\"\npassword_file = \"{certs}/password\"\n\
         cert_file = \"{certs}/client.crt\"\nkey_file = \"{certs}/client.key\"\n{ca_line}\n\
         [health]\nstatus_file = \"\"\n\n\
         [[lines]]\nname = \"line-b\"\nurl = \"tcp://127.0.0.1:{line}\"\n\n\
         [[lines.devices]]\nname = \"valve\"\nprofile = \"wuzhou-valve\"\naddress = 1\n",
        line = free_port(),
    );
    let config_path = work.join(format!("{client_id}.toml"));
    std::fs::write(&config_path, config).expect("write config");
    let log = work.join(format!("{client_id}.log"));
    let mut command = child::gateway_run(&config_path);
    command
        .env("SSL_CERT_FILE", store)
        .env_remove("SSL_CERT_DIR")
        .env("RUST_LOG", "warn")
        .stderr(std::fs::File::create(&log).expect("log file"));
    (
        KillOnDrop::spawn(command).expect("rtu2mqtt run starts"),
        log,
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mqtts_without_ca_file_trusts_the_system_store_and_ca_file_overrides_it() {
    let (broker, tls_port, certs) = Mosquitto::start_tls();
    let work = tempfile::tempdir().expect("temp dir");
    let other = other_ca(work.path(), "other-ca");
    // A store that holds the broker's CA among others, and one that holds only another CA.
    let with_ca = work.path().join("with-ca.pem");
    let mut bundle = std::fs::read(&other).expect("other CA");
    bundle.extend(std::fs::read(certs.path().join("ca.crt")).expect("test CA"));
    std::fs::write(&with_ca, bundle).expect("write bundle");

    let mut observer = TestClient::connect(broker.port, "trust-observer").await;
    observer.subscribe("plant/gateway/+/status").await;

    // The broker's CA is in the store: connected, verified by the store alone.
    let (_trusting, _) = start_gateway(
        work.path(),
        certs.path(),
        tls_port,
        "store-has-ca",
        None,
        &with_ca,
    );
    observer
        .wait_for("plant/gateway/store-has-ca/status", CONNECT_WAIT, |m| {
            m.text() == "online"
        })
        .await;

    // It is not: the handshake fails on the broker's certificate, nothing is published.
    let (mut refusing, log) = start_gateway(
        work.path(),
        certs.path(),
        tls_port,
        "store-lacks-ca",
        None,
        &other,
    );
    let deadline = tokio::time::Instant::now() + CONNECT_WAIT;
    let mut said = String::new();
    while !said.contains("UnknownIssuer") {
        assert!(
            tokio::time::Instant::now() < deadline,
            "no word of the untrusted certificate:\n{said}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
        said = std::fs::read_to_string(&log).unwrap_or_default();
    }
    let online = observer
        .try_wait_for(
            "plant/gateway/store-lacks-ca/status",
            Duration::from_secs(1),
            |m| m.text() == "online",
        )
        .await;
    assert!(
        online.is_none(),
        "connected to a broker whose CA is not trusted"
    );
    assert!(
        refusing.is_running(),
        "the gateway gave up instead of retrying"
    );
    assert!(
        !broker.log().contains("as store-lacks-ca"),
        "the broker saw a CONNECT:\n{}",
        broker.log()
    );

    // ca_file overrides the store (which lacks the CA).
    let (_overriding, _) = start_gateway(
        work.path(),
        certs.path(),
        tls_port,
        "ca-file-wins",
        Some(&certs.path().join("ca.crt")),
        &other,
    );
    observer
        .wait_for("plant/gateway/ca-file-wins/status", CONNECT_WAIT, |m| {
            m.text() == "online"
        })
        .await;
}
