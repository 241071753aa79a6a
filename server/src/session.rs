//! A session: one scene, one light configuration with its version, and the newest frame.
//!
//! Writers change the lights ([`Session::set_lights`]); the engine worker takes a snapshot
//! ([`Session::take`]) and publishes the frame it solved ([`Session::publish`]) into a
//! `watch` channel. A `watch` channel holds only the newest value, so a viewer that reads slowly
//! skips the frames it missed, costs the others nothing, and since the worker publishes each
//! session's frames in version order, never reads an older frame after a newer one.

use std::sync::{Mutex, MutexGuard};

use bounce_core::light::LightSet;
use tokio::sync::watch;

use crate::frame::Frame;

pub struct Session {
    pub id: String,
    /// Index of the scene in the hub.
    pub scene: usize,
    state: Mutex<State>,
    frames: watch::Sender<Option<Frame>>,
}

struct State {
    lights: LightSet,
    /// Counts light changes from 1 (the initial lights).
    version: u64,
    /// Whether the session waits in the worker's queue, so a burst of changes queues it once.
    queued: bool,
}

/// What [`Session::set_lights`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LightsChange {
    pub version: u64,
    pub changed: bool,
    /// The caller must queue the session for the worker (it was not queued already).
    pub enqueue: bool,
}

impl Session {
    /// A new session at version 1, waiting for its first frame (the caller queues it).
    pub(crate) fn new(id: String, scene: usize, lights: LightSet) -> Session {
        Session {
            id,
            scene,
            state: Mutex::new(State {
                lights,
                version: 1,
                queued: true,
            }),
            frames: watch::Sender::new(None),
        }
    }

    fn state(&self) -> MutexGuard<'_, State> {
        // A panic while holding this lock leaves plain data behind; keep serving it.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Replaces the lights. Lights equal to the current ones change nothing: no new version and
    /// no solve, so a client that repeats itself costs nothing.
    pub(crate) fn set_lights(&self, lights: LightSet) -> LightsChange {
        let mut s = self.state();
        if s.lights == lights {
            return LightsChange {
                version: s.version,
                changed: false,
                enqueue: false,
            };
        }
        s.lights = lights;
        s.version += 1;
        let enqueue = !s.queued;
        s.queued = true;
        LightsChange {
            version: s.version,
            changed: true,
            enqueue,
        }
    }

    pub fn lights_version(&self) -> u64 {
        self.state().version
    }

    /// The worker's snapshot: the newest lights and their version. A change after this queues
    /// the session again.
    pub(crate) fn take(&self) -> (LightSet, u64) {
        let mut s = self.state();
        s.queued = false;
        (s.lights.clone(), s.version)
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

    /// Publishes a frame unless one answering the same or a newer version is out already.
    /// Only the engine worker publishes, so this check is what keeps every viewer's frames in
    /// order even if a future change lets two solves of one session race.
    pub(crate) fn publish(&self, frame: Frame) -> bool {
        self.frames.send_if_modified(|cur| {
            let newer = cur
                .as_ref()
                .is_none_or(|f| f.header.lights_version < frame.header.lights_version);
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

    pub fn viewers(&self) -> usize {
        self.frames.receiver_count()
    }
}
