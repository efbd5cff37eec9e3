//! rtu2mqtt: a Modbus RTU (RS485) to MQTT gateway.
//!
//! The crate is layered from the wire upwards; each layer only knows the ones listed before it
//! (`tests/it/layers.rs` fails on any arrow pointing up; `ARCHITECTURE.md` draws them):
//!
//! - Modbus on the wire lives in its own crate, [`rtu2mqtt_modbus`] (`crates/rtu2mqtt-modbus`),
//!   below every module here: frame types with their arithmetic, CRC, the codec (pure byte
//!   work), line timing (character time, t1.5, t3.5, response timeout), the answer framer, the
//!   serial transport and master that run exactly one RTU transaction on a port with legal
//!   timing, and the TCP links (raw RTU to a serial device server, Modbus TCP to a gateway)
//!   behind one [`rtu2mqtt_modbus::link::Link`]. It knows nothing of MQTT or the configuration.
//! - [`rtu2mqtt_profile`]: device knowledge as data. A profile (TOML) describes read blocks, field codecs
//!   and write rules; pure functions decode raw blocks into field values and turn a command into
//!   the frames of one bus slot. No I/O. Built in: the seed devices and the device library;
//!   the SunSpec model table and the profile `rtu2mqtt sunspec` writes from it.
//! - [`bus`]: one task per line. It owns the link, decides what is due (pure scheduler with the
//!   clock passed in), runs polls and command slots, tracks device health and line statistics,
//!   and reports [`bus::LineEvent`]s (a slot's values before its command's end; fields with
//!   `publish` settings by exception, decided once for every consumer). A line may be
//!   served to other Modbus masters ([`bus::serve`]): their requests are slots of its scheduler.
//! - `sim` (feature `demo`): simulated devices (the three seed devices written from
//!   `docs/devices.md`, the device library's register maps, and a generic one built from any
//!   profile), on ptys or TCP, for tests, benchmarks and the demo.
//! - [`contract`]: the MQTT contract (topic names, Home Assistant ids, payload words, reserved
//!   names), pure strings shared by the configuration check, discovery and the bridge.
//! - [`config`]: the gateway configuration (file + environment), validated completely with the
//!   place of every problem before anything is opened.
//! - [`health`]: readiness, the watchdog thread and the status file; it knows heartbeats, not
//!   the bridge.
//! - [`history`]: the journal of what was measured while the broker was away (append-only,
//!   checksummed segment files in the `[history]` directory, bounded, crash-safe) and the
//!   history stream's documents. File I/O only; the bridge decides what goes in and out.
//! - [`bridge`]: the only plain-MQTT user. State, commands, outcomes, availability, Home
//!   Assistant discovery and statistics, decided by an I/O-free core and carried out by a thin
//!   driver.
//! - [`sparkplug`]: the optional Sparkplug B edge node on its own MQTT connection; its commands
//!   enter the bridge core like `…/set` commands, and the history the bridge replays goes out
//!   as historical DDATA.
//! - `broker` (feature `demo`): the demo's embedded MQTT broker; [`cli`]: the command line.
//! - [`app`]: wires the above together for `run` (with reload on SIGHUP), `check`, the
//!   commissioning tools `scan`, `read` and `sunspec`, and with the feature `demo`, `demo` and `simulate`.
//!
//! The feature `demo` (on by default) brings the simulators, the demo, its embedded broker and
//! `simulate`; the daemon for an edge box is built without it (`--no-default-features`).

// What the codebase keeps true, checked on every build (`-D warnings` in CI):
// - `pub` means part of the crate's surface: an item only its module uses is `pub(crate)` or
//   private, so the reader knows how far a change reaches;
// - every public type can be printed with `{:?}` in a log or a failing test;
// - the 2018 idioms (elided lifetimes shown as `'_`, no `extern crate`).
#![warn(unreachable_pub, missing_debug_implementations, rust_2018_idioms)]

pub mod app;
pub mod bridge;
#[cfg(feature = "demo")]
pub mod broker;
pub mod bus;
pub mod cli;
pub mod config;
pub mod health;
pub mod history;
#[cfg(feature = "demo")]
pub mod sim;
pub mod sparkplug;
