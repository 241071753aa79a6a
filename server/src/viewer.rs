//! One viewer's read side of a session, shared by the gRPC and WebSocket front ends so both
//! have the same semantics: the newest frame at once, then each newer one; a viewer that reads
//! slowly skips to the newest (counted as stale frames skipped), never gets an older frame
//! after a newer one, and its stream ends when the server shuts down or the session goes.

use std::sync::Arc;

use tokio::sync::watch;

use crate::frame::Frame;
use crate::metrics::{Metrics, Transport};
use crate::session::Session;

pub struct Viewer {
    session: Arc<Session>,
    frames: watch::Receiver<Option<Frame>>,
    shutdown: watch::Receiver<bool>,
    last_sequence: u64,
    transport: Transport,
    metrics: Arc<Metrics>,
}

impl Viewer {
    pub(crate) fn new(
        session: Arc<Session>,
        shutdown: watch::Receiver<bool>,
        transport: Transport,
        metrics: Arc<Metrics>,
    ) -> Viewer {
        let mut frames = session.subscribe();
        // The current frame counts as news to a new viewer.
        frames.mark_changed();
        session.touch();
        metrics
            .viewers
            .get_or_create(&Metrics::transport(transport))
            .inc();
        Viewer {
            session,
            frames,
            shutdown,
            last_sequence: 0,
            transport,
            metrics,
        }
    }

    /// The next frame newer than the last one returned, counted as sent. `None` once the
    /// server shuts down or the session is gone.
    pub async fn next(&mut self) -> Option<Frame> {
        loop {
            tokio::select! {
                biased;
                _ = self.shutdown.wait_for(|&s| s) => return None,
                changed = self.frames.changed() => {
                    changed.ok()?;
                    let Some(frame) = self.frames.borrow_and_update().clone() else {
                        continue;
                    };
                    let sequence = frame.header.sequence;
                    if sequence <= self.last_sequence {
                        continue;
                    }
                    let label = Metrics::transport(self.transport);
                    if self.last_sequence > 0 && sequence > self.last_sequence + 1 {
                        self.metrics
                            .stale_frames_skipped
                            .get_or_create(&label)
                            .inc_by(sequence - self.last_sequence - 1);
                    }
                    self.last_sequence = sequence;
                    self.metrics.frames_sent.get_or_create(&label).inc();
                    return Some(frame);
                }
            }
        }
    }
}

impl Viewer {
    pub fn session(&self) -> &Arc<Session> {
        &self.session
    }

    /// Whether the stream ended because the server is shutting down (rather than the session
    /// being removed).
    pub fn shutting_down(&self) -> bool {
        *self.shutdown.borrow()
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        // Watching counts as activity until the last viewer leaves.
        self.session.touch();
        self.metrics
            .viewers
            .get_or_create(&Metrics::transport(self.transport))
            .dec();
    }
}
