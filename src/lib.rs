//! rtu2mqtt: a Modbus RTU (RS485) to MQTT gateway daemon. This is its module map.
//!
//! Below this crate: [`rtu2mqtt_modbus`] (Modbus on the wire: frames, CRC, timing, the serial
//! and TCP links that run one transaction at a time with legal timing) and [`rtu2mqtt_profile`]
//! (device profiles as data, and the names the MQTT topics reserve). The simulators and the
//! demo are crates above it that it does not depend on. `ARCHITECTURE.md` draws how the crates
//! fit.
//!
//! The modules are layered from the wire upwards; each only knows the ones listed before it
//! (`tests/it/repository/layers.rs` fails on any arrow pointing up):
//!
//! - [`bus`]: one task per line. `line` (the loop; `line::command_side` its commands,
//!   refreshes and settle re-reads, `line::client_requests` its served side), `line_spec` and
//!   `device_spec` (what a line is started with), `port` (the link opened by the wire crate's
//!   `Link::open`, one reopen back-off), `device`, `poll` (a block, with the exception-02 fallback), `command` (a
//!   command from its queue to its outcome: `queue`, `slots`, `run`, `outcome`), `transaction`
//!   (one request with retries), `cadence` (each block's cadence), `scheduler` (what is due,
//!   pure, clock passed in: commands, then refreshes, then polls), `availability` (offline,
//!   back-off), `stats`, `report` (report by exception, pure) and `reporter` (its task),
//!   `write_clock` (when each field was last written, by any source), `serve` (a line served to
//!   other Modbus masters: their requests are slots of its scheduler), `event` (what it
//!   reports). It reports [`bus::LineEvent`]s and publishes nothing.
//! - [`topics`]: the MQTT topics of one gateway: `names` ([`topics::Topics`], every topic and
//!   Home Assistant id built), `kind` ([`topics::Topics::classify`], what a topic is, read
//!   once), `words` (`online`/`offline`, limits).
//! - [`config`]: the configuration (file + `RTU2MQTT__*` environment), validated completely with
//!   the place of every problem before anything is opened; each section checked in its own file
//!   (`mqtt`, `gateway`, `health`, `lines`, `devices`, `sparkplug`, `history`), `names`, and
//!   `poll_plan` (the poll plan and bus load `check` prints). Opens no port or socket.
//! - [`health`]: `assess` (pure judgement), `status_file` (and `rtu2mqtt health`), `systemd`
//!   (readiness, watchdog pings), `watchdog` (its own thread; self-exit when stuck). It knows
//!   heartbeats, not the bridge, and never judges devices.
//! - [`history`]: what was measured while the broker was away: `document` (the history stream's
//!   `{"ts","values"}`), `record` (length + CRC-32 per record, a damaged part skipped), `journal`
//!   (append-only segment files, bounded, crash-safe). File I/O only.
//! - [`bridge`]: the only plain-MQTT user, in three parts: `core` (every decision, no I/O:
//!   events in, actions out; `machine` the core that routes each event, with `settings`,
//!   `incoming`, `action` and `bridge_device` what it is built from, given and gives;
//!   `command_desk` the command desk from arrival to result, with `command_book` and
//!   `payload`; `publisher` the state cache and what is published from it, with `state`,
//!   `json_view`, `topic_guard`, and Home Assistant's `discovery`, `entity_naming`,
//!   `ha_templates`, `action_entities`), `driver` (the task that carries the actions out:
//!   `connection`, `outbox`, `writer`, `tls`, `history_stream`, `oversized`, `inputs`) and
//!   `observers` (`statistics` documents and Prometheus text, `figures` where they are read,
//!   `plant_view` what the console shows).
//! - [`sparkplug`]: the optional Sparkplug B edge node on its own MQTT connection, in two parts
//!   as the bridge: `core` (`protobuf`, `metrics`, `node_metrics`, `session_interface`, `session`
//!   the pure edge-node rules, `bd_seq`) and `driver` (the node's task and connection). Its
//!   commands enter the bridge core like `…/set` commands; it never touches the bus.
//! - [`cli`]: the command line (clap); parses, does nothing else.
//! - [`web`]: the console in the browser and the metrics endpoint, one HTTP server: the plant
//!   view pushed live, commands through the bridge like any MQTT client's, the lines' frames,
//!   commissioning reads through the running lines' schedulers. Off unless configured.
//! - [`commissioning`]: the commands that talk to devices without a gateway: `target` (where
//!   they talk and how the link is opened), `read`, `scan`, `sunspec`.
//! - [`app`]: wiring: `run`/[`app::run_gateway`] (lines, bridge, Sparkplug node, health, reload
//!   on SIGHUP), `signals`, `check`, `profiles`, `logging`. No protocol logic.

// What the codebase keeps true, checked on every build (`-D warnings` in CI):
// - `pub` means part of the crate's surface: an item only its module uses is `pub(crate)` or
//   private, so the reader knows how far a change reaches;
// - every public type can be printed with `{:?}` in a log or a failing test;
// - the 2018 idioms (elided lifetimes shown as `'_`, no `extern crate`).
// The module maps in this crate's docs name private modules on purpose: the daemon's library is
// its own wiring, read by those who change it (`cargo doc --document-private-items`).
#![allow(rustdoc::private_intra_doc_links)]
#![warn(unreachable_pub, missing_debug_implementations, rust_2018_idioms)]

pub mod app;
pub mod bridge;
pub mod bus;
pub mod cli;
pub mod commissioning;
pub mod config;
pub mod health;
pub mod history;
pub mod sparkplug;
pub mod topics;
pub mod web;
