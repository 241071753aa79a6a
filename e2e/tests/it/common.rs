//! What the client tests share: a small Cornell box baked once per test binary, and a real
//! server on loopback (gRPC) that can be stopped and started again on the same port.

pub use std::net::SocketAddr;
pub use std::path::PathBuf;
pub use std::sync::OnceLock;
pub use std::time::Duration;

pub use bounce_client::*;
pub use bounce_core::format::Baked;
pub use bounce_engine::EngineChoice;
pub use bounce_server::{Hub, HubConfig, Listeners};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

pub const SCENE: &str = "cornell-box";
/// Long enough for a loaded CI machine, short enough to fail rather than hang.
pub const PATIENCE: Duration = Duration::from_secs(60);

/// A directory holding `cornell-box.bounce`, baked once per test binary at about 300 patches.
pub fn scenes_dir() -> PathBuf {
    // In cargo's target tmp directory, written afresh on each run (so it is always this build's
    // format): a temporary directory held in a static is never dropped, and would stay in /tmp.
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("client-it-scenes");
        std::fs::create_dir_all(&dir).expect("creating the scenes directory");
        let baked = bounce_testkit::fixtures::baked_cornell_box(300);
        baked
            .write_atomic(&dir.join(format!("{SCENE}.bounce")))
            .expect("writing the baked file");
        dir
    })
    .clone()
}

pub fn baked() -> Baked {
    Baked::read(&scenes_dir().join(format!("{SCENE}.bounce"))).expect("reading the baked file")
}

pub fn config() -> HubConfig {
    HubConfig::new(scenes_dir(), EngineChoice::Cpu)
}

pub struct TestServer {
    pub addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: JoinHandle<Result<(), bounce_server::ServerError>>,
}

impl TestServer {
    /// A server on the shared scene directory, sessions in memory, no token.
    pub async fn start() -> TestServer {
        TestServer::start_with(config()).await
    }

    pub async fn start_with(config: HubConfig) -> TestServer {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        TestServer::serve(config, listener).await
    }

    /// On a given address, as a restarted server is: the old listener may take a moment to let
    /// go of the port.
    pub async fn start_on(config: HubConfig, addr: SocketAddr) -> TestServer {
        let deadline = tokio::time::Instant::now() + PATIENCE;
        let listener = loop {
            match TcpListener::bind(addr).await {
                Ok(l) => break l,
                Err(e) if tokio::time::Instant::now() < deadline => {
                    eprintln!("binding {addr} again: {e}; retrying");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
                Err(e) => panic!("binding {addr} again: {e}"),
            }
        };
        TestServer::serve(config, listener).await
    }

    async fn serve(config: HubConfig, listener: TcpListener) -> TestServer {
        let hub = tokio::task::spawn_blocking(move || Hub::start(&config))
            .await
            .expect("join")
            .expect("hub");
        let addr = listener.local_addr().expect("addr");
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(bounce_server::run(
            hub,
            Listeners::grpc_only(listener),
            async {
                let _ = stopped.await;
            },
        ));
        TestServer {
            addr,
            stop: Some(stop),
            task,
        }
    }

    pub fn grpc_url(&self) -> String {
        format!("http://{}", self.addr)
    }

    pub async fn client(&self) -> Client {
        Client::connect(self.grpc_url()).await.expect("connect")
    }

    /// Graceful shutdown: ends open streams, returns once the port is released.
    pub async fn stop(mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        tokio::time::timeout(PATIENCE, &mut self.task)
            .await
            .expect("shutdown timed out")
            .expect("join")
            .expect("serve");
    }
}

impl Drop for TestServer {
    fn drop(&mut self) {
        self.task.abort();
    }
}

pub fn point(intensity: f32) -> LightSet {
    LightSet {
        lights: vec![Light::Point {
            position: [0.0, 1.0, 0.0],
            color: [1.0, 0.9, 0.8],
            intensity,
            range: None,
            name: None,
        }],
    }
}

/// Reads frames until one answers `version`; checks their order on the way.
pub async fn read_until(stream: &mut FrameStream, version: u64) -> Frame {
    let read = async {
        let mut last: Option<FrameHeader> = None;
        loop {
            let frame = stream
                .next()
                .await
                .expect("a frame")
                .unwrap_or_else(|| panic!("stream ended before version {version}"));
            if let Some(l) = last {
                assert!(
                    frame.header.sequence > l.sequence,
                    "{:?} after {l:?}",
                    frame.header
                );
                assert!(frame.header.lights_version >= l.lights_version);
            }
            last = Some(frame.header);
            if frame.header.lights_version >= version {
                return frame;
            }
        }
    };
    tokio::time::timeout(PATIENCE, read)
        .await
        .unwrap_or_else(|_| panic!("no frame for version {version}"))
}

#[track_caller]
pub fn assert_refused<T: std::fmt::Debug>(
    result: Result<T, ClientError>,
    code: Refusal,
    contains: &str,
) {
    match result {
        Ok(v) => panic!("expected a {code} refusal, got {v:?}"),
        Err(e) => {
            assert_eq!(e.refusal(), Some(&code), "{e}");
            assert!(e.to_string().contains(contains), "{e} lacks {contains:?}");
            assert!(!e.is_transient(), "{e}");
        }
    }
}
