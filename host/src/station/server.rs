//! The station's HTTP server (axum on tokio): the page and its script and style (kept in
//! `page/`, built into the binary), the events (server-sent: `live`, `surface`, `status`), and
//! a small JSON API for capture, sessions, comparison and the calibration check.
//!
//! Safe by default: every request's `Host` must name this station (no other site can reach it
//! through a name that resolves here), a `POST` must come from its own page (`Origin`) and
//! carry JSON, names from the page are checked before any path is built ([`super::sessions`]),
//! and what it does not serve is refused (404, 405), with a content security policy that lets
//! the page run only its own script.

use super::calibration_check::{calibration_facts, plane_check};
use super::sessions::{
    compare_sessions, save_session, session_dir, session_file, sessions, subjects, CaptureSetup,
};
use super::state::Shared;
use crate::workflows::back::Calibration;
use axum::extract::{Path as UrlPath, Query, Request, State};
use axum::http::{header, HeaderValue, Method, StatusCode};
use axum::middleware::{self, Next};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures_util::stream::{self, Stream, StreamExt};
use serde::Deserialize;
use std::convert::Infallible;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::SystemTime;

/// The page, its style and script.
const INDEX_HTML: &str = include_str!("page/index.html");
const STATION_CSS: &str = include_str!("page/station.css");
const STATION_JS: &str = include_str!("page/station.js");

/// The bytes of the page with its style and script (what a browser loads before any event).
pub fn page_weight() -> usize {
    INDEX_HTML.len() + STATION_CSS.len() + STATION_JS.len()
}

/// The content security policy of every answer: the page's own script and style only, images
/// from `data:` URLs (the live frame), nothing fetched from elsewhere.
const POLICY: &str = "default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; \
                      img-src 'self' data:; connect-src 'self'; frame-ancestors 'none'; \
                      base-uri 'none'; form-action 'none'";

/// What the handlers share.
pub struct App {
    /// The threads' state.
    pub shared: Arc<Shared>,
    /// The calibration.
    pub calibration: Arc<Calibration>,
    /// system.json.
    pub system: PathBuf,
    /// The data folder.
    pub data: PathBuf,
    /// The device's centroid quantisation (px).
    pub centroid_step_px: Option<f64>,
    /// The frames of a capture.
    pub burst: usize,
    /// The `Host` values this station answers to (None: any, when listening beyond loopback).
    pub hosts: Option<Vec<String>>,
}

/// A refusal or failure, as JSON `{"error": ...}`.
struct ApiError(StatusCode, String);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.0, Json(serde_json::json!({ "error": self.1 }))).into_response()
    }
}

fn bad(e: anyhow::Error) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, format!("{e:#}"))
}

/// Runs blocking work (files, analysis) off the server's threads; its error is a 400 / 500.
async fn blocking<T: Send + 'static>(
    work: impl FnOnce() -> anyhow::Result<T> + Send + 'static,
) -> Result<T, ApiError> {
    tokio::task::spawn_blocking(work)
        .await
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?
        .map_err(bad)
}

/// The router of the station.
pub fn router(app: Arc<App>) -> Router {
    Router::new()
        .route(
            "/",
            get(|| async { page(INDEX_HTML, "text/html; charset=utf-8") }),
        )
        .route(
            "/station.css",
            get(|| async { page(STATION_CSS, "text/css; charset=utf-8") }),
        )
        .route(
            "/station.js",
            get(|| async { page(STATION_JS, "text/javascript; charset=utf-8") }),
        )
        .route("/events", get(events))
        .route("/api/status", get(status))
        .route("/api/calibration", get(calibration))
        .route("/api/plane-check", post(plane))
        .route("/api/capture", post(capture))
        .route("/api/subjects", get(subject_list))
        .route("/api/subjects/{subject}/sessions", get(session_list))
        .route("/api/compare", get(comparison))
        .route("/sessions/{subject}/{session}/{file}", get(file))
        .fallback(|| async { ApiError(StatusCode::NOT_FOUND, "not served here".to_owned()) })
        .layer(middleware::from_fn_with_state(app.clone(), guard))
        .with_state(app)
}

fn page(body: &'static str, kind: &'static str) -> Response {
    ([(header::CONTENT_TYPE, kind)], body).into_response()
}

/// Refuses a request whose `Host` is not this station's, or a `POST` from another page; adds
/// the security headers to every answer.
async fn guard(State(app): State<Arc<App>>, request: Request, next: Next) -> Response {
    let host = request
        .headers()
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .unwrap_or_default()
        .to_owned();
    let refused = |why: String| ApiError(StatusCode::FORBIDDEN, why).into_response();
    let mut response = if app
        .hosts
        .as_ref()
        .is_some_and(|hosts| !hosts.contains(&host))
    {
        refused(format!("refused: Host {host:?} is not this station"))
    } else if request.method() != Method::GET && request.method() != Method::HEAD {
        let origin = request
            .headers()
            .get(header::ORIGIN)
            .and_then(|h| h.to_str().ok());
        match origin {
            Some(o) if o != format!("http://{host}") => refused(format!(
                "refused: a request from {o:?}, not from this station's page"
            )),
            _ => next.run(request).await,
        }
    } else {
        next.run(request).await
    };
    let headers = response.headers_mut();
    headers.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(POLICY),
    );
    headers.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    response
}

