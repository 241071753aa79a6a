//! The HTTP front end over the [`Hub`]: health, readiness, Prometheus metrics, scenes and
//! sessions as JSON, and each session's WebSocket ([`ws`]). The same hub calls, checks and
//! frame bytes as gRPC ([`crate::grpc`]); only the encoding differs.
//!
//! | route | answer |
//! |---|---|
//! | `GET /healthz` | 200 `ok` while the process serves |
//! | `GET /readyz` | 200 when the hub is ready, 503 once it shuts down |
//! | `GET /metrics` | the Prometheus text exposition |
//! | `GET /v1/scenes` | `{"engine", "writes_need_token", "scenes": [{"name", "patch_count", "codec", "has_model", "fallback", "sky_view", "emitters"}]}` (`fallback`: why a GPU engine runs part of the scene on the CPU, else null; `sky_view`: false for a file baked before the sky view, where a sky adds nothing; `emitters`: the emissive materials a light set may change) |
//! | `GET /v1/scenes/{name}/layout` | the proto `Layout`'s fields as JSON |
//! | `GET /v1/scenes/{name}/model` | the scene's model, one GLB (`model/gltf-binary`); 404 when it has none |
//! | `GET /v1/sessions?scene=NAME&limit=N` | `{"sessions": [{"session_id", "scene", "lights_version", "viewers"}]}`, newest first |
//! | `POST /v1/sessions` | `{"scene", "lights"}` → 201 `{"session_id", "lights_version"}` |
//! | `GET /v1/sessions/{id}` | `{"session_id", "scene", "lights_version", "lights"}` |
//! | `PUT /v1/sessions/{id}/lights` | `{"lights"}` → `{"lights_version", "changed"}` |
//! | `GET /v1/sessions/{id}/ws` | the session's WebSocket |
//! | `POST /v1/sky/sun` | `{"direction": [x, y, z], "turbidity": 3, "scale": 1}` (towards the sun, +Y up; the last two optional) → `{"lights": [sun, sky]}`: a directional sun and its clear SH sky (`bounce_core::sunsky`), for a session's lights |
//! | `POST /v1/sky/sh` | an equirectangular HDR image (Radiance `.hdr` or OpenEXR, up to 64 MiB) → `{"sh", "width", "height"}`: its order-2 SH, ready for a sky light (`{"type": "sky", "sh": ...}`) |
//! | `GET /`, `GET /PATH` | the browser page: `index.html`, and each file of `web/public/` ([`web`]) |
//!
//! Writes present the hub's token, if it has one, as `Authorization: Bearer T` or `?token=T`;
//! with a read token (`--read-token`), so do reads under `/v1/` (the read or the write token).
//! Every refusal is `{"code", "message"}` with the status [`ErrorCode`] gives; a path that is
//! neither a route nor a file of the page is a 404 `no such route`.
//!
//! The model and the page's files carry a strong `ETag` (a 304 answers a matching
//! `If-None-Match`) and `Cache-Control: no-cache`, and are gzip- or brotli-compressed when the
//! client accepts it (the tag then turns weak). The JSON routes and WebSockets are not compressed.
//!
//! The folder, bottom up: [`error`] (what a refusal is, as every route and socket answers it),
//! [`state`] (what every handler shares), [`access`] (tokens and origins), then the routes
//! ([`routes`]), the WebSocket ([`ws`]) and the page ([`web`]); this file accepts connections
//! and puts the router together.

mod access;
pub mod error;
mod routes;
mod state;
pub mod web;
mod ws;

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::extract::ConnectInfo;
use axum::http::StatusCode;
use axum::routing::{MethodRouter, get, post, put};
use axum::serve::Listener;
use tokio::net::{TcpListener, TcpStream};
use tokio_util::task::TaskTracker;
use tower_http::compression::CompressionLayer;
use tracing::{info, warn};

use crate::cache;
use crate::error::ServerError;
use crate::hub::Hub;
use crate::limits::{ConnectionLimit, Limited};
use crate::metrics::Transport;
use bounce_wire::limits::MAX_REQUEST_BYTES;

use access::{check_origin, check_read};
pub use error::ErrorCode;
use error::{ApiError, count_refusals};
use routes::{
    MAX_ENVIRONMENT_BYTES, create_session, get_session, layout, list_scenes, list_sessions,
    metrics, model, readyz, set_lights, sky_sh, sky_sun,
};
use state::{AppState, Peer};

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
/// ([`ws`]). On `shutdown`, accepting stops, every connection finishes its request in
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
        .route("/v1/sky/sun", post(sky_sun))
        .route(
            "/v1/sky/sh",
            post(sky_sh).layer(axum::extract::DefaultBodyLimit::max(MAX_ENVIRONMENT_BYTES)),
        )
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
