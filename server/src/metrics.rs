//! The service's Prometheus metrics, one registry per hub, encoded in the text format for
//! `/metrics`. Front ends count what they send; the worker times what it solves.

use prometheus_client::encoding::{EncodeLabelSet, EncodeLabelValue, LabelValueEncoder};
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;

/// Which front end a viewer or frame went through.
#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
pub enum Transport {
    Grpc,
    Websocket,
    /// The HTTP routes other than the WebSocket (scenes, sessions).
    Http,
}

impl Transport {
    pub fn as_str(self) -> &'static str {
        match self {
            Transport::Grpc => "grpc",
            Transport::Websocket => "websocket",
            Transport::Http => "http",
        }
    }
}

// By hand: the derive writes variant names as they are spelt, and label values are lower case.
impl EncodeLabelValue for Transport {
    fn encode(&self, encoder: &mut LabelValueEncoder) -> Result<(), std::fmt::Error> {
        EncodeLabelValue::encode(&self.as_str(), encoder)
    }
}

#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct TransportLabel {
    pub transport: Transport,
}

#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct EngineLabel {
    pub engine: String,
}

#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct SceneLabel {
    pub scene: String,
}

#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
pub enum Outcome {
    Ok,
    Failed,
}

impl EncodeLabelValue for Outcome {
    fn encode(&self, encoder: &mut LabelValueEncoder) -> Result<(), std::fmt::Error> {
        let s = match self {
            Outcome::Ok => "ok",
            Outcome::Failed => "failed",
        };
        EncodeLabelValue::encode(&s, encoder)
    }
}

/// Which cap refused a new session.
#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
pub enum SessionLimit {
    /// `--max-sessions`.
    Total,
    /// `--max-sessions-per-client`.
    PerClient,
}

impl EncodeLabelValue for SessionLimit {
    fn encode(&self, encoder: &mut LabelValueEncoder) -> Result<(), std::fmt::Error> {
        let s = match self {
            SessionLimit::Total => "total",
            SessionLimit::PerClient => "per_client",
        };
        EncodeLabelValue::encode(&s, encoder)
    }
}

#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct SessionLimitLabel {
    pub limit: SessionLimit,
}

#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct ReloadLabel {
    pub scene: String,
    pub outcome: Outcome,
}

/// Every metric the service exports. Cheap to share: each metric is an `Arc` inside.
pub struct Metrics {
    registry: Registry,
    /// 1 for the engine in use, as it describes itself (`cpu (2 threads)`).
    pub engine: Family<EngineLabel, Gauge>,
    /// Wall time of one engine `relight` call (one batch), per scene.
    pub relight_seconds: Family<SceneLabel, Histogram>,
    /// Light sets per engine call, per scene: how much batching there is.
    pub batch_size: Family<SceneLabel, Histogram>,
    pub frames_sent: Family<TransportLabel, Counter>,
    /// Frames a viewer never got because a newer one was out by the time it read.
    pub stale_frames_skipped: Family<TransportLabel, Counter>,
    pub viewers: Family<TransportLabel, Gauge>,
    pub sessions: Gauge,
    pub sessions_expired: Counter,
    /// New sessions refused, by the cap that refused them.
    pub sessions_refused: Family<SessionLimitLabel, Counter>,
    /// Times the engine worker was restarted after a panic or a device fault.
    pub worker_restarts: Counter,
    /// Session relights that failed and were queued again.
    pub relight_retries: Counter,
    /// WebSockets closed because their client answered no ping or took no message in time.
    pub websocket_unresponsive: Counter,
    /// Light changes accepted (a repeat of the current lights does not count).
    pub light_updates: Counter,
    /// Light writes replaced by a newer write to the same session before they were stored:
    /// dropped, never stored or solved (their callers are answered with the newer version).
    pub light_writes_merged: Counter,
    /// Requests refused: bad input, unknown names, missing token, limits.
    pub requests_refused: Family<TransportLabel, Counter>,
    pub scene_reloads: Family<ReloadLabel, Counter>,
    /// Connections turned away at the connection limit.
    pub connections_refused: Family<TransportLabel, Counter>,
    /// Time from accepting a light change to publishing the frame that answers it.
    pub update_to_frame_seconds: Histogram,
    /// Store commits (each may carry several sessions' writes).
    pub store_commit_seconds: Histogram,
    /// Frames encoded with a value RGB9E5 cannot hold, by the frame flag set: `clamped` (above
    /// its maximum, written as the maximum) or `non_finite` (NaN or infinite). A viewer sees
    /// the same bits in the frame header; this makes them visible to an operator.
    pub frames_flagged: Family<FlagLabel, Counter>,
}

