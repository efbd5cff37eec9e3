//! The console's routes and the metrics endpoint: the page and its assets, the API behind the
//! login and the `Origin` check, `/metrics`, and the console's own commands and refreshes,
//! handed to the bridge like any MQTT client's.

use std::sync::Arc;

use axum::extract::{DefaultBodyLimit, Form, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use serde::Deserialize;
use tokio_util::sync::CancellationToken;

use super::console::Console;
use super::{auth, commission, gateway_info, listener, live, model, pages};
use crate::bridge::{BridgeFigures, LocalMessage};
use crate::topics::TopicKind;

/// Largest request body: a profile pasted for a try-out is the largest thing sent.
pub const MAX_BODY: usize = 256 * 1024;

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
