//! The HTTP front end over the [`Hub`]: health, readiness, Prometheus metrics, scenes and
//! sessions as JSON, and each session's WebSocket ([`crate::ws`]). The same hub calls, checks and
//! frame bytes as gRPC ([`crate::grpc`]); only the encoding differs.
//!
//! | route | answer |
//! |---|---|
//! | `GET /healthz` | 200 `ok` while the process serves |
//! | `GET /readyz` | 200 when the hub is ready, 503 once it shuts down |
//! | `GET /metrics` | the Prometheus text exposition |
//! | `GET /v1/scenes` | `{"engine", "writes_need_token", "scenes": [{"name", "patch_count", "codec", "has_model", "fallback"}]}` (`fallback`: why a GPU engine runs part of the scene on the CPU, else null) |
//! | `GET /v1/scenes/{name}/layout` | the proto `Layout`'s fields as JSON |
//! | `GET /v1/scenes/{name}/model` | the scene's model, one GLB (`model/gltf-binary`); 404 when it has none |
//! | `GET /v1/sessions?scene=NAME&limit=N` | `{"sessions": [{"session_id", "scene", "lights_version", "viewers"}]}`, newest first |
//! | `POST /v1/sessions` | `{"scene", "lights"}` → 201 `{"session_id", "lights_version"}` |
//! | `GET /v1/sessions/{id}` | `{"session_id", "scene", "lights_version", "lights"}` |
//! | `PUT /v1/sessions/{id}/lights` | `{"lights"}` → `{"lights_version", "changed"}` |
//! | `GET /v1/sessions/{id}/ws` | the session's WebSocket |
//! | `GET /`, `GET /PATH` | the browser page: `index.html`, and each file of `web/public/` ([`crate::web`]) |
//!
//! Writes present the hub's token, if it has one, as `Authorization: Bearer T` or `?token=T`;
//! with a read token (`--read-token`), so do reads under `/v1/` (the read or the write token).
//! Every refusal is `{"code", "message"}` with the status [`ErrorCode`] gives; a path that is
//! neither a route nor a file of the page is a 404 `no such route`.
//!
//! The model and the page's files carry a strong `ETag` (a 304 answers a matching
//! `If-None-Match`) and `Cache-Control: no-cache`, and are gzip- or brotli-compressed when the
//! client accepts it (the tag then turns weak). The JSON routes and WebSockets are not compressed.

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::rejection::BytesRejection;
use axum::extract::{ConnectInfo, FromRequestParts, Path, Query, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{MethodRouter, get, put};
use axum::serve::Listener;
use axum::{Extension, Json, Router};
use bounce_core::light::LightSet;
use bytes::Bytes;
use serde::{Deserialize, Serialize};
use tokio::net::{TcpListener, TcpStream};
use tokio_util::task::TaskTracker;
use tower_http::compression::CompressionLayer;
use tracing::{info, warn};

use crate::cache;
use crate::error::ServerError;
use crate::hub::Hub;
use crate::limits::{ConnectionLimit, Limited};
use crate::metrics::{self, Metrics, Transport};
use crate::serve::MAX_REQUEST_BYTES;
use crate::{web, ws};

/// How long open WebSockets get to send their close frames once the server stops; a client
/// that reads nothing must not hold the shutdown.
const SOCKETS_GRACE: Duration = Duration::from_secs(5);

/// Serves `hub` over HTTP on `listener` until `shutdown` resolves; then readiness turns 503, the
/// hub shuts down (every WebSocket closes with 1001), in-flight requests finish and this returns.
/// At most [`Hub::max_connections`] connections are open at once, WebSockets included.
pub async fn serve_http(
    hub: Hub,
    listener: TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServerError> {
    let sockets = TaskTracker::new();
    let hub_header_timeout = hub.header_read_timeout();
    let app = router(hub.clone(), sockets.clone());
    let listener = LimitedListener {
        listener,
        limit: ConnectionLimit::new(
            hub.max_connections(),
            Transport::Http,
            Arc::clone(hub.metrics()),
        )
        .with_first_byte_timeout(hub.first_byte_timeout())
        .with_per_ip(hub.max_connections_per_ip()),
    };
    let stopping = async move {
        shutdown.await;
        info!("HTTP shutting down");
        // The worker may be mid-batch: wait for it off the runtime's threads.
        let _ = tokio::task::spawn_blocking(move || hub.shutdown()).await;
    };
    serve_connections(listener, app, hub_header_timeout, stopping).await;
    // Upgraded connections are no longer the HTTP server's: wait for their close frames here.
    sockets.close();
    if tokio::time::timeout(SOCKETS_GRACE, sockets.wait())
        .await
        .is_err()
    {
        warn!(
            open = sockets.len(),
            "WebSockets still closing after the grace period; left to end on their own"
        );
    }
    Ok(())
}

/// axum's own accept-and-serve loop (`axum::serve`), with one difference: each connection's
/// HTTP/1 has a timer and a header-read timeout. `axum::serve` installs no timer, so hyper's
/// header-read timeout never fires there: a client that sends one byte of a request head and then
/// stalls (slowloris), or leaves a keep-alive connection idle, would hold its connection slot for
/// good. With the timer, a request head must arrive whole within `header_timeout` of hyper
/// starting to read it, which on a keep-alive connection also bounds the wait for the next
/// request. An upgraded WebSocket is no longer HTTP and keeps its own keep-alive
/// ([`crate::ws`]). On `shutdown`, accepting stops, every connection finishes its request in
/// flight and closes, and this returns once they have.
async fn serve_connections(
    mut listener: LimitedListener,
    app: Router,
    header_timeout: Duration,
    shutdown: impl Future<Output = ()> + Send + 'static,
) {
    use hyper::server::conn::http1;
    use hyper_util::rt::{TokioIo, TokioTimer};
    use hyper_util::service::TowerToHyperService;
    use tower::ServiceExt;

    let (signal_tx, signal_rx) = tokio::sync::watch::channel(());
    let (close_tx, close_rx) = tokio::sync::watch::channel(());
    let mut shutdown = std::pin::pin!(shutdown);
    loop {
        let (io, addr) = tokio::select! {
            accepted = Listener::accept(&mut listener) => accepted,
            () = &mut shutdown => break,
        };
        // The peer's address reaches handlers as axum's connect info would (the per-client
        // session cap reads it).
        let service =
            app.clone()
                .map_request(move |mut req: axum::http::Request<hyper::body::Incoming>| {
                    req.extensions_mut().insert(ConnectInfo(Peer(addr)));
                    req.map(axum::body::Body::new)
                });
        let service = TowerToHyperService::new(service);
        let mut signal = signal_rx.clone();
        let close = close_rx.clone();
        tokio::spawn(async move {
            let conn = http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(header_timeout)
                .serve_connection(TokioIo::new(io), service)
                .with_upgrades();
            let mut conn = std::pin::pin!(conn);
            loop {
                tokio::select! {
                    result = conn.as_mut() => {
                        if let Err(e) = result {
                            tracing::debug!(error = %e, "HTTP connection ended");
                        }
                        break;
                    }
                    _ = signal.changed() => conn.as_mut().graceful_shutdown(),
                }
            }
            drop(close);
        });
    }
    drop(listener);
    drop(close_rx);
    let _ = signal_tx.send(());
    close_tx.closed().await;
}

/// Accepts for axum: no Nagle delay (frames are small and latency matters), and past the
/// connection limit a connection is dropped, so closed, at once (the limit counts it). An
/// upgraded WebSocket keeps its connection's permit until it closes.
struct LimitedListener {
    listener: TcpListener,
    limit: ConnectionLimit,
}

impl Listener for LimitedListener {
    type Io = Limited<TcpStream>;
    type Addr = SocketAddr;

    async fn accept(&mut self) -> (Limited<TcpStream>, SocketAddr) {
        loop {
            // axum's own accept, which retries (and backs off on) accept errors.
            let (stream, addr) = Listener::accept(&mut self.listener).await;
            let _ = stream.set_nodelay(true);
            if let Some(admitted) = self.limit.admit_from(stream, addr.ip()) {
                return (admitted, addr);
            }
        }
    }

    fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.listener.local_addr()
    }
}

/// The address a request came from, as the connection limit admitted it
/// ([`serve_connections`] puts it in every request's extensions).
#[derive(Clone, Copy, Debug)]
struct Peer(SocketAddr);

/// What every handler shares.
#[derive(Clone)]
pub(crate) struct AppState {
    pub hub: Hub,
    /// Every open WebSocket, so shutdown can wait for their close frames.
    pub sockets: TaskTracker,
}

fn router(hub: Hub, sockets: TaskTracker) -> Router {
    let state = AppState {
        hub: hub.clone(),
        sockets,
    };
    Router::new()
        .route("/healthz", get(|| async { "ok" }))
        .route("/readyz", get(readyz))
        .route("/metrics", get(metrics))
        .route("/v1/scenes", get(list_scenes))
        .route("/v1/scenes/{name}/layout", get(layout))
        .route("/v1/scenes/{name}/model", compressed(get(model)))
        .route("/v1/sessions", get(list_sessions).post(create_session))
        .route("/v1/sessions/{id}", get(get_session))
        .route("/v1/sessions/{id}/lights", put(set_lights))
        .route("/v1/sessions/{id}/ws", get(ws::upgrade))
        .method_not_allowed_fallback(|| async {
            ApiError::from_rejection(
                StatusCode::METHOD_NOT_ALLOWED,
                "this route does not take that method".into(),
            )
        })
        // Routes first: the page's files answer only what no route takes.
        .fallback_service(compressed(axum::routing::any(web::serve)).with_state(state.clone()))
        .layer(axum::extract::DefaultBodyLimit::max(MAX_REQUEST_BYTES))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            check_origin,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            check_read,
        ))
        .layer(axum::middleware::map_response_with_state(
            hub,
            count_refusals,
        ))
        .with_state(state)
}

