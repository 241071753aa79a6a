//! A session: one scene, one light configuration with its version, and the newest frame.
//!
//! Writers change the lights ([`Session::set_lights`]); the engine worker takes a snapshot
//! ([`Session::take`]) and publishes the frame it solved ([`Session::publish`]) into a
//! `watch` channel. A `watch` channel holds only the newest value, so a viewer that reads slowly
//! skips the frames it missed, costs the others nothing, and since the worker publishes each
//! session's frames in version order, never reads an older frame after a newer one.

use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use bounce_core::light::LightSet;
use tokio::sync::{oneshot, watch};

use crate::error::ServerError;
use crate::frame::Frame;

pub struct Session {
    pub id: String,
    /// Index of the scene in the hub.
    pub scene: usize,
    /// The address of the client that created it, when known (not for restored sessions):
    /// whose per-client count of sessions it is in.
    pub client: Option<std::net::IpAddr>,
    /// When this process created or restored it: what lists sessions newest first. Not stored,
    /// so sessions restored after a restart all date from the restart.
    created: Instant,
    state: Mutex<State>,
    frames: watch::Sender<Option<Frame>>,
    /// Held across a write's store commit, so writes to one session are stored in order.
    writing: tokio::sync::Mutex<()>,
    /// Writes waiting while one is stored (see [`Session::offer_write`]).
    writes: Mutex<Writes>,
    /// Removed by expiry: a write that waited on `writing` meanwhile must not store it again.
    expired: std::sync::atomic::AtomicBool,
}

/// A write's answer, for its caller (see [`crate::Hub::set_lights`]).
pub(crate) type WriteReply = oneshot::Sender<Result<LightsVersion, ServerError>>;

/// The writes of a session that are not stored yet.
#[derive(Default)]
struct Writes {
    /// A task stores this session's writes now: a new one waits in `next`.
    storing: bool,
    /// The newest write waiting, and every caller to answer when it is stored: those whose
    /// own lights it replaced too.
    next: Option<(LightSet, Vec<WriteReply>)>,
}

/// What [`Session::offer_write`] tells its caller.
pub(crate) enum Offered {
    /// No write was being stored: the caller stores these lights and answers these callers,
    /// then each next write ([`Session::next_write`]) until none waits.
    Store(LightSet, Vec<WriteReply>),
    /// It waits as the newest write; `merged` when it replaced lights waiting before it, which
    /// are dropped, never stored.
    Waiting { merged: bool },
}

struct State {
    lights: LightSet,
    /// Counts light changes from 1 (the initial lights).
    version: u64,
    /// Whether the session waits in the worker's queue, so a burst of changes queues it once.
    queued: bool,
    /// When the current version was accepted: the start of its update-to-frame latency.
    changed_at: Instant,
    /// Last write, or last viewer arriving or leaving: what expiry measures from.
    touched: Instant,
}

impl Session {
    /// A session at `version`, waiting for its first frame (the caller queues it).
    pub(crate) fn new(
        id: String,
        scene: usize,
        lights: LightSet,
        version: u64,
        client: Option<std::net::IpAddr>,
    ) -> Session {
        let now = Instant::now();
        Session {
            id,
            scene,
            client,
            created: now,
            state: Mutex::new(State {
                lights,
                version,
                queued: true,
                changed_at: now,
                touched: now,
            }),
            frames: watch::Sender::new(None),
            writing: tokio::sync::Mutex::new(()),
            writes: Mutex::new(Writes::default()),
            expired: std::sync::atomic::AtomicBool::new(false),
        }
    }

    fn state(&self) -> MutexGuard<'_, State> {
        // A panic while holding this lock leaves plain data behind; keep serving it.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A write of `lights`, answered through `reply`. Writes are stored one at a time; while one
    /// is, only the newest of those arriving waits (last write wins): a client that writes faster
    /// than the store commits costs one light set and one reply each, never a queue of them.
    pub(crate) fn offer_write(&self, lights: LightSet, reply: WriteReply) -> Offered {
        let mut w = self.writes.lock().unwrap_or_else(|e| e.into_inner());
        if !w.storing {
            w.storing = true;
            return Offered::Store(lights, vec![reply]);
        }
        match &mut w.next {
            Some((waiting, replies)) => {
                *waiting = lights;
                replies.push(reply);
                Offered::Waiting { merged: true }
            }
            None => {
                w.next = Some((lights, vec![reply]));
                Offered::Waiting { merged: false }
            }
        }
    }

    /// The write to store next, or `None` (and nothing is being stored any more) when none
    /// waits.
    pub(crate) fn next_write(&self) -> Option<(LightSet, Vec<WriteReply>)> {
        let mut w = self.writes.lock().unwrap_or_else(|e| e.into_inner());
        let next = w.next.take();
        w.storing = next.is_some();
        next
    }

