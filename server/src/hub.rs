//! The hub: the scenes, the sessions, their store and the engine worker, behind the calls every
//! front end (gRPC, WebSocket) makes. Front ends convert and validate their input, then call
//! here; nothing here knows about a wire format.

use std::collections::HashMap;
use std::net::IpAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, RwLock, Weak};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bounce_core::format::Baked;
use bounce_core::light::LightSet;
use bounce_engine::EngineChoice;
use tokio::sync::{oneshot, watch};
use tracing::{info, warn};

use crate::error::ServerError;
use crate::frame::Frame;
use crate::metrics::{Metrics, Outcome, ReloadLabel, SessionLimit, SessionLimitLabel, Transport};
use crate::scenes::{self, SceneInfo};
pub use crate::session::LightsVersion;
use crate::session::{Offered, Session, WriteReply};
use crate::store::{Store, StoreError, StoredSession};
use crate::viewer::Viewer;
use crate::worker::{OnceJob, ReloadJob, Worker};

/// How to start a hub.
#[derive(Debug, Clone)]
pub struct HubConfig {
    /// The directory of `*.bounce` files to serve.
    pub scenes_dir: PathBuf,
    pub engine: EngineChoice,
    /// Where sessions are stored so they survive restarts; `None` keeps them in memory only.
    pub data_dir: Option<PathBuf>,
    /// A session nobody watches or writes for this long is removed.
    pub session_ttl: Duration,
    /// When set, every write (creating a session, changing lights, a one-shot relight) must
    /// present it.
    pub token: Option<String>,
    /// When set, every read of scenes and sessions (listing, layouts, models, frame streams)
    /// must present it or the write token. Health, readiness and metrics stay open.
    pub read_token: Option<String>,
    /// Serve the browser page from this directory, read on every request, instead of the copy
    /// of `web/public/` built into the binary: for working on the page without rebuilding.
    pub web_dir: Option<PathBuf>,
    /// How often the scene directory is checked for new or changed baked files; `None` never.
    pub reload_interval: Option<Duration>,
    /// Open connections each front end accepts; past it a new connection is closed at once.
    pub max_connections: usize,
    /// Open connections each front end accepts from one IP address, so that one client cannot
    /// take every place.
    pub max_connections_per_ip: usize,
    /// Sessions the hub holds at most; creating one more is refused (`resource_exhausted`).
    pub max_sessions: usize,
    /// Sessions one client address may have created and still hold; one more is refused
    /// (`resource_exhausted`), so that one client cannot take every place of `max_sessions`.
    pub max_sessions_per_client: usize,
    /// A connection that sends nothing this long after it opens is closed.
    pub first_byte_timeout: Duration,
    /// HTTP: a request head must arrive whole within this long of the server starting to read
    /// it (which, on a keep-alive connection, bounds the wait for the next request too).
    pub header_read_timeout: Duration,
    /// A WebSocket is pinged after this long without a message from its client, and closed
    /// when nothing at all (a pong included) comes back within this long again, or when a
    /// message to it cannot be sent within this long: a dead or stalled peer.
    pub ws_keepalive: Duration,
    /// Web origins (`https://app.example.com`) besides the server's own whose pages may write
    /// over HTTP and WebSocket (see [`crate::http`]'s origin check).
    pub allowed_origins: Vec<String>,
}

impl HubConfig {
    /// Defaults: sessions in memory only, expiring after a day idle; no token; the scene
    /// directory checked every two seconds; 4,096 connections per front end; 10,000 sessions,
    /// 64 per client address.
    pub fn new(scenes_dir: impl Into<PathBuf>, engine: EngineChoice) -> HubConfig {
        HubConfig {
            scenes_dir: scenes_dir.into(),
            engine,
            data_dir: None,
            session_ttl: Duration::from_secs(24 * 3600),
            token: None,
            read_token: None,
            web_dir: None,
            reload_interval: Some(Duration::from_secs(2)),
            max_connections: 4096,
            max_connections_per_ip: 256,
            max_sessions: 10_000,
            max_sessions_per_client: 64,
            allowed_origins: Vec::new(),
            first_byte_timeout: Duration::from_secs(10),
            header_read_timeout: Duration::from_secs(30),
            ws_keepalive: Duration::from_secs(30),
        }
    }
}

/// How long a one-shot relight waits for the engine worker.
pub const ONCE_DEADLINE: Duration = Duration::from_secs(30);

