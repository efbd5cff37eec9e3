//! The broker + plant + gateway bench most end-to-end tests stand on: a real mosquitto, the
//! three simulated seed devices on their two virtual lines, an observer subscribed to
//! `plant/#`, and the gateway running in the test's runtime with every device online. A test
//! adds what its area needs (a served line, faults, a child-process gateway) on top of it.

use std::time::Duration;

use rtu2mqtt_sim::SeedPlant;
use serde_json::Value as Json;
use tokio::sync::mpsc;

use crate::broker::Mosquitto;
use crate::client::{Message, TestClient};
use crate::gateway::{fast_config, Gateway, PlantConfig};

/// How long a bench waits for what the gateway publishes: it only runs out when something is
/// broken, even on a busy 2-core machine.
pub const PLANT_ANSWER: Duration = Duration::from_secs(15);

/// The seed devices, by the names every bench's configuration gives them.
pub const SEED_DEVICES: [&str; 3] = ["dust_collector", "air_shower", "valve"];

type ConfigText<'a> = Box<dyn FnOnce(&Mosquitto, &SeedPlant, &str) -> String + 'a>;

/// How a [`PlantBench`] is set up; [`PlantBench::setup`] makes one, [`PlantSetup::start`] starts it.
pub struct PlantSetup<'a> {
    name: String,
    broker_extra: String,
    make_plant: Box<dyn FnOnce() -> SeedPlant + 'a>,
    prepare: Box<dyn FnOnce(&SeedPlant) + 'a>,
    observe: Vec<String>,
    config: ConfigText<'a>,
    reloadable: bool,
    gateway: bool,
}

impl<'a> PlantSetup<'a> {
    /// More lines for the broker's configuration file.
    pub fn broker_extra(mut self, extra: &str) -> Self {
        self.broker_extra = extra.to_string();
        self
    }

    /// The plant, made after the broker has started (a child process started after the plant
    /// would inherit the ptys' master ends and keep an unplugged line open).
    pub fn plant(mut self, make_plant: impl FnOnce() -> SeedPlant + 'a) -> Self {
        self.make_plant = Box::new(make_plant);
        self
    }

    /// Sets the simulated devices up before the gateway starts.
    pub fn prepare(mut self, prepare: impl FnOnce(&SeedPlant) + 'a) -> Self {
        self.prepare = Box::new(prepare);
        self
    }

    /// One more topic filter for the observer, beside `plant/#`.
    pub fn observe(mut self, filter: &str) -> Self {
        self.observe.push(filter.to_string());
        self
    }

    /// The gateway's configuration text, from the broker, the plant and the gateway's client id.
    pub fn config(
        mut self,
        config: impl FnOnce(&Mosquitto, &SeedPlant, &str) -> String + 'a,
    ) -> Self {
        self.config = Box::new(config);
        self
    }

    /// The configuration is written to a file and the gateway reloads it on
    /// the bench's `reload` sender, as SIGHUP does for `rtu2mqtt run`.
    pub fn reloadable(mut self) -> Self {
        self.reloadable = true;
        self
    }

    /// No gateway in the test's runtime: the test starts one of its own (a child process).
    pub fn without_gateway(mut self) -> Self {
        self.gateway = false;
        self
    }

    /// Starts the broker, the plant, the observer and the gateway, and waits until every
    /// seed device is online.
    pub async fn start(self) -> PlantBench {
        let broker = Mosquitto::start_with(self.broker_extra);
        let plant = (self.make_plant)();
        (self.prepare)(&plant);
        let mut observer =
            TestClient::connect(broker.port, &format!("{}-observer", self.name)).await;
        observer.subscribe("plant/#").await;
        for filter in &self.observe {
            observer.subscribe(filter).await;
        }
        let client_id = format!("{}-gw", self.name);
        let config_text = (self.config)(&broker, &plant, &client_id);
        let mut bench = PlantBench {
            broker,
            plant,
            observer,
            gateway: None,
            client_id,
            config_text,
            reload: None,
        };
        if !self.gateway {
            return bench;
        }
        if self.reloadable {
            let dir = tempfile::tempdir().expect("a directory for the configuration");
            let path = dir.path().join("rtu2mqtt.toml");
            std::fs::write(&path, &bench.config_text).expect("the configuration is written");
            let (gateway, reload) =
                Gateway::start_reloadable(fast_config(&bench.config_text), path).await;
            bench.gateway = Some(gateway);
            bench.reload = Some((reload, dir));
        } else {
            bench.start_gateway().await;
        }
        for device in SEED_DEVICES {
            bench.wait_availability(device, "online").await;
        }
        bench
    }
}

