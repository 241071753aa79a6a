//! bounce-client's integration tests, in one binary: a real `bounce-server` on loopback with the
//! CPU engine, the client library against it.

mod common;
mod grpc;
mod watcher;
mod websocket;
