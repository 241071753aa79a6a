//! What can go wrong talking to a server, the same for gRPC and WebSocket.

use std::fmt;
use std::time::Duration;

use bounce_wire::frame::FrameError;
use thiserror::Error;

use crate::layout::LayoutError;

#[derive(Debug, Error)]
pub enum ClientError {
    #[error("{url:?} is not a server address: {reason}")]
    Url { url: String, reason: String },
    #[error("the token must be printable ASCII: it travels in a header")]
    InvalidToken,
    #[error("connecting to {url}: {message}")]
    Connect { url: String, message: String },
    #[error("{what}: no answer within {after:?}")]
    Timeout { what: String, after: Duration },
    /// The server understood the request and said no.
    #[error("refused ({code}): {message}")]
    Refused { code: Refusal, message: String },
    /// The connection broke or the server went away mid-call.
    #[error("connection lost: {0}")]
    Transport(String),
    /// The server closed a WebSocket with this code and no error message before it.
    #[error("server closed the connection (code {code}{})", if reason.is_empty() { String::new() } else { format!(": {reason}") })]
    Closed { code: u16, reason: String },
    /// The server sent something this client does not understand.
    #[error("unexpected answer from the server: {0}")]
    Protocol(String),
    #[error(transparent)]
    Layout(#[from] LayoutError),
    #[error("bad frame from the server: {0}")]
    Frame(#[from] FrameError),
}

/// Why a server refused, named as gRPC names it (and as the WebSocket/HTTP JSON `code` spells
/// it in snake case).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Refusal {
    InvalidArgument,
    NotFound,
    Unauthenticated,
    /// A request larger than the server accepts.
    ResourceExhausted,
    /// The server could not do it now (a store that could not commit, a stopping worker).
    Unavailable,
    Internal,
    /// A code this client does not know, as the server sent it.
    Other(String),
}

impl Refusal {
    /// From the WebSocket/HTTP JSON `code`.
    pub fn from_json_code(code: &str) -> Refusal {
        match code {
            "invalid_argument" => Refusal::InvalidArgument,
            "not_found" => Refusal::NotFound,
            "unauthenticated" => Refusal::Unauthenticated,
            "resource_exhausted" => Refusal::ResourceExhausted,
            "unavailable" => Refusal::Unavailable,
            "internal" => Refusal::Internal,
            other => Refusal::Other(other.to_string()),
        }
    }

    /// From a WebSocket close code with no error message before it: 4000 + the HTTP status for
    /// the application's codes, 1009 for a message too big.
    pub fn from_close_code(code: u16) -> Option<Refusal> {
        Some(match code {
            4400 => Refusal::InvalidArgument,
            4401 => Refusal::Unauthenticated,
            4404 => Refusal::NotFound,
            4503 => Refusal::Unavailable,
            1009 => Refusal::ResourceExhausted,
            1011 => Refusal::Internal,
            _ => return None,
        })
    }
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Refusal::InvalidArgument => "invalid_argument",
            Refusal::NotFound => "not_found",
            Refusal::Unauthenticated => "unauthenticated",
            Refusal::ResourceExhausted => "resource_exhausted",
            Refusal::Unavailable => "unavailable",
            Refusal::Internal => "internal",
            Refusal::Other(code) => code,
        })
    }
}

impl ClientError {
    /// Whether trying the same thing again later may succeed: the server was away, slow or busy.
    /// A refusal for a reason the request itself carries (an unknown session, bad lights, a
    /// missing token), an address that is not one, or an answer this client cannot read will
    /// not go away by retrying.
    pub fn is_transient(&self) -> bool {
        match self {
            ClientError::Connect { .. }
            | ClientError::Timeout { .. }
            | ClientError::Transport(_)
            | ClientError::Closed { .. } => true,
            ClientError::Refused { code, .. } => {
                matches!(code, Refusal::Unavailable | Refusal::Internal)
            }
            ClientError::Url { .. }
            | ClientError::InvalidToken
            | ClientError::Protocol(_)
            | ClientError::Layout(_)
            | ClientError::Frame(_) => false,
        }
    }

    /// The refusal's code, when the server refused.
    pub fn refusal(&self) -> Option<&Refusal> {
        match self {
            ClientError::Refused { code, .. } => Some(code),
            _ => None,
        }
    }

    pub(crate) fn from_status(status: tonic::Status) -> ClientError {
        use tonic::Code;
        let message = status.message().to_string();
        let code = match status.code() {
            Code::InvalidArgument | Code::FailedPrecondition | Code::OutOfRange => {
                Refusal::InvalidArgument
            }
            Code::NotFound => Refusal::NotFound,
            Code::Unauthenticated | Code::PermissionDenied => Refusal::Unauthenticated,
            Code::ResourceExhausted => Refusal::ResourceExhausted,
            Code::Internal => Refusal::Internal,
            // tonic reports a connection it could not make or lost as UNAVAILABLE (and a
            // server going away mid-stream as UNKNOWN or CANCELLED): transport, not refusals.
            Code::Unavailable | Code::Unknown | Code::Cancelled | Code::Aborted => {
                return ClientError::Transport(format!("{:?}: {message}", status.code()));
            }
            Code::DeadlineExceeded => {
                return ClientError::Transport(format!("deadline exceeded: {message}"));
            }
            other => Refusal::Other(format!("{other:?}")),
        };
        ClientError::Refused { code, message }
    }
}