/// The seed plant behind a real broker and the gateway; see the module's documentation.
pub struct PlantBench {
    pub broker: Mosquitto,
    pub plant: SeedPlant,
    /// Subscribed to `plant/#` (and the setup's other filters) before the gateway started.
    pub observer: TestClient,
    pub gateway: Option<Gateway>,
    pub client_id: String,
    /// The gateway's configuration, as [`PlantBench::start_gateway`] starts it.
    pub config_text: String,
    /// With a reloadable setup: what asks for a reload, and the configuration file's directory.
    pub reload: Option<(mpsc::Sender<()>, tempfile::TempDir)>,
}

impl PlantBench {
    /// A setup named `name` (the gateway connects as `<name>-gw`, the observer as
    /// `<name>-observer`) with the plain seed plant configuration.
    pub fn setup<'a>(name: &str) -> PlantSetup<'a> {
        PlantSetup {
            name: name.to_string(),
            broker_extra: String::new(),
            make_plant: Box::new(|| SeedPlant::spawn(false).expect("the seed plant starts")),
            prepare: Box::new(|_| {}),
            observe: Vec::new(),
            config: Box::new(|broker, plant, client_id| {
                PlantConfig::default().text(broker, plant, client_id)
            }),
            reloadable: false,
            gateway: true,
        }
    }

    /// Starts the gateway (again) with the bench's configuration.
    pub async fn start_gateway(&mut self) {
        self.gateway = Some(Gateway::start(fast_config(&self.config_text)).await);
    }

    /// Stops the gateway cleanly, if it runs.
    pub async fn stop_gateway(&mut self) {
        if let Some(gateway) = self.gateway.take() {
            gateway.stop().await;
        }
    }

    /// Waits for `text` on `topic` (a retained copy seen earlier counts).
    pub async fn wait_text(&mut self, topic: &str, text: &str) -> Message {
        let text = text.to_string();
        self.observer
            .wait_for(topic, PLANT_ANSWER, move |m| m.text() == text)
            .await
    }

    /// Waits for `text` on `topic` published from now on (not one seen earlier).
    pub async fn wait_new_text(&mut self, topic: &str, text: &str) -> Message {
        let text = text.to_string();
        self.observer
            .wait_for_new(topic, PLANT_ANSWER, move |m| m.text() == text)
            .await
    }

    /// Waits for `device`'s availability to read `text`.
    pub async fn wait_availability(&mut self, device: &str, text: &str) {
        self.wait_text(&format!("plant/{device}/availability"), text)
            .await;
    }

    /// Publishes `payload` on `plant/<device>/<field>/set` and returns the command's result.
    pub async fn command(&mut self, device: &str, field: &str, payload: &[u8]) -> Json {
        self.observer
            .publish(
                &format!("plant/{device}/{field}/set"),
                payload.to_vec(),
                false,
            )
            .await;
        self.result(device, field).await
    }

    /// The next result on `plant/<device>/<field>/result`.
    pub async fn result(&mut self, device: &str, field: &str) -> Json {
        self.observer
            .next_on(&format!("plant/{device}/{field}/result"), PLANT_ANSWER)
            .await
            .json()
    }

    /// Stops the gateway, then the plant and the broker.
    pub async fn stop(mut self) {
        self.stop_gateway().await;
    }
}