/// `route` behind gzip and brotli compression, for what is large and sent once (the model, the
/// page's files), with the `ETag` weakened when the body is compressed.
fn compressed(route: MethodRouter<AppState>) -> MethodRouter<AppState> {
    route
        .layer(CompressionLayer::new().gzip(true).br(true))
        .layer(axum::middleware::map_response(
            cache::weaken_compressed_etag,
        ))
}

/// What went wrong, as every HTTP and WebSocket answer names it: the JSON `code`, the HTTP
/// status and the WebSocket close code all come from here.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorCode {
    InvalidArgument,
    NotFound,
    Unauthenticated,
    /// A request body or WebSocket message over [`MAX_REQUEST_BYTES`].
    TooLarge,
    /// A limit of the server reached (sessions, queued requests): 429.
    Exhausted,
    /// A write from a web page of another origin: 403.
    Forbidden,
    Unavailable,
    Internal,
}

impl ErrorCode {
    /// The one mapping from the service's errors, as `From<ServerError> for tonic::Status`.
    pub fn of(e: &ServerError) -> ErrorCode {
        match e {
            ServerError::UnknownScene(_) | ServerError::UnknownSession(_) => ErrorCode::NotFound,
            ServerError::Lights(_) | ServerError::Invalid(_) => ErrorCode::InvalidArgument,
            ServerError::Unauthenticated | ServerError::ReadUnauthenticated => {
                ErrorCode::Unauthenticated
            }
            ServerError::Exhausted(_) => ErrorCode::Exhausted,
            ServerError::WorkerGone | ServerError::Store(_) => ErrorCode::Unavailable,
            _ => ErrorCode::Internal,
        }
    }

