//! The HTTP front end with a real client: health, readiness, metrics, scenes, sessions, tokens
//! and limits.

use crate::common::*;
use reqwest::StatusCode;

fn client() -> reqwest::Client {
    reqwest::Client::builder()
        .timeout(PATIENCE)
        .build()
        .expect("HTTP client")
}

/// A refusal's status, and its JSON body's `code` and `message`.
async fn refusal(r: reqwest::Response) -> (StatusCode, String, String) {
    let status = r.status();
    let body: Value = r.json().await.expect("JSON error body");
    let field = |k: &str| body[k].as_str().unwrap_or_default().to_string();
    (status, field("code"), field("message"))
}

#[track_caller]
fn assert_refused(got: (StatusCode, String, String), status: StatusCode, code: &str, has: &str) {
    assert_eq!((got.0, got.1.as_str()), (status, code), "{got:?}");
    assert!(got.2.contains(has), "{:?} does not contain {has:?}", got.2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_readiness_and_metrics() {
    let server = TestServer::start().await;
    let http = client();
    let r = http.get(server.url("/healthz")).send().await.expect("GET");
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.text().await.expect("body"), "ok");
    let r = http.get(server.url("/readyz")).send().await.expect("GET");
    assert_eq!(r.status(), StatusCode::OK);

    // A WebSocket viewer that got a frame shows in the metrics.
    let id = server.http_session(&http, 5.0).await;
    let mut ws = WsClient::connect(&server.ws_url(&id, None)).await;
    ws.frames_until(1).await;
    let r = http.get(server.url("/metrics")).send().await.expect("GET");
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(
        r.headers()[reqwest::header::CONTENT_TYPE],
        bounce_server::metrics::CONTENT_TYPE
    );
    let text = r.text().await.expect("body");
    assert!(
        text.contains(r#"bounce_frames_sent_total{transport="websocket"} "#),
        "{text}"
    );
    assert!(text.contains(r#"bounce_viewers{transport="websocket"} 1"#));
    assert!(text.contains("bounce_engine{"));
    assert!(text.trim_end().ends_with("# EOF"));
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readiness_turns_503_once_shutdown_begins() {
    let server = TestServer::start().await;
    let http = client();
    let ready = |s: String| {
        let get = http.get(s).send();
        async move { get.await.expect("GET").status() }
    };
    assert_eq!(ready(server.url("/readyz")).await, StatusCode::OK);
    // What the front ends' shutdown does first; the HTTP server itself still answers.
    let hub = server.hub.clone();
    tokio::task::spawn_blocking(move || hub.shutdown())
        .await
        .expect("join");
    assert_eq!(
        ready(server.url("/readyz")).await,
        StatusCode::SERVICE_UNAVAILABLE
    );
    assert_eq!(ready(server.url("/healthz")).await, StatusCode::OK);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scenes_and_layout_match_grpc() {
    let server = TestServer::start().await;
    let http = client();
    let mut grpc = server.client().await;

    let scenes: Value = http
        .get(server.url("/v1/scenes"))
        .send()
        .await
        .expect("GET")
        .json()
        .await
        .expect("json");
    let listed = grpc
        .list_scenes(proto::ListScenesRequest {})
        .await
        .expect("list")
        .into_inner();
    assert_eq!(scenes["engine"], listed.engine.as_str());
    let want: Vec<Value> = listed
        .scenes
        .iter()
        // `has_model` is HTTP's alone: the browser page is its client.
        .map(|s| json!({"name": s.name, "patch_count": s.patch_count, "codec": s.codec, "has_model": true, "fallback": null, "sky_view": s.sky_view, "emitters": s.emitters, "emitter_nodes": s.emitter_nodes}))
        .collect();
    assert_eq!(scenes["scenes"], Value::Array(want));
    assert_eq!(
        scenes["scenes"][0]["sky_view"], true,
        "a new bake has a sky view"
    );
    assert_eq!(
        scenes["scenes"][0]["emitters"],
        json!([]),
        "a new bake lists its emitters: the box has none"
    );
    assert_eq!(scenes["writes_need_token"], false);

    let layout: Value = http
        .get(server.url(&format!("/v1/scenes/{SCENE}/layout")))
        .send()
        .await
        .expect("GET")
        .json()
        .await
        .expect("json");
    let l = grpc
        .get_layout(proto::GetLayoutRequest {
            scene: SCENE.into(),
        })
        .await
        .expect("layout")
        .into_inner();
    assert_eq!(layout["scene"], l.scene.as_str());
    // JSON writes an f32 in its shortest form: compare as f32.
    let f32s = |v: &Value| -> Vec<f32> {
        v.as_array()
            .expect("array")
            .iter()
            .map(|x| x.as_f64().expect("number") as f32)
            .collect()
    };
    assert_eq!(f32s(&layout["origin"]), l.origin);
    assert_eq!(
        layout["voxel_size"].as_f64().map(|v| v as f32),
        Some(l.voxel_size)
    );
    assert_eq!(layout["dims"], json!(l.dims));
    assert_eq!(layout["patch_count"], json!(l.patch_count));
    assert_eq!(layout["voxels"], json!(l.voxels));
    assert_eq!(layout["faces"], json!(l.faces));
    assert_eq!(l.faces.len(), l.patch_count as usize);

    let r = http
        .get(server.url("/v1/scenes/no-such-scene/layout"))
        .send()
        .await
        .expect("GET");
    assert_refused(
        refusal(r).await,
        StatusCode::NOT_FOUND,
        "not_found",
        "no-such-scene",
    );
    let r = http
        .get(server.url("/v2/nothing"))
        .send()
        .await
        .expect("GET");
    assert_refused(refusal(r).await, StatusCode::NOT_FOUND, "not_found", "");
    let r = http
        .delete(server.url("/v1/scenes"))
        .send()
        .await
        .expect("DELETE");
    assert_refused(
        refusal(r).await,
        StatusCode::METHOD_NOT_ALLOWED,
        "invalid_argument",
        "method",
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_are_created_read_and_relit() {
    let server = TestServer::start().await;
    let http = client();
    let r = http
        .post(server.url("/v1/sessions"))
        .json(&json!({"scene": SCENE, "lights": [json_point(5.0)]}))
        .send()
        .await
        .expect("POST");
    assert_eq!(r.status(), StatusCode::CREATED);
    let created: Value = r.json().await.expect("json");
    assert_eq!(created["lights_version"], 1);
    let id = created["session_id"].as_str().expect("id").to_string();
    let mut ws = WsClient::connect(&server.ws_url(&id, None)).await;
    ws.frames_until(1).await;

    let session = format!("/v1/sessions/{id}");
    let got: Value = http
        .get(server.url(&session))
        .send()
        .await
        .expect("GET")
        .json()
        .await
        .expect("json");
    assert_eq!(got["session_id"], id.as_str());
    assert_eq!(got["scene"], SCENE);
    assert_eq!(got["lights_version"], 1);
    assert_eq!(got["lights"][0]["intensity"], 5.0);

    let lights = format!("/v1/sessions/{id}/lights");
    let put = |body: Value| http.put(server.url(&lights)).json(&body).send();
    let r = put(json!({"lights": [json_point(7.0), json_point(1.0)]}))
        .await
        .expect("PUT");
    assert_eq!(r.status(), StatusCode::OK);
    let changed: Value = r.json().await.expect("json");
    assert_eq!(changed, json!({"lights_version": 2, "changed": true}));
    // The same lights again: no new version.
    let same: Value = put(json!({"lights": [json_point(7.0), json_point(1.0)]}))
        .await
        .expect("PUT")
        .json()
        .await
        .expect("json");
    assert_eq!(same, json!({"lights_version": 2, "changed": false}));
    ws.frames_until(2).await;
    let got: Value = http
        .get(server.url(&session))
        .send()
        .await
        .expect("GET")
        .json()
        .await
        .expect("json");
    assert_eq!(got["lights_version"], 2);
    assert_eq!(got["lights"].as_array().map(Vec::len), Some(2));

    // Refusals name what is wrong, and nothing changes.
    let r = put(json!({"lights": [json_point(1.0), json_point(-2.0)]}))
        .await
        .expect("PUT");
    assert_refused(
        refusal(r).await,
        StatusCode::BAD_REQUEST,
        "invalid_argument",
        "lights[1].intensity",
    );
    let r = put(json!({"lights": [{"type": "area", "intensity": 1}]}))
        .await
        .expect("PUT");
    assert_refused(
        refusal(r).await,
        StatusCode::BAD_REQUEST,
        "invalid_argument",
        "lights[0]",
    );
    let r = http
        .put(server.url(&lights))
        .body("{not json")
        .send()
        .await
        .expect("PUT");
    assert_refused(
        refusal(r).await,
        StatusCode::BAD_REQUEST,
        "invalid_argument",
        "JSON",
    );
    let r = http
        .put(server.url("/v1/sessions/nope/lights"))
        .json(&json!({"lights": []}))
        .send()
        .await
        .expect("PUT");
    assert_refused(refusal(r).await, StatusCode::NOT_FOUND, "not_found", "nope");
    let r = http
        .get(server.url("/v1/sessions/nope"))
        .send()
        .await
        .expect("GET");
    assert_refused(refusal(r).await, StatusCode::NOT_FOUND, "not_found", "nope");
    let r = http
        .post(server.url("/v1/sessions"))
        .json(&json!({"scene": "no-such-scene", "lights": []}))
        .send()
        .await
        .expect("POST");
    assert_refused(
        refusal(r).await,
        StatusCode::NOT_FOUND,
        "not_found",
        "no-such-scene",
    );
    let r = http
        .post(server.url("/v1/sessions"))
        .json(&json!({"scene": SCENE, "lights": [
            {"type": "point", "position": [0, 1, 0], "intensity": -1}
        ]}))
        .send()
        .await
        .expect("POST");
    assert_refused(
        refusal(r).await,
        StatusCode::BAD_REQUEST,
        "invalid_argument",
        "lights[0].intensity",
    );
    let r = http
        .post(server.url("/v1/sessions"))
        .json(&json!({"scene": SCENE, "colour": "red"}))
        .send()
        .await
        .expect("POST");
    assert_refused(
        refusal(r).await,
        StatusCode::BAD_REQUEST,
        "invalid_argument",
        "colour",
    );
    let got: Value = http
        .get(server.url(&session))
        .send()
        .await
        .expect("GET")
        .json()
        .await
        .expect("json");
    assert_eq!(got["lights_version"], 2);
    let metrics = server.hub.metrics().encode();
    assert!(
        metrics.contains(r#"bounce_requests_refused_total{transport="http"} 8"#),
        "{metrics}"
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn writes_need_the_token_when_one_is_set() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.token = Some("s3cret".into());
    let server = TestServer::start_with(config).await;
    let http = client();
    let body = json!({"scene": SCENE, "lights": [json_point(3.0)]});
    let post = || http.post(server.url("/v1/sessions")).json(&body);

    let r = post().send().await.expect("POST");
    assert_refused(
        refusal(r).await,
        StatusCode::UNAUTHORIZED,
        "unauthenticated",
        "token",
    );
    let r = post().bearer_auth("wrong").send().await.expect("POST");
    assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
    let r = post().bearer_auth("s3cret").send().await.expect("POST");
    assert_eq!(r.status(), StatusCode::CREATED);
    let r = http
        .post(server.url("/v1/sessions?token=s3cret"))
        .json(&body)
        .send()
        .await
        .expect("POST");
    assert_eq!(r.status(), StatusCode::CREATED);
    let id = r.json::<Value>().await.expect("json")["session_id"]
        .as_str()
        .expect("id")
        .to_string();

    // Reading needs no token; writing does.
    let r = http
        .get(server.url(&format!("/v1/sessions/{id}")))
        .send()
        .await
        .expect("GET");
    assert_eq!(r.status(), StatusCode::OK);
    let lights = server.url(&format!("/v1/sessions/{id}/lights"));
    let change = json!({"lights": [json_point(4.0)]});
    let r = http.put(&lights).json(&change).send().await.expect("PUT");
    assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
    let r = http
        .put(&lights)
        .bearer_auth("s3cret")
        .json(&change)
        .send()
        .await
        .expect("PUT");
    assert_eq!(r.status(), StatusCode::OK);

    // A WebSocket views without a token; its writes need one, from the upgrade or the message.
    let mut viewer = WsClient::connect(&server.ws_url(&id, None)).await;
    viewer.frames_until(2).await;
    let answer = viewer
        .request(json!({"type": "set_lights", "lights": [json_point(5.0)], "token": "s3cret"}))
        .await;
    assert_eq!(answer["lights_version"], 3, "{answer}");
    let mut writer = WsClient::connect(&server.ws_url(&id, Some("s3cret"))).await;
    let answer = writer
        .request(json!({"type": "set_lights", "lights": [json_point(6.0)]}))
        .await;
    assert_eq!(answer["lights_version"], 4, "{answer}");
    viewer
        .send(json!({"type": "set_lights", "lights": [json_point(7.0)]}))
        .await;
    let (error, code, reason) = viewer.refused().await;
    assert_eq!(
        (error["code"].as_str(), code),
        (Some("unauthenticated"), 4401)
    );
    assert!(reason.contains("token"), "{reason}");
    let mut wrong = WsClient::connect(&server.ws_url(&id, Some("wrong"))).await;
    wrong
        .send(json!({"type": "set_lights", "lights": [json_point(7.0)]}))
        .await;
    assert_eq!(wrong.refused().await.1, 4401);
    writer.frames_until(4).await;
    server.stop().await;
}

/// An equirectangular HDR image, over the JSON routes' 1 MiB limit, posted to `/v1/sky/sh`: the
/// answer is `bounce_core::environment`'s projection of the same bytes, and it lights a session
/// as a sky. Anything but an HDR image is refused with the reason; a server with a write token
/// wants it here too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_hdr_image_becomes_a_sky() {
    let (w, h) = (1024u32, 512u32);
    let mut pixels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            // Bright above the horizon, bluer up high, with a ripple so the file does not
            // compress under the limit.
            let up = 1.0 - 2.0 * (y as f32 + 0.5) / h as f32;
            let ripple = 1.0 + 0.2 * ((x * 7 + y * 3) as f32).sin();
            let sky = if up > 0.0 { 1.0 + up } else { 0.1 };
            pixels.push(image::Rgb([
                sky * ripple,
                sky * ripple,
                (sky + up.max(0.0)) * ripple,
            ]));
        }
    }
    let mut bytes = Vec::new();
    image::codecs::hdr::HdrEncoder::new(&mut bytes)
        .encode(&pixels, w as usize, h as usize)
        .expect("an HDR file");
    assert!(
        bytes.len() > bounce_server::MAX_REQUEST_BYTES,
        "{} bytes",
        bytes.len()
    );
    let want = bounce_core::environment::sh_from_image(&bytes).expect("a projection");

    let server = TestServer::start().await;
    let http = client();
    let r = http
        .post(server.url("/v1/sky/sh"))
        .body(bytes.clone())
        .send()
        .await
        .expect("POST");
    assert_eq!(r.status(), StatusCode::OK);
    let answer: Value = r.json().await.expect("JSON");
    assert_eq!(
        (answer["width"].as_u64(), answer["height"].as_u64()),
        (Some(1024), Some(512))
    );
    let sh: Vec<[f32; 3]> = serde_json::from_value(answer["sh"].clone()).expect("9 triples");
    assert_eq!(sh, want.sh.to_vec());
    // Brighter above than below: Y1−1 (the up axis) is positive, and bluer.
    assert!(sh[1][0] > 0.0 && sh[1][2] > sh[1][0], "{sh:?}");
    let body = json!({"scene": SCENE, "lights": [{"type": "sky", "sh": sh}]});
    let r = http
        .post(server.url("/v1/sessions"))
        .json(&body)
        .send()
        .await
        .expect("POST");
    assert_eq!(r.status(), StatusCode::CREATED);

    let r = http
        .post(server.url("/v1/sky/sh"))
        .body("not an image")
        .send()
        .await
        .expect("POST");
    assert_refused(
        refusal(r).await,
        StatusCode::BAD_REQUEST,
        "invalid_argument",
        "the image: not an image",
    );
    server.stop().await;

    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.token = Some("s3cret".into());
    let server = TestServer::start_with(config).await;
    let r = http
        .post(server.url("/v1/sky/sh"))
        .body(bytes.clone())
        .send()
        .await
        .expect("POST");
    assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
    let r = http
        .post(server.url("/v1/sky/sh"))
        .bearer_auth("s3cret")
        .body(bytes)
        .send()
        .await
        .expect("POST");
    assert_eq!(r.status(), StatusCode::OK);
    server.stop().await;
}

/// `/v1/sky/sun`: a sun's direction becomes a directional sun and its SH sky, which a session
/// takes as they are; a sun below the horizon or an unknown field is refused with the reason.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sun_direction_becomes_a_sun_and_its_sky() {
    let server = TestServer::start().await;
    let http = client();
    let post = |body: Value| http.post(server.url("/v1/sky/sun")).json(&body).send();
    let r = post(json!({"direction": [0.5, 0.8, 0.2], "scale": 0.05}))
        .await
        .expect("POST");
    assert_eq!(r.status(), StatusCode::OK);
    let answer: Value = r.json().await.expect("JSON");
    let lights = answer["lights"].as_array().expect("lights");
    assert_eq!(lights.len(), 2, "{answer}");
    assert_eq!(lights[0]["type"], "directional");
    assert!(
        lights[0]["direction"][1].as_f64().unwrap() < 0.0,
        "{answer}"
    );
    assert_eq!(lights[1]["type"], "sky");
    assert_eq!(lights[1]["sh"].as_array().map(Vec::len), Some(9));
    let want = bounce_core::sunsky::sun_and_sky([0.5, 0.8, 0.2], 3.0, 0.05).unwrap();
    assert_eq!(
        answer["lights"],
        serde_json::to_value(&want.lights).unwrap()
    );
    let r = http
        .post(server.url("/v1/sessions"))
        .json(&json!({"scene": SCENE, "lights": lights}))
        .send()
        .await
        .expect("POST");
    assert_eq!(r.status(), StatusCode::CREATED);
    for (body, says) in [
        (json!({"direction": [0.5, -0.2, 0.0]}), "below the horizon"),
        (
            json!({"direction": [0.5, 0.8, 0.2], "turbidity": 40}),
            "turbidity",
        ),
        (
            json!({"direction": [0.5, 0.8, 0.2], "sun": 1}),
            "unknown field",
        ),
        (json!({"turbidity": 3}), "direction"),
    ] {
        let r = post(body).await.expect("POST");
        assert_refused(
            refusal(r).await,
            StatusCode::BAD_REQUEST,
            "invalid_argument",
            says,
        );
    }
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn request_bodies_over_the_limit_are_413() {
    let server = TestServer::start().await;
    let http = client();
    let id = server.http_session(&http, 2.0).await;
    let huge = format!(
        r#"{{"lights": [], "pad": "{}"}}"#,
        "x".repeat(bounce_server::MAX_REQUEST_BYTES)
    );
    for (method, path) in [
        (reqwest::Method::POST, "/v1/sessions".to_string()),
        (reqwest::Method::PUT, format!("/v1/sessions/{id}/lights")),
    ] {
        let r = http
            .request(method, server.url(&path))
            .bearer_auth("unused")
            .body(huge.clone())
            .send()
            .await
            .expect("send");
        assert_refused(
            refusal(r).await,
            StatusCode::PAYLOAD_TOO_LARGE,
            "resource_exhausted",
            "limit",
        );
    }
    // Still serving.
    let r = http
        .put(server.url(&format!("/v1/sessions/{id}/lights")))
        .json(&json!({"lights": [json_point(9.0)]}))
        .send()
        .await
        .expect("PUT");
    assert_eq!(r.status(), StatusCode::OK);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_past_the_limit_are_closed_and_counted() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.max_connections = 2;
    let server = TestServer::start_with(config).await;
    // Made on the hub, so no HTTP connection of ours is still closing when the count starts.
    let id = server
        .hub
        .create_session(SCENE, LightSet::default(), None)
        .await
        .expect("session")
        .id
        .clone();
    let deadline = Instant::now() + PATIENCE;
    let fresh = || {
        reqwest::Client::builder()
            .timeout(PATIENCE)
            .pool_max_idle_per_host(0)
            .build()
            .expect("HTTP client")
    };
    // WebSockets hold their connections.
    let mut first = WsClient::connect(&server.ws_url(&id, None)).await;
    let _second = WsClient::connect(&server.ws_url(&id, None)).await;
    let r = fresh().get(server.url("/healthz")).send().await;
    assert!(r.is_err(), "a third connection was served: {r:?}");
    let m = server.hub.metrics().encode();
    assert!(
        m.contains(r#"bounce_connections_refused_total{transport="http"}"#),
        "{m}"
    );
    // A closed connection frees its place.
    first.stream.close(None).await.expect("close");
    while !matches!(first.next().await, WsEvent::Closed(_) | WsEvent::Failed(_)) {}
    loop {
        let r = fresh().get(server.url("/healthz")).send().await;
        if r.is_ok_and(|r| r.status() == StatusCode::OK) {
            break;
        }
        assert!(Instant::now() < deadline, "no place freed");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    server.stop().await;
}

/// The hub holds at most `max_sessions`: one more is refused on both front ends, as
/// `resource_exhausted` (429 over HTTP), and the sessions it holds go on serving.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_past_the_limit_are_refused() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.max_sessions = 2;
    let server = TestServer::start_with(config).await;
    let mut c = server.client().await;
    let (first, _) = create_session(&mut c, vec![point(5.0)]).await;
    create_session(&mut c, vec![point(6.0)]).await;
    let refused = c
        .create_session(proto::CreateSessionRequest {
            scene: SCENE.into(),
            lights: vec![point(7.0)],
        })
        .await
        .expect_err("a third session");
    assert_eq!(refused.code(), Code::ResourceExhausted, "{refused:?}");
    assert!(refused.message().contains("--max-sessions"), "{refused:?}");
    let http = reqwest::Client::new();
    let r = http
        .post(server.url("/v1/sessions"))
        .json(&json!({"scene": SCENE, "lights": [json_point(5.0)]}))
        .send()
        .await
        .expect("POST");
    assert_eq!(r.status(), 429);
    let body: serde_json::Value = r.json().await.expect("json");
    assert_eq!(body["code"], "resource_exhausted");
    assert!(server.hub.session(&first).is_ok());
    assert_eq!(server.hub.session_count(), 2);
    server.stop().await;
}

/// One client address creates at most `max_sessions_per_client` sessions, whatever the total
/// cap: one more is refused on every way to create one (gRPC `CreateSession` and a `Relight`
/// stream naming a scene, HTTP `POST`) as `resource_exhausted` (429 over HTTP) and counted, and
/// a session that expires gives its place back. Before the cap, one client could take all of
/// `--max-sessions`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_client_holds_at_most_its_share_of_sessions() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.max_sessions_per_client = 2;
    // Long enough to start watching a new session on a loaded machine before it could expire
    // (watched sessions never do), short enough to wait for one to expire.
    config.session_ttl = Duration::from_secs(3);
    config.reload_interval = None;
    let server = TestServer::start_with(config).await;
    let mut c = server.client().await;
    let (first, _) = create_session(&mut c, vec![point(5.0)]).await;
    let first_frames = subscribe(&mut c, &first).await;
    let (second, _) = create_session(&mut c, vec![point(6.0)]).await;
    let _second_frames = subscribe(&mut c, &second).await;

    let refused = c
        .create_session(proto::CreateSessionRequest {
            scene: SCENE.into(),
            lights: vec![point(7.0)],
        })
        .await
        .expect_err("a third session from the same address");
    assert_eq!(refused.code(), Code::ResourceExhausted, "{refused:?}");
    assert!(
        refused.message().contains("--max-sessions-per-client"),
        "{refused:?}"
    );
    let opening = proto::RelightRequest {
        scene: SCENE.into(),
        set_lights: true,
        lights: vec![point(7.0)],
        ..Default::default()
    };
    assert_status(
        c.relight(tokio_stream::iter(vec![opening]))
            .await
            .map(|_| ()),
        Code::ResourceExhausted,
        "--max-sessions-per-client",
    );
    let http = reqwest::Client::new();
    let post = || {
        http.post(server.url("/v1/sessions"))
            .json(&json!({"scene": SCENE, "lights": [json_point(7.0)]}))
            .send()
    };
    let r = post().await.expect("POST");
    assert_eq!(r.status(), 429);
    let body: Value = r.json().await.expect("json");
    assert_eq!(body["code"], "resource_exhausted", "{body}");
    assert!(
        body["message"]
            .as_str()
            .is_some_and(|m| m.contains("--max-sessions-per-client")),
        "{body}"
    );
    assert_eq!(server.hub.session_count(), 2);
    let metrics = server.hub.metrics().encode();
    assert!(
        metrics.contains(r#"bounce_sessions_refused_total{limit="per_client"} 3"#),
        "{metrics}"
    );

    // Nobody watches the first any more: once it expires, its place is free again.
    drop(first_frames);
    let deadline = Instant::now() + PATIENCE;
    while server.hub.session(&first).is_ok() {
        assert!(
            Instant::now() < deadline,
            "the unwatched session never expired"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let r = post().await.expect("POST");
    assert_eq!(r.status(), reqwest::StatusCode::CREATED);
    assert!(server.hub.session(&second).is_ok());
    server.stop().await;
}

/// A web page of another site cannot write through a visitor's browser: a POST or a WebSocket
/// upgrade carrying a foreign `Origin` is refused (403 `permission_denied`), whatever its content
/// type, while the server's own pages, the `--allow-origin` list and clients that send no Origin
/// (gRPC, scripts) write as before. Before the check, a cross-site `text/plain` POST created a
/// session.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn writes_from_foreign_web_origins_are_refused() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.allowed_origins = vec!["https://app.example.com/".into()];
    let server = TestServer::start_with(config).await;
    let http = reqwest::Client::new();
    let body = json!({"scene": SCENE, "lights": [json_point(5.0)]}).to_string();
    let post = |origin: Option<String>, content_type: &str| {
        let mut r = http
            .post(server.url("/v1/sessions"))
            .header("content-type", content_type.to_string())
            .body(body.clone());
        if let Some(o) = origin {
            r = r.header("origin", o);
        }
        r.send()
    };
    let before = server.hub.session_count();
    for content_type in ["text/plain", "application/json"] {
        let r = post(Some("http://evil.example".into()), content_type)
            .await
            .expect("POST");
        assert_eq!(r.status(), StatusCode::FORBIDDEN, "{content_type}");
        let v: Value = r.json().await.expect("json");
        assert_eq!(v["code"], "permission_denied");
        assert!(
            v["message"].as_str().unwrap().contains("evil.example"),
            "{v}"
        );
    }
    assert_eq!(server.hub.session_count(), before, "no session was created");
    let own = format!("http://{}", server.http_addr);
    for origin in [
        Some(own.clone()),
        Some("https://APP.example.com".into()),
        None,
    ] {
        let r = post(origin.clone(), "application/json")
            .await
            .expect("POST");
        assert_eq!(r.status(), StatusCode::CREATED, "{origin:?}");
    }
    // Reads from anywhere stay open.
    let r = http
        .get(server.url("/v1/scenes"))
        .header("origin", "http://evil.example")
        .send()
        .await
        .expect("GET");
    assert_eq!(r.status(), StatusCode::OK);

    // A WebSocket takes writes, so its upgrade is checked the same way.
    let id = server.http_session(&http, 5.0).await;
    let url = format!("ws://{}/v1/sessions/{id}/ws", server.http_addr);
    let mut request =
        tokio_tungstenite::tungstenite::client::IntoClientRequest::into_client_request(
            url.as_str(),
        )
        .expect("request");
    request
        .headers_mut()
        .insert("origin", "http://evil.example".parse().expect("header"));
    match tokio_tungstenite::connect_async(request).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
            assert_eq!(response.status(), StatusCode::FORBIDDEN.as_u16());
        }
        other => panic!(
            "a foreign origin's upgrade was not refused: {:?}",
            other.map(|_| ())
        ),
    }
    let mut request =
        tokio_tungstenite::tungstenite::client::IntoClientRequest::into_client_request(
            url.as_str(),
        )
        .expect("request");
    request
        .headers_mut()
        .insert("origin", own.parse().expect("header"));
    let (stream, _) = tokio_tungstenite::connect_async(request)
        .await
        .expect("the server's own page connects");
    let client = WsClient::over(stream).await;
    assert_eq!(client.hello["type"], "hello");
    server.stop().await;
}

/// With a read token, reads of scenes and sessions need it (or the write token) on every front
/// end; health, readiness, metrics and the page stay open; the read token does not write.
/// Before, anyone could list every session and watch its frames.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reads_need_the_read_token_when_one_is_set() {
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.token = Some("w-token".into());
    config.read_token = Some("r-token".into());
    let server = TestServer::start_with(config).await;
    let http = reqwest::Client::new();
    let get = |path: &str, token: Option<&str>| {
        let mut r = http.get(server.url(path));
        if let Some(t) = token {
            r = r.bearer_auth(t);
        }
        r.send()
    };
    let r = get("/v1/scenes", None).await.expect("GET");
    assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
    let v: Value = r.json().await.expect("json");
    assert_eq!(v["code"], "unauthenticated");
    assert!(v["message"].as_str().unwrap().contains("reads"), "{v}");
    assert_eq!(
        get("/v1/scenes", Some("nope")).await.expect("GET").status(),
        401
    );
    for token in ["r-token", "w-token"] {
        let r = get("/v1/scenes", Some(token)).await.expect("GET");
        assert_eq!(r.status(), StatusCode::OK, "{token}");
        let v: Value = r.json().await.expect("json");
        assert_eq!(v["reads_need_token"], true);
    }
    let r = get(&format!("/v1/scenes/{SCENE}/layout?token=r-token"), None)
        .await
        .expect("GET");
    assert_eq!(
        r.status(),
        StatusCode::OK,
        "the token in the query, as the page sends it"
    );
    for open in ["/healthz", "/readyz", "/metrics", "/"] {
        assert_eq!(get(open, None).await.expect("GET").status(), 200, "{open}");
    }
    // The read token does not write; the write token does, and reads.
    let body = json!({"scene": SCENE, "lights": [json_point(5.0)]});
    let post = |t: &str| {
        http.post(server.url("/v1/sessions"))
            .bearer_auth(t)
            .json(&body)
            .send()
    };
    assert_eq!(post("r-token").await.expect("POST").status(), 401);
    let r = post("w-token").await.expect("POST");
    assert_eq!(r.status(), StatusCode::CREATED);
    let id = r.json::<Value>().await.expect("json")["session_id"]
        .as_str()
        .unwrap()
        .to_string();
    assert_eq!(get("/v1/sessions", None).await.expect("GET").status(), 401);
    assert_eq!(
        get("/v1/sessions", Some("r-token"))
            .await
            .expect("GET")
            .status(),
        200
    );

    // Frame sockets.
    let ws = |q: &str| format!("ws://{}/v1/sessions/{id}/ws{q}", server.http_addr);
    match tokio_tungstenite::connect_async(ws("")).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(r)) => assert_eq!(r.status(), 401),
        other => panic!(
            "a socket without the read token opened: {:?}",
            other.map(|_| ())
        ),
    }
    let client = WsClient::connect(&ws("?token=r-token")).await;
    assert_eq!(client.hello["type"], "hello");

    // gRPC reads: metadata.
    let mut c = server.client().await;
    let refused = c
        .list_scenes(proto::ListScenesRequest {})
        .await
        .expect_err("no token");
    assert_eq!(refused.code(), Code::Unauthenticated);
    let mut request = tonic::Request::new(proto::ListScenesRequest {});
    request
        .metadata_mut()
        .insert("authorization", "Bearer r-token".parse().expect("metadata"));
    c.list_scenes(request).await.expect("with the read token");
    let refused = c
        .subscribe(proto::SubscribeRequest {
            session_id: id.clone(),
        })
        .await
        .expect_err("no token");
    assert_eq!(refused.code(), Code::Unauthenticated);
    server.stop().await;
}
