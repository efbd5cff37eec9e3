//! rtu2mqtt: a Modbus RTU (RS485) to MQTT gateway.
//!
//! The crate is layered from the wire upwards; each layer only knows the ones below it.
//!
//! - [`rtu`]: the Modbus RTU wire protocol. Frame types, CRC, the codec (pure byte work), line
//!   timing (character time, t1.5, t3.5), the serial transport and the [`rtu::master`] that runs
//!   exactly one request/answer transaction on a port with legal timing.
//! - [`profile`]: device knowledge as data. A profile (TOML) describes read blocks, field codecs
//!   and write rules; pure functions decode raw blocks into field values and turn a command into
//!   the frames of one bus slot. No I/O.
//! - [`bus`]: one task per serial line. It owns the port, decides what is due (pure scheduler
//!   with the clock passed in), runs polls and command slots, tracks device health and line
//!   statistics, and reports [`bus::LineEvent`]s.
//! - [`contract`]: the MQTT contract (topic names, Home Assistant ids, payload words, reserved
//!   names), pure strings shared by the configuration check, discovery and the bridge.
//! - [`config`]: the gateway configuration (file + environment), validated completely with the
//!   place of every problem before anything is opened.
//! - [`bridge`]: the only MQTT user. State, commands, outcomes, availability, Home Assistant
//!   discovery and statistics, decided by an I/O-free core and carried out by a thin driver.
//! - [`sim`]: simulated devices (the three seed devices written from their documents, and a
//!   generic one built from any profile), for tests, benchmarks and the demo.
//! - [`app`]: wires the above together for `run` and `demo`; [`shutdown`] and [`health`] are
//!   the small process-level pieces (signals, watchdog, status file), [`cli`] the command line
//!   and [`broker`] the demo's embedded MQTT broker.

pub mod app;
pub mod bridge;
pub mod broker;
pub mod bus;
pub mod cli;
pub mod config;
pub mod contract;
pub mod health;
pub mod profile;
pub mod rtu;
pub mod shutdown;
pub mod sim;
pub mod sparkplug;