    /// The JSON `code`: gRPC's status names in snake case.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorCode::InvalidArgument => "invalid_argument",
            ErrorCode::NotFound => "not_found",
            ErrorCode::Unauthenticated => "unauthenticated",
            ErrorCode::TooLarge | ErrorCode::Exhausted => "resource_exhausted",
            ErrorCode::Unavailable => "unavailable",
            ErrorCode::Forbidden => "permission_denied",
            ErrorCode::Internal => "internal",
        }
    }

    pub fn status(self) -> StatusCode {
        match self {
            ErrorCode::InvalidArgument => StatusCode::BAD_REQUEST,
            ErrorCode::NotFound => StatusCode::NOT_FOUND,
            ErrorCode::Unauthenticated => StatusCode::UNAUTHORIZED,
            ErrorCode::TooLarge => StatusCode::PAYLOAD_TOO_LARGE,
            ErrorCode::Exhausted => StatusCode::TOO_MANY_REQUESTS,
            ErrorCode::Unavailable => StatusCode::SERVICE_UNAVAILABLE,
            ErrorCode::Forbidden => StatusCode::FORBIDDEN,
            ErrorCode::Internal => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    /// The WebSocket close code: 4000 plus the HTTP status where RFC 6455 has no code of its own
    /// (4000–4999 are the application's).
    pub fn close_code(self) -> u16 {
        match self {
            ErrorCode::TooLarge => 1009,
            ErrorCode::Internal => 1011,
            other => 4000 + other.status().as_u16(),
        }
    }
}

/// A refused request: its code, the status it is sent with and a message for people.
#[derive(Debug)]
pub(crate) struct ApiError {
    code: ErrorCode,
    status: StatusCode,
    message: String,
}

/// Marks a response as a refusal, for [`count_refusals`].
#[derive(Clone, Copy)]
struct Refused;

#[derive(Serialize)]
struct ErrorBody<'a> {
    code: &'a str,
    message: &'a str,
}

