//! The gRPC transport: the generated `bounce.v1` client on one tonic channel.

use std::future::Future;
use std::time::Duration;

use bounce_types::light::LightSet;
use bounce_wire::frame::Frame;
use bounce_wire::proto::{self, bounce_client::BounceClient};
use tonic::Request;
use tonic::metadata::{Ascii, MetadataValue};
use tonic::transport::{Channel, Endpoint};

use super::{ClientConfig, LightsChange, MAX_MESSAGE_BYTES, SessionInfo, SessionState};
use crate::error::ClientError;
use crate::layout::Layout;
use crate::lights;

#[derive(Clone)]
pub(super) struct Grpc {
    client: BounceClient<Channel>,
    /// `Bearer <token>`, attached to every call: a write token to writes, and reads too, which
    /// a server with a read token refuses without one.
    authorization: Option<MetadataValue<Ascii>>,
    request_timeout: Duration,
}

impl Grpc {
    pub async fn connect(config: &ClientConfig) -> Result<Grpc, ClientError> {
        let url = &config.url;
        let endpoint = Endpoint::from_shared(url.clone())
            .map_err(|e| ClientError::Url {
                url: url.clone(),
                reason: e.to_string(),
            })?
            .connect_timeout(config.connect_timeout)
            .tcp_nodelay(true)
            // HTTP/2 pings notice a server that vanished without closing (a cable, a frozen
            // host) while a subscription waits for frames that will not come.
            .http2_keep_alive_interval(config.keepalive)
            .keep_alive_timeout(config.keepalive)
            .keep_alive_while_idle(true);
        let channel = tokio::time::timeout(config.connect_timeout, endpoint.connect())
            .await
            .map_err(|_| ClientError::Timeout {
                what: format!("connecting to {url}"),
                after: config.connect_timeout,
            })?
            .map_err(|e| ClientError::Connect {
                url: url.clone(),
                message: error_chain(&e),
            })?;
        let authorization = match &config.token {
            Some(t) => Some(
                format!("Bearer {t}")
                    .parse()
                    .map_err(|_| ClientError::InvalidToken)?,
            ),
            None => None,
        };
        Ok(Grpc {
            client: BounceClient::new(channel)
                .max_decoding_message_size(MAX_MESSAGE_BYTES)
                .max_encoding_message_size(MAX_MESSAGE_BYTES),
            authorization,
            request_timeout: config.request_timeout,
        })
    }

    async fn call<T>(
        &self,
        what: &str,
        call: impl Future<Output = Result<tonic::Response<T>, tonic::Status>>,
    ) -> Result<T, ClientError> {
        match tokio::time::timeout(self.request_timeout, call).await {
            Ok(Ok(response)) => Ok(response.into_inner()),
            Ok(Err(status)) => Err(ClientError::from_status(status)),
            Err(_) => Err(ClientError::Timeout {
                what: what.to_string(),
                after: self.request_timeout,
            }),
        }
    }

    fn authorized<T>(&self, message: T) -> Request<T> {
        let mut request = Request::new(message);
        if let Some(a) = &self.authorization {
            request.metadata_mut().insert("authorization", a.clone());
        }
        request
    }

    pub async fn get_layout(&self, scene: &str) -> Result<Layout, ClientError> {
        let mut c = self.client.clone();
        let request = self.authorized(proto::GetLayoutRequest {
            scene: scene.to_string(),
        });
        let layout = self.call("GetLayout", c.get_layout(request)).await?;
        Ok(Layout::from_proto(&layout)?)
    }

    pub async fn create_session(
        &self,
        scene: &str,
        lights: &LightSet,
    ) -> Result<SessionInfo, ClientError> {
        let mut c = self.client.clone();
        let request = self.authorized(proto::CreateSessionRequest {
            scene: scene.to_string(),
            lights: lights::to_proto(lights),
        });
        let r = self
            .call("CreateSession", c.create_session(request))
            .await?;
        Ok(SessionInfo {
            id: r.session_id,
            lights_version: r.lights_version,
        })
    }

    pub async fn get_session(&self, session: &str) -> Result<SessionState, ClientError> {
        let mut c = self.client.clone();
        let request = self.authorized(proto::GetSessionRequest {
            session_id: session.to_string(),
        });
        let r = self.call("GetSession", c.get_session(request)).await?;
        let lights = bounce_wire::lights::light_set(&r.lights).map_err(|e| {
            ClientError::Protocol(format!(
                "GetSession answered lights the client cannot read: {e}"
            ))
        })?;
        Ok(SessionState {
            id: r.session_id,
            scene: r.scene,
            lights_version: r.lights_version,
            lights,
        })
    }

    pub async fn set_lights(
        &self,
        session: &str,
        lights: &LightSet,
    ) -> Result<LightsChange, ClientError> {
        let mut c = self.client.clone();
        let request = self.authorized(proto::SetLightsRequest {
            session_id: session.to_string(),
            lights: lights::to_proto(lights),
            // The metadata carries it.
            token: String::new(),
        });
        let r = self.call("SetLights", c.set_lights(request)).await?;
        Ok(LightsChange {
            lights_version: r.lights_version,
            changed: r.changed,
        })
    }

    pub async fn subscribe(&self, session: &str) -> Result<Frames, ClientError> {
        let mut c = self.client.clone();
        let request = self.authorized(proto::SubscribeRequest {
            session_id: session.to_string(),
        });
        let stream = self.call("Subscribe", c.subscribe(request)).await?;
        Ok(Frames { stream })
    }
}

pub(super) struct Frames {
    stream: tonic::Streaming<proto::Frame>,
}

impl Frames {
    pub async fn next(&mut self) -> Result<Option<Frame>, ClientError> {
        let Some(message) = self
            .stream
            .message()
            .await
            .map_err(ClientError::from_status)?
        else {
            return Ok(None);
        };
        let mut frame = Frame::parse(message.data)?;
        // The message repeats the header's numbers; a server whose two disagree is broken, and
        // ordering by either would be a guess.
        if frame.header.sequence != message.sequence
            || frame.header.lights_version != message.lights_version
        {
            return Err(ClientError::Protocol(format!(
                "frame message says sequence {} / lights version {}, its bytes {} / {}",
                message.sequence,
                message.lights_version,
                frame.header.sequence,
                frame.header.lights_version
            )));
        }
        if !message.probes.is_empty() {
            let probes = Frame::parse_probes(message.probes)?;
            if (probes.header.sequence, probes.header.lights_version)
                != (frame.header.sequence, frame.header.lights_version)
            {
                return Err(ClientError::Protocol(format!(
                    "probe frame answers sequence {} / lights version {}, its patch frame {} / {}",
                    probes.header.sequence,
                    probes.header.lights_version,
                    frame.header.sequence,
                    frame.header.lights_version
                )));
            }
            frame = frame.with_probes(probes);
        }
        Ok(Some(frame))
    }
}

/// tonic's transport errors say "transport error" and keep the cause in their source chain.
fn error_chain(e: &(dyn std::error::Error + 'static)) -> String {
    let mut message = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        message.push_str(": ");
        message.push_str(&s.to_string());
        source = s.source();
    }
    message
}
