//! [`Watcher`]: a session's newest frame, kept current by a background task through dropped
//! connections and server restarts.
//!
//! What a viewer draws from is the [`watch`] channel of frames: it always holds the newest frame
//! received, and keeps it while the connection is down, so the picture stays lit. Next to it a
//! second channel says how the connection is ([`ConnectionState`]), for an overlay.
//!
//! On a failure the task waits and tries again: 100 ms doubling to 5 s by default, each wait
//! drawn between half and all of that (jitter, so a restarted server is not hit by every viewer
//! in the same millisecond), back to the start once frames flow again. A refusal that retrying
//! cannot fix (an unknown session, a missing token) waits the longest delay each time rather
//! than giving up: a session's server may come back with it.
//!
//! Order: a frame is kept only if it is newer than the one held. On one connection that is a
//! greater (lights version, sequence). Sequences count per server run, so after a reconnect a
//! frame is newer when its lights version is at least the held one's (the same version is the
//! same light configuration solved again: equal or fresher, never older).

use std::time::Duration;

use bounce_wire::frame::{Frame, FrameHeader};
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tracing::{debug, info};

use crate::connection::{Client, ClientConfig};
use crate::error::ClientError;

/// How a watcher retries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WatcherOptions {
    /// The first wait after a failure.
    pub initial_backoff: Duration,
    /// Waits double up to this.
    pub max_backoff: Duration,
}

impl Default for WatcherOptions {
    fn default() -> WatcherOptions {
        WatcherOptions {
            initial_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(5),
        }
    }
}

/// The connection as a viewer's overlay would show it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConnectionState {
    /// Opening a connection and subscribing; `attempt` counts from 1 since the last live one.
    Connecting { attempt: u32 },
    /// Subscribed since then; frames arrive as the session's lights change.
    Live { since: Instant },
    /// No connection: since when (the loss of the last live one, or the watcher's start if it
    /// never had one), when the next attempt is, and why the last one ended.
    Disconnected {
        since: Instant,
        retry_in: Duration,
        error: String,
    },
}

/// A session's newest frame, kept by a background task; dropping the watcher stops it.
pub struct Watcher {
    session: String,
    frames: watch::Receiver<Option<Frame>>,
    state: watch::Receiver<ConnectionState>,
    task: JoinHandle<()>,
}

impl Watcher {
    /// Starts watching with the default retry policy. Call it inside a Tokio runtime.
    pub fn spawn(config: impl Into<ClientConfig>, session: impl Into<String>) -> Watcher {
        Watcher::spawn_with(config, session, WatcherOptions::default())
    }

    pub fn spawn_with(
        config: impl Into<ClientConfig>,
        session: impl Into<String>,
        options: WatcherOptions,
    ) -> Watcher {
        let session = session.into();
        let (frames_tx, frames) = watch::channel(None);
        let (state_tx, state) = watch::channel(ConnectionState::Connecting { attempt: 1 });
        let task = tokio::spawn(run(
            config.into(),
            session.clone(),
            options,
            frames_tx,
            state_tx,
        ));
        Watcher {
            session,
            frames,
            state,
            task,
        }
    }

    pub fn session(&self) -> &str {
        &self.session
    }

    /// The newest frame, `None` until the first arrives.
    pub fn latest(&self) -> Option<Frame> {
        self.frames.borrow().clone()
    }

    /// A receiver of the newest frame: `changed().await` wakes on each newer one.
    pub fn frames(&self) -> watch::Receiver<Option<Frame>> {
        self.frames.clone()
    }

    pub fn state(&self) -> watch::Receiver<ConnectionState> {
        self.state.clone()
    }
}

impl Drop for Watcher {
    fn drop(&mut self) {
        self.task.abort();
    }
}

async fn run(
    config: ClientConfig,
    session: String,
    options: WatcherOptions,
    frames: watch::Sender<Option<Frame>>,
    state: watch::Sender<ConnectionState>,
) {
    let mut backoff = Backoff::new(options);
    let mut newest = Newest::default();
    let mut outage_since = Instant::now();
    let mut attempt = 0u32;
    loop {
        attempt = attempt.saturating_add(1);
        state.send_replace(ConnectionState::Connecting { attempt });
        let mut live = false;
        let ended = watch_once(
            &config,
            &session,
            &mut newest,
            &frames,
            |event| match event {
                Event::Subscribed => {
                    live = true;
                    attempt = 0;
                    state.send_replace(ConnectionState::Live {
                        since: Instant::now(),
                    });
                }
                Event::Frame => backoff.reset(),
            },
        )
        .await;
        if live {
            outage_since = Instant::now();
        }
        let (retry_in, error) = match ended {
            Ok(()) => (backoff.next(), "the server ended the stream".to_string()),
            Err(e) if e.is_transient() => (backoff.next(), e.to_string()),
            Err(e) => (backoff.longest(), e.to_string()),
        };
        if live {
            info!(session = %session, %error, "frame stream lost; reconnecting");
        } else {
            debug!(session = %session, %error, attempt, "connecting failed");
        }
        state.send_replace(ConnectionState::Disconnected {
            since: outage_since,
            retry_in,
            error,
        });
        if frames.is_closed() && state.is_closed() {
            return;
        }
        tokio::time::sleep(retry_in).await;
    }
}

