//! What a refused HTTP request or WebSocket is: one code ([`ErrorCode`]) that gives the JSON
//! `code`, the HTTP status and the WebSocket close code, mapped once from the service's
//! [`ServerError`]. The bottom of the HTTP front end: it imports none of its siblings.

use axum::Json;
use axum::extract::State;
use axum::extract::rejection::BytesRejection;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;

use crate::error::ServerError;
use crate::hub::Hub;
use crate::metrics::{Metrics, Transport};
use bounce_wire::limits::MAX_REQUEST_BYTES;

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

/// Counts every refusal an HTTP answer carries in `bounce_requests_refused_total`.
pub(super) async fn count_refusals(State(hub): State<Hub>, response: Response) -> Response {
    if response.extensions().get::<Refused>().is_some() {
        hub.metrics()
            .requests_refused
            .get_or_create(&Metrics::transport(Transport::Http))
            .inc();
    }
    response
}