/// A cheap handle: clones share one hub.
#[derive(Clone)]
pub struct Hub {
    inner: Arc<Inner>,
}

struct Inner {
    scenes_dir: PathBuf,
    /// Indexed by the sessions' scene index; a reload replaces an entry, a new file appends.
    scenes: RwLock<Vec<Arc<SceneInfo>>>,
    engine: String,
    sessions: RwLock<HashMap<String, Arc<Session>>>,
    worker: Worker,
    store: Option<Store>,
    metrics: Arc<Metrics>,
    token: Option<String>,
    read_token: Option<String>,
    web_dir: Option<PathBuf>,
    session_ttl: Duration,
    max_connections: usize,
    max_connections_per_ip: usize,
    max_sessions: usize,
    max_sessions_per_client: usize,
    /// Sessions held per client address that created them (restored ones count for none: the
    /// store does not keep addresses).
    per_client: Mutex<HashMap<IpAddr, usize>>,
    /// Stored sessions whose scene is not served, and since when: restored if it comes back,
    /// removed from the store after the session TTL.
    orphans: Mutex<Vec<(String, StoredSession, Instant)>>,
    allowed_origins: Vec<String>,
    first_byte_timeout: Duration,
    header_read_timeout: Duration,
    ws_keepalive: Duration,
    ready: AtomicBool,
    /// `true` once shutting down: every frame stream ends.
    shutdown: watch::Sender<bool>,
    janitor: Mutex<Option<(std::sync::mpsc::Sender<()>, JoinHandle<()>)>>,
}

impl Hub {
    /// Reads the scene directory, opens the engine, loads every scene on it and restores the
    /// stored sessions. Blocking (it reads files and may upload to a GPU): call it before the
    /// runtime serves, or from `spawn_blocking`. Files that fail to read are logged and skipped.
    pub fn start(config: &HubConfig) -> Result<Hub, ServerError> {
        let (read, skipped) = scenes::read_dir(&config.scenes_dir)?;
        for s in &skipped {
            warn!(file = %s.path.display(), error = %s.source, "baked file skipped");
        }
        let stamps: Vec<_> = read
            .iter()
            .map(|r| (r.info.path.clone(), r.stamp))
            .collect();
        let (infos, baked): (Vec<_>, Vec<_>) = read
            .into_iter()
            .map(|r| (Arc::new(r.info.clone()), (r.info.name, r.baked)))
            .unzip();
        let metrics = Arc::new(Metrics::new());
        let (worker, engine) = Worker::start(config.engine, baked, Arc::clone(&metrics))?;
        for s in &skipped {
            metrics
                .scene_reloads
                .get_or_create(&ReloadLabel {
                    scene: scenes::scene_name(&s.path),
                    outcome: Outcome::Failed,
                })
                .inc();
        }

        let (store, stored) = match &config.data_dir {
            Some(dir) => {
                let (store, stored) = Store::open(dir, Arc::clone(&metrics))?;
                (Some(store), stored)
            }
            None => (None, Vec::new()),
        };
        let hub = Hub {
            inner: Arc::new(Inner {
                scenes_dir: config.scenes_dir.clone(),
                scenes: RwLock::new(infos),
                engine,
                sessions: RwLock::new(HashMap::new()),
                worker,
                store,
                metrics,
                token: config.token.clone().filter(|t| !t.is_empty()),
                read_token: config.read_token.clone().filter(|t| !t.is_empty()),
                web_dir: config.web_dir.clone(),
                session_ttl: config.session_ttl,
                max_connections: config.max_connections.max(1),
                max_connections_per_ip: config.max_connections_per_ip.max(1),
                max_sessions: config.max_sessions,
                max_sessions_per_client: config.max_sessions_per_client.max(1),
                per_client: Mutex::new(HashMap::new()),
                orphans: Mutex::new(Vec::new()),
                allowed_origins: config
                    .allowed_origins
                    .iter()
                    .map(|o| o.trim_end_matches('/').to_ascii_lowercase())
                    .collect(),
                first_byte_timeout: config.first_byte_timeout,
                header_read_timeout: config.header_read_timeout.max(Duration::from_millis(1)),
                ws_keepalive: config.ws_keepalive.max(Duration::from_millis(1)),
                ready: AtomicBool::new(false),
                shutdown: watch::Sender::new(false),
                janitor: Mutex::new(None),
            }),
        };
        hub.restore(stored);
        hub.start_janitor(config.reload_interval, stamps, skipped);
        hub.inner.ready.store(true, Ordering::Release);
        info!(
            engine = %hub.inner.engine,
            scenes = hub.scenes().len(),
            sessions = hub.session_count(),
            "hub ready"
        );
        Ok(hub)
    }

