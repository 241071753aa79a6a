//! The `bounce.v1.Bounce` gRPC service over the [`Hub`]: messages in, validated, hub calls,
//! frames out.

use std::pin::Pin;

use futures_util::Stream;
use tokio::sync::mpsc;
use tonic::{Request, Response, Status, Streaming};
use tracing::debug;

use crate::error::ServerError;
use crate::frame::Frame;
use crate::hub::Hub;
use crate::lights::{light_set, to_proto as lights_to_proto};
use crate::metrics::{Metrics, Transport};
use crate::proto;
use crate::proto::bounce_server::Bounce;
use crate::viewer::Viewer;

/// The service; cheap to clone (it is a [`Hub`] handle).
#[derive(Clone)]
pub struct BounceService {
    hub: Hub,
}

impl BounceService {
    pub fn new(hub: Hub) -> BounceService {
        BounceService { hub }
    }

    /// Counts a refusal and turns it into its status.
    fn refuse(&self, status: Status) -> Status {
        self.hub
            .metrics()
            .requests_refused
            .get_or_create(&Metrics::transport(Transport::Grpc))
            .inc();
        status
    }

    /// Checks a read's token (the read or the write token) where the server has a read token:
    /// the request's `authorization: Bearer T` metadata.
    fn authorize_read<T>(&self, request: &Request<T>) -> Result<(), Status> {
        self.hub
            .authorize_read(bearer(request.metadata()))
            .map_err(|e| self.refuse(e.into()))
    }

    /// Checks a write's token: the request's `authorization: Bearer T` metadata, or `field`
    /// where the message has one.
    fn authorize<T>(&self, request: &Request<T>, field: Option<&str>) -> Result<(), Status> {
        let token = field
            .filter(|t| !t.is_empty())
            .or_else(|| bearer(request.metadata()));
        self.hub.authorize(token).map_err(|e| self.refuse(e.into()))
    }
}

/// The token of an `authorization: Bearer T` header.
fn bearer(metadata: &tonic::metadata::MetadataMap) -> Option<&str> {
    metadata
        .get("authorization")?
        .to_str()
        .ok()?
        .strip_prefix("Bearer ")
        .map(str::trim)
}

type FrameStream = Pin<Box<dyn Stream<Item = Result<proto::Frame, Status>> + Send>>;

fn lights(l: &[proto::Light]) -> Result<bounce_core::light::LightSet, ServerError> {
    Ok(light_set(l)?)
}

fn to_proto(session_id: &str, frame: &Frame) -> proto::Frame {
    proto::Frame {
        session_id: session_id.to_string(),
        sequence: frame.header.sequence,
        lights_version: frame.header.lights_version,
        data: frame.bytes().clone(),
        probes: frame
            .probes()
            .map(|p| p.bytes().clone())
            .unwrap_or_default(),
    }
}

#[tonic::async_trait]
impl Bounce for BounceService {
    async fn list_scenes(
        &self,
        request: Request<proto::ListScenesRequest>,
    ) -> Result<Response<proto::ListScenesResponse>, Status> {
        self.authorize_read(&request)?;
        let scenes = self
            .hub
            .scenes()
            .iter()
            .map(|s| proto::SceneInfo {
                name: s.name.clone(),
                patch_count: u32::try_from(s.layout.len()).unwrap_or(u32::MAX),
                codec: s.codec.clone(),
                sky_view: s.sky_view,
                emitters: s
                    .emitters
                    .as_deref()
                    .map(bounce_core::emitter::materials_of)
                    .unwrap_or_default(),
                emitter_nodes: s
                    .emitters
                    .as_deref()
                    .map(bounce_core::emitter::nodes_of)
                    .unwrap_or_default(),
            })
            .collect();
        Ok(Response::new(proto::ListScenesResponse {
            scenes,
            engine: self.hub.engine(),
        }))
    }

