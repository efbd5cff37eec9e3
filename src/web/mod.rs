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
//!
//! The console commands through the bridge like any MQTT client (`…/set` through
//! [`crate::bridge::LocalMessage`]): the same validation, book and outcome.

pub mod auth;
pub mod commission;
pub mod decode;
pub mod gateway_info;
pub mod listener;
pub mod live;
pub mod model;
pub mod pages;

use std::sync::Arc;

use axum::extract::{DefaultBodyLimit, Form, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use serde::Deserialize;
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

use crate::bridge::observers::plant_view::PlantView;
use crate::bridge::{BridgeFigures, BridgeHealth, LocalMessage};
use crate::bus::LineHandle;
use crate::config::{Config, WebSettings};
use crate::topics::{TopicKind, Topics};
use rtu2mqtt_modbus::live_frames::LiveFrames;

/// Largest request body: a profile pasted for a try-out is the largest thing sent.
pub const MAX_BODY: usize = 256 * 1024;

/// What the console reads and where it sends, shared by every request.
#[derive(Debug)]
pub struct Console {
    pub settings: WebSettings,
    pub topics: Topics,
    /// The plant as configured now, following reloads.
    pub layout: watch::Receiver<Arc<Layout>>,
    pub view: PlantView,
    pub figures: BridgeFigures,
    pub health: BridgeHealth,
    /// The console's commands and refreshes, into the bridge.
    pub messages: mpsc::Sender<LocalMessage>,
    pub frames: LiveFrames,
    pub sessions: auth::Sessions,
    /// Places for the pages' event streams ([`live::MAX_STREAMS`]).
    pub streams: Arc<tokio::sync::Semaphore>,
    /// One commissioning run at a time: a second waits rather than doubling the bus share.
    pub commissioning: tokio::sync::Mutex<()>,
    pub started: std::time::Instant,
}

/// The plant as configured: what the page draws, the configuration it shows and the running
/// lines the commissioning reads go through. A reload makes a new one.
#[derive(Debug)]
pub struct Layout {
    pub model: model::PlantModel,
    /// The configuration in effect as JSON text, secrets masked (kept as text: a tree of a
    /// thousand lines' values would cost more than the page ever reads).
    pub effective_config: String,
    pub lines: Vec<LineHandle>,
}

impl Layout {
    /// The layout of `config` running on `lines`.
    pub fn of(config: &Config, lines: Vec<LineHandle>) -> Arc<Layout> {
        let read_only = config.web.as_ref().map_or(true, |web| web.token.is_none());
        Arc::new(Layout {
            model: model::PlantModel::of(config, read_only),
            effective_config: gateway_info::effective_config(config).to_string(),
            lines,
        })
    }
}

/// Everything the console is built from.
#[derive(Debug)]
pub struct ConsoleParts {
    pub view: PlantView,
    pub figures: BridgeFigures,
    pub health: BridgeHealth,
    /// The plant as configured, and after each reload.
    pub layout: watch::Receiver<Arc<Layout>>,
    pub messages: mpsc::Sender<LocalMessage>,
    pub frames: LiveFrames,
}

impl Console {
    /// The console of `config` (whose `[web]` is `settings`); its layout follows `parts`.
    pub fn new(config: &Config, settings: WebSettings, parts: ConsoleParts) -> Arc<Console> {
        Arc::new(Console {
            topics: config.mqtt.topics(),
            settings,
            layout: parts.layout,
            view: parts.view,
            figures: parts.figures,
            health: parts.health,
            messages: parts.messages,
            frames: parts.frames,
            sessions: auth::Sessions::default(),
            streams: Arc::new(tokio::sync::Semaphore::new(live::MAX_STREAMS)),
            commissioning: tokio::sync::Mutex::new(()),
            started: std::time::Instant::now(),
        })
    }

    /// The plant as configured now.
    pub fn layout(&self) -> Arc<Layout> {
        Arc::clone(&self.layout.borrow())
    }

    /// The running line named `name`.
    pub fn line(&self, name: &str) -> Option<LineHandle> {
        let layout = self.layout.borrow();
        layout.lines.iter().find(|line| line.name == name).cloned()
    }
}

/// The console's routes: the page and its assets, the API, `/metrics`; behind the login and
/// the `Origin` check.
pub fn router(console: Arc<Console>) -> Router {
    let guarded = Router::new()
        .route("/", get(pages::index))
        .route("/assets/{name}", get(pages::asset))
        .route("/api/model", get(model::serve_model))
        .route("/api/events", get(live::plant_events))
        .route("/api/frames", get(live::frame_events))
        .route("/api/stats", get(gateway_info::stats))
        .route("/api/gateway", get(gateway_info::gateway))
        .route("/api/command", post(command))
        .route("/api/refresh", post(refresh))
        .route("/api/scan", post(commission::scan))
        .route("/api/read", post(commission::read))
        .route("/api/tryout", post(commission::tryout))
        .route("/metrics", get(metrics))
        .route("/logout", post(auth::logout))
        .layer(axum::middleware::from_fn_with_state(
            Arc::clone(&console),
            auth::guard,
        ));
    Router::new()
        .route("/login", get(auth::login_page).post(auth::login))
        .route("/assets/login.css", get(pages::login_css))
        .merge(guarded)
        .layer(axum::middleware::from_fn(pages::security_headers))
        .layer(DefaultBodyLimit::max(MAX_BODY))
        .with_state(console)
}

/// The metrics endpoint alone (`gateway.metrics_listen`).
pub fn metrics_router(figures: BridgeFigures) -> Router {
    Router::new()
        .route(
            "/metrics",
            get(|State(figures): State<BridgeFigures>| async move { prometheus(&figures) }),
        )
        .layer(DefaultBodyLimit::max(1024))
        .with_state(figures)
}

/// Serves the console on `listener` until `shutdown`.
pub async fn serve(
    listener: listener::Listener,
    console: Arc<Console>,
    shutdown: CancellationToken,
) {
    listener.serve(router(console), shutdown).await;
}

/// Serves `/metrics` alone on `listener` until `shutdown`.
pub async fn serve_metrics(
    listener: listener::Listener,
    figures: BridgeFigures,
    shutdown: CancellationToken,
) {
    listener.serve(metrics_router(figures), shutdown).await;
}

fn prometheus(figures: &BridgeFigures) -> Response {
    (
        [(
            axum::http::header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        figures.prometheus_text(),
    )
        .into_response()
}

async fn metrics(State(console): State<Arc<Console>>) -> Response {
    prometheus(&console.figures)
}

/// A command from the page: a payload for a field's `…/set` topic.
#[derive(Debug, Deserialize)]
pub struct CommandForm {
    pub topic: String,
    pub payload: String,
}

/// The refresh of a device.
#[derive(Debug, Deserialize)]
pub struct RefreshForm {
    pub device: String,
}

/// An error in words, with its status.
pub fn refusal(status: StatusCode, reason: impl Into<String>) -> Response {
    (
        status,
        axum::Json(serde_json::json!({ "error": reason.into() })),
    )
        .into_response()
}

/// `POST /api/command`: hands the command to the bridge as a message on its `…/set` topic;
/// its outcome comes back on `…/result`, like any client's. A read-only console refuses.
async fn command(State(console): State<Arc<Console>>, Form(form): Form<CommandForm>) -> Response {
    if console.settings.token.is_none() {
        return refusal(
            StatusCode::FORBIDDEN,
            "this console only reads: set web.token_file to send commands from it",
        );
    }
    let TopicKind::Command { device, field } = console.topics.classify(&form.topic) else {
        return refusal(
            StatusCode::BAD_REQUEST,
            format!(
                "{:?} is not a command topic (<prefix>/<device>/<field>/set)",
                form.topic
            ),
        );
    };
    if form.payload.is_empty() {
        return refusal(StatusCode::BAD_REQUEST, "the command is empty");
    }
    tracing::info!(%device, %field, payload = %form.payload, via = "console", "command");
    let message = LocalMessage {
        topic: form.topic.clone(),
        payload: form.payload,
    };
    match console.messages.try_send(message) {
        Ok(()) => (
            StatusCode::ACCEPTED,
            axum::Json(serde_json::json!({ "result_topic": format!("{}/result", form.topic.trim_end_matches("/set")) })),
        )
            .into_response(),
        Err(_) => refusal(
            StatusCode::SERVICE_UNAVAILABLE,
            "the gateway is busy with earlier commands: try again in a moment",
        ),
    }
}

/// `POST /api/refresh`: every block of the device read in the line's next slots.
async fn refresh(State(console): State<Arc<Console>>, Form(form): Form<RefreshForm>) -> Response {
    if !console
        .layout()
        .model
        .devices
        .iter()
        .any(|d| d.name == form.device)
    {
        return refusal(
            StatusCode::NOT_FOUND,
            format!("no device named {:?}", form.device),
        );
    }
    tracing::info!(device = %form.device, via = "console", "refresh");
    let message = LocalMessage {
        topic: console.topics.refresh_topic(&form.device),
        // Any payload but an empty one, which is the clearing of a retained request.
        payload: "refresh".to_string(),
    };
    match console.messages.try_send(message) {
        Ok(()) => StatusCode::ACCEPTED.into_response(),
        Err(_) => refusal(StatusCode::SERVICE_UNAVAILABLE, "the gateway is busy"),
    }
}