enum Event {
    Subscribed,
    Frame,
}

/// One connection: connect, subscribe, keep every newer frame until the stream ends.
async fn watch_once(
    config: &ClientConfig,
    session: &str,
    newest: &mut Newest,
    frames: &watch::Sender<Option<Frame>>,
    mut event: impl FnMut(Event),
) -> Result<(), ClientError> {
    // A fresh connection each time: after a failure the old one's state is unknown.
    let client = Client::connect(config.clone()).await?;
    let mut stream = client.subscribe(session).await?;
    newest.reconnected();
    event(Event::Subscribed);
    while let Some(frame) = stream.next().await? {
        event(Event::Frame);
        if newest.accept(&frame.header) {
            frames.send_replace(Some(frame));
        } else {
            debug!(
                session,
                sequence = frame.header.sequence,
                lights_version = frame.header.lights_version,
                "older frame skipped"
            );
        }
    }
    Ok(())
}

/// The ordering rule of the module doc.
#[derive(Debug, Default)]
struct Newest {
    /// (lights version, sequence) of the frame held.
    held: Option<(u64, u64)>,
    /// No frame accepted on the current connection yet: sequences are not comparable.
    new_connection: bool,
}

impl Newest {
    fn reconnected(&mut self) {
        self.new_connection = true;
    }

    fn accept(&mut self, h: &FrameHeader) -> bool {
        let key = (h.lights_version, h.sequence);
        let newer = match self.held {
            None => true,
            Some((version, _)) if self.new_connection => h.lights_version >= version,
            Some(held) => key > held,
        };
        if newer {
            self.held = Some(key);
            self.new_connection = false;
        }
        newer
    }
}

/// Exponential backoff with "equal jitter": each wait is drawn from the upper half of the
/// current delay, which doubles per failure up to the maximum.
#[derive(Debug)]
struct Backoff {
    options: WatcherOptions,
    current: Duration,
}

impl Backoff {
    fn new(options: WatcherOptions) -> Backoff {
        Backoff {
            options,
            current: options.initial_backoff,
        }
    }

    fn next(&mut self) -> Duration {
        let delay = self.current.min(self.options.max_backoff);
        self.current = (self.current * 2).min(self.options.max_backoff);
        jitter(delay)
    }

    fn longest(&self) -> Duration {
        jitter(self.options.max_backoff)
    }

    fn reset(&mut self) {
        self.current = self.options.initial_backoff;
    }
}

fn jitter(delay: Duration) -> Duration {
    delay / 2 + delay.mul_f64(0.5 * fastrand::f64())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(lights_version: u64, sequence: u64) -> FrameHeader {
        FrameHeader {
            flags: 0,
            patch_count: 1,
            sequence,
            lights_version,
        }
    }

    #[test]
    fn on_one_connection_only_newer_frames_pass() {
        let mut n = Newest::default();
        n.reconnected();
        assert!(n.accept(&header(1, 1)));
        assert!(n.accept(&header(1, 2)));
        assert!(!n.accept(&header(1, 2)), "the same frame twice");
        assert!(!n.accept(&header(1, 1)), "an older sequence");
        assert!(n.accept(&header(3, 3)));
        assert!(!n.accept(&header(2, 9)), "an older lights version");
    }

    #[test]
    fn after_a_reconnect_sequences_restart_and_versions_decide() {
        let mut n = Newest::default();
        n.reconnected();
        assert!(n.accept(&header(2, 40)));
        // A restarted server counts from 1 again: same version is accepted...
        n.reconnected();
        assert!(n.accept(&header(2, 1)));
        // ...and from then on sequences compare again on this connection.
        assert!(!n.accept(&header(2, 1)));
        assert!(n.accept(&header(2, 2)));
        // An older version is refused even as a new connection's first frame.
        n.reconnected();
        assert!(!n.accept(&header(1, 50)));
        assert!(n.accept(&header(3, 1)));
    }

    #[test]
    fn backoff_doubles_with_jitter_up_to_the_cap_and_resets() {
        let options = WatcherOptions::default();
        let mut b = Backoff::new(options);
        let mut nominal = options.initial_backoff;
        for _ in 0..12 {
            let d = b.next();
            assert!(d >= nominal / 2 && d <= nominal, "{d:?} for {nominal:?}");
            nominal = (nominal * 2).min(options.max_backoff);
        }
        assert_eq!(nominal, Duration::from_secs(5));
        let d = b.next();
        assert!(d >= Duration::from_millis(2500) && d <= Duration::from_secs(5));
        let l = b.longest();
        assert!(l >= Duration::from_millis(2500) && l <= Duration::from_secs(5));
        b.reset();
        assert!(b.next() <= Duration::from_millis(100));
        // Not every wait is the same: the jitter is real.
        let waits: Vec<_> = (0..16).map(|_| jitter(Duration::from_secs(1))).collect();
        assert!(waits.iter().any(|w| *w != waits[0]));
    }
}