    /// Brings back the stored sessions whose scene is served. The others wait, in the store,
    /// for their scene to come back (a hot reload that adds it restores them) for one session
    /// TTL, then expire like an idle session. A record with invalid lights is removed.
    fn restore(&self, stored: Vec<(String, StoredSession)>) {
        let mut restored = 0usize;
        for (id, s) in stored {
            let Ok(scene) = self.scene_index(&s.scene) else {
                warn!(session = %id, scene = %s.scene, "stored session's scene is not served; kept for one session TTL in case it comes back");
                self.inner
                    .orphans
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .push((id, s, Instant::now()));
                continue;
            };
            if let Err(e) = s.lights.validate() {
                warn!(session = %id, error = %e, "stored session has invalid lights; removed");
                if let Some(store) = &self.inner.store
                    && let Err(e) = store.delete_blocking(&id)
                {
                    warn!(session = %id, error = %e, "removing a stored session");
                }
                continue;
            }
            let session = Arc::new(Session::new(id.clone(), scene, s.lights, s.version, None));
            // Idle since its last write, as before the restart, but never so long that it
            // expires before its viewers (whose watching was not stored) can reconnect.
            if let Some(written) = s.written_unix_ms {
                let ttl = self.inner.session_ttl;
                let grace = (ttl / 10).min(Duration::from_secs(300));
                let idle = Duration::from_millis(crate::store::unix_ms().saturating_sub(written));
                session.backdate(idle.min(ttl.saturating_sub(grace)));
            }
            self.write_sessions().insert(id, Arc::clone(&session));
            self.inner.worker.enqueue(session);
            restored += 1;
        }
        self.inner.metrics.sessions.set(self.session_count() as i64);
        if restored > 0 {
            info!(sessions = restored, "sessions restored from the store");
        }
    }

