//! The WebSocket transport: session sockets for frames, the HTTP JSON routes for the rest (light
//! changes included: a socket per change would cost its upgrade, hello and first frame).
//!
//! The socket protocol (`GET /v1/sessions/{id}/ws`, `?token=T` for writes):
//! the server sends `{"type": "hello", "session_id", "scene", "lights_version", "patch_count"}`
//! first, then every frame as a binary message holding exactly the frame's bytes. The client may
//! send `{"type": "set_lights", "lights": [...], "token"}` (answered by `{"type": "lights",
//! "lights_version", "changed"}`) and `{"type": "ping"}` (answered by `{"type": "pong"}`). A
//! refusal is `{"type": "error", "code", "message"}` followed by a close with code 4400, 4401,
//! 4404 or 1009; a server shutting down closes with 1001.

use std::time::Duration;

use bounce_types::light::LightSet;
use bounce_wire::frame::Frame;
use futures_util::{SinkExt, StreamExt};
use http::Method;
use serde::Deserialize;
use tokio::net::TcpStream;
use tokio::time::{Instant, MissedTickBehavior};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;
use tokio_tungstenite::tungstenite::{self, Message};
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};
use tracing::debug;

use super::address::{Address, escape};
use super::http_json::{Call, refusal};
use super::{ClientConfig, LightsChange, MAX_MESSAGE_BYTES, SessionInfo, SessionState};
use crate::error::{ClientError, Refusal};
use crate::layout::Layout;
use crate::lights;

type Socket = WebSocketStream<MaybeTlsStream<TcpStream>>;

#[derive(Clone)]
pub(super) struct WebSocket {
    address: Address,
    token: Option<String>,
    connect_timeout: Duration,
    request_timeout: Duration,
    keepalive: Duration,
}

impl WebSocket {
    /// Nothing stays open between calls; this only finds out early whether anything listens.
    pub async fn connect(
        address: Address,
        config: &ClientConfig,
    ) -> Result<WebSocket, ClientError> {
        let probe = TcpStream::connect((address.host.as_str(), address.port));
        match tokio::time::timeout(config.connect_timeout, probe).await {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => {
                return Err(ClientError::Connect {
                    url: config.url.clone(),
                    message: e.to_string(),
                });
            }
            Err(_) => {
                return Err(ClientError::Timeout {
                    what: format!("connecting to {}", config.url),
                    after: config.connect_timeout,
                });
            }
        }
        Ok(WebSocket {
            address,
            token: config.token.clone(),
            connect_timeout: config.connect_timeout,
            request_timeout: config.request_timeout,
            keepalive: config.keepalive,
        })
    }

