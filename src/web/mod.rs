//! The console in the browser and the metrics endpoint: one HTTP server (axum on hyper) for
//! both, off unless `[web] listen` or `gateway.metrics_listen` is set.
//!
//! - [`listener`]: binds, accepts and bounds connections (their number, the TLS handshake,
//!   the request head), serving a router on each; the metrics endpoint is the same server with
//!   one route.
//! - [`auth`]: the login (a token, a session cookie), the `Origin` check of every request
//!   that changes something, and the read-only console without a token.
//! - [`model`]: the plant as the page draws it: devices, fields and the controls their
//!   profiles' rules allow.
//! - [`live`]: what the page is pushed (server-sent events): the plant view's messages and a
//!   line's frames.
//! - [`commission`]: the commissioning reads (scan, read every way, profile try-out), sent
//!   through the running line's scheduler as slots, between its polls; [`decode`] shows
//!   registers every way a profile could read them.
//! - [`gateway_info`]: the gateway page: connection, health, version, the configuration with
//!   its secrets masked.
//! - [`pages`]: the page and its assets, embedded in the binary.
//! - [`console`]: the state every request reads ([`Console`], the plant's [`Layout`]).
//! - [`routes`]: the router, the console's own commands and refreshes, and `/metrics`.
//!
//! The console commands through the bridge like any MQTT client (`…/set` through
//! [`crate::bridge::LocalMessage`]): the same validation, book and outcome.

pub mod auth;
pub mod commission;
pub mod console;
pub mod decode;
pub mod gateway_info;
pub mod listener;
pub mod live;
pub mod model;
pub mod pages;
pub mod routes;

pub use console::{Console, ConsoleParts, Layout};
pub use routes::{
    metrics_router, refusal, router, serve, serve_metrics, CommandForm, RefreshForm, MAX_BODY,
};