impl ApiError {
    pub fn new(code: ErrorCode, message: impl Into<String>) -> ApiError {
        ApiError {
            code,
            status: code.status(),
            message: message.into(),
        }
    }

    /// An axum extractor's refusal: its own status (405, 426, ...), our body.
    pub fn from_rejection(status: StatusCode, message: String) -> ApiError {
        let code = match status {
            StatusCode::PAYLOAD_TOO_LARGE => ErrorCode::TooLarge,
            StatusCode::TOO_MANY_REQUESTS => ErrorCode::Exhausted,
            StatusCode::FORBIDDEN => ErrorCode::Forbidden,
            StatusCode::UNAUTHORIZED => ErrorCode::Unauthenticated,
            s if s.is_server_error() => ErrorCode::Internal,
            _ => ErrorCode::InvalidArgument,
        };
        ApiError {
            code,
            status,
            message,
        }
    }
}

impl From<ServerError> for ApiError {
    fn from(e: ServerError) -> ApiError {
        ApiError::new(ErrorCode::of(&e), e.to_string())
    }
}

impl From<BytesRejection> for ApiError {
    fn from(r: BytesRejection) -> ApiError {
        if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
            ApiError::new(
                ErrorCode::TooLarge,
                format!("the request body is over the {MAX_REQUEST_BYTES}-byte limit"),
            )
        } else {
            ApiError::from_rejection(r.status(), r.body_text())
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = ErrorBody {
            code: self.code.as_str(),
            message: &self.message,
        };
        let mut response = (self.status, Json(body)).into_response();
        response.extensions_mut().insert(Refused);
        response
    }
}

async fn count_refusals(State(hub): State<Hub>, response: Response) -> Response {
    if response.extensions().get::<Refused>().is_some() {
        hub.metrics()
            .requests_refused
            .get_or_create(&Metrics::transport(Transport::Http))
            .inc();
    }
    response
}

