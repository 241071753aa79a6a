//! The engine worker: one thread that owns the [`Engine`] and its loaded scenes and solves, per
//! scene, every queued session and one-shot request in one `relight` batch.
//!
//! A thread rather than tokio tasks because engine calls block for milliseconds (CPU) or wait on
//! a device (GPU); the async side only touches a mutex and a condition variable. The engine is
//! created on this thread, so it never has to cross threads. One worker per engine: a second
//! device would get a second worker.
//!
//! The thread supervises itself. A panic in a batch (a driver's, or wgpu's on an error nothing
//! caught) or a fault the GPU reports ends that engine: the thread opens a new one on the same
//! baked files and goes on, the sessions of the lost batch queued again, one-shot callers told;
//! a GPU engine that faults, or panics a second time since the start, is replaced by the CPU
//! engine. While no engine serves, [`Worker::serving`] is false and the hub is not ready. A
//! relight that fails without a panic is tried again for its sessions after [`RETRY_AFTER`].

use std::collections::BTreeMap;
use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bounce_core::format::Baked;
use bounce_core::light::LightSet;
use bounce_engine::{Engine, EngineChoice, EngineKind, Scene};
use tokio::sync::oneshot;
use tracing::{debug, error, info, warn};

use crate::error::ServerError;
use crate::frame::Frame;
use crate::metrics::{Metrics, SceneLabel};
use crate::session::Session;

/// Light sets per `relight` call at most: bounds the batch's memory (`batch × patches` vectors)
/// and how long one scene's batch holds up the next scene.
pub const MAX_BATCH: usize = 64;

/// One-shot relights waiting for the engine at most (sessions need no bound: a session is in
/// the queue once, whatever its writes, and the hub caps their number).
pub const MAX_ONCE_QUEUED: usize = 4 * MAX_BATCH;

/// A session whose relight failed is solved again after this long.
pub const RETRY_AFTER: Duration = Duration::from_millis(250);

/// Panics (since the start) after which a GPU worker gives way to the CPU engine.
const GPU_PANICS: u32 = 2;

/// A one-shot relight: a scene and lights, the frame back through `reply`.
pub(crate) struct OnceJob {
    pub scene: usize,
    pub lights: LightSet,
    pub reply: oneshot::Sender<Result<Frame, ServerError>>,
}

/// A new or changed baked file, validated, to load in place of scene `scene` (or as a new
/// scene when `scene` is one past the last); then `sessions` are solved again on it.
pub(crate) struct ReloadJob {
    pub scene: usize,
    pub name: String,
    pub baked: Baked,
    pub sessions: Vec<Arc<Session>>,
    pub reply: mpsc::Sender<Result<(), ServerError>>,
}

#[derive(Default)]
struct Work {
    sessions: Vec<Arc<Session>>,
    once: Vec<OnceJob>,
    reloads: Vec<ReloadJob>,
    /// Sessions whose relight failed, and when to solve them again.
    retry: Vec<(Instant, Arc<Session>)>,
    stop: bool,
}

impl Work {
    fn idle(&self) -> bool {
        self.sessions.is_empty() && self.once.is_empty() && self.reloads.is_empty()
    }
}

#[derive(Default)]
struct Queue {
    work: Mutex<Work>,
    wake: Condvar,
    /// An engine is open and solving; false while the worker (re)starts or after it gave up.
    serving: AtomicBool,
    /// Sessions of the batch in progress: queued again if the batch panics.
    in_flight: Mutex<Vec<Arc<Session>>>,
    /// The engine solving now, as it describes itself (it changes when a restart falls back).
    engine: Mutex<String>,
    /// Per scene name, why part of its work runs on the CPU under a GPU engine.
    fallbacks: Mutex<BTreeMap<String, String>>,
    /// Test hook (`fault-injection`): the next batch panics.
    panic_next: AtomicBool,
    /// Test hook (`fault-injection`): the next relight fails with an engine error.
    fail_next: AtomicBool,
    /// Test hook (`fault-injection`): the worker takes no work while set, as if a batch took
    /// that long.
    held: AtomicBool,
}

impl Queue {
    fn lock(&self) -> MutexGuard<'_, Work> {
        self.work.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Sessions back into the queue (those a newer change has not queued already).
    fn requeue(&self, sessions: impl IntoIterator<Item = Arc<Session>>) {
        let mut w = self.lock();
        w.sessions
            .extend(sessions.into_iter().filter(|s| s.requeue()));
        drop(w);
        self.wake.notify_one();
    }
}

