//! The hub: the scenes, the sessions and the engine worker, behind the calls every front end
//! (gRPC now, WebSocket later) makes. Front ends convert and validate their input, then call
//! here; nothing here knows about a wire format.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, RwLock};

use bounce_core::light::LightSet;
use bounce_engine::EngineChoice;
use tokio::sync::{oneshot, watch};
use tracing::{info, warn};

use crate::error::ServerError;
use crate::frame::Frame;
use crate::scenes::{self, SceneInfo};
use crate::session::Session;
use crate::worker::{OnceJob, Worker};

/// How to start a hub.
#[derive(Debug, Clone)]
pub struct HubConfig {
    /// The directory of `*.bounce` files to serve.
    pub scenes_dir: PathBuf,
    pub engine: EngineChoice,
}

/// A cheap handle: clones share one hub.
#[derive(Clone)]
pub struct Hub {
    inner: Arc<Inner>,
}

struct Inner {
    scenes: Vec<SceneInfo>,
    engine: String,
    sessions: RwLock<HashMap<String, Arc<Session>>>,
    worker: Worker,
    /// `true` once shutting down: every frame stream ends.
    shutdown: watch::Sender<bool>,
}

/// What [`Hub::set_lights`] answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LightsVersion {
    pub version: u64,
    /// `false` when the lights equalled the current ones: no new version, no new frame.
    pub changed: bool,
}

impl Hub {
    /// Reads the scene directory, opens the engine and loads every scene on it. Blocking (it
    /// reads files and may upload to a GPU): call it before the runtime serves, or from
    /// `spawn_blocking`. Files that fail to read are logged and skipped.
    pub fn start(config: &HubConfig) -> Result<Hub, ServerError> {
        let (read, skipped) = scenes::read_dir(&config.scenes_dir)?;
        for s in &skipped {
            warn!(file = %s.path.display(), error = %s.source, "baked file skipped");
        }
        let (infos, baked): (Vec<_>, Vec<_>) = read
            .into_iter()
            .map(|r| (r.info.clone(), (r.info.name, r.baked)))
            .unzip();
        let (worker, engine) = Worker::start(config.engine, baked)?;
        info!(engine = %engine, scenes = infos.len(), "hub ready");
        Ok(Hub {
            inner: Arc::new(Inner {
                scenes: infos,
                engine,
                sessions: RwLock::new(HashMap::new()),
                worker,
                shutdown: watch::Sender::new(false),
            }),
        })
    }

    pub fn scenes(&self) -> &[SceneInfo] {
        &self.inner.scenes
    }

    /// The engine relighting, as it describes itself (`cpu (2 threads)`).
    pub fn engine(&self) -> &str {
        &self.inner.engine
    }

    fn scene_index(&self, name: &str) -> Result<usize, ServerError> {
        self.inner
            .scenes
            .iter()
            .position(|s| s.name == name)
            .ok_or_else(|| ServerError::UnknownScene(name.to_string()))
    }

    pub fn scene(&self, name: &str) -> Result<&SceneInfo, ServerError> {
        Ok(&self.inner.scenes[self.scene_index(name)?])
    }

    pub fn session(&self, id: &str) -> Result<Arc<Session>, ServerError> {
        self.inner
            .sessions
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .get(id)
            .cloned()
            .ok_or_else(|| ServerError::UnknownSession(id.to_string()))
    }

    /// A new session on `scene` with validated `lights` at version 1; its first frame is
    /// queued at once.
    pub fn create_session(
        &self,
        scene: &str,
        lights: LightSet,
    ) -> Result<Arc<Session>, ServerError> {
        let scene = self.scene_index(scene)?;
        let id = uuid::Uuid::new_v4().simple().to_string();
        let session = Arc::new(Session::new(id.clone(), scene, lights));
        self.inner
            .sessions
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .insert(id, Arc::clone(&session));
        self.inner.worker.enqueue(Arc::clone(&session));
        info!(session = %session.id, scene = %self.inner.scenes[scene].name, "session created");
        Ok(session)
    }

    /// Replaces a session's validated lights and marks it dirty; returns at once, the frame
    /// follows on the session's channel.
    pub fn set_lights(&self, id: &str, lights: LightSet) -> Result<LightsVersion, ServerError> {
        let session = self.session(id)?;
        let change = session.set_lights(lights);
        if change.enqueue {
            self.inner.worker.enqueue(session);
        }
        Ok(LightsVersion {
            version: change.version,
            changed: change.changed,
        })
    }

    /// Relights `scene` once, outside any session, batched with whatever the worker solves
    /// next for that scene.
    pub async fn relight_once(&self, scene: &str, lights: LightSet) -> Result<Frame, ServerError> {
        let scene = self.scene_index(scene)?;
        let (reply, answer) = oneshot::channel();
        self.inner.worker.enqueue_once(OnceJob {
            scene,
            lights,
            reply,
        });
        answer.await.map_err(|_| ServerError::WorkerGone)?
    }

    /// A receiver that turns `true` when the server shuts down.
    pub fn shutdown_signal(&self) -> watch::Receiver<bool> {
        self.inner.shutdown.subscribe()
    }

    /// Ends every frame stream and stops the engine worker (after its current batch). Blocks
    /// for that batch; idempotent.
    pub fn shutdown(&self) {
        self.inner.shutdown.send_replace(true);
        self.inner.worker.stop();
    }
}
