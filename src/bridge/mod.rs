//! The only plain-MQTT user: state, commands, outcomes, availability, Home Assistant discovery
//! and statistics, in three parts:
//!
//! - [`core`]: every decision, without I/O: events in (with the time), actions out.
//! - [`driver`]: the one task that carries the core's actions out: the rumqttc connection, the
//!   outbox and its writer, the channels to the lines, the history stream, TLS.
//! - [`observers`]: what reads the bridge's figures from outside: the statistics documents and
//!   the Prometheus text, and the plant view the console shows.
//!
//! Lower parts never name higher ones: the core knows neither the driver nor the observers'
//! endpoint; the driver runs the core.

pub mod core;
pub mod driver;
pub mod observers;

pub use driver::{
    Bridge, BridgeFigures, BridgeHealth, LocalMessage, Reconfiguration, OVERLOAD_HIGH,
    OVERLOAD_LOW, TICK,
};
