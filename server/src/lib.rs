//! `bounce-server`: the lighting service of docs/design.md §2 "Serve" and §5.
//!
//! It owns what happens between a baked scene on disk and a viewer's frames: the scenes loaded
//! from a directory and reloaded when they change ([`scenes`]), sessions (a scene, a light
//! configuration and its version, [`session`]) kept in an embedded store so they survive
//! restarts ([`store`]), the engine worker that solves every changed session of a scene in one
//! batch ([`worker`]), what each viewer reads of the frames ([`viewer`]), the hub tying these
//! together ([`hub`]), Prometheus [`metrics`], connection limits ([`limits`]), and the front ends,
//! one folder each: gRPC ([`grpc`]) with health and reflection, and HTTP ([`http`]) with the
//! session WebSockets, the browser page and each scene's model ([`model`]), cached by tag
//! ([`cache`]). [`run()`] serves both over one hub and stops them together; the command line, the
//! benchmark and the tests all start a server through it.
//!
//! Not here: the math (`bounce-core`), the engines themselves (`bounce-engine`), the protobuf
//! messages, the frame byte layout and the light messages (`bounce-wire`, re-exported here as
//! [`proto`], [`frame`], [`lights`] and [`codec`]), the command line and its runtime, logging
//! setup and signals (`bounce serve` in `bounce-cli`).

pub mod cache;
pub mod error;
pub mod grpc;
pub mod http;
pub mod hub;
pub mod limits;
pub mod metrics;
pub mod model;
pub mod run;
pub mod scenes;
pub mod session;
pub mod store;
pub mod viewer;
mod worker;

pub use bounce_wire::limits::MAX_REQUEST_BYTES;
pub use bounce_wire::text::{ClientText, parse_client_text};
pub use error::ServerError;
pub use frame::Frame;
pub use grpc::serve_grpc;
pub use http::serve_http;
pub use hub::{Hub, HubConfig, LightsVersion};
pub use run::{Listeners, run};
pub use worker::{MAX_BATCH, MAX_ONCE_QUEUED};

// The wire vocabulary is `bounce-wire`'s; these paths stay for the server's users.
pub use bounce_wire::{codec, frame, lights, proto};
