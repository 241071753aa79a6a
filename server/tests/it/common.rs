//! What the server tests share: a small Cornell box baked once per test binary, a real server
//! (gRPC and HTTP, each on its own `127.0.0.1:0`) with the CPU engine, tonic client helpers and a
//! WebSocket client.

pub use std::path::PathBuf;
pub use std::sync::OnceLock;
pub use std::time::{Duration, Instant};

pub use bounce_core::bake::{BakeOptions, NoProgress, bake_file};
pub use bounce_core::format::Baked;
pub use bounce_core::light::{Light, LightSet};
pub use bounce_core::voxel::Resolution;
pub use bounce_engine::{Engine, EngineChoice};
pub use bounce_server::frame::Frame;
pub use bounce_server::proto::bounce_client::BounceClient;
pub use bounce_server::proto::{self, Light as PbLight};
pub use bounce_server::{Hub, HubConfig, Listeners};
pub use tokio::net::TcpListener;
pub use tokio::sync::watch;
pub use tokio::task::JoinHandle;
pub use tonic::transport::Channel;
pub use tonic::{Code, Status, Streaming};

pub const SCENE: &str = "cornell-box";
/// Long enough for a loaded CI machine, short enough to fail rather than hang.
pub const PATIENCE: Duration = Duration::from_secs(60);

/// A directory holding `cornell-box.bounce`, baked once per test binary at about 300 patches,
/// with probes.
pub fn scenes_dir() -> PathBuf {
    // In cargo's target tmp directory, written afresh on each run (so it is always this build's
    // format): a temporary directory held in a static is never dropped, and would stay in /tmp.
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("server-it-scenes");
        std::fs::create_dir_all(&dir).expect("creating the scenes directory");
        // As the testkit's box, with irradiance probes, so every test runs against a scene that
        // has them (a client that did not ask for probe frames must not see one).
        let options = BakeOptions {
            resolution: Resolution::TargetPatches(300),
            rays: 512,
            probes: Some(bounce_core::probe::ProbeOptions {
                spacing: None,
                rays: 256,
            }),
            ..BakeOptions::default()
        };
        let mut baked = bake_file(&bounce_testkit::cornell_gltf(), &options, &NoProgress)
            .expect("baking the Cornell box");
        // As `bounce bake` keeps it: the browser page's model.
        baked.model = Some(
            bounce_core::import::pack_glb(&bounce_testkit::cornell_gltf())
                .expect("packing the model"),
        );
        baked
            .write_atomic(&dir.join(format!("{SCENE}.bounce")))
            .expect("writing the baked file");
        // Not a baked file: must be skipped, not fatal.
        std::fs::write(dir.join("broken.bounce"), b"not a baked file").expect("write");
        dir
    })
    .clone()
}

pub fn baked() -> Baked {
    Baked::read(&scenes_dir().join(format!("{SCENE}.bounce"))).expect("reading the baked file")
}

pub struct TestServer {
    pub hub: Hub,
    /// The gRPC address.
    pub addr: std::net::SocketAddr,
    pub http_addr: std::net::SocketAddr,
    stop: watch::Sender<bool>,
    served: JoinHandle<Result<(), bounce_server::ServerError>>,
}

impl TestServer {
    /// A server on the shared scene directory, sessions in memory, no token.
    pub async fn start() -> TestServer {
        TestServer::start_with(HubConfig::new(scenes_dir(), EngineChoice::Cpu)).await
    }

    pub async fn start_with(config: HubConfig) -> TestServer {
        let hub = tokio::task::spawn_blocking(move || Hub::start(&config))
            .await
            .expect("join")
            .expect("hub");
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        let http_listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let http_addr = http_listener.local_addr().expect("addr");
        // Both front ends under one stop, as `bounce serve` runs them.
        let stop = watch::Sender::new(false);
        let mut stopped = stop.subscribe();
        let served = tokio::spawn(bounce_server::run(
            hub.clone(),
            Listeners::both(listener, http_listener),
            async move {
                let _ = stopped.wait_for(|&s| s).await;
            },
        ));
        TestServer {
            hub,
            addr,
            http_addr,
            stop,
            served,
        }
    }

    /// `http://ADDR/PATH` on the HTTP front end.
    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.http_addr)
    }

    /// A client on its own connection, as separate viewers are.
    pub async fn client(&self) -> BounceClient<Channel> {
        BounceClient::new(self.channel().await)
    }

    pub async fn channel(&self) -> Channel {
        Channel::from_shared(format!("http://{}", self.addr))
            .expect("uri")
            .connect()
            .await
            .expect("connect")
    }

    /// Graceful shutdown: must end open streams and sockets, and both front ends return.
    pub async fn stop(self) {
        self.stop.send_replace(true);
        tokio::time::timeout(PATIENCE, self.served)
            .await
            .expect("shutdown timed out")
            .expect("join")
            .expect("serve");
    }
}

