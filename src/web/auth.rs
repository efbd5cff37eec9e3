//! Who may use the console. With a token (`web.token_file`): every page but the login needs a
//! session, given by `POST /login` for the right token as an `HttpOnly; SameSite=Strict`
//! cookie (or, for scripts and scrapers, `Authorization: Bearer <token>`). Without one the
//! console listens on loopback only and refuses commands. Either way every request that
//! changes something (a POST) must come from the console's own origin.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use axum::extract::{Form, Request, State};
use axum::http::{header, HeaderMap, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{Html, IntoResponse, Redirect, Response};
use rand::RngCore;
use serde::Deserialize;

use super::{refusal, Console};

/// The session cookie's name.
pub const COOKIE: &str = "rtu2mqtt_session";
/// A session ends this long after the login.
pub const SESSION_LIFETIME: Duration = Duration::from_secs(12 * 3600);
/// Sessions kept at once; a login beyond them ends the oldest.
pub const MAX_SESSIONS: usize = 32;
/// A wrong token is answered after this, so guessing costs time.
const WRONG_TOKEN_DELAY: Duration = Duration::from_millis(500);

/// The open sessions, by their random id.
#[derive(Debug, Default)]
pub struct Sessions {
    open: Mutex<HashMap<String, Instant>>,
}

impl Sessions {
    /// Opens a session; its id for the cookie.
    fn open(&self, now: Instant) -> String {
        let mut bytes = [0u8; 32];
        rand::rngs::OsRng.fill_bytes(&mut bytes);
        let id: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        let mut open = self.open.lock().unwrap_or_else(PoisonError::into_inner);
        open.retain(|_, started| now.duration_since(*started) < SESSION_LIFETIME);
        if open.len() >= MAX_SESSIONS {
            if let Some(oldest) = open
                .iter()
                .min_by_key(|(_, at)| **at)
                .map(|(id, _)| id.clone())
            {
                open.remove(&oldest);
            }
        }
        open.insert(id.clone(), now);
        id
    }

    fn is_open(&self, id: &str, now: Instant) -> bool {
        let open = self.open.lock().unwrap_or_else(PoisonError::into_inner);
        open.get(id)
            .is_some_and(|started| now.duration_since(*started) < SESSION_LIFETIME)
    }

    fn close(&self, id: &str) {
        let mut open = self.open.lock().unwrap_or_else(PoisonError::into_inner);
        open.remove(id);
    }
}

/// Equal without telling how much of it was (no early exit on the first difference).
fn same_secret(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// The session id the request's cookie carries.
fn session_of(headers: &HeaderMap) -> Option<&str> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|value| value.to_str().ok())
        .flat_map(|cookies| cookies.split(';'))
        .filter_map(|cookie| cookie.trim().split_once('='))
        .find(|(name, _)| *name == COOKIE)
        .map(|(_, value)| value)
}

/// The request carries a live session or the token itself.
fn signed_in(console: &Console, headers: &HeaderMap) -> bool {
    let Some(token) = &console.settings.token else {
        return true;
    };
    let bearer = headers
        .get(header::AUTHORIZATION)
        .and_then(|value| value.to_str().ok())
        .and_then(|value| value.strip_prefix("Bearer "));
    if let Some(bearer) = bearer {
        return same_secret(bearer.trim(), token);
    }
    session_of(headers).is_some_and(|id| console.sessions.is_open(id, Instant::now()))
}

/// The request comes from a page of this console: its `Origin` is the scheme and `Host` it
/// was sent to. A request without `Origin` (no browser sends a POST without one) is refused.
pub fn same_origin(headers: &HeaderMap, tls: bool) -> bool {
    let origin = headers.get(header::ORIGIN).and_then(|v| v.to_str().ok());
    let host = headers.get(header::HOST).and_then(|v| v.to_str().ok());
    let scheme = if tls { "https" } else { "http" };
    match (origin, host) {
        (Some(origin), Some(host)) => origin == format!("{scheme}://{host}"),
        _ => false,
    }
}

/// In front of every route but the login: a session (when a token is set), and the origin
/// check on everything that is not a plain read.
pub async fn guard(State(console): State<Arc<Console>>, request: Request, next: Next) -> Response {
    let headers = request.headers();
    if !signed_in(&console, headers) {
        let wants_page = request.method() == Method::GET
            && !request.uri().path().starts_with("/api/")
            && request.uri().path() != "/metrics";
        if wants_page {
            return Redirect::to("/login").into_response();
        }
        return refusal(
            StatusCode::UNAUTHORIZED,
            "log in first (POST /login with the token)",
        );
    }
    let reads = matches!(*request.method(), Method::GET | Method::HEAD);
    if !reads && !same_origin(headers, console.settings.tls.is_some()) {
        tracing::warn!(
            path = %request.uri().path(),
            origin = ?headers.get(header::ORIGIN),
            "console: a request from another origin refused"
        );
        return refusal(
            StatusCode::FORBIDDEN,
            "refused: the request does not come from this console's own page",
        );
    }
    next.run(request).await
}

