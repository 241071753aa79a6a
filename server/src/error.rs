//! What can go wrong serving, and which gRPC status each is.

use std::path::PathBuf;

use bounce_core::format::FormatError;
use bounce_core::light::LightError;
use bounce_engine::EngineError;
use thiserror::Error;

use crate::frame::FrameError;

#[derive(Debug, Error)]
pub enum ServerError {
    #[error("reading the scene directory {path}: {source}")]
    ScenesDir {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("no usable .bounce file in {0}")]
    NoScenes(PathBuf),
    // Boxed: engine errors are large and every hub call returns this type.
    #[error("opening the engine: {0}")]
    Engine(Box<EngineError>),
    #[error("loading scene {name:?} on the engine: {source}")]
    Load {
        name: String,
        source: Box<EngineError>,
    },
    /// The engine failed on a batch (the message, as one error may answer several callers).
    #[error("relighting scene {scene:?}: {message}")]
    Relight { scene: String, message: String },
    #[error("the engine worker has stopped")]
    WorkerGone,
    #[error("unknown scene {0:?}")]
    UnknownScene(String),
    #[error("unknown session {0:?}")]
    UnknownSession(String),
    /// A refused light configuration; the message starts with the field's path.
    #[error(transparent)]
    Lights(#[from] LightError),
    #[error(transparent)]
    Frame(#[from] FrameError),
    /// A request that is malformed in a way the light validator does not cover.
    #[error("{0}")]
    Invalid(String),
    #[error("this server needs a token for writes; none or a wrong one was given")]
    Unauthenticated,
    #[error(
        "this server needs a token for reads (its read token or its write token); none or a wrong one was given"
    )]
    ReadUnauthenticated,
    /// A limit of the server reached (sessions, queued requests); the message says which.
    #[error("{0}")]
    Exhausted(String),
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    /// A baked file that failed validation on reload: the previous scene keeps serving.
    #[error("{path}: {source}")]
    SceneFile { path: PathBuf, source: FormatError },
    #[error("gRPC reflection: {0}")]
    Reflection(String),
    #[error("gRPC transport: {0}")]
    Transport(#[from] tonic::transport::Error),
    #[error("HTTP server: {0}")]
    Http(std::io::Error),
}

/// A baked file the server could not read: skipped with this reason, the others still serve.
#[derive(Debug, Error)]
#[error("{path}: {source}")]
pub struct SkippedScene {
    pub path: PathBuf,
    pub source: FormatError,
}

impl From<ServerError> for tonic::Status {
    fn from(e: ServerError) -> tonic::Status {
        use tonic::Status;
        match e {
            ServerError::UnknownScene(_) | ServerError::UnknownSession(_) => {
                Status::not_found(e.to_string())
            }
            ServerError::Lights(_) | ServerError::Invalid(_) => {
                Status::invalid_argument(e.to_string())
            }
            ServerError::Unauthenticated | ServerError::ReadUnauthenticated => {
                Status::unauthenticated(e.to_string())
            }
            ServerError::Exhausted(_) => Status::resource_exhausted(e.to_string()),
            ServerError::WorkerGone | ServerError::Store(_) => Status::unavailable(e.to_string()),
            _ => Status::internal(e.to_string()),
        }
    }
}
