//! What every HTTP handler shares, and where a request came from.

use std::net::SocketAddr;

use tokio_util::task::TaskTracker;

use crate::hub::Hub;

/// The address a request came from, as the connection limit admitted it
/// ([`super::serve_connections`] puts it in every request's extensions).
#[derive(Clone, Copy, Debug)]
pub(super) struct Peer(pub SocketAddr);

/// What every handler shares.
#[derive(Clone)]
pub(crate) struct AppState {
    pub hub: Hub,
    /// Every open WebSocket, so shutdown can wait for their close frames.
    pub sockets: TaskTracker,
}
