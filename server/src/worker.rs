//! The engine worker: one thread that owns the [`Engine`] and its loaded scenes and solves, per
//! scene, every queued session and one-shot request in one `relight` batch.
//!
//! A thread rather than tokio tasks because engine calls block for milliseconds (CPU) or wait on
//! a device (GPU); the async side only touches a mutex and a condition variable. The engine is
//! created on this thread, so it never has to cross threads. One worker per engine: a second
//! device would get a second worker.

use std::collections::BTreeMap;
use std::sync::mpsc;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Instant;

use bounce_core::format::Baked;
use bounce_core::light::LightSet;
use bounce_engine::{Engine, EngineChoice, Scene};
use tokio::sync::oneshot;
use tracing::{debug, error, info, warn};

use crate::error::ServerError;
use crate::frame::Frame;
use crate::metrics::{Metrics, SceneLabel};
use crate::session::Session;

/// Light sets per `relight` call at most: bounds the batch's memory (`batch × patches` vectors)
/// and how long one scene's batch holds up the next scene.
pub const MAX_BATCH: usize = 64;

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
    stop: bool,
}

#[derive(Default)]
struct Queue {
    work: Mutex<Work>,
    wake: Condvar,
}

impl Queue {
    fn lock(&self) -> MutexGuard<'_, Work> {
        self.work.lock().unwrap_or_else(|e| e.into_inner())
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
            .spawn(move || {
                let opened = open(choice, scenes);
                let (engine, mut loaded) = match opened {
                    Ok((engine, loaded)) => {
                        let _ = ready_tx.send(Ok(engine.describe().to_string()));
                        (engine, loaded)
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                run(&q, &engine, &mut loaded, &metrics);
            })
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

    /// Queues a session whose lights changed (the caller checked it was not queued already).
    pub fn enqueue(&self, session: Arc<Session>) {
        self.queue.lock().sessions.push(session);
        self.queue.wake.notify_one();
    }

    pub fn enqueue_once(&self, job: OnceJob) {
        self.queue.lock().once.push(job);
        self.queue.wake.notify_one();
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

fn open(
    choice: EngineChoice,
    scenes: Vec<(String, Baked)>,
) -> Result<(Engine, Loaded), ServerError> {
    let engine = Engine::new(choice).map_err(|e| ServerError::Engine(Box::new(e)))?;
    if let Some(why) = engine.fallback() {
        info!(reason = why, "no GPU engine");
    }
    let mut loaded = Vec::with_capacity(scenes.len());
    for (name, baked) in scenes {
        let start = Instant::now();
        let scene = engine.load(&baked).map_err(|source| ServerError::Load {
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
        log_fallbacks(&name, &scene);
        loaded.push((name, scene));
    }
    Ok((engine, loaded))
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

fn run(queue: &Queue, engine: &Engine, scenes: &mut Loaded, metrics: &Metrics) {
    loop {
        let work = {
            let mut w = queue.lock();
            while w.sessions.is_empty() && w.once.is_empty() && w.reloads.is_empty() && !w.stop {
                w = queue.wake.wait(w).unwrap_or_else(|e| e.into_inner());
            }
            if w.stop {
                return;
            }
            std::mem::take(&mut *w)
        };
        for job in work.reloads {
            reload(engine, scenes, job, metrics);
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
                solve_scene(engine, name, loaded, targets.chain(once).collect(), metrics);
            }
        }
    }
}

/// A changed scene onto the engine, in place of the old one only once it loaded; then its
/// sessions solved again so viewers see the new matrix.
fn reload(engine: &Engine, scenes: &mut Loaded, job: ReloadJob, metrics: &Metrics) {
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
    let at = if job.scene < scenes.len() {
        scenes[job.scene] = (job.name, loaded);
        job.scene
    } else {
        scenes.push((job.name, loaded));
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
    solve_scene(engine, name, scene, items, metrics);
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
) {
    let (targets, sets): (Vec<Target>, Vec<LightSet>) = items.into_iter().unzip();
    let label = SceneLabel {
        scene: name.to_string(),
    };
    let mut targets = targets.into_iter();
    for batch in sets.chunks(MAX_BATCH) {
        let start = Instant::now();
        let result = engine.relight(scene, batch);
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
                    deliver(target, &irr.indirect, metrics);
                }
            }
            Err(source) => {
                // Lights were validated on the way in, so this is an engine fault: report it to
                // one-shot callers and in the log; sessions keep their last frame.
                error!(scene = name, error = %source, "relight failed");
                let msg = source.to_string();
                for target in batch_targets {
                    if let Target::Once(reply) = target {
                        let _ = reply.send(Err(ServerError::Relight {
                            scene: name.to_string(),
                            message: msg.clone(),
                        }));
                    }
                }
            }
        }
    }
}

fn deliver(target: Target, indirect: &[[f32; 3]], metrics: &Metrics) {
    match target {
        Target::Session {
            session,
            version,
            since,
            resolve,
        } => match Frame::encode(session.next_sequence(), version, indirect) {
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
            let frame = Frame::encode(0, 0, indirect).map_err(ServerError::from);
            if let Ok(f) = &frame {
                metrics.count_frame_flags(f.header.flags);
            }
            let _ = reply.send(frame);
        }
    }
}