pub fn point(intensity: f32) -> PbLight {
    PbLight {
        r#type: "point".into(),
        position: vec![0.0, 1.0, 0.0],
        color: vec![1.0, 0.9, 0.8],
        intensity: Some(intensity),
        ..Default::default()
    }
}

pub async fn create_session(c: &mut BounceClient<Channel>, lights: Vec<PbLight>) -> (String, u64) {
    let r = c
        .create_session(proto::CreateSessionRequest {
            scene: SCENE.into(),
            lights,
        })
        .await
        .expect("create session")
        .into_inner();
    (r.session_id, r.lights_version)
}

pub async fn subscribe(c: &mut BounceClient<Channel>, id: &str) -> Streaming<proto::Frame> {
    c.subscribe(proto::SubscribeRequest {
        session_id: id.into(),
    })
    .await
    .expect("subscribe")
    .into_inner()
}

/// The first frame of `stream` answering `version` or a later one.
pub async fn frame_answering(stream: &mut Streaming<proto::Frame>, version: u64) -> proto::Frame {
    loop {
        let f = tokio::time::timeout(PATIENCE, stream.message())
            .await
            .expect("a frame in time")
            .expect("stream")
            .expect("a frame");
        if f.lights_version >= version {
            return f;
        }
    }
}

/// `got` (a frame's values) is `want` (the engine's) within RGB9E5's step: a ninth bit of the
/// largest channel, the smallest step, and a hair for summation order.
#[track_caller]
pub fn assert_within_rgb9e5_step(got: &[[f32; 3]], want: &[[f32; 3]]) {
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(want) {
        let max = w.iter().fold(0.0f64, |m, &x| m.max(f64::from(x)));
        let bound = max / 511.0 + 2f64.powi(-25) + 1e-5 * max;
        for k in 0..3 {
            assert!(
                (f64::from(g[k]) - f64::from(w[k])).abs() <= bound,
                "{g:?} vs {w:?}"
            );
        }
    }
}

/// Reads frames until one answers `version`; checks order on the way and returns the
/// (sequence, version) of every frame seen.
pub async fn read_until(stream: &mut Streaming<proto::Frame>, version: u64) -> Vec<(u64, u64)> {
    let mut seen: Vec<(u64, u64)> = Vec::new();
    let read = async {
        while let Some(f) = stream.message().await.expect("frame") {
            let parsed = Frame::parse(f.data.clone()).expect("frame bytes");
            assert_eq!(parsed.header.sequence, f.sequence);
            assert_eq!(parsed.header.lights_version, f.lights_version);
            if let Some(&(seq, ver)) = seen.last() {
                assert!(f.sequence > seq, "sequence {} after {seq}", f.sequence);
                assert!(
                    f.lights_version > ver,
                    "version {} after {ver}",
                    f.lights_version
                );
            }
            seen.push((f.sequence, f.lights_version));
            if f.lights_version >= version {
                return;
            }
        }
        panic!("stream ended before version {version}: saw {seen:?}");
    };
    tokio::time::timeout(PATIENCE, read)
        .await
        .unwrap_or_else(|_| panic!("no frame for version {version}"));
    seen
}

#[track_caller]
pub fn assert_status(result: Result<impl std::fmt::Debug, Status>, code: Code, contains: &str) {
    match result {
        Ok(v) => panic!("expected {code:?}, got {v:?}"),
        Err(s) => {
            assert_eq!(s.code(), code, "{s:?}");
            assert!(
                s.message().contains(contains),
                "{:?} does not contain {contains:?}",
                s.message()
            );
        }
    }
}

pub type WsStream = tokio_tungstenite::WebSocketStream<MaybeTlsStream<tokio::net::TcpStream>>;
pub use futures_util::{SinkExt as _, StreamExt as _};
pub use serde_json::{Value, json};
pub use tokio_tungstenite::MaybeTlsStream;
pub use tokio_tungstenite::tungstenite::Message as WsMessage;

impl TestServer {
    /// The WebSocket URL of session `id`, with `?token=` when given.
    pub fn ws_url(&self, id: &str, token: Option<&str>) -> String {
        let query = token.map(|t| format!("?token={t}")).unwrap_or_default();
        format!("ws://{}/v1/sessions/{id}/ws{query}", self.http_addr)
    }

