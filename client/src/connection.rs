//! [`Client`]: one server, over gRPC (`http://host:port`) or WebSocket (`ws://host:port`), with
//! the same calls and the same errors either way.
//!
//! Over gRPC every call is the `bounce.v1.Bounce` service's, on one HTTP/2 connection that
//! tonic re-establishes by itself after a failure. Over WebSocket the one-shot calls are the
//! server's HTTP JSON routes on the same port (`GET /v1/scenes/{name}/layout`,
//! `POST /v1/sessions`, and `PUT /v1/sessions/{id}/lights` for [`Client::set_lights`]) and a
//! subscription is a session socket (`GET /v1/sessions/{id}/ws`). A socket opened for a change
//! would be sent the hello and the newest frame first (16 KB on pandora), on every step of a drag.

mod address;
mod grpc;
mod http_json;
mod websocket;

use std::time::Duration;

use bounce_types::light::LightSet;
use bounce_wire::frame::Frame;

pub use address::Scheme;

use crate::error::ClientError;
use crate::layout::Layout;
use address::Address;

pub use bounce_wire::limits::MAX_MESSAGE_BYTES;

/// Where and how to connect.
#[derive(Debug, Clone)]
pub struct ClientConfig {
    /// `http://host:port` (gRPC) or `ws://host:port` (WebSocket).
    pub url: String,
    /// The server's token, when it has one: sent with every call. A write token for a client
    /// that writes; a read token is enough for one that only watches.
    pub token: Option<String>,
    /// How long opening a connection may take.
    pub connect_timeout: Duration,
    /// How long a one-shot call may take, and opening a subscription.
    pub request_timeout: Duration,
    /// How often an idle connection is checked; a server silent for twice this is gone.
    pub keepalive: Duration,
}

impl ClientConfig {
    /// Defaults: no token, 5 s to connect, 30 s a call, keepalive every 10 s.
    pub fn new(url: impl Into<String>) -> ClientConfig {
        ClientConfig {
            url: url.into(),
            token: None,
            connect_timeout: Duration::from_secs(5),
            request_timeout: Duration::from_secs(30),
            keepalive: Duration::from_secs(10),
        }
    }

    pub fn with_token(mut self, token: impl Into<String>) -> ClientConfig {
        self.token = Some(token.into()).filter(|t| !t.is_empty());
        self
    }
}

impl From<&str> for ClientConfig {
    fn from(url: &str) -> ClientConfig {
        ClientConfig::new(url)
    }
}

impl From<String> for ClientConfig {
    fn from(url: String) -> ClientConfig {
        ClientConfig::new(url)
    }
}

/// A session as the server answered its creation.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionInfo {
    pub id: String,
    /// The initial lights' version: the session's first frame answers it.
    pub lights_version: u64,
}

/// A session as [`Client::get_session`] reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionState {
    pub id: String,
    pub scene: String,
    pub lights_version: u64,
    pub lights: LightSet,
}

/// What [`Client::set_lights`] answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LightsChange {
    pub lights_version: u64,
    /// `false` when the lights equalled the current ones: same version, no new frame.
    pub changed: bool,
}

/// A connection to one server. Clones share it.
#[derive(Clone)]
pub struct Client {
    transport: Transport,
}

#[derive(Clone)]
enum Transport {
    Grpc(grpc::Grpc),
    WebSocket(websocket::WebSocket),
}

impl Client {
    /// Connects (gRPC) or checks that the server's port answers (WebSocket, whose calls each
    /// open their own connection).
    pub async fn connect(config: impl Into<ClientConfig>) -> Result<Client, ClientError> {
        let config = config.into();
        let address = Address::parse(&config.url)?;
        let transport = match address.scheme {
            Scheme::Grpc => Transport::Grpc(grpc::Grpc::connect(&config).await?),
            Scheme::WebSocket => {
                Transport::WebSocket(websocket::WebSocket::connect(address, &config).await?)
            }
        };
        Ok(Client { transport })
    }

    pub fn scheme(&self) -> Scheme {
        match self.transport {
            Transport::Grpc(_) => Scheme::Grpc,
            Transport::WebSocket(_) => Scheme::WebSocket,
        }
    }

    /// The scene's patch layout, validated.
    pub async fn get_layout(&self, scene: &str) -> Result<Layout, ClientError> {
        match &self.transport {
            Transport::Grpc(t) => t.get_layout(scene).await,
            Transport::WebSocket(t) => t.get_layout(scene).await,
        }
    }

    /// A new session on `scene` with these lights (none: only emissive surfaces light it).
    pub async fn create_session(
        &self,
        scene: &str,
        lights: &LightSet,
    ) -> Result<SessionInfo, ClientError> {
        match &self.transport {
            Transport::Grpc(t) => t.create_session(scene, lights).await,
            Transport::WebSocket(t) => t.create_session(scene, lights).await,
        }
    }

    /// A session's scene, lights and lights version.
    pub async fn get_session(&self, session: &str) -> Result<SessionState, ClientError> {
        match &self.transport {
            Transport::Grpc(t) => t.get_session(session).await,
            Transport::WebSocket(t) => t.get_session(session).await,
        }
    }

    /// Replaces a session's lights.
    pub async fn set_lights(
        &self,
        session: &str,
        lights: &LightSet,
    ) -> Result<LightsChange, ClientError> {
        match &self.transport {
            Transport::Grpc(t) => t.set_lights(session, lights).await,
            Transport::WebSocket(t) => t.set_lights(session, lights).await,
        }
    }

    /// The session's frames: the newest at once (when there is one), then each newer one.
    pub async fn subscribe(&self, session: &str) -> Result<FrameStream, ClientError> {
        let inner = match &self.transport {
            Transport::Grpc(t) => Frames::Grpc(t.subscribe(session).await?),
            Transport::WebSocket(t) => Frames::WebSocket(t.subscribe(session).await?),
        };
        Ok(FrameStream { inner })
    }
}

/// One subscription's frames, in the server's order.
pub struct FrameStream {
    inner: Frames,
}

enum Frames {
    Grpc(grpc::Frames),
    WebSocket(websocket::Frames),
}

impl FrameStream {
    /// The next frame; `Ok(None)` when the server ended the stream in good order (it is
    /// shutting down), an error when the connection broke or the server refused.
    pub async fn next(&mut self) -> Result<Option<Frame>, ClientError> {
        match &mut self.inner {
            Frames::Grpc(f) => f.next().await,
            Frames::WebSocket(f) => f.next().await,
        }
    }

    /// Ends the subscription, telling the server (a WebSocket close frame; gRPC cancels the
    /// stream on drop).
    pub async fn close(self) {
        if let Frames::WebSocket(f) = self.inner {
            f.close().await;
        }
    }
}
