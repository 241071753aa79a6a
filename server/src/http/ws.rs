//! A session's WebSocket, `GET /v1/sessions/{id}/ws`: the gRPC `Relight` stream's semantics in
//! JSON text messages and binary frames.
//!
//! Server → client: first a text `{"type": "hello", "session_id", "scene", "lights_version",
//! "patch_count"}`, then every frame as a binary message holding exactly [`Frame::bytes`] (the
//! layout gRPC's `Frame.data` carries), through a [`Viewer`]: the newest frame at once, then each
//! newer one; a slow reader skips to the newest, never gets an older one. The hello also says
//! `probe_count`; a client that upgrades with `?probes=1` and a scene with probes gets, after
//! each frame, its probe frame (`BNCP`, `bounce_wire::frame`) as a second binary message. Without
//! the query a client gets patch frames only, as before probes.
//!
//! Client → server, text: `{"type": "set_lights", "lights": [...], "token": "T"}` (the token is
//! optional where the upgrade request presented one) answered by `{"type": "lights",
//! "lights_version", "changed"}`; `{"type": "ping"}` answered by `{"type": "pong"}`. A refused
//! message is answered by `{"type": "error", "code", "message"}` and a close frame with
//! [`ErrorCode::close_code`]; shutdown closes with 1001.

use std::time::Duration;

use tokio::time::Instant;

use axum::extract::ws::rejection::WebSocketUpgradeRejection;
use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, Query, State};
use axum::response::Response;
use serde::{Deserialize, Serialize};
use tokio::sync::watch;
use tracing::debug;

use bounce_wire::text::{ClientText, parse_client_text};

use super::access::Token;
use super::error::{ApiError, ErrorCode};
use super::state::AppState;
use crate::error::ServerError;
use crate::frame::Frame;
use crate::hub::Hub;
use crate::metrics::{Metrics, Transport};
use crate::viewer::Viewer;
use bounce_wire::limits::MAX_REQUEST_BYTES;

/// Close code for a server going away (RFC 6455).
const GOING_AWAY: u16 = 1001;
/// RFC 6455's "policy violation": the client broke the keep-alive rule.
const POLICY_VIOLATION: u16 = 1008;
/// RFC 6455 caps a close frame's payload at 125 bytes, two of them the code.
const MAX_CLOSE_REASON: usize = 123;
/// How long a closing socket waits for the client's close frame before dropping the connection.
const CLOSE_GRACE: Duration = Duration::from_secs(2);

/// The upgrade: an unknown session is a plain 404 before it; the token the request presents
/// authorises the connection's writes.
pub(crate) async fn upgrade(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Token(token): Token,
    Query(options): Query<WsQuery>,
    upgrade: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Result<Response, ApiError> {
    let probes = match options.probes.as_deref() {
        None | Some("0" | "false") => false,
        Some("1" | "true") => true,
        Some(other) => {
            return Err(ApiError::from(ServerError::Invalid(format!(
                "probes={other}: give probes=1 (or true) to receive probe frames"
            ))));
        }
    };
    let viewer = state.hub.viewer(&id, Transport::Websocket)?;
    let upgrade = upgrade.map_err(|r| ApiError::from_rejection(r.status(), r.body_text()))?;
    let connection = Connection {
        shutdown: state.hub.shutdown_signal(),
        hub: state.hub,
        viewer,
        token,
        probes,
    };
    // Held for the socket's life, so shutdown waits for its close frame.
    let tracked = state.sockets.token();
    Ok(upgrade
        .max_message_size(MAX_REQUEST_BYTES)
        .max_frame_size(MAX_REQUEST_BYTES)
        .on_failed_upgrade(|e| debug!(error = %e, "WebSocket upgrade failed"))
        .on_upgrade(move |socket| async move {
            connection.run(socket).await;
            drop(tracked);
        }))
}

/// The upgrade's query besides the token: whether the client takes probe frames.
#[derive(Deserialize)]
pub(crate) struct WsQuery {
    probes: Option<String>,
}

#[derive(Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
enum ServerMessage<'a> {
    Hello {
        session_id: &'a str,
        scene: &'a str,
        lights_version: u64,
        patch_count: usize,
        /// Probes of the scene (six values each in a probe frame); 0 without.
        probe_count: usize,
    },
    Lights {
        lights_version: u64,
        changed: bool,
    },
    Pong,
    Error {
        code: &'static str,
        message: &'a str,
    },
}