    /// Snapshot of the scenes served, in index order.
    pub fn scenes(&self) -> Vec<Arc<SceneInfo>> {
        self.inner
            .scenes
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// The engine relighting, as it describes itself (`cpu (2 threads)`).
    /// The engine solving now, as it describes itself: the one opened at start, or the CPU
    /// engine a restart fell back to.
    pub fn engine(&self) -> String {
        self.inner.worker.engine()
    }

    /// Why scene `name` runs partly on the CPU under a GPU engine, if it does.
    pub fn scene_fallback(&self, name: &str) -> Option<String> {
        self.inner.worker.fallback(name)
    }

    pub fn metrics(&self) -> &Arc<Metrics> {
        &self.inner.metrics
    }

    /// Ready to serve: scenes loaded, sessions restored, an engine solving (not while the
    /// worker restarts one), not shutting down.
    pub fn is_ready(&self) -> bool {
        self.inner.ready.load(Ordering::Acquire)
            && self.inner.worker.serving()
            && !*self.inner.shutdown.borrow()
    }

    /// Test hook: the engine's next relight fails, as a device readback error would.
    #[cfg(feature = "fault-injection")]
    pub fn inject_relight_failure(&self) {
        self.inner.worker.inject_failure();
    }

    /// Test hook: the engine worker's next batch panics, as a driver fault would.
    #[cfg(feature = "fault-injection")]
    pub fn inject_worker_panic(&self) {
        self.inner.worker.inject_panic();
    }

    /// Test hook: the engine worker takes no new work until [`Hub::release_worker`], as if a
    /// batch took that long.
    #[cfg(feature = "fault-injection")]
    pub fn hold_worker(&self) {
        self.inner.worker.hold();
    }

    /// Test hook: ends [`Hub::hold_worker`].
    #[cfg(feature = "fault-injection")]
    pub fn release_worker(&self) {
        self.inner.worker.release();
    }

    /// Test hook: one-shot relights waiting for the engine worker now.
    #[cfg(feature = "fault-injection")]
    pub fn once_waiting(&self) -> usize {
        self.inner.worker.once_waiting()
    }

    fn scene_index(&self, name: &str) -> Result<usize, ServerError> {
        self.inner
            .scenes
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .position(|s| s.name == name)
            .ok_or_else(|| ServerError::UnknownScene(name.to_string()))
    }

    /// Refuses lights whose emissive changes name no emissive material of scene `index`, as
    /// the other light errors are refused: before anything is stored or solved.
    fn check_emitters(&self, index: usize, lights: &LightSet) -> Result<(), ServerError> {
        if let Some(info) = self.scene_at(index) {
            bounce_core::emitter::check_names(info.emitters.as_deref(), lights)?;
        }
        Ok(())
    }

    fn scene_at(&self, index: usize) -> Option<Arc<SceneInfo>> {
        self.inner
            .scenes
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .get(index)
            .cloned()
    }

    pub fn scene(&self, name: &str) -> Result<Arc<SceneInfo>, ServerError> {
        let index = self.scene_index(name)?;
        self.scene_at(index)
            .ok_or_else(|| ServerError::UnknownScene(name.to_string()))
    }

    /// The name of the scene a session is on.
    pub fn scene_of(&self, session: &Session) -> String {
        self.scene_at(session.scene)
            .map(|s| s.name.clone())
            .unwrap_or_default()
    }

    fn write_sessions(&self) -> std::sync::RwLockWriteGuard<'_, HashMap<String, Arc<Session>>> {
        self.inner
            .sessions
            .write()
            .unwrap_or_else(|e| e.into_inner())
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

    /// The sessions, on `scene` only when given (an unknown scene is an error), newest first
    /// (by when this process created or restored them; then by id), at most `limit`.
    pub fn list_sessions(
        &self,
        scene: Option<&str>,
        limit: usize,
    ) -> Result<Vec<Arc<Session>>, ServerError> {
        let scene = scene.map(|s| self.scene_index(s)).transpose()?;
        let mut list: Vec<Arc<Session>> = self
            .inner
            .sessions
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .values()
            .filter(|s| scene.is_none_or(|i| s.scene == i))
            .cloned()
            .collect();
        list.sort_by(|a, b| b.created().cmp(&a.created()).then_with(|| a.id.cmp(&b.id)));
        list.truncate(limit);
        Ok(list)
    }

    pub fn session_count(&self) -> usize {
        self.inner
            .sessions
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .len()
    }

    /// Checks a write's token: `Ok` when the hub has none, or `presented` equals it.
    pub fn authorize(&self, presented: Option<&str>) -> Result<(), ServerError> {
        match &self.inner.token {
            None => Ok(()),
            Some(token) if presented.is_some_and(|p| constant_time_eq(p, token)) => Ok(()),
            Some(_) => Err(ServerError::Unauthenticated),
        }
    }

    /// How long a new connection may stay silent before it is closed.
    pub fn first_byte_timeout(&self) -> Duration {
        self.inner.first_byte_timeout
    }

    /// How long an HTTP request head may take to arrive whole ([`HubConfig::header_read_timeout`]).
    pub fn header_read_timeout(&self) -> Duration {
        self.inner.header_read_timeout
    }

    /// A WebSocket's keep-alive period ([`HubConfig::ws_keepalive`]).
    pub fn ws_keepalive(&self) -> Duration {
        self.inner.ws_keepalive
    }

    /// Checks a read's token: `Ok` when the hub has no read token, or `presented` is the read
    /// token or the write token.
    pub fn authorize_read(&self, presented: Option<&str>) -> Result<(), ServerError> {
        let Some(read) = &self.inner.read_token else {
            return Ok(());
        };
        let matches = |t: &String| presented.is_some_and(|p| constant_time_eq(p, t));
        if matches(read) || self.inner.token.as_ref().is_some_and(matches) {
            Ok(())
        } else {
            Err(ServerError::ReadUnauthenticated)
        }
    }

    /// Whether reads need a token.
    pub fn has_read_token(&self) -> bool {
        self.inner.read_token.is_some()
    }

    /// Open connections each front end accepts.
    pub fn max_connections(&self) -> usize {
        self.inner.max_connections
    }

    /// Open connections each front end accepts from one IP address.
    pub fn max_connections_per_ip(&self) -> usize {
        self.inner.max_connections_per_ip
    }

    /// Whether a page from `origin` (an `Origin` header's value) other than the server's own
    /// may write: it is on the `--allow-origin` list.
    pub fn origin_allowed(&self, origin: &str) -> bool {
        let origin = origin.trim_end_matches('/').to_ascii_lowercase();
        self.inner.allowed_origins.contains(&origin)
    }

    /// Whether writes need a token.
    pub fn has_token(&self) -> bool {
        self.inner.token.is_some()
    }

    /// Where the browser page is read from, when not from the binary.
    pub fn web_dir(&self) -> Option<&std::path::Path> {
        self.inner.web_dir.as_deref()
    }

    /// A new session on `scene` with validated `lights` at version 1, created by a client at
    /// `client` (when the front end knows it), stored before this returns; its first frame is
    /// queued at once.
    pub async fn create_session(
        &self,
        scene: &str,
        lights: LightSet,
        client: Option<IpAddr>,
    ) -> Result<Arc<Session>, ServerError> {
        let index = self.scene_index(scene)?;
        self.check_emitters(index, &lights)?;
        // A soft cap (two creations racing may both pass it): what it bounds is memory and the
        // worker's batches, not an exact count.
        let held = self.session_count();
        if held >= self.inner.max_sessions {
            self.count_refused(SessionLimit::Total);
            return Err(ServerError::Exhausted(format!(
                "the server holds {held} sessions, its limit (--max-sessions); reuse one or wait \
                 for idle ones to expire"
            )));
        }
        // Taken before the session is stored, so that one client's creations racing each other
        // cannot all pass the check; given back if the creation fails.
        let place = match client {
            Some(ip) => Some(self.take_client_place(ip)?),
            None => None,
        };
        let id = uuid::Uuid::new_v4().simple().to_string();
        if let Some(store) = &self.inner.store {
            let record = StoredSession {
                scene: scene.to_string(),
                lights: lights.clone(),
                version: 1,
                written_unix_ms: Some(crate::store::unix_ms()),
            };
            store.put(&id, &record).await?;
        }
        let session = Arc::new(Session::new(id.clone(), index, lights, 1, client));
        // The session holds the place from now on; expiry gives it back.
        if let Some(place) = place {
            place.keep();
        }
        self.write_sessions().insert(id, Arc::clone(&session));
        self.inner.metrics.sessions.set(self.session_count() as i64);
        self.inner.worker.enqueue(Arc::clone(&session));
        info!(session = %session.id, scene, "session created");
        Ok(session)
    }

    fn count_refused(&self, limit: SessionLimit) {
        self.inner
            .metrics
            .sessions_refused
            .get_or_create(&SessionLimitLabel { limit })
            .inc();
    }

    /// One more session for `ip`, or `resource_exhausted` when it holds its limit already.
    fn take_client_place(&self, ip: IpAddr) -> Result<ClientPlace<'_>, ServerError> {
        let mut held = self
            .inner
            .per_client
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let n = held.entry(ip).or_insert(0);
        if *n >= self.inner.max_sessions_per_client {
            let n = *n;
            drop(held);
            self.count_refused(SessionLimit::PerClient);
            return Err(ServerError::Exhausted(format!(
                "this client address holds {n} sessions, the limit for one client \
                 (--max-sessions-per-client); reuse one or wait for idle ones to expire"
            )));
        }
        *n += 1;
        Ok(ClientPlace { hub: self, ip })
    }

