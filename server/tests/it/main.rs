//! bounce-server's integration tests, in one binary: real servers on loopback, real clients.

mod common;
mod emissive;
mod grpc;
mod http;
mod lifecycle;
mod stress;
mod web;
mod ws;