#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
pub enum FrameFlag {
    Clamped,
    NonFinite,
}

impl EncodeLabelValue for FrameFlag {
    fn encode(&self, encoder: &mut LabelValueEncoder) -> Result<(), std::fmt::Error> {
        let s = match self {
            FrameFlag::Clamped => "clamped",
            FrameFlag::NonFinite => "non_finite",
        };
        EncodeLabelValue::encode(&s, encoder)
    }
}

#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct FlagLabel {
    pub flag: FrameFlag,
}

impl Metrics {
    pub fn new() -> Metrics {
        let mut registry = Registry::with_prefix("bounce");
        // A gauge rather than an info metric: the engine is known only once the worker opened
        // it, after the registry is shared.
        let engine = Family::<EngineLabel, Gauge>::default();
        registry.register("engine", "The relight engine in use (1)", engine.clone());
        let relight_seconds =
            Family::<SceneLabel, Histogram>::new_with_constructor(|| Histogram::new(seconds()));
        registry.register(
            "relight_seconds",
            "Engine time of one relight batch",
            relight_seconds.clone(),
        );
        let batch_size = Family::<SceneLabel, Histogram>::new_with_constructor(|| {
            Histogram::new(exponential_buckets(1.0, 2.0, 8))
        });
        registry.register(
            "relight_batch_size",
            "Light sets solved in one engine call",
            batch_size.clone(),
        );
        let frames_sent = Family::<TransportLabel, Counter>::default();
        registry.register("frames_sent", "Frames sent to viewers", frames_sent.clone());
        let stale_frames_skipped = Family::<TransportLabel, Counter>::default();
        registry.register(
            "stale_frames_skipped",
            "Frames a slow viewer skipped because a newer one was ready",
            stale_frames_skipped.clone(),
        );
        let viewers = Family::<TransportLabel, Gauge>::default();
        registry.register("viewers", "Frame streams open now", viewers.clone());
        let sessions = Gauge::default();
        registry.register("sessions", "Sessions held", sessions.clone());
        let sessions_expired = Counter::default();
        registry.register(
            "sessions_expired",
            "Sessions removed after nobody watched or wrote for the expiry time",
            sessions_expired.clone(),
        );
        let sessions_refused = Family::<SessionLimitLabel, Counter>::default();
        registry.register(
            "sessions_refused",
            "New sessions refused at a session cap (total, or per client address)",
            sessions_refused.clone(),
        );
        let worker_restarts = Counter::default();
        registry.register(
            "worker_restarts",
            "Engine worker restarts after a panic or a GPU fault",
            worker_restarts.clone(),
        );
        let websocket_unresponsive = Counter::default();
        registry.register(
            "websocket_unresponsive",
            "WebSockets closed because their client answered no ping or took no frame within the keep-alive period",
            websocket_unresponsive.clone(),
        );
        let relight_retries = Counter::default();
        registry.register(
            "relight_retries",
            "Session relights that failed and were queued again",
            relight_retries.clone(),
        );
        let light_updates = Counter::default();
        registry.register(
            "light_updates",
            "Light changes accepted",
            light_updates.clone(),
        );
        let light_writes_merged = Counter::default();
        registry.register(
            "light_writes_merged",
            "Light writes replaced by a newer write to the same session before they were stored",
            light_writes_merged.clone(),
        );
        let requests_refused = Family::<TransportLabel, Counter>::default();
        registry.register(
            "requests_refused",
            "Requests refused (bad input, unknown names, missing token, limits)",
            requests_refused.clone(),
        );
        let scene_reloads = Family::<ReloadLabel, Counter>::default();
        registry.register(
            "scene_reloads",
            "Baked files reloaded while serving, by outcome",
            scene_reloads.clone(),
        );
        let connections_refused = Family::<TransportLabel, Counter>::default();
        registry.register(
            "connections_refused",
            "Connections closed at once because the connection limit was reached",
            connections_refused.clone(),
        );
        let update_to_frame_seconds = Histogram::new(seconds());
        registry.register(
            "update_to_frame_seconds",
            "From accepting a light change to publishing its frame",
            update_to_frame_seconds.clone(),
        );
        let store_commit_seconds = Histogram::new(seconds());
        registry.register(
            "store_commit_seconds",
            "Durable session-store commits",
            store_commit_seconds.clone(),
        );
        let frames_flagged = Family::<FlagLabel, Counter>::default();
        registry.register(
            "frames_flagged",
            "Frames with a value past RGB9E5's range (clamped) or not finite, by frame flag",
            frames_flagged.clone(),
        );
        Metrics {
            registry,
            engine,
            relight_seconds,
            batch_size,
            frames_sent,
            stale_frames_skipped,
            viewers,
            sessions,
            sessions_expired,
            sessions_refused,
            worker_restarts,
            relight_retries,
            websocket_unresponsive,
            light_updates,
            light_writes_merged,
            requests_refused,
            scene_reloads,
            connections_refused,
            update_to_frame_seconds,
            store_commit_seconds,
            frames_flagged,
        }
    }