    fn call(&self, method: Method, path: String, body: Option<Vec<u8>>) -> Call<'_> {
        Call {
            address: &self.address,
            method,
            path,
            token: self.token.as_deref(),
            body,
            timeout: self.request_timeout,
        }
    }

    pub async fn get_layout(&self, scene: &str) -> Result<Layout, ClientError> {
        let path = format!("/v1/scenes/{}/layout", escape(scene));
        let body = self.call(Method::GET, path, None).send().await?;
        Ok(Layout::from_json(&body)?)
    }

    pub async fn create_session(
        &self,
        scene: &str,
        lights: &LightSet,
    ) -> Result<SessionInfo, ClientError> {
        let request = serde_json::json!({ "scene": scene, "lights": lights::to_json(lights) });
        let body = self
            .call(
                Method::POST,
                "/v1/sessions".into(),
                Some(request.to_string().into_bytes()),
            )
            .send()
            .await?;
        #[derive(Deserialize)]
        struct Created {
            session_id: String,
            lights_version: u64,
        }
        let created: Created = serde_json::from_slice(&body)
            .map_err(|e| ClientError::Protocol(format!("POST /v1/sessions answered: {e}")))?;
        Ok(SessionInfo {
            id: created.session_id,
            lights_version: created.lights_version,
        })
    }

    /// `GET /v1/sessions/{id}`.
    pub async fn get_session(&self, session: &str) -> Result<SessionState, ClientError> {
        let path = format!("/v1/sessions/{}", escape(session));
        let body = self.call(Method::GET, path, None).send().await?;
        #[derive(Deserialize)]
        struct State {
            session_id: String,
            scene: String,
            lights_version: u64,
            lights: serde_json::Value,
        }
        let state: State = serde_json::from_slice(&body)
            .map_err(|e| ClientError::Protocol(format!("GET /v1/sessions answered: {e}")))?;
        let lights =
            LightSet::from_json(&serde_json::json!({ "lights": state.lights }).to_string())
                .map_err(|e| {
                    ClientError::Protocol(format!("GET /v1/sessions answered lights: {e}"))
                })?;
        Ok(SessionState {
            id: state.session_id,
            scene: state.scene,
            lights_version: state.lights_version,
            lights,
        })
    }

    /// `PUT /v1/sessions/{id}/lights`. Not a session socket: opening one to send a change costs
    /// an upgrade, the hello and the newest frame (16 KB on pandora), which a viewer dragging a
    /// light would pay on every step, and it would count as a viewer of the session meanwhile.
    pub async fn set_lights(
        &self,
        session: &str,
        lights: &LightSet,
    ) -> Result<LightsChange, ClientError> {
        let path = format!("/v1/sessions/{}/lights", escape(session));
        let request = serde_json::json!({ "lights": lights::to_json(lights) });
        let body = self
            .call(Method::PUT, path, Some(request.to_string().into_bytes()))
            .send()
            .await?;
        #[derive(Deserialize)]
        struct Answer {
            lights_version: u64,
            changed: bool,
        }
        let answer: Answer = serde_json::from_slice(&body).map_err(|e| {
            ClientError::Protocol(format!("PUT /v1/sessions/{{id}}/lights answered: {e}"))
        })?;
        Ok(LightsChange {
            lights_version: answer.lights_version,
            changed: answer.changed,
        })
    }

    pub async fn subscribe(&self, session: &str) -> Result<Frames, ClientError> {
        let (socket, hello) = self.open(session).await?;
        let mut ping = tokio::time::interval_at(Instant::now() + self.keepalive, self.keepalive);
        ping.set_missed_tick_behavior(MissedTickBehavior::Delay);
        Ok(Frames {
            socket,
            patch_count: hello.patch_count,
            ping,
            keepalive: self.keepalive,
            heard: Instant::now(),
            done: false,
        })
    }

    /// Opens the session's socket and reads its hello.
    async fn open(&self, session: &str) -> Result<(Socket, Hello), ClientError> {
        let mut url = format!(
            "ws://{}/v1/sessions/{}/ws",
            self.address.authority(),
            escape(session)
        );
        if let Some(t) = &self.token {
            url.push_str("?token=");
            url.push_str(&escape(t));
        }
        let request = url
            .as_str()
            .into_client_request()
            .map_err(|e| ClientError::Url {
                url: url.clone(),
                reason: e.to_string(),
            })?;
        let config = WebSocketConfig::default()
            .max_message_size(Some(MAX_MESSAGE_BYTES))
            .max_frame_size(Some(MAX_MESSAGE_BYTES));
        let connect = tokio_tungstenite::connect_async_with_config(request, Some(config), true);
        let (mut socket, _) = tokio::time::timeout(self.connect_timeout, connect)
            .await
            .map_err(|_| ClientError::Timeout {
                what: format!("opening {url}"),
                after: self.connect_timeout,
            })?
            .map_err(|e| handshake_error(&url, e))?;
        let hello = tokio::time::timeout(self.request_timeout, read(&mut socket))
            .await
            .map_err(|_| ClientError::Timeout {
                what: "the session socket's hello".into(),
                after: self.request_timeout,
            })??;
        match hello {
            Incoming::Text(ServerMessage::Hello {
                session_id,
                patch_count,
                ..
            }) => {
                if session_id != session {
                    return Err(ClientError::Protocol(format!(
                        "asked for session {session:?}, the socket says {session_id:?}"
                    )));
                }
                Ok((socket, Hello { patch_count }))
            }
            Incoming::Text(ServerMessage::Error { code, message }) => Err(refused(&code, message)),
            Incoming::End(end) => Err(end.error()),
            _ => Err(ClientError::Protocol(
                "the session socket did not start with a hello".into(),
            )),
        }
    }
}

struct Hello {
    patch_count: u64,
}

pub(super) struct Frames {
    socket: Socket,
    patch_count: u64,
    ping: tokio::time::Interval,
    keepalive: Duration,
    /// When the server last sent anything: frames stop when lights do, so pings prove it lives.
    heard: Instant,
    done: bool,
}

impl Frames {
    pub async fn next(&mut self) -> Result<Option<Frame>, ClientError> {
        if self.done {
            return Ok(None);
        }
        let result = self.read_frame().await;
        if !matches!(result, Ok(Some(_))) {
            self.done = true;
        }
        result
    }

