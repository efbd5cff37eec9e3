//! The end-to-end test harness every integration test and benchmark of the workspace shares.
//!
//! - [`broker`]: a real mosquitto on a free loopback port ([`Mosquitto`]: temporary config,
//!   killed on drop, restartable on the same port).
//! - [`browser`]: headless chromium driven through chromedriver, for the console ([`Browser`]).
//! - [`client`]: a small rumqttc client that records what it receives ([`TestClient`]).
//! - [`recorder`]: a subscriber that hands each message to its owner as it arrives, for the
//!   benches' long runs ([`Recorder`]).
//! - [`gateway`]: the gateway over the simulated seed plant ([`PlantConfig`], [`Gateway`]: its
//!   configuration, started and stopped by a test).
//! - [`plant_bench`]: the broker + plant + gateway bench most end-to-end tests stand on
//!   ([`PlantBench`]).
//! - [`child`]: the workspace's binaries as child processes, killed and reaped on drop.
//! - [`disk`]: a small tmpfs to fill, for a full disk ([`SmallDisk`]).
//! - [`hex`]: frames as hex text.
//! - [`pysparkplug`]: the Sparkplug B decoder written by others, run through Python.
//! - [`pymodbus`]: the pymodbus scripts of `tests/interop/` run as clients, servers and
//!   snippets: the one place the tests start pymodbus.
//! - [`paced_pymodbus`]: a serial line whose device is pymodbus's RTU server, paced at the
//!   wire's rate ([`PacedPymodbus`]), with a journal of what crossed it.
//! - [`soak`]: the gateway process under a long run of chaos, with its end checks.

pub mod broker;
pub mod browser;
pub mod child;
pub mod client;
pub mod disk;
pub mod gateway;
pub mod hex;
pub mod paced_pymodbus;
pub mod plant_bench;
pub mod pymodbus;
pub mod pysparkplug;
pub mod recorder;
pub mod soak;

pub use broker::{free_port, Mosquitto, MOSQUITTO};
pub use browser::Browser;
pub use client::{Message, TestClient};
pub use disk::SmallDisk;
pub use gateway::{fast_config, Gateway, PlantConfig};
pub use paced_pymodbus::PacedPymodbus;
pub use plant_bench::{PlantBench, PlantSetup, PLANT_ANSWER, SEED_DEVICES};
pub use recorder::Recorder;