    /// Counts a frame's header flags (see [`crate::frame::FLAG_CLAMPED`]).
    pub fn count_frame_flags(&self, flags: u32) {
        for (bit, flag) in [
            (crate::frame::FLAG_CLAMPED, FrameFlag::Clamped),
            (crate::frame::FLAG_NON_FINITE, FrameFlag::NonFinite),
        ] {
            if flags & bit != 0 {
                self.frames_flagged.get_or_create(&FlagLabel { flag }).inc();
            }
        }
    }

    /// The Prometheus text exposition (content type [`CONTENT_TYPE`]).
    pub fn encode(&self) -> String {
        let mut out = String::new();
        // Writing into a String cannot fail.
        let _ = prometheus_client::encoding::text::encode(&mut out, &self.registry);
        out
    }

    pub fn transport(t: Transport) -> TransportLabel {
        TransportLabel { transport: t }
    }
}

/// 0.25 ms .. ~4 s: a CPU batch of pandora takes a few ms, a cold GPU upload seconds.
fn seconds() -> impl Iterator<Item = f64> {
    exponential_buckets(0.00025, 2.0, 15)
}

impl Default for Metrics {
    fn default() -> Metrics {
        Metrics::new()
    }
}

/// The content type of [`Metrics::encode`]'s output.
pub const CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encodes_what_was_counted() {
        let m = Metrics::new();
        m.engine
            .get_or_create(&EngineLabel {
                engine: "cpu (2 threads)".into(),
            })
            .set(1);
        m.frames_sent
            .get_or_create(&Metrics::transport(Transport::Websocket))
            .inc_by(3);
        m.relight_seconds
            .get_or_create(&SceneLabel {
                scene: "cornell-box".into(),
            })
            .observe(0.004);
        let text = m.encode();
        assert!(
            text.contains(r#"bounce_frames_sent_total{transport="websocket"} 3"#),
            "{text}"
        );
        assert!(text.contains(r#"bounce_engine{engine="cpu (2 threads)"} 1"#));
        assert!(text.contains(r#"bounce_relight_seconds_count{scene="cornell-box"} 1"#));
        assert!(text.trim_end().ends_with("# EOF"));
    }
}