/// `GET /login`: the form (straight to the console when no token is set).
pub async fn login_page(State(console): State<Arc<Console>>) -> Response {
    if console.settings.token.is_none() {
        return Redirect::to("/").into_response();
    }
    Html(super::pages::LOGIN_PAGE.replace("{message}", "")).into_response()
}

/// The login form's field.
#[derive(Debug, Deserialize)]
pub struct LoginForm {
    pub token: String,
}

/// `POST /login`: a session for the right token, from this console's own page.
pub async fn login(
    State(console): State<Arc<Console>>,
    headers: HeaderMap,
    Form(form): Form<LoginForm>,
) -> Response {
    let Some(token) = &console.settings.token else {
        return Redirect::to("/").into_response();
    };
    if !same_origin(&headers, console.settings.tls.is_some()) {
        return refusal(
            StatusCode::FORBIDDEN,
            "refused: the login does not come from this console's own page",
        );
    }
    if !same_secret(form.token.trim(), token) {
        tracing::warn!("console: a login with a wrong token");
        tokio::time::sleep(WRONG_TOKEN_DELAY).await;
        let page = super::pages::LOGIN_PAGE.replace(
            "{message}",
            "<p class=\"error\" role=\"alert\">That token is not the console's token.</p>",
        );
        return (StatusCode::UNAUTHORIZED, Html(page)).into_response();
    }
    let id = console.sessions.open(Instant::now());
    tracing::info!("console: logged in");
    let secure = if console.settings.tls.is_some() {
        "; Secure"
    } else {
        ""
    };
    let cookie = format!(
        "{COOKIE}={id}; HttpOnly; SameSite=Strict; Path=/; Max-Age={}{secure}",
        SESSION_LIFETIME.as_secs()
    );
    ([(header::SET_COOKIE, cookie)], Redirect::to("/")).into_response()
}

/// `POST /logout`: ends the session.
pub async fn logout(State(console): State<Arc<Console>>, headers: HeaderMap) -> Response {
    if let Some(id) = session_of(&headers) {
        console.sessions.close(id);
    }
    let cookie = format!("{COOKIE}=; HttpOnly; SameSite=Strict; Path=/; Max-Age=0");
    ([(header::SET_COOKIE, cookie)], Redirect::to("/login")).into_response()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn secrets_compare_whole() {
        assert!(same_secret("0123456789abcdef", "0123456789abcdef"));
        assert!(!same_secret("0123456789abcdeF", "0123456789abcdef"));
        assert!(!same_secret("0123456789abcdef0", "0123456789abcdef"));
        assert!(!same_secret("", "0123456789abcdef"));
        assert!(!same_secret("0123", ""));
    }

    #[test]
    fn a_session_lives_until_its_lifetime_or_logout() {
        let sessions = Sessions::default();
        let now = Instant::now();
        let id = sessions.open(now);
        assert_eq!(id.len(), 64);
        assert!(sessions.is_open(&id, now));
        assert!(!sessions.is_open(&id, now + SESSION_LIFETIME));
        assert!(!sessions.is_open("guess", now));
        sessions.close(&id);
        assert!(!sessions.is_open(&id, now));
    }

    #[test]
    fn sessions_are_bounded() {
        let sessions = Sessions::default();
        let now = Instant::now();
        let first = sessions.open(now);
        for i in 0..MAX_SESSIONS {
            sessions.open(now + Duration::from_millis(i as u64 + 1));
        }
        assert!(!sessions.is_open(&first, now + Duration::from_secs(1)));
    }

    #[test]
    fn the_origin_must_be_the_host_it_was_sent_to() {
        let mut headers = HeaderMap::new();
        headers.insert(header::HOST, "127.0.0.1:8080".parse().unwrap());
        assert!(!same_origin(&headers, false));
        headers.insert(header::ORIGIN, "http://127.0.0.1:8080".parse().unwrap());
        assert!(same_origin(&headers, false));
        assert!(!same_origin(&headers, true));
        headers.insert(header::ORIGIN, "http://evil.example".parse().unwrap());
        assert!(!same_origin(&headers, false));
    }
}