/// The events: each stream's latest event first, then every change (a slow page skips to the
/// newest).
async fn events(State(app): State<Arc<App>>) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let streams = app.shared.subscribe().map(|mut receiver| {
        receiver.mark_changed();
        stream::unfold(receiver, |mut receiver| async move {
            loop {
                receiver.changed().await.ok()?;
                let event = receiver.borrow_and_update().clone();
                if event.1 != "null" {
                    let sse = Event::default().event(&event.0).data(&event.1);
                    return Some((Ok(sse), receiver));
                }
            }
        })
        .boxed()
    });
    Sse::new(stream::select_all(streams)).keep_alive(KeepAlive::default())
}

/// The latest live frame (without its image), surface (without its figures) and status.
async fn status(State(app): State<Arc<App>>) -> Json<serde_json::Value> {
    let [live, surface, status] = app.shared.latest();
    let parse = |text: &str| serde_json::from_str(text).unwrap_or(serde_json::Value::Null);
    let mut live = parse(&live.1);
    let mut surface = parse(&surface.1);
    if let Some(o) = live.as_object_mut() {
        o.remove("image");
        o.remove("dots");
    }
    if let Some(o) = surface.as_object_mut() {
        o.remove("topography_svg");
        o.remove("rotation_svg");
    }
    Json(serde_json::json!({ "live": live, "surface": surface, "status": parse(&status.1) }))
}

async fn calibration(State(app): State<Arc<App>>) -> Json<serde_json::Value> {
    Json(calibration_facts(&app.calibration, &app.system))
}

async fn plane(State(app): State<Arc<App>>) -> Result<Json<serde_json::Value>, ApiError> {
    let check = blocking(move || {
        let kept = app.shared.kept();
        let last = &kept[kept.len().saturating_sub(3)..];
        Ok(serde_json::to_value(plane_check(last, &app.calibration)?)?)
    })
    .await?;
    Ok(Json(check))
}

/// A capture request.
#[derive(Deserialize)]
struct CaptureRequest {
    subject: String,
    #[serde(default = "standing")]
    posture: String,
}

fn standing() -> String {
    "standing".to_owned()
}

async fn capture(
    State(app): State<Arc<App>>,
    Json(request): Json<CaptureRequest>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let session = blocking(move || {
        let kept = app.shared.kept();
        let burst = &kept[kept.len().saturating_sub(app.burst)..];
        let setup = CaptureSetup {
            data: &app.data,
            calibration: &app.calibration,
            centroid_step_px: app.centroid_step_px,
        };
        let session = save_session(
            &setup,
            &request.subject,
            &request.posture,
            SystemTime::now(),
            burst,
        )?;
        Ok(serde_json::to_value(session)?)
    })
    .await?;
    Ok(Json(session))
}

async fn subject_list(State(app): State<Arc<App>>) -> Result<Json<serde_json::Value>, ApiError> {
    let list = blocking(move || Ok(serde_json::to_value(subjects(&app.data)?)?)).await?;
    Ok(Json(list))
}

async fn session_list(
    State(app): State<Arc<App>>,
    UrlPath(subject): UrlPath<String>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let list = blocking(move || Ok(serde_json::to_value(sessions(&app.data, &subject)?)?)).await?;
    Ok(Json(list))
}

/// Two sessions of a subject to compare.
#[derive(Deserialize)]
struct CompareQuery {
    subject: String,
    before: String,
    after: String,
}

async fn comparison(
    State(app): State<Arc<App>>,
    Query(q): Query<CompareQuery>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let c = blocking(move || compare_sessions(&app.data, &q.subject, &q.before, &q.after)).await?;
    Ok(Json(c))
}

async fn file(
    State(app): State<Arc<App>>,
    UrlPath((subject, session, name)): UrlPath<(String, String, String)>,
) -> Result<Response, ApiError> {
    let (bytes, name) = blocking(move || {
        let name = session_file(&name)?;
        let path = session_dir(&app.data, &subject, &session)?.join(name);
        let bytes = std::fs::read(&path)
            .map_err(|e| anyhow::anyhow!("{name} of session {session}: cannot read: {e}"))?;
        Ok((bytes, name))
    })
    .await?;
    let kind = match name.rsplit('.').next() {
        Some("html") => "text/html; charset=utf-8",
        Some("json") => "application/json",
        _ => "text/csv; charset=utf-8",
    };
    Ok(([(header::CONTENT_TYPE, kind)], bytes).into_response())
}