    async fn get_layout(
        &self,
        request: Request<proto::GetLayoutRequest>,
    ) -> Result<Response<proto::Layout>, Status> {
        self.authorize_read(&request)?;
        let name = request.into_inner().scene;
        let scene = self.hub.scene(&name).map_err(|e| self.refuse(e.into()))?;
        Ok(Response::new(scene.wire_layout()))
    }

    async fn create_session(
        &self,
        request: Request<proto::CreateSessionRequest>,
    ) -> Result<Response<proto::CreateSessionResponse>, Status> {
        self.authorize(&request, None)?;
        let client = request.remote_addr().map(|a| a.ip());
        let r = request.into_inner();
        let created = async {
            let set = lights(&r.lights)?;
            self.hub.create_session(&r.scene, set, client).await
        };
        let session = created.await.map_err(|e| self.refuse(e.into()))?;
        Ok(Response::new(proto::CreateSessionResponse {
            session_id: session.id.clone(),
            lights_version: session.lights_version(),
        }))
    }

    async fn get_session(
        &self,
        request: Request<proto::GetSessionRequest>,
    ) -> Result<Response<proto::Session>, Status> {
        self.authorize_read(&request)?;
        let id = request.into_inner().session_id;
        let session = self.hub.session(&id).map_err(|e| self.refuse(e.into()))?;
        Ok(Response::new(proto::Session {
            session_id: session.id.clone(),
            scene: self.hub.scene_of(&session),
            lights_version: session.lights_version(),
            lights: lights_to_proto(&session.lights()),
        }))
    }

    async fn set_lights(
        &self,
        request: Request<proto::SetLightsRequest>,
    ) -> Result<Response<proto::SetLightsResponse>, Status> {
        self.authorize(&request, Some(&request.get_ref().token))?;
        let r = request.into_inner();
        let changed = async {
            // The session first: an unknown session is NOT_FOUND whatever the lights hold.
            self.hub.session(&r.session_id)?;
            let set = lights(&r.lights)?;
            self.hub.set_lights(&r.session_id, set).await
        };
        let v = changed.await.map_err(|e| self.refuse(e.into()))?;
        Ok(Response::new(proto::SetLightsResponse {
            lights_version: v.version,
            changed: v.changed,
        }))
    }

    type SubscribeStream = FrameStream;

    async fn subscribe(
        &self,
        request: Request<proto::SubscribeRequest>,
    ) -> Result<Response<FrameStream>, Status> {
        self.authorize_read(&request)?;
        let id = request.into_inner().session_id;
        let viewer = self
            .hub
            .viewer(&id, Transport::Grpc)
            .map_err(|e| self.refuse(e.into()))?;
        Ok(Response::new(frame_stream(viewer, None)))
    }

    type RelightStream = FrameStream;