    async fn read_frame(&mut self) -> Result<Option<Frame>, ClientError> {
        loop {
            let incoming = tokio::select! {
                incoming = read(&mut self.socket) => incoming?,
                _ = self.ping.tick() => {
                    if self.heard.elapsed() > 2 * self.keepalive {
                        return Err(ClientError::Timeout {
                            what: "the session socket".into(),
                            after: 2 * self.keepalive,
                        });
                    }
                    send(&mut self.socket, Message::text(r#"{"type":"ping"}"#)).await?;
                    continue;
                }
            };
            self.heard = Instant::now();
            match incoming {
                Incoming::Frame(frame) => {
                    if u64::from(frame.header.patch_count) != self.patch_count {
                        return Err(ClientError::Protocol(format!(
                            "a frame of {} patches on a socket whose hello said {}",
                            frame.header.patch_count, self.patch_count
                        )));
                    }
                    return Ok(Some(frame));
                }
                Incoming::Text(ServerMessage::Error { code, message }) => {
                    return Err(refused(&code, message));
                }
                Incoming::Text(_) | Incoming::Other => {}
                Incoming::End(End::Closed { code, .. }) if code == 1000 || code == 1001 => {
                    return Ok(None);
                }
                Incoming::End(end) => return Err(end.error()),
            }
        }
    }

    pub async fn close(mut self) {
        if !self.done {
            let _ = self.socket.close(None).await;
        }
    }
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
enum ServerMessage {
    Hello {
        session_id: String,
        patch_count: u64,
    },
    Error {
        code: String,
        message: String,
    },
    /// `pong`, `lights` (answers to a socket's `set_lights`, which this client sends as a PUT),
    /// and whatever a newer server adds.
    #[serde(other)]
    Other,
}

enum Incoming {
    Frame(Frame),
    Text(ServerMessage),
    /// Pings and pongs of the WebSocket itself.
    Other,
    End(End),
}

enum End {
    Closed {
        code: u16,
        reason: String,
    },
    /// The connection ended without a close frame.
    Dropped,
}

impl End {
    fn error(self) -> ClientError {
        match self {
            End::Closed { code, reason } => match Refusal::from_close_code(code) {
                Some(code) => ClientError::Refused {
                    code,
                    message: reason,
                },
                None => ClientError::Closed { code, reason },
            },
            End::Dropped => {
                ClientError::Transport("the socket closed without a close frame".into())
            }
        }
    }
}

async fn read(socket: &mut Socket) -> Result<Incoming, ClientError> {
    let message = match socket.next().await {
        None => return Ok(Incoming::End(End::Dropped)),
        Some(Err(tungstenite::Error::ConnectionClosed | tungstenite::Error::AlreadyClosed)) => {
            return Ok(Incoming::End(End::Dropped));
        }
        Some(Err(tungstenite::Error::Capacity(e))) => {
            return Err(ClientError::Protocol(format!("message too large: {e}")));
        }
        Some(Err(tungstenite::Error::Protocol(e))) => {
            return Err(ClientError::Transport(format!("WebSocket protocol: {e}")));
        }
        Some(Err(e)) => return Err(ClientError::Transport(e.to_string())),
        Some(Ok(m)) => m,
    };
    Ok(match message {
        Message::Binary(bytes) => Incoming::Frame(Frame::parse(bytes)?),
        Message::Text(text) => match serde_json::from_str(text.as_str()) {
            Ok(m) => Incoming::Text(m),
            Err(e) => {
                return Err(ClientError::Protocol(format!(
                    "text message {:?}: {e}",
                    text.as_str().chars().take(120).collect::<String>()
                )));
            }
        },
        Message::Close(frame) => Incoming::End(match frame {
            Some(f) => End::Closed {
                code: u16::from(f.code),
                reason: f.reason.to_string(),
            },
            None => End::Closed {
                code: u16::from(CloseCode::Status),
                reason: String::new(),
            },
        }),
        Message::Ping(_) | Message::Pong(_) | Message::Frame(_) => Incoming::Other,
    })
}

async fn send(socket: &mut Socket, message: Message) -> Result<(), ClientError> {
    socket
        .send(message)
        .await
        .map_err(|e| ClientError::Transport(format!("sending on the session socket: {e}")))
}

fn refused(code: &str, message: String) -> ClientError {
    ClientError::Refused {
        code: Refusal::from_json_code(code),
        message,
    }
}

/// A refused upgrade (an unknown session is a plain 404 before it) is the server's answer, not
/// a connection problem.
fn handshake_error(url: &str, e: tungstenite::Error) -> ClientError {
    match e {
        tungstenite::Error::Http(response) => {
            let body = response.body().as_deref().unwrap_or_default();
            refusal(response.status(), body)
        }
        tungstenite::Error::Io(e) => ClientError::Connect {
            url: url.to_string(),
            message: e.to_string(),
        },
        other => {
            debug!(error = %other, "WebSocket handshake failed");
            ClientError::Transport(format!("opening {url}: {other}"))
        }
    }
}