    /// Gives back a removed session's place in its client's count.
    fn release_client_place(&self, ip: IpAddr) {
        let mut held = self
            .inner
            .per_client
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        if let Some(n) = held.get_mut(&ip) {
            *n = n.saturating_sub(1);
            if *n == 0 {
                held.remove(&ip);
            }
        }
    }

    /// Replaces a session's validated lights, stores them, marks the session dirty and returns;
    /// the frame follows on the session's channel. Writes to one session are stored one at a
    /// time, so the store always holds the newest version, and those that arrive while one is
    /// stored are merged: only the newest is stored next (last write wins), and every caller
    /// whose lights it replaced is answered with its version.
    pub async fn set_lights(
        &self,
        id: &str,
        lights: LightSet,
    ) -> Result<LightsVersion, ServerError> {
        let session = self.session(id)?;
        self.check_emitters(session.scene, &lights)?;
        let (reply, answer) = oneshot::channel();
        match session.offer_write(lights, reply) {
            Offered::Store(lights, replies) => {
                // On a task of its own: the writes merged meanwhile wait on it, and are answered
                // even if this caller goes away.
                let hub = self.clone();
                tokio::spawn(async move { hub.store_writes(session, lights, replies).await });
            }
            Offered::Waiting { merged } => {
                if merged {
                    self.inner.metrics.light_writes_merged.inc();
                }
            }
        }
        // The storing task answers every reply it takes; none comes only if it panicked.
        answer
            .await
            .map_err(|_| ServerError::Store(StoreError::Gone))?
    }