    /// After a panic while storing: nothing is being stored, and the callers waiting are told
    /// (their replies dropped), so the next write stores again rather than waiting forever.
    pub(crate) fn abandon_writes(&self) {
        let mut w = self.writes.lock().unwrap_or_else(|e| e.into_inner());
        w.storing = false;
        w.next = None;
    }

    /// Held by a writer from [`Session::next_version`] to [`Session::apply`].
    pub(crate) async fn write_lock(&self) -> tokio::sync::MutexGuard<'_, ()> {
        self.writing.lock().await
    }

    /// The write lock if no write holds it: expiry skips a session being written (a write
    /// makes it busy anyway).
    pub(crate) fn try_write_lock(&self) -> Option<tokio::sync::MutexGuard<'_, ()>> {
        self.writing.try_lock().ok()
    }

    /// Marks the session removed by expiry (under its write lock).
    pub(crate) fn mark_expired(&self) {
        self.expired
            .store(true, std::sync::atomic::Ordering::Release);
    }

    pub fn is_expired(&self) -> bool {
        self.expired.load(std::sync::atomic::Ordering::Acquire)
    }

    /// The version `lights` would get, or `None` when they equal the current lights: a client
    /// that repeats itself gets no new version and costs no solve.
    pub(crate) fn next_version(&self, lights: &LightSet) -> Option<u64> {
        let s = self.state();
        (s.lights != *lights).then_some(s.version + 1)
    }

    /// Makes `lights` current at `version`. Returns whether the caller must queue the session
    /// for the worker (it was not queued already).
    pub(crate) fn apply(&self, lights: LightSet, version: u64) -> bool {
        let mut s = self.state();
        s.lights = lights;
        s.version = version;
        let now = Instant::now();
        s.changed_at = now;
        s.touched = now;
        !std::mem::replace(&mut s.queued, true)
    }

    /// Makes the session idle for `idle` already (a restored session's time since its last
    /// write); a clock that cannot go back that far leaves it idle from now.
    pub(crate) fn backdate(&self, idle: Duration) {
        let now = Instant::now();
        self.state().touched = now.checked_sub(idle).unwrap_or(now);
    }

    /// Marks the session as in use now (for expiry).
    pub fn touch(&self) {
        self.state().touched = Instant::now();
    }

    /// How long since the last write or viewer arriving or leaving.
    pub fn idle_for(&self) -> Duration {
        self.state().touched.elapsed()
    }

    pub fn lights_version(&self) -> u64 {
        self.state().version
    }

    /// The worker's snapshot: the newest lights, their version and when it was accepted. A
    /// change after this queues the session again.
    pub(crate) fn take(&self) -> (LightSet, u64, Instant) {
        let mut s = self.state();
        s.queued = false;
        (s.lights.clone(), s.version, s.changed_at)
    }

    /// Back into the worker's queue after a failed or lost relight. Returns whether the caller
    /// must queue it (a newer change has not queued it already).
    pub(crate) fn requeue(&self) -> bool {
        !std::mem::replace(&mut self.state().queued, true)
    }

    /// The same snapshot without leaving the queue, for solving again after a scene reload.
    pub(crate) fn snapshot(&self) -> (LightSet, u64, Instant) {
        let s = self.state();
        (s.lights.clone(), s.version, s.changed_at)
    }

    pub fn lights(&self) -> LightSet {
        self.state().lights.clone()
    }

    /// The lights version of the newest published frame, 0 before the first.
    pub fn published_version(&self) -> u64 {
        self.frames
            .borrow()
            .as_ref()
            .map_or(0, |f| f.header.lights_version)
    }

    /// Sequence number for the next frame.
    pub(crate) fn next_sequence(&self) -> u64 {
        self.frames
            .borrow()
            .as_ref()
            .map_or(1, |f| f.header.sequence + 1)
    }

    /// Publishes a frame unless one answering a newer version (or the same version, unless
    /// `resolve` says this one replaces it after a scene reload) is out already. Only the engine
    /// worker publishes, so this check is what keeps every viewer's frames in order even if a
    /// future change lets two solves of one session race.
    pub(crate) fn publish(&self, frame: Frame, resolve: bool) -> bool {
        self.frames.send_if_modified(|cur| {
            let newer = cur.as_ref().is_none_or(|f| {
                let (old, new) = (f.header.lights_version, frame.header.lights_version);
                old < new || (resolve && old == new)
            });
            if newer {
                *cur = Some(frame);
            }
            newer
        })
    }

    /// A receiver of the session's frames; its current value is the newest frame, if any.
    pub fn subscribe(&self) -> watch::Receiver<Option<Frame>> {
        self.frames.subscribe()
    }

    /// When this process created or restored the session.
    pub fn created(&self) -> Instant {
        self.created
    }

    /// Open viewers (gRPC streams and WebSockets): each holds one receiver of the frames.
    pub fn viewers(&self) -> usize {
        self.frames.receiver_count()
    }
}

/// What [`crate::Hub::set_lights`] answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LightsVersion {
    pub version: u64,
    /// `false` when the lights equalled the current ones: no new version, no new frame.
    pub changed: bool,
}
