//! The `bounce.v1.Bounce` gRPC service over the [`Hub`]: messages in, validated, hub calls,
//! frames out.

use std::pin::Pin;

use futures_util::Stream;
use tokio::sync::{mpsc, watch};
use tonic::{Request, Response, Status, Streaming};
use tracing::debug;

use crate::frame::Frame;
use crate::hub::Hub;
use crate::lights::light_set;
use crate::proto;
use crate::proto::bounce_server::Bounce;

/// The service; cheap to clone (it is a [`Hub`] handle).
#[derive(Clone)]
pub struct BounceService {
    hub: Hub,
}

impl BounceService {
    pub fn new(hub: Hub) -> BounceService {
        BounceService { hub }
    }
}

type FrameStream = Pin<Box<dyn Stream<Item = Result<proto::Frame, Status>> + Send>>;

fn lights(l: &[proto::Light]) -> Result<bounce_core::light::LightSet, Status> {
    light_set(l).map_err(|e| Status::invalid_argument(e.to_string()))
}

fn to_proto(session_id: &str, frame: &Frame) -> proto::Frame {
    proto::Frame {
        session_id: session_id.to_string(),
        sequence: frame.header.sequence,
        lights_version: frame.header.lights_version,
        data: frame.bytes().clone(),
    }
}

#[tonic::async_trait]
impl Bounce for BounceService {
    async fn list_scenes(
        &self,
        _: Request<proto::ListScenesRequest>,
    ) -> Result<Response<proto::ListScenesResponse>, Status> {
        let scenes = self
            .hub
            .scenes()
            .iter()
            .map(|s| proto::SceneInfo {
                name: s.name.clone(),
                patch_count: u32::try_from(s.layout.len()).unwrap_or(u32::MAX),
                codec: s.codec.clone(),
            })
            .collect();
        Ok(Response::new(proto::ListScenesResponse {
            scenes,
            engine: self.hub.engine().to_string(),
        }))
    }

    async fn get_layout(
        &self,
        request: Request<proto::GetLayoutRequest>,
    ) -> Result<Response<proto::Layout>, Status> {
        let name = request.into_inner().scene;
        let scene = self.hub.scene(&name)?;
        let l = &scene.layout;
        Ok(Response::new(proto::Layout {
            scene: scene.name.clone(),
            origin: l.origin.to_vec(),
            voxel_size: l.voxel_size,
            dims: l.dims.to_vec(),
            patch_count: u32::try_from(l.len()).unwrap_or(u32::MAX),
            voxels: l.patches.iter().flat_map(|p| p.voxel).collect(),
            // The proto enum's numbers are the face codes.
            faces: l.patches.iter().map(|p| i32::from(p.face.code())).collect(),
        }))
    }

    async fn create_session(
        &self,
        request: Request<proto::CreateSessionRequest>,
    ) -> Result<Response<proto::CreateSessionResponse>, Status> {
        let r = request.into_inner();
        let set = lights(&r.lights)?;
        let session = self.hub.create_session(&r.scene, set)?;
        Ok(Response::new(proto::CreateSessionResponse {
            session_id: session.id.clone(),
            lights_version: session.lights_version(),
        }))
    }

    async fn set_lights(
        &self,
        request: Request<proto::SetLightsRequest>,
    ) -> Result<Response<proto::SetLightsResponse>, Status> {
        let r = request.into_inner();
        // The session first: an unknown session is NOT_FOUND whatever the lights hold.
        self.hub.session(&r.session_id)?;
        let set = lights(&r.lights)?;
        let v = self.hub.set_lights(&r.session_id, set)?;
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
        let id = request.into_inner().session_id;
        let frames = self.hub.session(&id)?.subscribe();
        Ok(Response::new(frame_stream(
            id,
            frames,
            self.hub.shutdown_signal(),
            None,
        )))
    }

    type RelightStream = FrameStream;