impl ServerMessage<'_> {
    fn to_message(&self) -> Message {
        // These types always serialise.
        Message::text(serde_json::to_string(self).unwrap_or_default())
    }
}

/// Why a connection ends.
enum End {
    /// The client closed, vanished or broke the protocol: nothing more to say.
    ClientGone,
    /// A refused message: answered, then closed with its code.
    Refused(ErrorCode, String),
    ShuttingDown,
    /// The client answered no ping, or did not take a message, within the keep-alive period.
    Unresponsive,
}

struct Connection {
    hub: Hub,
    viewer: Viewer,
    /// What the upgrade request presented.
    token: Option<String>,
    /// Whether the client asked for probe frames.
    probes: bool,
    shutdown: watch::Receiver<bool>,
}

impl Connection {
    async fn run(mut self, mut socket: WebSocket) {
        let mut end = self.serve(&mut socket).await;
        if let End::Refused(code, message) = end {
            let id = &self.viewer.session().id;
            debug!(session = %id, code = code.as_str(), %message, "WebSocket message refused");
            self.hub
                .metrics()
                .requests_refused
                .get_or_create(&Metrics::transport(Transport::Websocket))
                .inc();
            let error = ServerMessage::Error {
                code: code.as_str(),
                message: &message,
            };
            end = match self.send(&mut socket, error.to_message()).await {
                Ok(()) => return close(&mut socket, code.close_code(), &message).await,
                Err(end) => end,
            };
        }
        match end {
            End::ShuttingDown => close(&mut socket, GOING_AWAY, "server shutting down").await,
            End::Unresponsive => {
                self.hub.metrics().websocket_unresponsive.inc();
                close(
                    &mut socket,
                    POLICY_VIOLATION,
                    "no reply within the keep-alive period",
                )
                .await
            }
            _ => {}
        }
    }

    async fn serve(&mut self, socket: &mut WebSocket) -> End {
        let session = std::sync::Arc::clone(self.viewer.session());
        let scene = self.hub.scene_of(&session);
        let (patch_count, probe_count) = self
            .hub
            .scene(&scene)
            .map_or((0, 0), |s| (s.layout.len(), s.probes.len()));
        let hello = ServerMessage::Hello {
            session_id: &session.id,
            scene: &scene,
            lights_version: session.lights_version(),
            patch_count,
            probe_count,
        };
        if let Err(end) = self.send(socket, hello.to_message()).await {
            return end;
        }
        // A viewer may watch for hours without a word, so silence alone ends nothing: after a
        // keep-alive period without a message the client is pinged, and a client that answers
        // nothing (not even the pong its WebSocket library sends by itself) within another is
        // gone, however its TCP connection looks.
        let keepalive = self.hub.ws_keepalive();
        let mut heard = Instant::now();
        let mut pinged = false;
        loop {
            let quiet = heard + if pinged { keepalive * 2 } else { keepalive };
            let event = tokio::select! {
                biased;
                _ = self.shutdown.wait_for(|&s| s) => return End::ShuttingDown,
                message = socket.recv() => Event::Message(message),
                frame = self.viewer.next() => Event::Frame(frame),
                _ = tokio::time::sleep_until(quiet) => Event::Quiet,
            };
            if let Event::Message(Some(Ok(_))) = &event {
                heard = Instant::now();
                pinged = false;
            }
            let reply = match event {
                Event::Quiet if pinged => {
                    debug!(session = %session.id, "WebSocket client answered no ping: closing");
                    return End::Unresponsive;
                }
                Event::Quiet => {
                    pinged = true;
                    Message::Ping(Default::default())
                }
                Event::Frame(None) => return End::ShuttingDown,
                Event::Frame(Some(frame)) => {
                    if let (true, Some(probes)) = (self.probes, frame.probes()) {
                        // The patch frame first, its probe frame right after it.
                        if let Err(end) = self.send(socket, frame_message(&frame)).await {
                            return end;
                        }
                        frame_message(probes)
                    } else {
                        frame_message(&frame)
                    }
                }
                Event::Message(None) => return End::ClientGone,
                Event::Message(Some(Err(e))) => return read_error(e),
                Event::Message(Some(Ok(Message::Text(text)))) => {
                    match self.handle(&session.id, text.as_str()).await {
                        Ok(reply) => reply,
                        Err(e) => return End::Refused(ErrorCode::of(&e), e.to_string()),
                    }
                }
                Event::Message(Some(Ok(Message::Binary(_)))) => {
                    return End::Refused(
                        ErrorCode::InvalidArgument,
                        "binary messages are not accepted: send JSON text".into(),
                    );
                }
                // Pings are answered by the protocol layer; after the client's close frame the
                // next read ends the stream.
                Event::Message(Some(Ok(_))) => continue,
            };
            if let Err(end) = self.send(socket, reply).await {
                return end;
            }
        }
    }