pub(crate) struct Worker {
    queue: Arc<Queue>,
    thread: Mutex<Option<JoinHandle<()>>>,
}

impl Worker {
    /// Opens the engine and loads `scenes` on a new thread; returns once both are done, with
    /// the engine's description.
    pub fn start(
        choice: EngineChoice,
        scenes: Vec<(String, Baked)>,
        metrics: Arc<Metrics>,
    ) -> Result<(Worker, String), ServerError> {
        let queue = Arc::new(Queue::default());
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let q = Arc::clone(&queue);
        let thread = std::thread::Builder::new()
            .name("bounce-engine".into())
            .spawn(move || supervise(&q, choice, scenes, &metrics, ready_tx))
            .map_err(|_| ServerError::WorkerGone)?;
        let description = ready_rx.recv().map_err(|_| ServerError::WorkerGone)??;
        Ok((
            Worker {
                queue,
                thread: Mutex::new(Some(thread)),
            },
            description,
        ))
    }

    /// The engine solving now, as it describes itself.
    pub fn engine(&self) -> String {
        self.queue
            .engine
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Why scene `name` runs partly on the CPU under a GPU engine (its matrix or its direct light
    /// over what the device holds), if it does.
    pub fn fallback(&self, name: &str) -> Option<String> {
        self.queue
            .fallbacks
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(name)
            .cloned()
    }

    /// Whether an engine is open and solving (false while the worker restarts, or after it
    /// stopped or gave up).
    pub fn serving(&self) -> bool {
        self.queue.serving.load(Ordering::Acquire)
    }

    /// Test hook: the next batch panics, as a driver fault would.
    #[cfg_attr(not(feature = "fault-injection"), allow(dead_code))]
    pub fn inject_panic(&self) {
        self.queue.panic_next.store(true, Ordering::Release);
    }

    /// Test hook: the next relight fails, as a device readback error would.
    #[cfg_attr(not(feature = "fault-injection"), allow(dead_code))]
    pub fn inject_failure(&self) {
        self.queue.fail_next.store(true, Ordering::Release);
    }

    /// Test hook: the worker takes no new work until [`Worker::release`].
    #[cfg_attr(not(feature = "fault-injection"), allow(dead_code))]
    pub fn hold(&self) {
        self.queue.held.store(true, Ordering::Release);
    }

    /// Test hook: ends [`Worker::hold`].
    #[cfg_attr(not(feature = "fault-injection"), allow(dead_code))]
    pub fn release(&self) {
        // Under the queue's lock, so the worker cannot miss the wake between its check of
        // `held` and its wait.
        let w = self.queue.lock();
        self.queue.held.store(false, Ordering::Release);
        drop(w);
        self.queue.wake.notify_one();
    }

    /// One-shot relights waiting for the engine now.
    #[cfg_attr(not(feature = "fault-injection"), allow(dead_code))]
    pub fn once_waiting(&self) -> usize {
        self.queue.lock().once.len()
    }

    /// Queues a session whose lights changed (the caller checked it was not queued already).
    pub fn enqueue(&self, session: Arc<Session>) {
        self.queue.lock().sessions.push(session);
        self.queue.wake.notify_one();
    }

    /// Queues a one-shot relight, or refuses it when [`MAX_ONCE_QUEUED`] wait already: sessions
    /// merge their changes, but each one-shot request is its own light set.
    pub fn enqueue_once(&self, job: OnceJob) -> Result<(), ServerError> {
        let mut w = self.queue.lock();
        if w.once.len() >= MAX_ONCE_QUEUED {
            return Err(ServerError::Exhausted(format!(
                "{MAX_ONCE_QUEUED} one-shot relights are already waiting for the engine"
            )));
        }
        w.once.push(job);
        drop(w);
        self.queue.wake.notify_one();
        Ok(())
    }

    pub fn enqueue_reload(&self, job: ReloadJob) {
        self.queue.lock().reloads.push(job);
        self.queue.wake.notify_one();
    }

    /// Stops after the batch in progress and waits for the thread; queued work is dropped (a
    /// one-shot caller gets [`ServerError::WorkerGone`]).
    pub fn stop(&self) {
        self.queue.lock().stop = true;
        self.queue.wake.notify_one();
        let thread = self.thread.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(t) = thread
            && t.join().is_err()
        {
            error!("the engine worker panicked");
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.queue.lock().stop = true;
        self.queue.wake.notify_one();
    }
}

/// Names are kept beside the engine's scenes for logs and errors.
type Loaded = Vec<(String, Scene)>;

/// The worker thread: an engine opened on `scenes`, run until told to stop, and opened again
/// (on the CPU after a GPU fault) whenever a batch panics or the device faults.
fn supervise(
    queue: &Queue,
    choice: EngineChoice,
    mut scenes: Vec<(String, Baked)>,
    metrics: &Metrics,
    ready: mpsc::Sender<Result<String, ServerError>>,
) {
    let mut ready = Some(ready);
    let mut choice = choice;
    let mut panics = 0u32;
    loop {
        let (engine, mut loaded) = match open(choice, &scenes) {
            Ok(opened) => opened,
            Err(e) => {
                if let Some(tx) = ready.take() {
                    let _ = tx.send(Err(e));
                    return;
                }
                if choice == EngineChoice::Cpu {
                    error!(error = %e, "the CPU engine did not open again; the worker stops");
                    return;
                }
                error!(error = %e, "the engine did not open again; trying the CPU engine");
                choice = EngineChoice::Cpu;
                continue;
            }
        };
        *queue.engine.lock().unwrap_or_else(|e| e.into_inner()) = engine.describe().to_string();
        // The gauge names the engine solving now, the replacement after a fallback.
        metrics.engine.clear();
        metrics
            .engine
            .get_or_create(&crate::metrics::EngineLabel {
                engine: engine.describe().to_string(),
            })
            .set(1);
        {
            let mut notes = queue.fallbacks.lock().unwrap_or_else(|e| e.into_inner());
            notes.clear();
            for (name, scene) in &loaded {
                if let Some(note) = fallback_note(scene) {
                    notes.insert(name.clone(), note);
                }
            }
        }
        // Serving before the first start is reported: the hub is ready as soon as it returns.
        queue.serving.store(true, Ordering::Release);
        if let Some(tx) = ready.take() {
            let _ = tx.send(Ok(engine.describe().to_string()));
        }
        let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| {
            run(queue, &engine, &mut loaded, &mut scenes, metrics)
        }));
        queue.serving.store(false, Ordering::Release);
        let reason = match outcome {
            Ok(Stopped::Asked) => return,
            Ok(Stopped::DeviceFault(why)) => {
                // A device that faulted is not tried again.
                choice = EngineChoice::Cpu;
                why
            }
            Err(payload) => {
                panics += 1;
                if engine.kind() == EngineKind::Gpu && panics >= GPU_PANICS {
                    choice = EngineChoice::Cpu;
                }
                panic_message(payload.as_ref())
            }
        };
        metrics.worker_restarts.inc();
        let lost = std::mem::take(&mut *queue.in_flight.lock().unwrap_or_else(|e| e.into_inner()));
        error!(
            reason = %reason,
            engine = %engine.describe(),
            next = ?choice,
            sessions_requeued = lost.len(),
            "the engine worker lost its engine; opening one again"
        );
        queue.requeue(lost);
        drop(loaded);
        drop(engine);
    }
}

/// Why [`run`] returned.
enum Stopped {
    /// [`Worker::stop`].
    Asked,
    /// The GPU reported a fault: this engine must not be used again.
    DeviceFault(String),
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".to_string())
}

fn open(choice: EngineChoice, scenes: &[(String, Baked)]) -> Result<(Engine, Loaded), ServerError> {
    let engine = Engine::new(choice).map_err(|e| ServerError::Engine(Box::new(e)))?;
    if let Some(why) = engine.fallback() {
        info!(reason = why, "no GPU engine");
    }
    let mut loaded = Vec::with_capacity(scenes.len());
    for (name, baked) in scenes {
        let start = Instant::now();
        let scene = engine.load(baked).map_err(|source| ServerError::Load {
            name: name.clone(),
            source: Box::new(source),
        })?;
        info!(
            scene = %name,
            patches = baked.layout.len(),
            codec = %baked.transport.codec,
            ms = start.elapsed().as_secs_f64() * 1e3,
            "scene loaded"
        );
        log_fallbacks(name, &scene);
        loaded.push((name.clone(), scene));
    }
    Ok((engine, loaded))
}

/// What a scene a GPU engine serves partly on the CPU says in `/v1/scenes`.
fn fallback_note(scene: &Scene) -> Option<String> {
    let parts: Vec<String> = [
        scene
            .transport_fallback()
            .map(|why| format!("transport on the CPU: {why}")),
        scene
            .direct_fallback()
            .map(|why| format!("direct light on the CPU: {why}")),
    ]
    .into_iter()
    .flatten()
    .collect();
    (!parts.is_empty()).then(|| parts.join("; "))
}

/// A scene a GPU engine serves partly on the CPU says so once, with the reason.
fn log_fallbacks(name: &str, scene: &bounce_engine::Scene) {
    if let Some(why) = scene.transport_fallback() {
        warn!(scene = %name, reason = why, "transport product on the CPU for this scene");
    }
    if let Some(why) = scene.direct_fallback() {
        warn!(scene = %name, reason = why, "direct light on the CPU for this scene");
    }
}

fn run(
    queue: &Queue,
    engine: &Engine,
    scenes: &mut Loaded,
    baked: &mut Vec<(String, Baked)>,
    metrics: &Metrics,
) -> Stopped {
    loop {
        let work = {
            let mut w = queue.lock();
            loop {
                if w.stop {
                    return Stopped::Asked;
                }
                // Failed sessions whose time has come go back into the queue.
                let now = Instant::now();
                let (due, later): (Vec<_>, Vec<_>) = std::mem::take(&mut w.retry)
                    .into_iter()
                    .partition(|(at, _)| *at <= now);
                w.retry = later;
                w.sessions.extend(due.into_iter().map(|(_, s)| s));
                if !w.idle() && !queue.held.load(Ordering::Acquire) {
                    break;
                }
                w = match w.retry.iter().map(|(at, _)| *at).min() {
                    Some(at) => {
                        let wait = at.saturating_duration_since(now);
                        queue
                            .wake
                            .wait_timeout(w, wait)
                            .unwrap_or_else(|e| e.into_inner())
                            .0
                    }
                    None => queue.wake.wait(w).unwrap_or_else(|e| e.into_inner()),
                };
            }
            Work {
                sessions: std::mem::take(&mut w.sessions),
                once: std::mem::take(&mut w.once),
                reloads: std::mem::take(&mut w.reloads),
                retry: Vec::new(),
                stop: false,
            }
        };
        *queue.in_flight.lock().unwrap_or_else(|e| e.into_inner()) = work.sessions.clone();
        for job in work.reloads {
            reload(engine, scenes, baked, job, metrics, queue);
        }
        // Per scene, its sessions and one-shot jobs: each scene is one batch.
        let mut by_scene: BTreeMap<usize, (Vec<Arc<Session>>, Vec<OnceJob>)> = BTreeMap::new();
        for s in work.sessions {
            by_scene.entry(s.scene).or_default().0.push(s);
        }
        for j in work.once {
            by_scene.entry(j.scene).or_default().1.push(j);
        }
        for (scene, (sessions, once)) in by_scene {
            if let Some((name, loaded)) = scenes.get(scene) {
                let targets = sessions.into_iter().filter_map(|session| {
                    let (lights, version, since) = session.take();
                    // Already answered (queued twice around a publish): nothing to solve.
                    (version > session.published_version()).then_some((
                        Target::Session {
                            session,
                            version,
                            since,
                            resolve: false,
                        },
                        lights,
                    ))
                });
                let once = once.into_iter().map(|j| (Target::Once(j.reply), j.lights));
                solve_scene(
                    engine,
                    name,
                    loaded,
                    targets.chain(once).collect(),
                    metrics,
                    queue,
                );
            }
            if let Some(why) = engine.device_fault() {
                return Stopped::DeviceFault(why);
            }
        }
        queue
            .in_flight
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clear();
    }
}

/// A changed scene onto the engine, in place of the old one only once it loaded; then its
/// sessions solved again so viewers see the new matrix.
fn reload(
    engine: &Engine,
    scenes: &mut Loaded,
    baked: &mut Vec<(String, Baked)>,
    job: ReloadJob,
    metrics: &Metrics,
    queue: &Queue,
) {
    let start = Instant::now();
    let loaded = match engine.load(&job.baked) {
        Ok(scene) => scene,
        Err(source) => {
            let _ = job.reply.send(Err(ServerError::Load {
                name: job.name,
                source: Box::new(source),
            }));
            return;
        }
    };
    info!(
        scene = %job.name,
        patches = job.baked.layout.len(),
        ms = start.elapsed().as_secs_f64() * 1e3,
        "scene loaded"
    );
    log_fallbacks(&job.name, &loaded);
    {
        let mut notes = queue.fallbacks.lock().unwrap_or_else(|e| e.into_inner());
        match fallback_note(&loaded) {
            Some(note) => notes.insert(job.name.clone(), note),
            None => notes.remove(&job.name),
        };
    }
    // The file is kept beside the engine's copy: a restarted engine loads it again.
    let at = if job.scene < scenes.len() {
        scenes[job.scene] = (job.name.clone(), loaded);
        baked[job.scene] = (job.name, job.baked);
        job.scene
    } else {
        scenes.push((job.name.clone(), loaded));
        baked.push((job.name, job.baked));
        scenes.len() - 1
    };
    let _ = job.reply.send(Ok(()));
    let (name, scene) = &scenes[at];
    let items = job
        .sessions
        .into_iter()
        .map(|session| {
            let (lights, version, since) = session.snapshot();
            let target = Target::Session {
                session,
                version,
                since,
                resolve: true,
            };
            (target, lights)
        })
        .collect();
    solve_scene(engine, name, scene, items, metrics, queue);
}

/// One item of a batch: where its frame goes.
enum Target {
    Session {
        session: Arc<Session>,
        version: u64,
        /// When the version was accepted, for the update-to-frame latency.
        since: Instant,
        /// Solved again after a reload: replaces the frame of the same version.
        resolve: bool,
    },
    Once(oneshot::Sender<Result<Frame, ServerError>>),
}

fn solve_scene(
    engine: &Engine,
    name: &str,
    scene: &Scene,
    items: Vec<(Target, LightSet)>,
    metrics: &Metrics,
    queue: &Queue,
) {
    if queue.panic_next.swap(false, Ordering::AcqRel) {
        panic!("injected fault: the engine worker panics in a batch of scene '{name}'");
    }
    let (targets, sets): (Vec<Target>, Vec<LightSet>) = items.into_iter().unzip();
    let names = scene.emitter_names();
    let sets: Vec<LightSet> = sets
        .into_iter()
        .map(|set| usable_lights(name, names.as_deref(), set))
        .collect();
    let label = SceneLabel {
        scene: name.to_string(),
    };
    let mut targets = targets.into_iter();
    for batch in sets.chunks(MAX_BATCH) {
        let start = Instant::now();
        let result = if queue.fail_next.swap(false, Ordering::AcqRel) {
            Err(bounce_engine::EngineError::Gpu(
                bounce_engine::gpu::GpuError::Readback("injected fault".into()),
            ))
        } else {
            engine.relight(scene, batch)
        };
        let solve_s = start.elapsed().as_secs_f64();
        metrics
            .relight_seconds
            .get_or_create(&label)
            .observe(solve_s);
        metrics
            .batch_size
            .get_or_create(&label)
            .observe(batch.len() as f64);
        let batch_targets: Vec<Target> = targets.by_ref().take(batch.len()).collect();
        match result {
            Ok(lit) => {
                debug!(
                    scene = name,
                    batch = batch.len(),
                    ms = solve_s * 1e3,
                    "solved"
                );
                for (target, irr) in batch_targets.into_iter().zip(lit) {
                    deliver(target, &irr.streamed(), &irr.probes, metrics);
                }
            }
            Err(source) => {
                // Lights were validated on the way in, so this is an engine fault: one-shot
                // callers are told, sessions keep their last frame and are solved again after
                // RETRY_AFTER.
                error!(scene = name, error = %source, "relight failed");
                let msg = source.to_string();
                let mut retry = Vec::new();
                for target in batch_targets {
                    match target {
                        Target::Once(reply) => {
                            let _ = reply.send(Err(ServerError::Relight {
                                scene: name.to_string(),
                                message: msg.clone(),
                            }));
                        }
                        Target::Session { session, .. } => {
                            if session.requeue() {
                                retry.push((Instant::now() + RETRY_AFTER, session));
                            }
                        }
                    }
                }
                metrics.relight_retries.inc_by(retry.len() as u64);
                queue.lock().retry.extend(retry);
            }
        }
    }
}

/// `set` without the emissive changes that reach no emitter of the scene, each left out with a
/// warning. Lights are checked against the scene when they are set, so this only happens to a
/// session whose scene file was replaced by one without that emitter: it keeps being solved
/// with its other lights rather than failing every batch it shares with others.
fn usable_lights(
    scene: &str,
    emitters: Option<&[bounce_core::emitter::EmitterName]>,
    set: LightSet,
) -> LightSet {
    let lights = set
        .lights
        .into_iter()
        .filter(|l| {
            let Some(change) = bounce_core::light::EmissiveChange::of(l) else {
                return true;
            };
            let known = emitters.is_some_and(|names| {
                names
                    .iter()
                    .any(|n| change.reaches(&n.material, n.node.as_deref()))
            });
            if !known {
                warn!(
                    scene,
                    emitter = change.describe(),
                    "an emissive change reaches no emitter of the scene as it is now (the file \
                     was replaced?): left out"
                );
            }
            known
        })
        .collect();
    LightSet { lights }
}

/// A patch frame, with its probe frame beside it when the scene has probes.
fn frame(
    sequence: u64,
    version: u64,
    indirect: &[[f32; 3]],
    probes: &[[f32; 3]],
) -> Result<Frame, bounce_wire::frame::FrameError> {
    let frame = Frame::encode(sequence, version, indirect)?;
    if probes.is_empty() {
        return Ok(frame);
    }
    Ok(frame.with_probes(Frame::encode_probes(sequence, version, probes)?))
}

fn deliver(target: Target, indirect: &[[f32; 3]], probes: &[[f32; 3]], metrics: &Metrics) {
    match target {
        Target::Session {
            session,
            version,
            since,
            resolve,
        } => match frame(session.next_sequence(), version, indirect, probes) {
            Ok(frame) => {
                metrics.count_frame_flags(frame.header.flags);
                if session.publish(frame, resolve) && !resolve {
                    metrics
                        .update_to_frame_seconds
                        .observe(since.elapsed().as_secs_f64());
                }
            }
            Err(e) => error!(session = %session.id, error = %e, "encoding a frame"),
        },
        Target::Once(reply) => {
            let frame = frame(0, 0, indirect, probes).map_err(ServerError::from);
            if let Ok(f) = &frame {
                metrics.count_frame_flags(f.header.flags);
            }
            let _ = reply.send(frame);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounce_core::light::Light;

    #[test]
    fn emissive_changes_the_scene_no_longer_has_are_left_out() {
        let set = LightSet::from_json(
            r#"{"lights": [{"type": "point", "position": [0, 1, 0], "intensity": 1},
                           {"type": "emissive", "material": "Lamp", "strength": 0},
                           {"type": "emissive", "material": "Screen", "strength": 2}]}"#,
        )
        .unwrap();
        let names = vec![bounce_core::emitter::EmitterName {
            material: "Screen".to_string(),
            node: Some("Tv".to_string()),
        }];
        let kept = usable_lights("s", Some(&names), set.clone());
        assert_eq!(kept.lights.len(), 2);
        assert!(
            matches!(&kept.lights[1], Light::Emissive { material: Some(m), .. } if m == "Screen")
        );
        assert!(kept.validate().is_ok());
        // A file that lists no emitters keeps only the punctual light.
        assert_eq!(usable_lights("s", None, set.clone()).lights.len(), 1);
        // A set the scene takes whole is untouched.
        let names: Vec<_> = ["Lamp", "Screen"]
            .map(|m| bounce_core::emitter::EmitterName {
                material: m.to_string(),
                node: None,
            })
            .to_vec();
        assert_eq!(usable_lights("s", Some(&names), set.clone()), set);
        // By node: kept where a node of that name places an emitter.
        let by_node = LightSet::from_json(
            r#"{"lights": [{"type": "emissive", "node": "Tv", "strength": 0},
                           {"type": "emissive", "node": "Desk", "strength": 0}]}"#,
        )
        .unwrap();
        let names = vec![bounce_core::emitter::EmitterName {
            material: "Screen".to_string(),
            node: Some("Tv".to_string()),
        }];
        assert_eq!(
            usable_lights("s", Some(&names), by_node.clone()).lights,
            by_node.lights[..1]
        );
    }
}