/// Refuses a write from a web page of another site: a request that can change something (any
/// method but GET, HEAD and OPTIONS, and a WebSocket upgrade, whose socket takes writes) and
/// carries an `Origin` must come from the server's own origin (the `Host` it was sent to) or one
/// on the `--allow-origin` list. Without this a page anywhere could create sessions and change
/// lights through a visitor's browser (a cross-site `text/plain` POST needs no preflight, and
/// browsers do not apply CORS to WebSockets). Requests without an `Origin` (gRPC, curl, the
/// native viewer) are not web pages and pass; the write token, when set, still applies to them.
async fn check_origin(
    State(state): State<AppState>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let method = request.method();
    let upgrade = request
        .headers()
        .get(header::UPGRADE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.eq_ignore_ascii_case("websocket"));
    let writes = !matches!(
        *method,
        axum::http::Method::GET | axum::http::Method::HEAD | axum::http::Method::OPTIONS
    ) || upgrade;
    if writes && let Some(origin) = request.headers().get(header::ORIGIN) {
        let origin = origin.to_str().unwrap_or("");
        // Behind a proxy that rewrites `Host`, the host the page was served from is in
        // `X-Forwarded-Host` (a cross-site page cannot set it without a preflight, which this
        // server does not answer).
        let host = |name: &str| {
            request
                .headers()
                .get(name)
                .and_then(|v| v.to_str().ok())
                .unwrap_or("")
        };
        let own =
            same_origin(origin, host("host")) || same_origin(origin, host("x-forwarded-host"));
        if !own && !state.hub.origin_allowed(origin) {
            return ApiError::new(
                ErrorCode::Forbidden,
                format!(
                    "writes from pages of origin '{origin}' are refused: only this server's own \
                     pages and origins given with --allow-origin may write"
                ),
            )
            .into_response();
        }
    }
    next.run(request).await
}

/// With a read token, every read under `/v1/` (scenes, layouts, models, sessions, the frame
/// sockets) presents it, or the write token, as writes present theirs. The page's files,
/// health, readiness and metrics stay open: the page asks for the token itself.
async fn check_read(
    State(state): State<AppState>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let reads = matches!(
        *request.method(),
        axum::http::Method::GET | axum::http::Method::HEAD
    ) && request.uri().path().starts_with("/v1/");
    if reads && state.hub.has_read_token() {
        let (mut parts, body) = request.into_parts();
        let presented = match Token::from_request_parts(&mut parts, &()).await {
            Ok(Token(t)) => t,
            Err(e) => return e.into_response(),
        };
        if let Err(e) = state.hub.authorize_read(presented.as_deref()) {
            return ApiError::from(e).into_response();
        }
        return next
            .run(axum::extract::Request::from_parts(parts, body))
            .await;
    }
    next.run(request).await
}

/// Whether `origin` (`scheme://host[:port]`) names the host a request was sent to.
fn same_origin(origin: &str, host: &str) -> bool {
    let Some((scheme, rest)) = origin.split_once("://") else {
        return false;
    };
    matches!(scheme, "http" | "https") && !host.is_empty() && rest.eq_ignore_ascii_case(host)
}

/// The write token a request presents: `Authorization: Bearer T`, else `?token=T` (browsers
/// cannot set headers on a WebSocket).
pub(crate) struct Token(pub Option<String>);

#[derive(Deserialize)]
struct TokenQuery {
    token: Option<String>,
}

impl<S: Send + Sync> FromRequestParts<S> for Token {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Token, ApiError> {
        if let Some(t) = bearer(&parts.headers) {
            return Ok(Token(Some(t.to_string())));
        }
        let Query(q) = Query::<TokenQuery>::try_from_uri(&parts.uri)
            .map_err(|r| ApiError::from_rejection(r.status(), r.body_text()))?;
        Ok(Token(q.token.filter(|t| !t.is_empty())))
    }
}

fn bearer(headers: &HeaderMap) -> Option<&str> {
    headers
        .get(header::AUTHORIZATION)?
        .to_str()
        .ok()?
        .strip_prefix("Bearer ")
        .map(str::trim)
        .filter(|t| !t.is_empty())
}

/// `lights` (the array of a `{"lights": [...]}` document) read and validated as
/// [`LightSet::from_json`] does, so errors name the light and field (`lights[2].intensity`).
pub(crate) fn light_set(lights: serde_json::Value) -> Result<LightSet, ServerError> {
    Ok(bounce_wire::text::light_set(lights)?)
}

