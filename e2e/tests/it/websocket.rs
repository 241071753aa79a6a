//! The client over WebSocket and the HTTP JSON routes against a real server's HTTP front end
//! (`bounce_server::serve_http`): the same calls as gRPC give the same answers, refusals keep
//! their codes, and the watcher reconnects over WebSocket as it does over gRPC.

use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::common::*;

/// One hub served over gRPC and HTTP/WebSocket at once, as `bounce serve` does.
struct BothServer {
    grpc: SocketAddr,
    http: SocketAddr,
    stop: watch::Sender<bool>,
    tasks: Vec<JoinHandle<Result<(), bounce_server::ServerError>>>,
}

impl BothServer {
    async fn start(config: HubConfig) -> BothServer {
        BothServer::start_on(config, "127.0.0.1:0".parse().expect("addr")).await
    }

    /// HTTP on `http` (port 0: any), gRPC on any port.
    async fn start_on(config: HubConfig, http: SocketAddr) -> BothServer {
        let hub = tokio::task::spawn_blocking(move || Hub::start(&config))
            .await
            .expect("join")
            .expect("hub");
        let deadline = tokio::time::Instant::now() + PATIENCE;
        let http_listener = loop {
            match TcpListener::bind(http).await {
                Ok(l) => break l,
                Err(e) if tokio::time::Instant::now() < deadline => {
                    eprintln!("binding {http} again: {e}; retrying");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
                Err(e) => panic!("binding {http}: {e}"),
            }
        };
        let grpc_listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let (stop, mut stopped) = watch::channel(false);
        BothServer {
            grpc: grpc_listener.local_addr().expect("addr"),
            http: http_listener.local_addr().expect("addr"),
            tasks: vec![tokio::spawn(bounce_server::run(
                hub,
                Listeners::both(grpc_listener, http_listener),
                async move {
                    let _ = stopped.wait_for(|s| *s).await;
                },
            ))],
            stop,
        }
    }

    /// `bounce_frames_sent_total{transport="websocket"}` from the server's `/metrics`.
    async fn frames_sent_over_websocket(&self) -> u64 {
        let http = self.http;
        let text = tokio::task::spawn_blocking(move || {
            use std::io::{Read, Write};
            let mut stream = std::net::TcpStream::connect(http).expect("connect for /metrics");
            stream
                .write_all(b"GET /metrics HTTP/1.1\r\nHost: bounce\r\nConnection: close\r\n\r\n")
                .expect("send GET /metrics");
            let mut text = String::new();
            stream.read_to_string(&mut text).expect("read /metrics");
            text
        })
        .await
        .expect("join");
        text.lines()
            .find_map(|l| l.strip_prefix(r#"bounce_frames_sent_total{transport="websocket"} "#))
            .map_or(0, |n| n.trim().parse().expect("a count"))
    }

    fn ws_url(&self) -> String {
        format!("ws://{}", self.http)
    }

    async fn ws(&self) -> Client {
        let client = Client::connect(self.ws_url()).await.expect("connect");
        assert_eq!(client.scheme(), Scheme::WebSocket);
        client
    }

    async fn grpc(&self) -> Client {
        Client::connect(format!("http://{}", self.grpc))
            .await
            .expect("connect")
    }

    async fn stop(mut self) {
        self.stop.send_replace(true);
        for task in self.tasks.drain(..) {
            tokio::time::timeout(PATIENCE, task)
                .await
                .expect("shutdown timed out")
                .expect("join")
                .expect("serve");
        }
    }
}

impl Drop for BothServer {
    fn drop(&mut self) {
        for task in &self.tasks {
            task.abort();
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn websocket_calls_answer_as_grpc_does() {
    let server = BothServer::start(config()).await;
    let ws = server.ws().await;
    let grpc = server.grpc().await;
    let layout = ws.get_layout(SCENE).await.expect("layout over HTTP");
    assert_eq!(
        layout,
        grpc.get_layout(SCENE).await.expect("layout over gRPC")
    );

    let session = ws
        .create_session(SCENE, &point(5.0))
        .await
        .expect("session");
    assert_eq!(session.lights_version, 1);
    let mut over_ws = ws.subscribe(&session.id).await.expect("subscribe");
    let mut over_grpc = grpc.subscribe(&session.id).await.expect("subscribe");
    let a = read_until(&mut over_ws, 1).await;
    let b = read_until(&mut over_grpc, 1).await;
    assert_eq!(a, b, "one frame, one byte layout on both transports");
    let mut volume = Volume::new(&layout).expect("volume");
    volume.apply(&a).expect("apply");

    let sent_before = server.frames_sent_over_websocket().await;
    let change = ws
        .set_lights(&session.id, &point(20.0))
        .await
        .expect("set lights over HTTP");
    assert_eq!(
        change,
        LightsChange {
            lights_version: 2,
            changed: true
        }
    );
    assert_eq!(read_until(&mut over_ws, 2).await.header.lights_version, 2);
    assert_eq!(read_until(&mut over_grpc, 2).await.header.lights_version, 2);
    let same = ws
        .set_lights(&session.id, &point(20.0))
        .await
        .expect("set lights");
    assert!(!same.changed);
    assert_eq!(same.lights_version, 2);
    // A change is one PUT, not a session socket of its own: the only frame sent over WebSocket
    // meanwhile is the subscriber's new one (a socket would have been sent the newest at once).
    assert_eq!(server.frames_sent_over_websocket().await, sent_before + 1);

    // A viewer joining the session reads its lights (for direct light) on either transport.
    let read_ws = ws
        .get_session(&session.id)
        .await
        .expect("session over HTTP");
    let read_grpc = grpc
        .get_session(&session.id)
        .await
        .expect("session over gRPC");
    assert_eq!(read_ws, read_grpc);
    assert_eq!(
        (
            read_ws.scene.as_str(),
            read_ws.lights_version,
            &read_ws.lights
        ),
        (SCENE, 2, &point(20.0))
    );
    for client in [&ws, &grpc] {
        let err = client.get_session("no-such-session").await.unwrap_err();
        assert_eq!(err.refusal(), Some(&Refusal::NotFound), "{err}");
    }
    over_ws.close().await;
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn websocket_refusals_keep_their_codes() {
    let mut config = config();
    config.token = Some("s3cret".into());
    let server = BothServer::start(config).await;
    let anonymous = server.ws().await;
    let writer = Client::connect(ClientConfig::new(server.ws_url()).with_token("s3cret"))
        .await
        .expect("connect");
    assert_refused(
        anonymous.get_layout("no-such-scene").await,
        Refusal::NotFound,
        "no-such-scene",
    );
    assert_refused(
        anonymous.create_session(SCENE, &point(1.0)).await,
        Refusal::Unauthenticated,
        "token",
    );
    assert_refused(
        writer.create_session(SCENE, &point(-2.0)).await,
        Refusal::InvalidArgument,
        "lights[0].intensity",
    );
    assert_refused(
        writer.subscribe("nobody").await.map(|_| ()),
        Refusal::NotFound,
        "nobody",
    );
    let session = writer
        .create_session(SCENE, &point(1.0))
        .await
        .expect("with the token");
    assert_refused(
        anonymous.set_lights(&session.id, &point(2.0)).await,
        Refusal::Unauthenticated,
        "token",
    );
    assert_refused(
        writer.set_lights(&session.id, &point(-2.0)).await,
        Refusal::InvalidArgument,
        "lights[0].intensity",
    );
    assert_refused(
        writer.set_lights("nobody", &point(2.0)).await,
        Refusal::NotFound,
        "nobody",
    );
    let change = writer
        .set_lights(&session.id, &point(2.0))
        .await
        .expect("with the token");
    assert_eq!(change.lights_version, 2);
    // Viewers need no token.
    let mut frames = anonymous.subscribe(&session.id).await.expect("subscribe");
    read_until(&mut frames, 2).await;
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_websocket_subscription_ends_cleanly_on_shutdown() {
    let server = BothServer::start(config()).await;
    let ws = server.ws().await;
    let session = ws
        .create_session(SCENE, &point(5.0))
        .await
        .expect("session");
    let mut frames = ws.subscribe(&session.id).await.expect("subscribe");
    read_until(&mut frames, 1).await;
    server.stop().await;
    let end = tokio::time::timeout(PATIENCE, frames.next())
        .await
        .expect("the stream ends");
    assert!(matches!(end, Ok(None)), "1001 is a clean end: {end:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_watcher_reconnects_over_websocket_after_a_restart() {
    let data = tempfile::tempdir().expect("tempdir");
    let durable = || {
        let mut c = config();
        c.data_dir = Some(data.path().to_path_buf());
        c
    };
    let first = BothServer::start(durable()).await;
    let addr = first.http;
    let session = first
        .ws()
        .await
        .create_session(SCENE, &point(5.0))
        .await
        .expect("session");
    let watcher = Watcher::spawn(first.ws_url(), session.id.clone());
    let mut frames = watcher.frames();
    let mut state = watcher.state();
    let before = tokio::time::timeout(PATIENCE, frames.wait_for(|f| f.is_some()))
        .await
        .expect("a first frame")
        .expect("watcher alive")
        .clone()
        .expect("a frame");
    frames.borrow_and_update();

    first.stop().await;
    tokio::time::timeout(
        PATIENCE,
        state.wait_for(|s| matches!(s, ConnectionState::Disconnected { .. })),
    )
    .await
    .expect("disconnected in time")
    .expect("watcher alive");
    assert_eq!(watcher.latest(), Some(before.clone()));

    let second = BothServer::start_on(durable(), addr).await;
    tokio::time::timeout(PATIENCE, frames.changed())
        .await
        .expect("a frame from the restarted server")
        .expect("watcher alive");
    let again = frames.borrow_and_update().clone().expect("a frame");
    assert_eq!(again.header.lights_version, 1);
    assert_eq!(again.irradiance(), before.irradiance());
    assert!(matches!(*state.borrow(), ConnectionState::Live { .. }));
    drop(watcher);
    second.stop().await;
}
