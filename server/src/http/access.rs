//! Who may do what over HTTP: the write and read tokens a request presents, and the origin
//! check that keeps web pages of other sites from writing through a visitor's browser.

use axum::extract::{FromRequestParts, Query, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, header};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;

use super::error::{ApiError, ErrorCode};
use super::state::AppState;

/// Refuses a write from a web page of another site: a request that can change something (any
/// method but GET, HEAD and OPTIONS, and a WebSocket upgrade, whose socket takes writes) and
/// carries an `Origin` must come from the server's own origin (the `Host` it was sent to) or one
/// on the `--allow-origin` list. Without this a page anywhere could create sessions and change
/// lights through a visitor's browser (a cross-site `text/plain` POST needs no preflight, and
/// browsers do not apply CORS to WebSockets). Requests without an `Origin` (gRPC, curl, the
/// native viewer) are not web pages and pass; the write token, when set, still applies to them.
pub(super) async fn check_origin(
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
pub(super) async fn check_read(
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