fn body_str(body: &Bytes) -> Result<&str, ServerError> {
    std::str::from_utf8(body)
        .map_err(|e| ServerError::Invalid(format!("request body: not UTF-8 ({e})")))
}

async fn readyz(State(state): State<AppState>) -> (StatusCode, &'static str) {
    if state.hub.is_ready() {
        (StatusCode::OK, "ready")
    } else {
        (StatusCode::SERVICE_UNAVAILABLE, "not ready")
    }
}

async fn metrics(State(state): State<AppState>) -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, metrics::CONTENT_TYPE)],
        state.hub.metrics().encode(),
    )
}

#[derive(Serialize)]
struct SceneList {
    engine: String,
    /// Whether creating sessions and changing lights need the server's token.
    writes_need_token: bool,
    /// Whether reads need a token (only a client that presented one sees this answer).
    reads_need_token: bool,
    scenes: Vec<SceneEntry>,
}

#[derive(Serialize)]
struct SceneEntry {
    name: String,
    patch_count: usize,
    codec: String,
    /// Whether `GET /v1/scenes/{name}/model` has a model to give.
    has_model: bool,
    /// Why a GPU engine runs part of this scene on the CPU (a matrix or a triangle set over what
    /// the device holds), or null.
    fallback: Option<String>,
}

async fn list_scenes(State(state): State<AppState>) -> Json<SceneList> {
    let scenes = state
        .hub
        .scenes()
        .iter()
        .map(|s| SceneEntry {
            name: s.name.clone(),
            patch_count: s.layout.len(),
            codec: s.codec.clone(),
            has_model: s.model.is_some(),
            fallback: state.hub.scene_fallback(&s.name),
        })
        .collect();
    Json(SceneList {
        engine: state.hub.engine(),
        writes_need_token: state.hub.has_token(),
        reads_need_token: state.hub.has_read_token(),
        scenes,
    })
}

/// The scene's model as one GLB: from its baked file, else from a glTF beside it.
async fn model(
    State(state): State<AppState>,
    Path(name): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let scene = state.hub.scene(&name)?;
    let Some(model) = &scene.model else {
        let file = |ext| {
            scene
                .path
                .with_extension(ext)
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default()
        };
        return Err(ApiError::new(
            ErrorCode::NotFound,
            format!(
                "scene {name:?} has no model: its baked file {} was made without one (an older \
                 bounce, or `bounce bake --no-model`). Bake the scene again with this bounce, \
                 which keeps the model, or put the glTF it was baked from beside it as {} or {} \
                 (a .gltf with its files beside it)",
                file("bounce"),
                file("glb"),
                file("gltf")
            ),
        ));
    };
    Ok(cache::respond(
        &headers,
        model.bytes.clone(),
        &model.etag,
        "model/gltf-binary",
    ))
}

/// The proto `Layout`, field for field.
#[derive(Serialize)]
struct Layout {
    scene: String,
    origin: [f32; 3],
    voxel_size: f32,
    dims: [u32; 3],
    patch_count: usize,
    /// x, y, z of each patch's voxel, flat.
    voxels: Vec<u32>,
    /// Each patch's face code (0..5: +X, −X, +Y, −Y, +Z, −Z).
    faces: Vec<u8>,
}

async fn layout(
    State(state): State<AppState>,
    Path(name): Path<String>,
) -> Result<Json<Layout>, ApiError> {
    let scene = state.hub.scene(&name)?;
    let l = &scene.layout;
    Ok(Json(Layout {
        scene: scene.name.clone(),
        origin: l.origin,
        voxel_size: l.voxel_size,
        dims: l.dims,
        patch_count: l.len(),
        voxels: l.patches.iter().flat_map(|p| p.voxel).collect(),
        faces: l.patches.iter().map(|p| p.face.code()).collect(),
    }))
}

/// Sessions a list gives when no `limit` is asked, and the most it gives.
const LIST_DEFAULT: usize = 100;
const LIST_MAX: usize = 1000;

