//! The WebSocket front end with a real client: hello and frames, control messages, many and slow
//! viewers, gRPC and WebSocket writers on one session, refusals and shutdown.

use crate::common::*;

fn client() -> reqwest::Client {
    reqwest::Client::builder()
        .timeout(PATIENCE)
        .build()
        .expect("HTTP client")
}

async fn set_lights_http(server: &TestServer, http: &reqwest::Client, id: &str, i: f32) -> u64 {
    let r: Value = http
        .put(server.url(&format!("/v1/sessions/{id}/lights")))
        .json(&json!({"lights": [json_point(i)]}))
        .send()
        .await
        .expect("PUT")
        .json()
        .await
        .expect("json");
    r["lights_version"].as_u64().expect("lights_version")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hello_frames_and_control_messages() {
    let server = TestServer::start().await;
    let http = client();
    let id = server.http_session(&http, 5.0).await;
    let mut ws = WsClient::connect(&server.ws_url(&id, None)).await;
    let patches = server.hub.scene(SCENE).expect("scene").layout.len();
    let probes = server.hub.scene(SCENE).expect("scene").probes.len();
    assert!(probes > 0, "the test scene has probes");
    // No probe frame comes unless asked for: every binary message below parses as a patch
    // frame (`WsClient::next` would panic on a probe frame).
    assert_eq!(
        ws.hello,
        json!({"type": "hello", "session_id": id, "scene": SCENE, "lights_version": 1,
               "patch_count": patches, "probe_count": probes})
    );
    let WsEvent::Frame(first) = ws.next().await else {
        panic!("expected the first frame");
    };
    assert_eq!(first.header.patch_count as usize, patches);
    assert_eq!(first.header.lights_version, 1);
    assert_eq!(first.bytes().len(), 32 + 4 * patches);

    assert_eq!(
        ws.request(json!({"type": "ping"})).await,
        json!({"type": "pong"})
    );
    let answer = ws
        .request(json!({"type": "set_lights", "lights": [json_point(8.0)]}))
        .await;
    assert_eq!(
        answer,
        json!({"type": "lights", "lights_version": 2, "changed": true})
    );
    let again = ws
        .request(json!({"type": "set_lights", "lights": [json_point(8.0)]}))
        .await;
    assert_eq!(
        again,
        json!({"type": "lights", "lights_version": 2, "changed": false})
    );
    ws.frames_until(2).await;

    // The same bytes as gRPC's frame.
    let mut grpc = server.client().await;
    let mut stream = subscribe(&mut grpc, &id).await;
    let f = stream.message().await.expect("frame").expect("a frame");
    let last = ws.last.as_ref().expect("a frame");
    assert_eq!(f.lights_version, 2);
    assert_eq!(&f.data, last.bytes());
    server.stop().await;
}

/// `?probes=1`: each patch frame is followed by its probe frame, the same one gRPC carries.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn probe_frames_follow_their_patch_frames_when_asked_for() {
    let server = TestServer::start().await;
    let http = client();
    let id = server.http_session(&http, 5.0).await;
    let probes = server.hub.scene(SCENE).expect("scene").probes.len();
    let url = format!("{}?probes=1", server.ws_url(&id, None));
    let (mut stream, _) = tokio_tungstenite::connect_async(&url)
        .await
        .expect("WebSocket connect");
    let mut binary = Vec::new();
    while binary.len() < 2 {
        let message = tokio::time::timeout(PATIENCE, stream.next())
            .await
            .expect("a message in time")
            .expect("open")
            .expect("a message");
        match message {
            WsMessage::Text(t) => {
                let hello: Value = serde_json::from_str(t.as_str()).expect("JSON");
                assert_eq!(hello["probe_count"], json!(probes));
            }
            WsMessage::Binary(b) => binary.push(b),
            _ => {}
        }
    }
    let patch = Frame::parse(binary[0].clone()).expect("a patch frame first");
    let probe = Frame::parse_probes(binary[1].clone()).expect("then its probe frame");
    assert_eq!(probe.header.sequence, patch.header.sequence);
    assert_eq!(probe.header.lights_version, patch.header.lights_version);
    assert_eq!(probe.header.patch_count as usize, 6 * probes);
    // The same bytes as gRPC's probe frame.
    let mut grpc = server.client().await;
    let mut frames = subscribe(&mut grpc, &id).await;
    let f = frames.message().await.expect("frame").expect("a frame");
    assert_eq!(f.sequence, patch.header.sequence);
    assert_eq!(&f.probes, probe.bytes());
    // Anything but 1/true/0/false is refused before the upgrade.
    let bad = format!("{}?probes=yes", server.ws_url(&id, None));
    assert!(tokio_tungstenite::connect_async(&bad).await.is_err());
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn many_viewers_end_on_the_last_version_in_order() {
    let server = TestServer::start().await;
    let http = client();
    let id = server.http_session(&http, 1.0).await;
    let url = server.ws_url(&id, None);
    let mut viewers = Vec::new();
    for _ in 0..20 {
        viewers.push(WsClient::connect(&url).await);
    }
    let mut writer = WsClient::connect(&url).await;
    const CHANGES: u64 = 16;
    let last = 1 + CHANGES;
    let reading: Vec<_> = viewers
        .into_iter()
        .map(|mut v| {
            tokio::spawn(async move {
                v.frames_until(last).await;
                v.frames
            })
        })
        .collect();
    // Writers on both paths, one after the other.
    for k in 1..=CHANGES {
        let version = if k % 2 == 0 {
            set_lights_http(&server, &http, &id, 10.0 + k as f32).await
        } else {
            let a = writer
                .request(json!({"type": "set_lights", "lights": [json_point(10.0 + k as f32)]}))
                .await;
            a["lights_version"].as_u64().expect("lights_version")
        };
        assert_eq!(version, 1 + k);
    }
    for r in reading {
        // Order was checked frame by frame as they came.
        let frames = r.await.expect("viewer");
        assert_eq!(frames.last().map(|f| f.1), Some(last), "{frames:?}");
    }
    writer.frames_until(last).await;
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_viewer_does_not_delay_the_others() {
    let server = TestServer::start().await;
    let http = client();
    let id = server.http_session(&http, 1.0).await;
    let url = server.ws_url(&id, None);
    // Viewers that never read. A small receive buffer and small segments (the server sizes its
    // send buffer in segments: loopback's 64 KiB ones would let it buffer megabytes) make the
    // server's sends to them block after a few dozen frames.
    let mut stalled = Vec::new();
    for _ in 0..2 {
        let socket = tokio::net::TcpSocket::new_v4().expect("socket");
        socket.set_recv_buffer_size(4096).expect("SO_RCVBUF");
        socket2::SockRef::from(&socket)
            .set_tcp_mss(536)
            .expect("TCP_MAXSEG");
        let tcp = socket.connect(server.http_addr).await.expect("connect");
        let (ws, _) = tokio_tungstenite::client_async(&url, MaybeTlsStream::Plain(tcp))
            .await
            .expect("upgrade");
        stalled.push(ws);
    }
    let mut live = WsClient::connect(&url).await;
    const CHANGES: u64 = 200;
    let last = 1 + CHANGES;
    for k in 1..=CHANGES {
        let version = set_lights_http(&server, &http, &id, 10.0 + k as f32).await;
        assert_eq!(version, 1 + k);
        // Read as a live viewer does, between changes.
        live.frames_until(version).await;
    }
    assert_eq!(live.frames.last().map(|f| f.1), Some(last));

    // The first stalled viewer catches up: in order, ending on the newest, having been handed
    // only the newest frame whenever it was blocked.
    let mut caught_up = WsClient::over(stalled.remove(0)).await;
    caught_up.frames_until(last).await;
    eprintln!(
        "stalled viewer: {} frames of {}",
        caught_up.frames.len(),
        live.frames.len()
    );
    assert!(
        caught_up.frames.len() < live.frames.len(),
        "the stalled viewer got every frame ({}), so it never stalled",
        caught_up.frames.len()
    );
    let metrics = server.hub.metrics().encode();
    assert!(
        metrics.contains(r#"bounce_stale_frames_skipped_total{transport="websocket"}"#),
        "{metrics}"
    );
    // The other never reads: shutdown must not wait for it.
    server.stop().await;
    drop(stalled);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_and_websocket_writers_reach_each_other() {
    let server = TestServer::start().await;
    let mut grpc = server.client().await;
    let (id, _) = create_session(&mut grpc, vec![point(3.0)]).await;
    let mut stream = subscribe(&mut grpc, &id).await;
    let mut ws = WsClient::connect(&server.ws_url(&id, None)).await;

    let a = ws
        .request(json!({"type": "set_lights", "lights": [json_point(4.0)]}))
        .await;
    assert_eq!(a["lights_version"], 2);
    read_until(&mut stream, 2).await;

    let r = grpc
        .set_lights(proto::SetLightsRequest {
            session_id: id.clone(),
            lights: vec![point(6.0)],
            token: String::new(),
        })
        .await
        .expect("set lights")
        .into_inner();
    assert_eq!(r.lights_version, 3);
    ws.frames_until(3).await;
    let mut from_grpc = None;
    while from_grpc.is_none() {
        let f = stream.message().await.expect("frame").expect("a frame");
        if f.lights_version == 3 {
            from_grpc = Some(f);
        }
    }
    let from_grpc = from_grpc.expect("frame");
    let from_ws = ws.last.as_ref().expect("frame");
    assert_eq!(from_ws.header.sequence, from_grpc.sequence);
    assert_eq!(&from_grpc.data, from_ws.bytes());
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn refused_messages_close_with_their_code_and_the_server_keeps_serving() {
    let server = TestServer::start().await;
    let http = client();
    let id = server.http_session(&http, 2.0).await;
    let url = server.ws_url(&id, None);
    let max = bounce_server::MAX_REQUEST_BYTES;
    let cases: Vec<(WsMessage, &str, u16, &str)> = vec![
        (
            WsMessage::text(
                json!({"type": "set_lights", "lights": [
                    json_point(1.0),
                    {"type": "point", "position": [0, 1, 0], "intensity": -2}
                ]})
                .to_string(),
            ),
            "invalid_argument",
            4400,
            "lights[1].intensity",
        ),
        (
            WsMessage::text(json!({"type": "dance"}).to_string()),
            "invalid_argument",
            4400,
            "dance",
        ),
        (
            WsMessage::text("{not json"),
            "invalid_argument",
            4400,
            "message",
        ),
        (
            WsMessage::binary(vec![1u8, 2, 3]),
            "invalid_argument",
            4400,
            "binary",
        ),
        (
            WsMessage::text("x".repeat(max + 1)),
            "resource_exhausted",
            1009,
            "limit",
        ),
    ];
    for (message, code, close, has) in cases {
        let mut ws = WsClient::connect(&url).await;
        ws.frames_until(1).await;
        // A send to a server that refused early may fail half-way; the refusal is still read.
        let _ = ws.stream.send(message).await;
        let (error, got_close, reason) = ws.refused().await;
        assert_eq!(error["code"], code, "{error}");
        assert_eq!(got_close, close, "{error}");
        let message = error["message"].as_str().expect("message");
        assert!(message.contains(has), "{message:?} lacks {has:?}");
        assert!(
            reason.len() <= 123 && message.starts_with(&reason),
            "{reason:?}"
        );
    }

    // An unknown session is refused before the upgrade.
    match tokio_tungstenite::connect_async(server.ws_url("no-such-session", None)).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(r)) => {
            assert_eq!(r.status(), 404);
        }
        other => panic!("expected 404, got {other:?}"),
    }

    // Still serving, the session untouched.
    let mut ws = WsClient::connect(&url).await;
    ws.frames_until(1).await;
    assert_eq!(ws.hello["lights_version"], 1);
    let metrics = server.hub.metrics().encode();
    assert!(
        metrics.contains(r#"bounce_requests_refused_total{transport="websocket"} 5"#),
        "{metrics}"
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_closes_sockets_with_going_away() {
    let server = TestServer::start().await;
    let http = client();
    let id = server.http_session(&http, 2.0).await;
    let mut sockets = Vec::new();
    for _ in 0..3 {
        let mut ws = WsClient::connect(&server.ws_url(&id, None)).await;
        ws.frames_until(1).await;
        sockets.push(ws);
    }
    let stopping = tokio::spawn(server.stop());
    for mut ws in sockets {
        let (error, code, _) = ws.refused().await;
        assert_eq!((error, code), (Value::Null, 1001));
    }
    tokio::time::timeout(PATIENCE, stopping)
        .await
        .expect("stopped in time")
        .expect("join");
}

/// A WebSocket whose client answers nothing, not even a ping, is closed with 1008 after two
/// keep-alive periods; a client that reads (its library answers pings) is served on through any
/// silence, and a viewer that only watches is never closed for not writing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_answers_no_ping_is_closed_and_one_that_does_stays() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.ws_keepalive = Duration::from_millis(300);
    let server = TestServer::start_with(config).await;
    let http = client();
    let id = server.http_session(&http, 1.0).await;
    let url = server.ws_url(&id, None);
    // Never polled until the end: its library never sees the ping, so never answers it.
    let (deaf, _) = tokio_tungstenite::connect_async(&url)
        .await
        .expect("upgrade");
    let mut live = WsClient::connect(&url).await;
    live.frames_until(1).await;
    // Five keep-alive periods in which the live viewer only reads.
    let quiet = tokio::time::sleep(Duration::from_millis(1500));
    tokio::pin!(quiet);
    loop {
        tokio::select! {
            _ = &mut quiet => break,
            event = live.next() => assert!(matches!(event, WsEvent::Frame(_)), "{event:?}"),
        }
    }
    let version = set_lights_http(&server, &http, &id, 3.0).await;
    live.frames_until(version).await;
    // The deaf client finds its hello, its first frame, a ping, and the close.
    let mut deaf = WsClient::over(deaf).await;
    let end = loop {
        match deaf.next().await {
            WsEvent::Frame(_) => {}
            other => break other,
        }
    };
    match end {
        WsEvent::Closed(Some((code, reason))) => {
            assert_eq!(code, 1008, "{reason}");
            assert!(reason.contains("keep-alive"), "{reason}");
        }
        other => panic!("expected a close, got {other:?}"),
    }
    let metrics = server.hub.metrics().encode();
    assert!(
        metrics.contains("bounce_websocket_unresponsive_total 1"),
        "{metrics}"
    );
    server.stop().await;
}
