//! A session's life beyond one process and one file: stored across restarts, expired when idle,
//! kept through hot reloads of its scene (good and corrupted files), guarded by a write token.

use crate::common::*;

fn light_set(intensity: f32) -> LightSet {
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

/// A CPU hub serving `scenes` that stores its sessions under `data`.
fn stored(scenes: PathBuf, data: &std::path::Path) -> HubConfig {
    let mut c = HubConfig::new(scenes, EngineChoice::Cpu);
    c.data_dir = Some(data.to_path_buf());
    c
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_survive_a_restart_with_their_lights_and_version() {
    let data = tempfile::tempdir().expect("tempdir");
    let config = || stored(scenes_dir(), data.path());
    let first = TestServer::start_with(config()).await;
    let mut c = first.client().await;
    let (id, v1) = create_session(&mut c, vec![point(5.0)]).await;
    assert_eq!(v1, 1);
    let v = c
        .set_lights(proto::SetLightsRequest {
            session_id: id.clone(),
            lights: vec![point(12.0)],
            token: String::new(),
        })
        .await
        .expect("set lights")
        .into_inner();
    assert_eq!(v.lights_version, 2);
    let mut before = subscribe(&mut c, &id).await;
    let before = read_until(&mut before, 2).await;
    let before_frame = first.hub.session(&id).expect("session").subscribe();
    let before_data = before_frame
        .borrow()
        .clone()
        .expect("a frame")
        .bytes()
        .clone();
    assert!(!before.is_empty());
    first.stop().await;

    let second = TestServer::start_with(config()).await;
    let session = second.hub.session(&id).expect("the session came back");
    assert_eq!(session.lights_version(), 2);
    assert_eq!(session.lights(), light_set(12.0));
    let mut c = second.client().await;
    let mut frames = subscribe(&mut c, &id).await;
    let frame = tokio::time::timeout(PATIENCE, frames.message())
        .await
        .expect("a frame in time")
        .expect("stream")
        .expect("a frame");
    assert_eq!(frame.lights_version, 2);
    // Same lights, same matrix: the same frame body (the header's sequence restarts per run).
    let parsed = Frame::parse(frame.data.clone()).expect("frame");
    let old = Frame::parse(before_data).expect("frame");
    assert_eq!(parsed.irradiance(), old.irradiance());
    second.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_sessions_expire_and_watched_ones_stay() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.session_ttl = Duration::from_millis(300);
    config.reload_interval = None;
    let server = TestServer::start_with(config).await;
    let mut c = server.client().await;
    let (idle, _) = create_session(&mut c, vec![point(5.0)]).await;
    let (watched, _) = create_session(&mut c, vec![point(5.0)]).await;
    let mut stream = subscribe(&mut c, &watched).await;
    read_until(&mut stream, 1).await;

    let deadline = Instant::now() + PATIENCE;
    while server.hub.session(&idle).is_ok() {
        assert!(Instant::now() < deadline, "the idle session never expired");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Well past the TTL, the watched session is still there and still answers.
    tokio::time::sleep(Duration::from_millis(600)).await;
    let v = c
        .set_lights(proto::SetLightsRequest {
            session_id: watched.clone(),
            lights: vec![point(7.0)],
            token: String::new(),
        })
        .await
        .expect("the watched session stays")
        .into_inner();
    assert_eq!(v.lights_version, 2);
    assert_status(
        c.subscribe(proto::SubscribeRequest {
            session_id: idle.clone(),
        })
        .await,
        Code::NotFound,
        &idle,
    );
    let metrics = server.hub.metrics().encode();
    assert!(
        metrics.contains("bounce_sessions_expired_total 1"),
        "{metrics}"
    );
    drop(stream);
    server.stop().await;
}

/// The served file replaced by a different valid bake (fewer patches), then by garbage.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hot_reload_swaps_a_good_file_and_keeps_serving_through_a_bad_one() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join(format!("{SCENE}.bounce"));
    std::fs::copy(scenes_dir().join(format!("{SCENE}.bounce")), &file).expect("copy");
    let mut config = HubConfig::new(dir.path(), EngineChoice::Cpu);
    config.reload_interval = Some(Duration::from_millis(50));
    let server = TestServer::start_with(config).await;
    let mut c = server.client().await;
    let (id, _) = create_session(&mut c, vec![point(5.0)]).await;
    let mut stream = subscribe(&mut c, &id).await;
    let first = stream.message().await.expect("stream").expect("frame");
    let old_patches = Frame::parse(first.data).expect("frame").header.patch_count;

    // A different bake, written beside and renamed in, as a deploy would.
    let gltf = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box/scene.gltf");
    let options = BakeOptions {
        resolution: Resolution::TargetPatches(150),
        rays: 256,
        ..BakeOptions::default()
    };
    let smaller = tokio::task::spawn_blocking(move || bake_file(&gltf, &options, &NoProgress))
        .await
        .expect("join")
        .expect("bake");
    let new_patches = u32::try_from(smaller.layout.len()).expect("patches");
    assert_ne!(new_patches, old_patches);
    smaller.write_atomic(&file).expect("write");

    // The same session, same lights version, now answered on the new matrix.
    let frame = tokio::time::timeout(PATIENCE, stream.message())
        .await
        .expect("a frame after the reload")
        .expect("stream")
        .expect("frame");
    let parsed = Frame::parse(frame.data).expect("frame");
    assert_eq!(parsed.header.patch_count, new_patches);
    assert_eq!(frame.lights_version, 1);
    let layout = c
        .get_layout(proto::GetLayoutRequest {
            scene: SCENE.into(),
        })
        .await
        .expect("layout")
        .into_inner();
    assert_eq!(layout.patch_count, new_patches);

    // Garbage in place of the file: refused, counted, and the scene keeps serving.
    std::fs::write(&file, b"BNCE but not really a baked file").expect("write");
    let deadline = Instant::now() + PATIENCE;
    loop {
        let m = server.hub.metrics().encode();
        if m.contains(r#"bounce_scene_reloads_total{scene="cornell-box",outcome="failed"} 1"#) {
            assert!(
                m.contains(r#"bounce_scene_reloads_total{scene="cornell-box",outcome="ok"} 1"#),
                "{m}"
            );
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the bad file was never reported:\n{m}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    c.set_lights(proto::SetLightsRequest {
        session_id: id.clone(),
        lights: vec![point(9.0)],
        token: String::new(),
    })
    .await
    .expect("set lights after a bad reload");
    let frame = tokio::time::timeout(PATIENCE, stream.message())
        .await
        .expect("a frame")
        .expect("stream")
        .expect("frame");
    assert_eq!(frame.lights_version, 2);
    assert_eq!(
        Frame::parse(frame.data).expect("frame").header.patch_count,
        new_patches
    );
    drop(stream);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn writes_need_the_token_and_viewing_does_not() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.token = Some("s3cret".into());
    let server = TestServer::start_with(config).await;
    let mut c = server.client().await;
    let create = |token: Option<&str>| {
        let mut r = tonic::Request::new(proto::CreateSessionRequest {
            scene: SCENE.into(),
            lights: vec![point(5.0)],
        });
        if let Some(t) = token {
            r.metadata_mut().insert(
                "authorization",
                format!("Bearer {t}").parse().expect("metadata"),
            );
        }
        r
    };
    assert_status(
        c.create_session(create(None)).await,
        Code::Unauthenticated,
        "token",
    );
    assert_status(
        c.create_session(create(Some("guess"))).await,
        Code::Unauthenticated,
        "token",
    );
    let id = c
        .create_session(create(Some("s3cret")))
        .await
        .expect("with the token")
        .into_inner()
        .session_id;
    let set = |token: &str| proto::SetLightsRequest {
        session_id: id.clone(),
        lights: vec![point(8.0)],
        token: token.into(),
    };
    assert_status(c.set_lights(set("")).await, Code::Unauthenticated, "token");
    let v = c
        .set_lights(set("s3cret"))
        .await
        .expect("token in the message");
    assert_eq!(v.into_inner().lights_version, 2);
    // Read-only viewers need nothing.
    let mut stream = subscribe(&mut c, &id).await;
    read_until(&mut stream, 2).await;
    drop(stream);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_past_the_limit_are_closed_and_counted() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.max_connections = 2;
    let server = TestServer::start_with(config).await;
    let list = |mut c: BounceClient<Channel>| async move {
        c.list_scenes(proto::ListScenesRequest {}).await.map(|_| ())
    };
    let a = server.client().await;
    let b = server.client().await;
    list(a.clone()).await.expect("first connection");
    list(b.clone()).await.expect("second connection");
    // The third is accepted by the kernel, then closed by the server before HTTP/2 starts.
    let third = Channel::from_shared(format!("http://{}", server.addr))
        .expect("uri")
        .connect()
        .await;
    match third {
        Err(_) => {}
        Ok(ch) => assert!(list(BounceClient::new(ch)).await.is_err()),
    }
    let m = server.hub.metrics().encode();
    assert!(
        m.contains(r#"bounce_connections_refused_total{transport="grpc"}"#),
        "{m}"
    );
    // A closed connection frees its place.
    drop(a);
    let deadline = Instant::now() + PATIENCE;
    loop {
        let fresh = Channel::from_shared(format!("http://{}", server.addr))
            .expect("uri")
            .connect()
            .await;
        if let Ok(ch) = fresh
            && list(BounceClient::new(ch)).await.is_ok()
        {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the freed permit never came back"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    list(b).await.expect("the second connection still serves");
    server.stop().await;
}

/// Waits until the session has published `version`.
async fn published(hub: &Hub, id: &str, version: u64) {
    let session = hub.session(id).expect("session");
    let start = Instant::now();
    while session.published_version() < version {
        assert!(
            start.elapsed() < PATIENCE,
            "version {version} never published (at {})",
            session.published_version()
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// A worker whose batch panics (a driver fault, wgpu's panic on an error nothing caught) is
/// restarted: the session whose batch was lost still gets its frame, the server is ready again,
/// one-shot relights work, and the restart is counted. Before supervision the worker thread died
/// with the panic and the session never got its frame.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_panicking_engine_worker_is_restarted_and_its_sessions_solved() {
    let server = TestServer::start().await;
    let mut c = server.client().await;
    let (id, v1) = create_session(&mut c, vec![point(5.0)]).await;
    published(&server.hub, &id, v1).await;

    server.hub.inject_worker_panic();
    let v = c
        .set_lights(proto::SetLightsRequest {
            session_id: id.clone(),
            lights: vec![point(9.0)],
            token: String::new(),
        })
        .await
        .expect("set lights")
        .into_inner();
    assert_eq!(v.lights_version, 2);
    published(&server.hub, &id, 2).await;
    assert_eq!(server.hub.metrics().worker_restarts.get(), 1);
    assert!(server.hub.is_ready());
    let ready = reqwest::get(server.url("/readyz")).await.expect("readyz");
    assert_eq!(ready.status(), 200);
    let frame = server
        .hub
        .relight_once(SCENE, light_set(3.0))
        .await
        .expect("a one-shot relight after the restart");
    assert!(frame.irradiance().iter().flatten().any(|&v| v > 0.0));
    // And the restarted worker keeps serving later changes.
    c.set_lights(proto::SetLightsRequest {
        session_id: id.clone(),
        lights: vec![point(2.0)],
        token: String::new(),
    })
    .await
    .expect("set lights");
    published(&server.hub, &id, 3).await;
    server.stop().await;
}

/// A relight that fails (an engine error, no panic) is tried again for its session: the viewer
/// gets the frame for its change, and the retry is counted. Before, the session kept its old
/// frame until the next change.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failed_relight_is_retried() {
    let server = TestServer::start().await;
    let mut c = server.client().await;
    let (id, v1) = create_session(&mut c, vec![point(5.0)]).await;
    published(&server.hub, &id, v1).await;
    server.hub.inject_relight_failure();
    c.set_lights(proto::SetLightsRequest {
        session_id: id.clone(),
        lights: vec![point(7.0)],
        token: String::new(),
    })
    .await
    .expect("set lights");
    published(&server.hub, &id, 2).await;
    assert_eq!(server.hub.metrics().relight_retries.get(), 1);
    assert_eq!(server.hub.metrics().worker_restarts.get(), 0);
    server.stop().await;
}

/// A GPU engine that panics a second time gives way to the CPU engine: the server says so in
/// `/v1/scenes` and goes on solving (on lavapipe in CI).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gpu_worker_that_keeps_panicking_falls_back_to_the_cpu() {
    let config = HubConfig::new(scenes_dir(), EngineChoice::Gpu);
    let hub = match tokio::task::spawn_blocking(move || Hub::start(&config))
        .await
        .expect("join")
    {
        Ok(hub) => hub,
        Err(e) => {
            bounce_testkit::missing::<()>(bounce_testkit::Tool::GpuAdapter, e.to_string());
            return;
        }
    };
    assert!(hub.engine().starts_with("gpu"), "{}", hub.engine());
    let session = hub
        .create_session(SCENE, light_set(5.0), None)
        .await
        .expect("session");
    published(&hub, &session.id, 1).await;
    for (k, intensity) in [(2u64, 6.0f32), (3, 7.0)] {
        hub.inject_worker_panic();
        hub.set_lights(&session.id, light_set(intensity))
            .await
            .expect("set lights");
        published(&hub, &session.id, k).await;
    }
    assert_eq!(hub.metrics().worker_restarts.get(), 2);
    assert!(hub.engine().starts_with("cpu"), "{}", hub.engine());
    assert!(hub.is_ready());
    hub.shutdown();
}

/// Connections that never send a byte are closed after the first-byte timeout, so as many of
/// them as the connection limit lock nobody out for long. Before, they held their places
/// forever: with the limit taken, every later client was turned away.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_connections_are_closed_and_free_their_places() {
    use tokio::io::AsyncReadExt;
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.max_connections = 3;
    config.first_byte_timeout = Duration::from_millis(400);
    let server = TestServer::start_with(config).await;
    let mut silent = Vec::new();
    for _ in 0..3 {
        silent.push(
            tokio::net::TcpStream::connect(server.http_addr)
                .await
                .expect("connect"),
        );
    }
    // Every place is held by a silent socket: a request now may be turned away. The server
    // closes the silent ones once their timeout passes, and then requests are served.
    let http = reqwest::Client::new();
    let deadline = Instant::now() + PATIENCE;
    loop {
        match http.get(server.url("/healthz")).send().await {
            Ok(r) if r.status() == 200 => break,
            _ => {
                assert!(
                    Instant::now() < deadline,
                    "silent sockets were never closed"
                );
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    }
    for mut s in silent {
        let mut byte = [0u8; 1];
        let read = tokio::time::timeout(PATIENCE, s.read(&mut byte))
            .await
            .expect("the server closes a silent socket");
        assert!(matches!(read, Ok(0) | Err(_)), "{read:?}");
    }
    // gRPC clients, which speak first, are not affected.
    let mut c = server.client().await;
    create_session(&mut c, vec![point(5.0)]).await;
    server.stop().await;
}

/// A client that sends the start of a request head and then stalls (slowloris), or leaves a
/// keep-alive connection idle after its answer, is closed after the header-read timeout. Before,
/// both held their connection slots for good: the first-byte timeout only catches silence.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stalled_request_heads_and_idle_keep_alives_are_closed() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.header_read_timeout = Duration::from_millis(500);
    let server = TestServer::start_with(config).await;
    let closed = |mut s: tokio::net::TcpStream| async move {
        // Read whatever the server sends (an answer, a 408) until it closes.
        let mut buf = Vec::new();
        let read = tokio::time::timeout(PATIENCE, s.read_to_end(&mut buf)).await;
        assert!(read.is_ok(), "the server never closed the connection");
        String::from_utf8_lossy(&buf).into_owned()
    };
    // Half a request head, then nothing.
    let mut stalled = tokio::net::TcpStream::connect(server.http_addr)
        .await
        .expect("connect");
    stalled
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        .await
        .expect("write");
    let started = Instant::now();
    closed(stalled).await;
    assert!(
        started.elapsed() >= Duration::from_millis(400),
        "closed before the timeout"
    );
    // A whole request, answered, then an idle keep-alive connection.
    let mut idle = tokio::net::TcpStream::connect(server.http_addr)
        .await
        .expect("connect");
    idle.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        .await
        .expect("write");
    let answer = closed(idle).await;
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    // Requests that are quick are served as before.
    let http = reqwest::Client::new();
    let r = http
        .get(server.url("/healthz"))
        .send()
        .await
        .expect("served");
    assert_eq!(r.status(), 200);
    server.stop().await;
}

/// One address holds at most `max_connections_per_ip` connections: past it the next is closed at
/// once, and counted; a closed one frees its place. (Every client here is on loopback, one
/// address.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_address_cannot_take_every_connection() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.max_connections_per_ip = 2;
    let server = TestServer::start_with(config).await;
    let mut held = Vec::new();
    for _ in 0..2 {
        held.push(
            tokio::net::TcpStream::connect(server.http_addr)
                .await
                .expect("connect"),
        );
    }
    // Both places of loopback are held (the server accepts in order, so the two are in).
    let http = reqwest::Client::builder()
        .pool_max_idle_per_host(0)
        .build()
        .expect("client");
    let refused = tokio::time::timeout(PATIENCE, http.get(server.url("/healthz")).send())
        .await
        .expect("answered in time");
    assert!(
        refused.is_err(),
        "a third connection was served: {refused:?}"
    );
    let metrics = server.hub.metrics().encode();
    assert!(
        metrics.contains(r#"bounce_connections_refused_total{transport="http"}"#),
        "{metrics}"
    );
    drop(held.pop());
    let deadline = Instant::now() + PATIENCE;
    loop {
        match http.get(server.url("/healthz")).send().await {
            Ok(r) if r.status() == 200 => break,
            other => {
                assert!(Instant::now() < deadline, "never served again: {other:?}");
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        }
    }
    drop(held);
    server.stop().await;
}

/// Stored sessions do not outlive their use: one whose scene is not served waits one session TTL
/// for it (a hot reload that adds the scene brings it back), then is removed from the store; a
/// record that no longer parses is moved out of the sessions table (kept, not read again).
/// Before, both stayed in the store forever.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stored_sessions_of_absent_scenes_expire_and_unreadable_ones_are_set_aside() {
    let data = tempfile::tempdir().expect("tempdir");
    let config = |dir: PathBuf, ttl: Duration| {
        let mut c = stored(dir, data.path());
        c.session_ttl = ttl;
        c.reload_interval = Some(Duration::from_millis(50));
        c
    };
    let day = Duration::from_secs(86_400);
    let first = TestServer::start_with(config(scenes_dir(), day)).await;
    let mut c = first.client().await;
    let (s1, _) = create_session(&mut c, vec![point(5.0)]).await;
    first.stop().await;
    // A record this server cannot read.
    {
        let db = redb::Database::create(data.path().join("sessions.redb")).expect("open store");
        let txn = db.begin_write().expect("txn");
        {
            let table: redb::TableDefinition<&str, &[u8]> = redb::TableDefinition::new("sessions");
            let mut t = txn.open_table(table).expect("table");
            t.insert("junk", b"{not a session".as_slice())
                .expect("insert");
        }
        txn.commit().expect("commit");
    }
    // Another directory: the session's scene is absent, then appears.
    let other = tempfile::tempdir().expect("tempdir");
    let baked = scenes_dir().join(format!("{SCENE}.bounce"));
    std::fs::copy(&baked, other.path().join("other-scene.bounce")).expect("copy");
    let second = TestServer::start_with(config(other.path().to_path_buf(), day)).await;
    assert!(second.hub.session(&s1).is_err(), "its scene is not served");
    std::fs::copy(&baked, other.path().join(format!("{SCENE}.bounce"))).expect("copy");
    let deadline = Instant::now() + PATIENCE;
    while second.hub.session(&s1).is_err() {
        assert!(
            Instant::now() < deadline,
            "the session never came back with its scene"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    second.stop().await;

    // Absent again, with a short TTL: the stored session expires.
    let third_dir = tempfile::tempdir().expect("tempdir");
    std::fs::copy(&baked, third_dir.path().join("other-scene.bounce")).expect("copy");
    let third = TestServer::start_with(config(
        third_dir.path().to_path_buf(),
        Duration::from_millis(200),
    ))
    .await;
    let deadline = Instant::now() + PATIENCE;
    while third.hub.metrics().sessions_expired.get() < 1 {
        assert!(
            Instant::now() < deadline,
            "the orphaned session never expired"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    third.stop().await;

    let fourth = TestServer::start_with(config(scenes_dir(), day)).await;
    assert!(
        fourth.hub.session(&s1).is_err(),
        "an expired record came back"
    );
    fourth.stop().await;
    let db = redb::Database::create(data.path().join("sessions.redb")).expect("open store");
    let read = redb::ReadableDatabase::begin_read(&db).expect("read");
    let table = |name: &'static str| {
        let t: redb::TableDefinition<&str, &[u8]> = redb::TableDefinition::new(name);
        read.open_table(t).expect("table")
    };
    assert!(table("sessions").get("junk").expect("get").is_none());
    assert!(
        table("sessions_unreadable")
            .get("junk")
            .expect("get")
            .is_some()
    );
}

/// A session's idle time survives a restart: the store keeps when it was last written, and the
/// restored session counts from there, so expiry is not reset by every restart. A record from
/// an older server (without that time) still restores, idle from the restart.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_time_survives_a_restart() {
    let data = tempfile::tempdir().expect("tempdir");
    let config = || stored(scenes_dir(), data.path());
    let first = TestServer::start_with(config()).await;
    let mut c = first.client().await;
    let (id, _) = create_session(&mut c, vec![point(5.0)]).await;
    first.stop().await;
    // An older server's record: no write time.
    {
        let db = redb::Database::create(data.path().join("sessions.redb")).expect("open store");
        let txn = db.begin_write().expect("txn");
        {
            let table: redb::TableDefinition<&str, &[u8]> = redb::TableDefinition::new("sessions");
            let mut t = txn.open_table(table).expect("table");
            let old = json!({"scene": SCENE, "lights": {"lights": []}, "version": 3}).to_string();
            t.insert("old-record", old.as_bytes()).expect("insert");
        }
        txn.commit().expect("commit");
    }
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let second = TestServer::start_with(config()).await;
    let idle = second.hub.session(&id).expect("restored").idle_for();
    assert!(
        idle >= Duration::from_millis(1500),
        "idle {idle:?} after the restart"
    );
    let old = second
        .hub
        .session("old-record")
        .expect("an old record restores");
    assert!(old.idle_for() < Duration::from_millis(1500));
    assert_eq!(old.lights_version(), 3);
    second.stop().await;
}

/// The value of sample `name` (its labels included, as exposed) in a metrics text; 0 when absent.
fn sample(metrics: &str, name: &str) -> f64 {
    metrics
        .lines()
        .find_map(|l| {
            l.strip_prefix(name)?
                .strip_prefix(' ')?
                .split(' ')
                .next()?
                .parse()
                .ok()
        })
        .unwrap_or(0.0)
}

/// Writes to one session never queue up: 200 at once, while each store commit waits on its
/// fsync, are merged into the newest (the light sets in between are dropped, never stored or
/// solved), every caller is answered with success and the version that took its write's place,
/// and the last frame answers the lights that won. Before merging, each write waited its turn on
/// the session's write lock holding its light set, and each got a commit and a version of its own.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_writes_to_one_session_are_merged_into_the_newest() {
    const WRITES: usize = 200;
    let data = tempfile::tempdir().expect("tempdir");
    let server = TestServer::start_with(stored(scenes_dir(), data.path())).await;
    let mut c = server.client().await;
    let (id, _) = create_session(&mut c, vec![point(1.0)]).await;
    published(&server.hub, &id, 1).await;
    let solved = |hub: &Hub| {
        sample(
            &hub.metrics().encode(),
            r#"bounce_relight_batch_size_sum{scene="cornell-box"}"#,
        )
    };
    let solved_before = solved(&server.hub);

    let intensity = |i: usize| 2.0 + i as f32;
    let writes: Vec<_> = (0..WRITES)
        .map(|i| {
            let mut c = c.clone();
            let id = id.clone();
            tokio::spawn(async move {
                c.set_lights(proto::SetLightsRequest {
                    session_id: id,
                    lights: vec![point(intensity(i))],
                    token: String::new(),
                })
                .await
            })
        })
        .collect();
    let mut versions = Vec::with_capacity(WRITES);
    for w in writes {
        let answer = tokio::time::timeout(PATIENCE, w)
            .await
            .expect("a write answered in time")
            .expect("join")
            .expect("every write succeeds")
            .into_inner();
        assert!(answer.changed);
        versions.push(answer.lights_version);
    }

    let session = server.hub.session(&id).expect("session");
    let last = session.lights_version();
    assert_eq!(versions.iter().max(), Some(&last));
    assert!(versions.iter().all(|&v| v >= 2), "{versions:?}");
    // Each version after the first is one write stored; the others were merged into them.
    let stored = (last - 1) as usize;
    assert!(
        stored <= WRITES / 4,
        "{stored} of {WRITES} concurrent writes were stored one by one"
    );
    let metrics = server.hub.metrics().encode();
    assert_eq!(
        sample(&metrics, "bounce_light_writes_merged_total") as usize,
        WRITES - stored,
        "{metrics}"
    );

    // The lights that won are one of the writes, answered with the last version, and the last
    // frame is theirs.
    let lights = session.lights();
    let won = (0..WRITES)
        .find(|&i| lights == light_set(intensity(i)))
        .expect("the session's lights are one of the writes");
    assert_eq!(versions[won], last);
    published(&server.hub, &id, last).await;
    let relit = solved(&server.hub) - solved_before;
    assert!(
        relit as usize <= stored,
        "{relit} relights for {stored} stored versions"
    );
    let frame = session.subscribe().borrow().clone().expect("a frame");
    assert_eq!(frame.header.lights_version, last);
    let want = server
        .hub
        .relight_once(SCENE, lights)
        .await
        .expect("relight once");
    assert_eq!(frame.irradiance(), want.irradiance());
    server.stop().await;
}

/// A write racing with expiry never stores a deleted session again. With no TTL, an unwatched
/// session expires as soon as the janitor (every 10 ms) finds its write lock free, between two
/// stored writes, while writers keep changing its lights back to back; once all are gone, the
/// store holds none of them. With the expiry check under the write lock taken out, a write that
/// fetched the session before expiry removed it stored it back (one to four of the 20 sessions
/// here, every run).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn writes_racing_with_expiry_never_store_a_deleted_session_again() {
    const SESSIONS: usize = 20;
    const WRITERS: usize = 4;
    let data = tempfile::tempdir().expect("tempdir");
    let mut config = stored(scenes_dir(), data.path());
    config.session_ttl = Duration::ZERO;
    config.reload_interval = None;
    let server = TestServer::start_with(config).await;
    let c = server.client().await;
    let mut writers = Vec::new();
    for s in 0..SESSIONS {
        let (id, _) = create_session(&mut c.clone(), vec![point(1.0)]).await;
        for w in 0..WRITERS {
            let mut c = c.clone();
            let id = id.clone();
            writers.push(tokio::spawn(async move {
                let deadline = Instant::now() + PATIENCE;
                for n in 0.. {
                    assert!(Instant::now() < deadline, "session {s} never expired");
                    let write = c
                        .set_lights(proto::SetLightsRequest {
                            session_id: id.clone(),
                            lights: vec![point(2.0 + (n * WRITERS + w) as f32)],
                            token: String::new(),
                        })
                        .await;
                    match write {
                        Ok(_) => {}
                        Err(status) if status.code() == Code::NotFound => return,
                        Err(status) => panic!("write: {status:?}"),
                    }
                }
            }));
        }
    }
    for w in writers {
        w.await.expect("writer");
    }
    assert_eq!(server.hub.session_count(), 0);
    server.stop().await;

    // The hub is gone once its front ends stop; its store closes with it.
    let deadline = Instant::now() + PATIENCE;
    let left = loop {
        match bounce_server::store::Store::open(data.path(), Default::default()) {
            Ok((_store, left)) => break left,
            Err(e) => {
                assert!(Instant::now() < deadline, "the store never closed: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        }
    };
    let ids: Vec<&str> = left.iter().map(|(id, _)| id.as_str()).collect();
    assert!(ids.is_empty(), "expired sessions stored again: {ids:?}");
}

/// One-shot relights waiting for the engine are bounded: with the worker held and
/// `MAX_ONCE_QUEUED` of them waiting, one more is refused at once as `RESOURCE_EXHAUSTED`
/// rather than queued (queued, it would have waited out the one-shot deadline and answered
/// `UNAVAILABLE`); once the worker goes on, every waiting one is answered and there is room again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_shot_relights_past_the_queue_bound_are_refused_not_queued() {
    use bounce_server::MAX_ONCE_QUEUED;
    let server = TestServer::start().await;
    server.hub.hold_worker();
    let waiting: Vec<_> = (0..MAX_ONCE_QUEUED)
        .map(|i| {
            let hub = server.hub.clone();
            tokio::spawn(async move { hub.relight_once(SCENE, light_set(1.0 + i as f32)).await })
        })
        .collect();
    let deadline = Instant::now() + PATIENCE;
    while server.hub.once_waiting() < MAX_ONCE_QUEUED {
        assert!(
            Instant::now() < deadline,
            "only {} one-shot relights queued",
            server.hub.once_waiting()
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let mut c = server.client().await;
    let once = || proto::RelightOnceRequest {
        scene: SCENE.into(),
        lights: vec![point(2.0)],
    };
    assert_status(
        c.relight_once(once()).await,
        Code::ResourceExhausted,
        "already waiting for the engine",
    );
    assert_eq!(server.hub.once_waiting(), MAX_ONCE_QUEUED);

    server.hub.release_worker();
    for w in waiting {
        tokio::time::timeout(PATIENCE, w)
            .await
            .expect("answered in time")
            .expect("join")
            .expect("a waiting one-shot relight is solved");
    }
    c.relight_once(once())
        .await
        .expect("room again once the queue drained");
    server.stop().await;
}