    async fn relight(
        &self,
        request: Request<Streaming<proto::RelightRequest>>,
    ) -> Result<Response<FrameStream>, Status> {
        let mut inbound = request.into_inner();
        let first = inbound
            .message()
            .await?
            .ok_or_else(|| Status::invalid_argument("the stream ended before its first message"))?;
        let session = match (first.session_id.is_empty(), first.scene.is_empty()) {
            (false, true) => {
                let session = self.hub.session(&first.session_id)?;
                if first.set_lights {
                    self.hub.set_lights(&session.id, lights(&first.lights)?)?;
                }
                session
            }
            (true, false) => {
                let set = if first.set_lights {
                    lights(&first.lights)?
                } else {
                    Default::default()
                };
                self.hub.create_session(&first.scene, set)?
            }
            _ => {
                return Err(Status::invalid_argument(
                    "session_id, scene: the first message names exactly one of them",
                ));
            }
        };
        let frames = session.subscribe();
        let id = session.id.clone();
        // Later messages are read on their own task; a refused one ends the frame stream with
        // its status, through `errors`.
        let (errors_tx, errors_rx) = mpsc::channel(1);
        let hub = self.hub.clone();
        let mut shutdown = self.hub.shutdown_signal();
        let task_id = id.clone();
        tokio::spawn(async move {
            loop {
                let message = tokio::select! {
                    _ = until_true(&mut shutdown) => return,
                    m = inbound.message() => m,
                };
                let m = match message {
                    Ok(Some(m)) => m,
                    Ok(None) | Err(_) => return,
                };
                let result = if !m.scene.is_empty()
                    || (!m.session_id.is_empty() && m.session_id != task_id)
                {
                    Err(Status::invalid_argument(
                        "session_id, scene: only the first message names the session",
                    ))
                } else if m.set_lights {
                    lights(&m.lights)
                        .and_then(|set| hub.set_lights(&task_id, set).map_err(Status::from))
                        .map(|_| ())
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
        Ok(Response::new(frame_stream(
            id,
            frames,
            self.hub.shutdown_signal(),
            Some(errors_rx),
        )))
    }

    async fn relight_once(
        &self,
        request: Request<proto::RelightOnceRequest>,
    ) -> Result<Response<proto::Frame>, Status> {
        let r = request.into_inner();
        self.hub.scene(&r.scene)?;
        let set = lights(&r.lights)?;
        let frame = self.hub.relight_once(&r.scene, set).await?;
        Ok(Response::new(to_proto("", &frame)))
    }
}

async fn until_true(rx: &mut watch::Receiver<bool>) {
    // An error means the hub is gone: as good as shut down.
    let _ = rx.wait_for(|&s| s).await;
}

async fn next_error(errors: &mut Option<mpsc::Receiver<Status>>) -> Option<Status> {
    match errors {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}

/// A session's frames as a stream: the newest at once, then each newer one as it is published.
/// Reading from the `watch` receiver means a reader that falls behind gets the newest frame
/// next, never a backlog. Ends on shutdown, or with the first status sent on `errors`.
fn frame_stream(
    session_id: String,
    mut frames: watch::Receiver<Option<Frame>>,
    shutdown: watch::Receiver<bool>,
    errors: Option<mpsc::Receiver<Status>>,
) -> FrameStream {
    // The current frame counts as news to a new viewer.
    frames.mark_changed();
    struct State {
        id: String,
        frames: watch::Receiver<Option<Frame>>,
        shutdown: watch::Receiver<bool>,
        errors: Option<mpsc::Receiver<Status>>,
        done: bool,
    }
    let state = State {
        id: session_id,
        frames,
        shutdown,
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
                _ = until_true(&mut st.shutdown) => return None,
                status = next_error(&mut st.errors) => match status {
                    Some(status) => {
                        st.done = true;
                        return Some((Err(status), st));
                    }
                    // The reader task ended quietly (the client closed its side): keep sending.
                    None => st.errors = None,
                },
                changed = st.frames.changed() => {
                    if changed.is_err() {
                        return None;
                    }
                    let frame = st.frames.borrow_and_update().clone();
                    if let Some(frame) = frame {
                        let msg = to_proto(&st.id, &frame);
                        return Some((Ok(msg), st));
                    }
                }
            }
        }
    }))
}