#[derive(Deserialize)]
struct ListQuery {
    scene: Option<String>,
    /// Read as text so that a bad value gets our message, not the extractor's.
    limit: Option<String>,
}

#[derive(Serialize)]
struct SessionList {
    sessions: Vec<SessionEntry>,
}

#[derive(Serialize)]
struct SessionEntry {
    session_id: String,
    scene: String,
    lights_version: u64,
    /// Open viewers: gRPC streams and WebSockets.
    viewers: usize,
}

async fn list_sessions(
    State(state): State<AppState>,
    query: Result<Query<ListQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Json<SessionList>, ApiError> {
    let Query(q) = query.map_err(|r| ApiError::from_rejection(r.status(), r.body_text()))?;
    let limit = match q.limit.as_deref() {
        None => LIST_DEFAULT,
        Some(l) => l
            .trim()
            .parse::<usize>()
            .ok()
            .filter(|n| (1..=LIST_MAX).contains(n))
            .ok_or_else(|| {
                ServerError::Invalid(format!(
                    "limit {l:?}: give a whole number from 1 to {LIST_MAX} (default {LIST_DEFAULT})"
                ))
            })?,
    };
    let scene = q.scene.as_deref().filter(|s| !s.is_empty());
    let sessions = state
        .hub
        .list_sessions(scene, limit)?
        .iter()
        .map(|s| SessionEntry {
            session_id: s.id.clone(),
            scene: state.hub.scene_of(s),
            lights_version: s.lights_version(),
            viewers: s.viewers(),
        })
        .collect();
    Ok(Json(SessionList { sessions }))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CreateSession {
    scene: String,
    /// Absent: no lights yet, as gRPC's empty list.
    #[serde(default)]
    lights: Option<serde_json::Value>,
}

#[derive(Serialize)]
struct Created {
    session_id: String,
    lights_version: u64,
}

async fn create_session(
    State(state): State<AppState>,
    connected: Option<Extension<ConnectInfo<Peer>>>,
    Token(token): Token,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, ApiError> {
    state.hub.authorize(token.as_deref())?;
    let body = body?;
    let request: CreateSession = serde_json::from_str(body_str(&body)?)
        .map_err(|e| ServerError::Invalid(format!("request body: {e}")))?;
    let lights = match request.lights {
        Some(l) => light_set(l)?,
        None => LightSet::default(),
    };
    let client = connected.map(|Extension(ConnectInfo(Peer(addr)))| addr.ip());
    let session = state
        .hub
        .create_session(&request.scene, lights, client)
        .await?;
    let location = format!("/v1/sessions/{}", session.id);
    let created = Created {
        session_id: session.id.clone(),
        lights_version: session.lights_version(),
    };
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        Json(created),
    )
        .into_response())
}

#[derive(Serialize)]
struct SessionState {
    session_id: String,
    scene: String,
    lights_version: u64,
    lights: Vec<bounce_core::light::Light>,
}

async fn get_session(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<SessionState>, ApiError> {
    let session = state.hub.session(&id)?;
    Ok(Json(SessionState {
        session_id: session.id.clone(),
        scene: state.hub.scene_of(&session),
        lights_version: session.lights_version(),
        lights: session.lights().lights,
    }))
}

#[derive(Serialize)]
struct LightsChanged {
    lights_version: u64,
    changed: bool,
}

async fn set_lights(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Token(token): Token,
    body: Result<Bytes, BytesRejection>,
) -> Result<Json<LightsChanged>, ApiError> {
    state.hub.authorize(token.as_deref())?;
    // The session first: an unknown session is 404 whatever the lights hold.
    state.hub.session(&id)?;
    let body = body?;
    let lights = LightSet::from_json(body_str(&body)?).map_err(ServerError::from)?;
    let v = state.hub.set_lights(&id, lights).await?;
    Ok(Json(LightsChanged {
        lights_version: v.version,
        changed: v.changed,
    }))
}
