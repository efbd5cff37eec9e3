//! The gateway over the simulated seed plant: its configuration ([`PlantConfig`]) and the
//! daemon (`run_gateway`) started and stopped by a test ([`Gateway`]).

use std::time::Duration;

use rtu2mqtt::app::{run_gateway, Hooks, Running};
use rtu2mqtt::config::Config;
use rtu2mqtt_sim::SeedPlant;
use tokio_util::sync::CancellationToken;

use crate::broker::Mosquitto;

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
    /// More keys (or sub-tables, such as `[lines.serve]`) for line-a, and for line-b.
    pub line_a_keys: &'a str,
    pub line_b_keys: &'a str,
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
{line_keys}{line_a_keys}
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
{line_keys}{line_b_keys}
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
            line_a_keys = with_newline(self.line_a_keys),
            line_b_keys = with_newline(self.line_b_keys),
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
            console_socket: None,
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