    /// Stores `lights` and answers `replies`, then each write that waited meanwhile, until none
    /// does.
    async fn store_writes(
        &self,
        session: Arc<Session>,
        mut lights: LightSet,
        mut replies: Vec<WriteReply>,
    ) {
        let _unwinding = AbandonOnPanic(&session);
        loop {
            let answer = self.store_lights(&session, lights).await;
            for reply in replies {
                let _ = reply.send(match &answer {
                    Ok(v) => Ok(*v),
                    Err(e) => Err(shared_error(e)),
                });
            }
            match session.next_write() {
                Some((next, waiting)) => (lights, replies) = (next, waiting),
                None => return,
            }
        }
    }

    /// One write, under the session's write lock.
    async fn store_lights(
        &self,
        session: &Arc<Session>,
        lights: LightSet,
    ) -> Result<LightsVersion, ServerError> {
        let id = session.id.as_str();
        let _writing = session.write_lock().await;
        // Expiry may have removed it while this write waited: storing it now would bring a
        // deleted session back on the next start.
        if session.is_expired() {
            return Err(ServerError::UnknownSession(id.to_string()));
        }
        let Some(version) = session.next_version(&lights) else {
            session.touch();
            return Ok(LightsVersion {
                version: session.lights_version(),
                changed: false,
            });
        };
        if let Some(store) = &self.inner.store {
            let record = StoredSession {
                scene: self.scene_of(session),
                lights: lights.clone(),
                version,
                written_unix_ms: Some(crate::store::unix_ms()),
            };
            store.put(id, &record).await?;
        }
        if session.apply(lights, version) {
            self.inner.worker.enqueue(Arc::clone(session));
        }
        self.inner.metrics.light_updates.inc();
        Ok(LightsVersion {
            version,
            changed: true,
        })
    }

    /// A viewer of session `id`: the newest frame at once, then each newer one.
    pub fn viewer(&self, id: &str, transport: Transport) -> Result<Viewer, ServerError> {
        let session = self.session(id)?;
        let viewer = Viewer::new(
            Arc::clone(&session),
            self.inner.shutdown.subscribe(),
            transport,
            Arc::clone(&self.inner.metrics),
        );
        // Expiry removes a session only while it has no viewers, checked under the map's lock.
        // If it removed this one before the viewer counted, the viewer would wait forever on a
        // session nobody publishes to: look again now that it counts.
        let still_here = self
            .inner
            .sessions
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .get(id)
            .is_some_and(|s| Arc::ptr_eq(s, &session));
        if !still_here {
            return Err(ServerError::UnknownSession(id.to_string()));
        }
        Ok(viewer)
    }

    /// Relights `scene` once, outside any session, batched with whatever the worker solves
    /// next for that scene.
    pub async fn relight_once(&self, scene: &str, lights: LightSet) -> Result<Frame, ServerError> {
        let scene = self.scene_index(scene)?;
        self.check_emitters(scene, &lights)?;
        let (reply, answer) = oneshot::channel();
        self.inner.worker.enqueue_once(OnceJob {
            scene,
            lights,
            reply,
        })?;
        // A deadline, so a worker that is restarting or stuck answers as unavailable rather
        // than holding the request forever.
        match tokio::time::timeout(ONCE_DEADLINE, answer).await {
            Ok(answer) => answer.map_err(|_| ServerError::WorkerGone)?,
            Err(_) => Err(ServerError::WorkerGone),
        }
    }

    /// A receiver that turns `true` when the server shuts down.
    pub fn shutdown_signal(&self) -> watch::Receiver<bool> {
        self.inner.shutdown.subscribe()
    }

    /// Ends every frame stream, stops the janitor and the engine worker (after its current
    /// batch). Blocks for that batch; idempotent.
    pub fn shutdown(&self) {
        self.inner.shutdown.send_replace(true);
        let janitor = self
            .inner
            .janitor
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take();
        if let Some((stop, thread)) = janitor {
            drop(stop);
            let _ = thread.join();
        }
        self.inner.worker.stop();
    }

