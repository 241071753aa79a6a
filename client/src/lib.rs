//! `bounce-client`: the client library of docs/design.md §2 "Clients", what a viewer (a window, a
//! headless renderer, a tool) needs between a bounce server and its own shading.
//!
//! It owns:
//! - [`layout`]: a scene's patch layout as a server sends it, validated so that a hostile or
//!   broken answer is an error and never a panic or an out-of-bounds write;
//! - [`volume`]: the six-direction irradiance volume built from a layout and filled from frames,
//!   its texel layout for a 3D texture upload, and a CPU sampler that is the shader's twin (the
//!   convention is in that module's doc);
//! - [`connection`]: [`Client`], the same calls over gRPC (`http://`) and WebSocket (`ws://`):
//!   layout, sessions, lights, frame subscriptions;
//! - [`watcher`]: [`Watcher`], a subscription that reconnects with backoff, keeps the newest
//!   frame through outages and never goes back to an older one.
//!
//! Not here: the frame byte layout and its RGB9E5 codec (`bounce_wire::frame`, one definition
//! for the server and every client; re-exported as [`Frame`]), light validation (the server
//! judges; `bounce_types::light` defines the JSON form), windows, GPU textures, shaders and
//! direct light (the viewer's).

pub mod connection;
pub mod error;
pub mod layout;
pub mod lights;
pub mod volume;
pub mod watcher;

pub use bounce_types::light::{Light, LightSet};
pub use bounce_wire::frame::{Frame, FrameHeader};
pub use connection::{
    Client, ClientConfig, FrameStream, LightsChange, MAX_MESSAGE_BYTES, Scheme, SessionInfo,
    SessionState,
};
pub use error::{ClientError, Refusal};
pub use layout::{Face, Layout, LayoutError, PatchFace};
pub use volume::{Volume, VolumeError, blend_weights};
pub use watcher::{ConnectionState, Watcher, WatcherOptions};