    /// One text message from the client, and the reply to send.
    async fn handle(&self, session_id: &str, text: &str) -> Result<Message, ServerError> {
        match parse_client_text(text).map_err(|e| ServerError::Invalid(e.0))? {
            ClientText::Ping => Ok(ServerMessage::Pong.to_message()),
            ClientText::SetLights { lights, token } => {
                let token = token.filter(|t| !t.is_empty()).or(self.token.clone());
                // The token first: a client without one learns nothing about its lights.
                self.hub.authorize(token.as_deref())?;
                let v = self.hub.set_lights(session_id, lights?).await?;
                Ok(ServerMessage::Lights {
                    lights_version: v.version,
                    changed: v.changed,
                }
                .to_message())
            }
        }
    }

    /// Sends unless the server shuts down first or the client takes more than a keep-alive
    /// period to take it: a client that stopped reading blocks only its own connection, and not
    /// for long.
    async fn send(&mut self, socket: &mut WebSocket, message: Message) -> Result<(), End> {
        let deadline = tokio::time::sleep(self.hub.ws_keepalive());
        tokio::select! {
            biased;
            _ = self.shutdown.wait_for(|&s| s) => Err(End::ShuttingDown),
            sent = socket.send(message) => sent.map_err(|_| End::ClientGone),
            _ = deadline => Err(End::Unresponsive),
        }
    }
}

enum Event {
    Message(Option<Result<Message, axum::Error>>),
    Frame(Option<Frame>),
    /// A keep-alive period passed without a word from the client.
    Quiet,
}

fn frame_message(frame: &Frame) -> Message {
    Message::Binary(frame.bytes().clone())
}

/// A failed read: a message over the size limit is refused with 1009; anything else means the
/// client is gone or broke the protocol.
fn read_error(e: axum::Error) -> End {
    let inner = e.into_inner();
    match inner.downcast_ref::<tungstenite::Error>() {
        Some(tungstenite::Error::Capacity(c)) => End::Refused(
            ErrorCode::TooLarge,
            format!("message over the {MAX_REQUEST_BYTES}-byte limit ({c})"),
        ),
        _ => {
            debug!(error = %inner, "WebSocket read failed");
            End::ClientGone
        }
    }
}

/// Sends a close frame and waits a little for the client's, so the close frame is read before
/// the connection drops.
async fn close(socket: &mut WebSocket, code: u16, reason: &str) {
    let frame = CloseFrame {
        code,
        reason: truncate(reason, MAX_CLOSE_REASON).into(),
    };
    let closing = async {
        if socket.send(Message::Close(Some(frame))).await.is_err() {
            return;
        }
        while let Some(Ok(_)) = socket.recv().await {}
    };
    let _ = tokio::time::timeout(CLOSE_GRACE, closing).await;
}

/// At most `max` bytes of `s`, cut at a character boundary.
fn truncate(s: &str, max: usize) -> &str {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn close_reasons_fit_and_stay_utf8() {
        assert_eq!(truncate("short", MAX_CLOSE_REASON), "short");
        let long = "é".repeat(100);
        let cut = truncate(&long, MAX_CLOSE_REASON);
        assert!(cut.len() <= MAX_CLOSE_REASON);
        assert_eq!(cut.len(), 122);
    }

    #[test]
    fn close_codes() {
        assert_eq!(ErrorCode::InvalidArgument.close_code(), 4400);
        assert_eq!(ErrorCode::Unauthenticated.close_code(), 4401);
        assert_eq!(ErrorCode::NotFound.close_code(), 4404);
        assert_eq!(ErrorCode::TooLarge.close_code(), 1009);
        assert_eq!(ErrorCode::Unavailable.close_code(), 4503);
        assert_eq!(ErrorCode::Internal.close_code(), 1011);
    }
}