    /// Removes sessions nobody watched or wrote for the expiry time. Returns how many.
    pub fn expire_idle(&self) -> usize {
        let ttl = self.inner.session_ttl;
        let idle: Vec<Arc<Session>> = self
            .inner
            .sessions
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .values()
            .filter(|s| s.viewers() == 0 && s.idle_for() >= ttl)
            .cloned()
            .collect();
        let mut removed = 0;
        for s in idle {
            // Under the session's write lock, so a write that raced with expiry either lands
            // first (and the session is no longer idle) or sees it expired and stores nothing.
            let Some(_writing) = s.try_write_lock() else {
                continue;
            };
            // Checked again under the map's lock: a viewer may have come in meanwhile.
            let mut map = self.write_sessions();
            if s.viewers() > 0 || s.idle_for() < ttl {
                continue;
            }
            s.mark_expired();
            map.remove(&s.id);
            drop(map);
            if let Some(ip) = s.client {
                self.release_client_place(ip);
            }
            if let Some(store) = &self.inner.store
                && let Err(e) = store.delete_blocking(&s.id)
            {
                warn!(session = %s.id, error = %e, "removing an expired session from the store");
            }
            info!(session = %s.id, "session expired");
            removed += 1;
        }
        // Stored sessions whose scene never came back.
        let gone: Vec<String> = {
            let mut orphans = self.inner.orphans.lock().unwrap_or_else(|e| e.into_inner());
            let (gone, kept): (Vec<_>, Vec<_>) = std::mem::take(&mut *orphans)
                .into_iter()
                .partition(|(_, _, since)| since.elapsed() >= ttl);
            *orphans = kept;
            gone.into_iter().map(|(id, _, _)| id).collect()
        };
        for id in gone {
            if let Some(store) = &self.inner.store
                && let Err(e) = store.delete_blocking(&id)
            {
                warn!(session = %id, error = %e, "removing an expired stored session");
            }
            info!(session = %id, "stored session expired: its scene did not come back");
            removed += 1;
        }
        if removed > 0 {
            self.inner.metrics.sessions_expired.inc_by(removed as u64);
            self.inner.metrics.sessions.set(self.session_count() as i64);
        }
        removed
    }

    /// Loads a new or changed baked file: validated first, then swapped in on the engine;
    /// sessions stay, and those on the scene are solved again with the new matrix. A file that
    /// fails leaves the old scene serving. Blocking.
    pub fn reload(&self, path: &std::path::Path) -> Result<(), ServerError> {
        let name = scenes::scene_name(path);
        let result = self.reload_inner(path, &name);
        let outcome = match &result {
            Ok(()) => Outcome::Ok,
            Err(e) => {
                warn!(file = %path.display(), error = %e, "reload refused; the previous scene keeps serving");
                Outcome::Failed
            }
        };
        self.inner
            .metrics
            .scene_reloads
            .get_or_create(&ReloadLabel {
                scene: name,
                outcome,
            })
            .inc();
        result
    }

    fn reload_inner(&self, path: &std::path::Path, name: &str) -> Result<(), ServerError> {
        let mut baked = Baked::read(path).map_err(|source| ServerError::SceneFile {
            path: path.to_path_buf(),
            source,
        })?;
        // The model too is read again: a new bake, or a glTF put beside the file, replaces it.
        let info = SceneInfo::new(name.to_string(), path.to_path_buf(), &mut baked);
        let existing = self.scene_index(name).ok();
        let index = existing.unwrap_or_else(|| self.scenes().len());
        if let Some(old) = existing.and_then(|i| self.scene_at(i))
            && old.layout != info.layout
        {
            warn!(
                scene = name,
                "the reloaded scene's patch layout changed: clients must fetch it again"
            );
        }
        let sessions: Vec<Arc<Session>> = self
            .inner
            .sessions
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .values()
            .filter(|s| s.scene == index)
            .cloned()
            .collect();
        let (reply, answer) = std::sync::mpsc::channel();
        self.inner.worker.enqueue_reload(ReloadJob {
            scene: index,
            name: name.to_string(),
            baked,
            sessions,
            reply,
        });
        answer.recv().map_err(|_| ServerError::WorkerGone)??;
        let mut scenes = self.inner.scenes.write().unwrap_or_else(|e| e.into_inner());
        if index < scenes.len() {
            scenes[index] = Arc::new(info);
        } else {
            scenes.push(Arc::new(info));
        }
        drop(scenes);
        info!(scene = name, file = %path.display(), new = existing.is_none(), "scene reloaded");
        if existing.is_none() {
            // Stored sessions that waited for this scene come back with it.
            let waiting: Vec<(String, StoredSession)> = {
                let mut orphans = self.inner.orphans.lock().unwrap_or_else(|e| e.into_inner());
                let (mine, others): (Vec<_>, Vec<_>) = std::mem::take(&mut *orphans)
                    .into_iter()
                    .partition(|(_, s, _)| s.scene == name);
                *orphans = others;
                mine.into_iter().map(|(id, s, _)| (id, s)).collect()
            };
            if !waiting.is_empty() {
                self.restore(waiting);
            }
        }
        Ok(())
    }