    async fn relight(
        &self,
        request: Request<Streaming<proto::RelightRequest>>,
    ) -> Result<Response<FrameStream>, Status> {
        // A stream that writes presents its token once, in the call's metadata; it also reads
        // frames, so a read token applies too.
        let authorized = self
            .authorize(&request, None)
            .and_then(|()| self.authorize_read(&request));
        let client = request.remote_addr().map(|a| a.ip());
        let mut inbound = request.into_inner();
        let first = inbound.message().await?.ok_or_else(|| {
            self.refuse(Status::invalid_argument(
                "the stream ended before its first message",
            ))
        })?;
        let writes = first.set_lights || !first.scene.is_empty();
        if writes {
            authorized.clone()?;
        }
        let opened = async {
            match (first.session_id.is_empty(), first.scene.is_empty()) {
                (false, true) => {
                    let session = self.hub.session(&first.session_id)?;
                    if first.set_lights {
                        self.hub
                            .set_lights(&session.id, lights(&first.lights)?)
                            .await?;
                    }
                    Ok(session)
                }
                (true, false) => {
                    let set = if first.set_lights {
                        lights(&first.lights)?
                    } else {
                        Default::default()
                    };
                    self.hub.create_session(&first.scene, set, client).await
                }
                _ => Err(ServerError::Invalid(
                    "session_id, scene: the first message names exactly one of them".into(),
                )),
            }
        };
        let session = opened.await.map_err(|e| self.refuse(e.into()))?;
        let viewer = self
            .hub
            .viewer(&session.id, Transport::Grpc)
            .map_err(|e| self.refuse(e.into()))?;
        // Later messages are read on their own task; a refused one ends the frame stream with
        // its status, through `errors`.
        let (errors_tx, errors_rx) = mpsc::channel(1);
        let service = self.clone();
        let mut shutdown = self.hub.shutdown_signal();
        let task_id = session.id.clone();
        tokio::spawn(async move {
            loop {
                let message = tokio::select! {
                    _ = shutdown.wait_for(|&s| s) => return,
                    m = inbound.message() => m,
                };
                let m = match message {
                    Ok(Some(m)) => m,
                    Ok(None) | Err(_) => return,
                };
                let result = if !m.scene.is_empty()
                    || (!m.session_id.is_empty() && m.session_id != task_id)
                {
                    Err(service.refuse(Status::invalid_argument(
                        "session_id, scene: only the first message names the session",
                    )))
                } else if m.set_lights {
                    match authorized.clone() {
                        Err(status) => Err(status),
                        Ok(()) => {
                            let changed = async {
                                let set = lights(&m.lights)?;
                                service.hub.set_lights(&task_id, set).await
                            };
                            changed
                                .await
                                .map(|_| ())
                                .map_err(|e| service.refuse(e.into()))
                        }
                    }
                } else {
                    Ok(())
                };
                if let Err(status) = result {
                    debug!(session = %task_id, %status, "relight stream refused a message");
                    let _ = errors_tx.send(status).await;
                    return;
                }
            }
        });
        Ok(Response::new(frame_stream(viewer, Some(errors_rx))))
    }

    async fn relight_once(
        &self,
        request: Request<proto::RelightOnceRequest>,
    ) -> Result<Response<proto::Frame>, Status> {
        self.authorize(&request, None)?;
        self.authorize_read(&request)?;
        let r = request.into_inner();
        let solved = async {
            self.hub.scene(&r.scene)?;
            let set = lights(&r.lights)?;
            self.hub.relight_once(&r.scene, set).await
        };
        let frame = solved.await.map_err(|e| self.refuse(e.into()))?;
        Ok(Response::new(to_proto("", &frame)))
    }
}

async fn next_error(errors: &mut Option<mpsc::Receiver<Status>>) -> Option<Status> {
    match errors {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}

/// A viewer's frames as a stream. Ends on shutdown, when the session goes, or with the first
/// status sent on `errors`.
fn frame_stream(viewer: Viewer, errors: Option<mpsc::Receiver<Status>>) -> FrameStream {
    struct State {
        viewer: Viewer,
        errors: Option<mpsc::Receiver<Status>>,
        done: bool,
    }
    let state = State {
        viewer,
        errors,
        done: false,
    };
    Box::pin(futures_util::stream::unfold(state, |mut st| async move {
        if st.done {
            return None;
        }
        loop {
            tokio::select! {
                biased;
                status = next_error(&mut st.errors) => match status {
                    Some(status) => {
                        st.done = true;
                        return Some((Err(status), st));
                    }
                    // The reader task ended quietly (the client closed its side): keep sending.
                    None => st.errors = None,
                },
                frame = st.viewer.next() => {
                    let Some(frame) = frame else {
                        // A stream that ends with OK looks like a normal end; one the server
                        // ends says why, so a client knows to reconnect elsewhere or later.
                        st.done = true;
                        let status = if st.viewer.shutting_down() {
                            Status::unavailable("the server is shutting down")
                        } else {
                            Status::not_found(format!(
                                "session {:?} is gone (expired)",
                                st.viewer.session().id
                            ))
                        };
                        return Some((Err(status), st));
                    };
                    let msg = to_proto(&st.viewer.session().id, &frame);
                    return Some((Ok(msg), st));
                }
            }
        }
    }))
}
