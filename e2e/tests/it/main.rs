//! bounce-client against a real `bounce-server` on loopback with the CPU engine, in one binary
//! (this crate, `bounce-e2e`, exists so the client itself needs no server to build its tests).

mod common;
mod grpc;
mod watcher;
mod websocket;
