//! The engine worker: one thread that owns the [`Engine`] and its loaded scenes and solves, per
//! scene, every queued session and one-shot request in one `relight` batch.
//!
//! A thread rather than tokio tasks because engine calls block for milliseconds (CPU) or wait on
//! a device (GPU); the async side only touches a mutex and a condition variable. The engine is
//! created on this thread, so it never has to cross threads. One worker per engine: a second
//! device would get a second worker.

use std::collections::BTreeMap;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Instant;

use bounce_core::format::Baked;
use bounce_core::light::LightSet;
use bounce_engine::{Engine, EngineChoice, Scene};
use tokio::sync::oneshot;
use tracing::{debug, error, info};

use crate::error::ServerError;
use crate::frame::Frame;
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

#[derive(Default)]
struct Work {
    sessions: Vec<Arc<Session>>,
    once: Vec<OnceJob>,
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
    ) -> Result<(Worker, String), ServerError> {
        let queue = Arc::new(Queue::default());
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let q = Arc::clone(&queue);
        let thread = std::thread::Builder::new()
            .name("bounce-engine".into())
            .spawn(move || {
                let opened = open(choice, scenes);
                let (engine, loaded) = match opened {
                    Ok((engine, loaded)) => {
                        let _ = ready_tx.send(Ok(engine.describe().to_string()));
                        (engine, loaded)
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                run(&q, &engine, &loaded);
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
        loaded.push((name, scene));
    }
    Ok((engine, loaded))
}

fn run(queue: &Queue, engine: &Engine, scenes: &Loaded) {
    loop {
        let work = {
            let mut w = queue.lock();
            while w.sessions.is_empty() && w.once.is_empty() && !w.stop {
                w = queue.wake.wait(w).unwrap_or_else(|e| e.into_inner());
            }
            if w.stop {
                return;
            }
            std::mem::take(&mut *w)
        };
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
                solve_scene(engine, name, loaded, sessions, once);
            }
        }
    }
}

/// One item of a batch: where its frame goes.
enum Target {
    Session { session: Arc<Session>, version: u64 },
    Once(oneshot::Sender<Result<Frame, ServerError>>),
}

fn solve_scene(
    engine: &Engine,
    name: &str,
    scene: &Scene,
    sessions: Vec<Arc<Session>>,
    once: Vec<OnceJob>,
) {
    let mut targets = Vec::with_capacity(sessions.len() + once.len());
    let mut sets = Vec::with_capacity(targets.capacity());
    for session in sessions {
        let (lights, version) = session.take();
        // Already answered (queued twice around a publish): nothing to solve.
        if version <= session.published_version() {
            continue;
        }
        targets.push(Target::Session { session, version });
        sets.push(lights);
    }
    for job in once {
        targets.push(Target::Once(job.reply));
        sets.push(job.lights);
    }
    let mut targets = targets.into_iter();
    for batch in sets.chunks(MAX_BATCH) {
        let start = Instant::now();
        let result = engine.relight(scene, batch);
        let solve_ms = start.elapsed().as_secs_f64() * 1e3;
        let batch_targets: Vec<Target> = targets.by_ref().take(batch.len()).collect();
        match result {
            Ok(lit) => {
                debug!(scene = name, batch = batch.len(), ms = solve_ms, "solved");
                for (target, irr) in batch_targets.into_iter().zip(lit) {
                    deliver(target, &irr.indirect);
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

fn deliver(target: Target, indirect: &[[f32; 3]]) {
    match target {
        Target::Session { session, version } => {
            match Frame::encode(session.next_sequence(), version, indirect) {
                Ok(frame) => {
                    session.publish(frame);
                }
                Err(e) => error!(session = %session.id, error = %e, "encoding a frame"),
            }
        }
        Target::Once(reply) => {
            let _ = reply.send(Frame::encode(0, 0, indirect).map_err(ServerError::from));
        }
    }
}