    /// One thread for housekeeping: expiring idle sessions and watching the scene directory.
    fn start_janitor(
        &self,
        reload_interval: Option<Duration>,
        stamps: Vec<(PathBuf, scenes::Stamp)>,
        skipped: Vec<crate::error::SkippedScene>,
    ) {
        let (stop, stopped) = std::sync::mpsc::channel::<()>();
        let weak: Weak<Inner> = Arc::downgrade(&self.inner);
        let ttl = self.inner.session_ttl;
        // Expiry need not be prompt: a tenth of the TTL, between 10 ms (tests) and a minute.
        let expiry_every = (ttl / 10).clamp(Duration::from_millis(10), Duration::from_secs(60));
        let tick = reload_interval.map_or(expiry_every, |r| r.min(expiry_every));
        let mut known: HashMap<PathBuf, scenes::Stamp> = stamps.into_iter().collect();
        // A file skipped at start is remembered as seen, so it is retried only once it changes.
        for s in skipped {
            if let Ok(stamp) = scenes::stamp(&s.path) {
                known.insert(s.path, stamp);
            }
        }
        let dir = self.inner.scenes_dir.clone();
        let spawned = std::thread::Builder::new()
            .name("bounce-janitor".into())
            .spawn(move || {
                let mut last_expiry = Instant::now();
                let mut last_scan = Instant::now();
                loop {
                    match stopped.recv_timeout(tick) {
                        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                        _ => return,
                    }
                    let Some(inner) = weak.upgrade() else { return };
                    let hub = Hub { inner };
                    if last_expiry.elapsed() >= expiry_every {
                        last_expiry = Instant::now();
                        hub.expire_idle();
                    }
                    if let Some(every) = reload_interval
                        && last_scan.elapsed() >= every
                    {
                        last_scan = Instant::now();
                        for path in scenes::changed_files(&dir, &mut known) {
                            let _ = hub.reload(&path);
                        }
                    }
                }
            });
        match spawned {
            Ok(thread) => {
                *self.inner.janitor.lock().unwrap_or_else(|e| e.into_inner()) =
                    Some((stop, thread));
            }
            Err(e) => {
                warn!(error = %e, "no janitor thread: sessions will not expire, scenes not reload")
            }
        }
    }
}

/// A place taken in a client's count of sessions while its session is being created: given
/// back when dropped, which is what a failed creation does; a created session keeps it.
struct ClientPlace<'a> {
    hub: &'a Hub,
    ip: IpAddr,
}

impl ClientPlace<'_> {
    /// The created session holds the place now: expiry gives it back.
    fn keep(self) {
        std::mem::forget(self);
    }
}

impl Drop for ClientPlace<'_> {
    fn drop(&mut self) {
        self.hub.release_client_place(self.ip);
    }
}

/// Leaves a session writable again should storing its writes panic.
struct AbandonOnPanic<'a>(&'a Session);

impl Drop for AbandonOnPanic<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.abandon_writes();
        }
    }
}

/// One write's error again, for each caller merged into that write.
fn shared_error(e: &ServerError) -> ServerError {
    match e {
        ServerError::UnknownSession(id) => ServerError::UnknownSession(id.clone()),
        ServerError::Store(StoreError::Gone) => ServerError::Store(StoreError::Gone),
        ServerError::Store(StoreError::Commit(m)) => {
            ServerError::Store(StoreError::Commit(m.clone()))
        }
        // Storing fails only as above; anything else is still the store's.
        other => ServerError::Store(StoreError::Commit(other.to_string())),
    }
}

/// Compares without an early exit, so the time taken does not tell how much of a guess matched.
fn constant_time_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}
