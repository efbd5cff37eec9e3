//! rtu2mqtt-demo: the seed plant with no hardware, and single simulated devices for a desk.
//!
//! - [`demo`]: `rtu2mqtt-demo`: the three simulated seed devices on two virtual serial lines,
//!   the [`broker`] embedded (or a broker of one's own), the very gateway of `rtu2mqtt run`, and
//!   a live table of what it publishes.
//! - [`simulate`]: `rtu2mqtt-demo simulate`: one simulated device, or a seed plant line, on a
//!   serial port or behind TCP.
//! - [`broker`]: the embedded MQTT broker (rumqttd), loopback only.
//! - [`cli`]: the command line.
//!
//! The daemon (`rtu2mqtt`) depends on none of this: the simulators, the broker and the demo live
//! in crates of their own (`rtu2mqtt-sim`, this one).

#![warn(unreachable_pub, missing_debug_implementations, rust_2018_idioms)]

pub mod broker;
pub mod cli;
pub mod demo;
pub mod simulate;
