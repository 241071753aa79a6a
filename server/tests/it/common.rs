//! What the server tests share: a small Cornell box baked once per test binary, a real server
//! on `127.0.0.1:0` with the CPU engine, and tonic client helpers.

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
pub use bounce_server::{Hub, HubConfig, serve_grpc};
pub use tokio::net::TcpListener;
pub use tokio::sync::oneshot;
pub use tokio::task::JoinHandle;
pub use tonic::transport::Channel;
pub use tonic::{Code, Status, Streaming};

pub const SCENE: &str = "cornell-box";
/// Long enough for a loaded CI machine, short enough to fail rather than hang.
pub const PATIENCE: Duration = Duration::from_secs(60);

/// A directory holding `cornell-box.bounce`, baked once per test binary at about 300 patches.
pub fn scenes_dir() -> PathBuf {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::tempdir().expect("tempdir");
        let gltf =
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box/scene.gltf");
        let options = BakeOptions {
            resolution: Resolution::TargetPatches(300),
            rays: 512,
            ..BakeOptions::default()
        };
        let baked = bake_file(&gltf, &options, &NoProgress).expect("baking the Cornell box");
        baked
            .write_atomic(&dir.path().join(format!("{SCENE}.bounce")))
            .expect("writing the baked file");
        // Not a baked file: must be skipped, not fatal.
        std::fs::write(dir.path().join("broken.bounce"), b"not a baked file").expect("write");
        dir
    })
    .path()
    .to_path_buf()
}

pub fn baked() -> Baked {
    Baked::read(&scenes_dir().join(format!("{SCENE}.bounce"))).expect("reading the baked file")
}

pub struct TestServer {
    pub hub: Hub,
    pub addr: std::net::SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: JoinHandle<Result<(), bounce_server::ServerError>>,
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
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(serve_grpc(hub.clone(), listener, async {
            let _ = stopped.await;
        }));
        TestServer {
            hub,
            addr,
            stop: Some(stop),
            task,
        }
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

    /// Graceful shutdown: must end open streams and return.
    pub async fn stop(mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        tokio::time::timeout(PATIENCE, self.task)
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