    /// A session made over HTTP with one point light; returns its id.
    pub async fn http_session(&self, http: &reqwest::Client, intensity: f32) -> String {
        let r = http
            .post(self.url("/v1/sessions"))
            .json(&json!({"scene": SCENE, "lights": [json_point(intensity)]}))
            .send()
            .await
            .expect("POST /v1/sessions");
        assert_eq!(r.status(), reqwest::StatusCode::CREATED);
        let body: Value = r.json().await.expect("json");
        body["session_id"].as_str().expect("session_id").to_string()
    }
}

/// The JSON twin of [`point`].
pub fn json_point(intensity: f32) -> Value {
    json!({"type": "point", "position": [0, 1, 0], "color": [1, 0.9, 0.8], "intensity": intensity})
}

/// What a WebSocket client reads.
#[derive(Debug)]
pub enum WsEvent {
    Text(Value),
    Frame(Frame),
    /// A close frame's code and reason (`None`: the stream ended without one).
    Closed(Option<(u16, String)>),
    /// The connection failed (reset, protocol error); read in panic messages.
    Failed(#[allow(dead_code)] String),
}

/// A WebSocket client of one session that checks every frame it reads: a sequence always above
/// the last, a lights version never below it.
pub struct WsClient {
    pub stream: WsStream,
    /// The server's first message.
    pub hello: Value,
    /// (sequence, lights version) of every frame read.
    pub frames: Vec<(u64, u64)>,
    pub last: Option<Frame>,
}

impl WsClient {
    pub async fn connect(url: &str) -> WsClient {
        let (stream, _) = tokio_tungstenite::connect_async(url)
            .await
            .expect("WebSocket connect");
        WsClient::over(stream).await
    }

    /// A client over a connected stream; reads the hello.
    pub async fn over(stream: WsStream) -> WsClient {
        let mut c = WsClient {
            stream,
            hello: Value::Null,
            frames: Vec::new(),
            last: None,
        };
        match c.next().await {
            WsEvent::Text(v) if v["type"] == "hello" => c.hello = v,
            other => panic!("expected hello, got {other:?}"),
        }
        c
    }

    pub async fn next(&mut self) -> WsEvent {
        loop {
            let message = tokio::time::timeout(PATIENCE, self.stream.next())
                .await
                .expect("no WebSocket message in time");
            return match message {
                None => WsEvent::Closed(None),
                Some(Err(e)) => WsEvent::Failed(e.to_string()),
                Some(Ok(WsMessage::Text(t))) => {
                    WsEvent::Text(serde_json::from_str(t.as_str()).expect("JSON text message"))
                }
                Some(Ok(WsMessage::Binary(b))) => {
                    let f = Frame::parse(b).expect("frame bytes");
                    self.record(&f);
                    WsEvent::Frame(f)
                }
                Some(Ok(WsMessage::Close(c))) => {
                    WsEvent::Closed(c.map(|c| (u16::from(c.code), c.reason.to_string())))
                }
                Some(Ok(_)) => continue,
            };
        }
    }

    fn record(&mut self, f: &Frame) {
        let (seq, ver) = (f.header.sequence, f.header.lights_version);
        if let Some(&(last_seq, last_ver)) = self.frames.last() {
            assert!(seq > last_seq, "sequence {seq} after {last_seq}");
            assert!(ver >= last_ver, "lights version {ver} after {last_ver}");
        }
        self.frames.push((seq, ver));
        self.last = Some(f.clone());
    }

    /// Reads frames until one answers `version`.
    pub async fn frames_until(&mut self, version: u64) {
        if self.frames.last().is_some_and(|&(_, v)| v >= version) {
            return;
        }
        loop {
            match self.next().await {
                WsEvent::Frame(f) if f.header.lights_version >= version => return,
                WsEvent::Frame(_) => {}
                other => panic!("waiting for version {version}: {other:?}"),
            }
        }
    }

    pub async fn send(&mut self, v: Value) {
        self.stream
            .send(WsMessage::text(v.to_string()))
            .await
            .expect("WebSocket send");
    }

    /// Sends `v` and returns the next text message; frames read meanwhile are checked.
    pub async fn request(&mut self, v: Value) -> Value {
        self.send(v).await;
        loop {
            match self.next().await {
                WsEvent::Text(t) => return t,
                WsEvent::Frame(_) => {}
                other => panic!("expected an answer: {other:?}"),
            }
        }
    }

    /// Reads past frames to the error message, if any, and the close frame: (error, close code,
    /// reason).
    pub async fn refused(&mut self) -> (Value, u16, String) {
        let mut error = Value::Null;
        loop {
            match self.next().await {
                WsEvent::Frame(_) => {}
                WsEvent::Text(t) => {
                    assert_eq!(t["type"], "error", "{t}");
                    error = t;
                }
                WsEvent::Closed(Some((code, reason))) => return (error, code, reason),
                other => panic!("expected a close frame: {other:?} (error {error})"),
            }
        }
    }
}
