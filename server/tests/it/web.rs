//! What the browser page needs from the server: the scene's model (from the baked file, or a glTF
//! beside it), the scene and session lists, and the page's own files, cached by tag and
//! compressed.

use std::io::Read as _;

use crate::common::*;
use reqwest::StatusCode;
use reqwest::header::{
    ACCEPT_ENCODING, CACHE_CONTROL, CONTENT_ENCODING, CONTENT_TYPE, ETAG, IF_NONE_MATCH,
};

fn client() -> reqwest::Client {
    reqwest::Client::builder()
        .timeout(PATIENCE)
        .build()
        .expect("HTTP client")
}

/// `GET url` with `headers`.
async fn get(
    http: &reqwest::Client,
    url: &str,
    headers: &[(reqwest::header::HeaderName, &str)],
) -> reqwest::Response {
    let mut request = http.get(url);
    for (name, value) in headers {
        request = request.header(name, *value);
    }
    request.send().await.expect("GET")
}

fn header(r: &reqwest::Response, name: reqwest::header::HeaderName) -> String {
    r.headers()
        .get(&name)
        .map(|v| v.to_str().expect("ASCII header").to_string())
        .unwrap_or_default()
}

/// A refusal's status, `code` and `message`.
async fn refusal(r: reqwest::Response) -> (StatusCode, String, String) {
    let status = r.status();
    let body: Value = r.json().await.expect("JSON error body");
    let field = |k: &str| body[k].as_str().unwrap_or_default().to_string();
    (status, field("code"), field("message"))
}

fn gunzip(bytes: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(bytes)
        .read_to_end(&mut out)
        .expect("gzip body");
    out
}

fn cornell_gltf() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box/scene.gltf")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_model_route_gives_the_baked_model_cached_and_compressed() {
    let server = TestServer::start().await;
    let http = client();
    let want = baked().model.expect("the test scene keeps its model");
    let url = server.url(&format!("/v1/scenes/{SCENE}/model"));

    let r = get(&http, &url, &[]).await;
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(header(&r, CONTENT_TYPE), "model/gltf-binary");
    assert_eq!(header(&r, CACHE_CONTROL), "no-cache");
    assert_eq!(header(&r, CONTENT_ENCODING), "", "not asked to compress");
    let etag = header(&r, ETAG);
    assert!(
        etag.starts_with('"') && etag.len() > 10,
        "strong tag: {etag}"
    );
    assert!(r.bytes().await.expect("body").as_ref() == want.as_slice());

    // Revalidation: the same tag gets a 304 with no body; another tag the bytes.
    let r = get(&http, &url, &[(IF_NONE_MATCH, &etag)]).await;
    assert_eq!(r.status(), StatusCode::NOT_MODIFIED);
    assert_eq!(header(&r, ETAG), etag);
    assert!(r.bytes().await.expect("body").is_empty());
    let r = get(&http, &url, &[(IF_NONE_MATCH, "\"something-else\"")]).await;
    assert_eq!(r.status(), StatusCode::OK);

    // gzip when accepted; the tag turns weak, and still revalidates.
    let r = get(&http, &url, &[(ACCEPT_ENCODING, "gzip")]).await;
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(header(&r, CONTENT_ENCODING), "gzip");
    let weak = header(&r, ETAG);
    assert_eq!(weak, format!("W/{etag}"));
    let body = r.bytes().await.expect("body");
    assert!(body.len() < want.len(), "compressed: {} bytes", body.len());
    assert!(gunzip(&body) == want);
    let r = get(
        &http,
        &url,
        &[(ACCEPT_ENCODING, "gzip"), (IF_NONE_MATCH, &weak)],
    )
    .await;
    assert_eq!(r.status(), StatusCode::NOT_MODIFIED);

    // Brotli too.
    let r = get(&http, &url, &[(ACCEPT_ENCODING, "br")]).await;
    assert_eq!(header(&r, CONTENT_ENCODING), "br");

    // JSON answers are not compressed.
    let r = http
        .get(server.url("/v1/scenes"))
        .header(ACCEPT_ENCODING, "gzip")
        .send()
        .await
        .expect("GET");
    assert_eq!(header(&r, CONTENT_ENCODING), "");

    let (status, code, message) = refusal(
        http.get(server.url("/v1/scenes/nowhere/model"))
            .send()
            .await
            .expect("GET"),
    )
    .await;
    assert_eq!(
        (status, code.as_str()),
        (StatusCode::NOT_FOUND, "not_found")
    );
    assert!(message.contains("unknown scene"), "{message}");
    server.stop().await;
}

/// A scene directory of the test scene three ways: with its model (`cornell-box`), without one
/// (`bare`), and without one but with the glTF beside it (`sibling.gltf`, its `scene.bin` too).
fn model_dir() -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("tempdir");
    let with = baked();
    with.write_atomic(&dir.path().join(format!("{SCENE}.bounce")))
        .expect("write");
    let mut without = with.clone();
    without.model = None;
    for name in ["bare", "sibling"] {
        without
            .write_atomic(&dir.path().join(format!("{name}.bounce")))
            .expect("write");
    }
    let assets = cornell_gltf();
    std::fs::copy(&assets, dir.path().join("sibling.gltf")).expect("copy");
    std::fs::copy(
        assets.with_file_name("scene.bin"),
        dir.path().join("scene.bin"),
    )
    .expect("copy");
    dir
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_model_beside_the_baked_file_serves_and_none_is_a_404_that_says_how_to_fix_it() {
    let dir = model_dir();
    let mut config = HubConfig::new(dir.path(), EngineChoice::Cpu);
    config.reload_interval = None;
    config.token = Some("secret".into());
    let server = TestServer::start_with(config).await;
    let http = client();

    let scenes: Value = http
        .get(server.url("/v1/scenes"))
        .send()
        .await
        .expect("GET")
        .json()
        .await
        .expect("JSON");
    assert_eq!(scenes["writes_need_token"], true);
    let has_model = |name: &str| has_model(&scenes, name);
    assert_eq!(has_model(SCENE), Some(json!(true)));
    assert_eq!(has_model("sibling"), Some(json!(true)));
    assert_eq!(has_model("bare"), Some(json!(false)));

    // The sibling glTF, packed: the same GLB `bounce bake` would have kept.
    let r = http
        .get(server.url("/v1/scenes/sibling/model"))
        .send()
        .await
        .expect("GET");
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(header(&r, CONTENT_TYPE), "model/gltf-binary");
    let packed = bounce_core::import::pack_glb(&cornell_gltf()).expect("pack");
    assert!(r.bytes().await.expect("body").as_ref() == packed.as_slice());

    let (status, code, message) = refusal(
        http.get(server.url("/v1/scenes/bare/model"))
            .send()
            .await
            .expect("GET"),
    )
    .await;
    assert_eq!(
        (status, code.as_str()),
        (StatusCode::NOT_FOUND, "not_found")
    );
    for says in [
        "bare.bounce",
        "Bake the scene again",
        "bare.glb",
        "bare.gltf",
    ] {
        assert!(message.contains(says), "{message:?} lacks {says:?}");
    }

    // A GLB put beside the file is picked up when the scene reloads.
    std::fs::write(dir.path().join("bare.glb"), &packed).expect("write");
    let hub = server.hub.clone();
    let path = dir.path().join("bare.bounce");
    tokio::task::spawn_blocking(move || hub.reload(&path))
        .await
        .expect("join")
        .expect("reload");
    let r = http
        .get(server.url("/v1/scenes/bare/model"))
        .send()
        .await
        .expect("GET");
    assert_eq!(r.status(), StatusCode::OK);
    assert!(r.bytes().await.expect("body").as_ref() == packed.as_slice());
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_are_listed_newest_first_by_scene_with_their_viewers() {
    let dir = model_dir();
    let mut config = HubConfig::new(dir.path(), EngineChoice::Cpu);
    config.reload_interval = None;
    let server = TestServer::start_with(config).await;
    let http = client();
    let list = |query: &str| {
        let http = http.clone();
        let url = server.url(&format!("/v1/sessions{query}"));
        async move { http.get(url).send().await.expect("GET") }
    };
    let ids = |v: &Value| -> Vec<String> {
        v["sessions"]
            .as_array()
            .expect("sessions")
            .iter()
            .map(|s| s["session_id"].as_str().expect("id").to_string())
            .collect()
    };

    let empty: Value = list("").await.json().await.expect("JSON");
    assert_eq!(empty, json!({"sessions": []}));

    let first = server.http_session(&http, 1.0).await;
    let second = server.http_session(&http, 2.0).await;
    let r = http
        .post(server.url("/v1/sessions"))
        .json(&json!({"scene": "bare"}))
        .send()
        .await
        .expect("POST");
    assert_eq!(r.status(), StatusCode::CREATED);
    let other = r.json::<Value>().await.expect("JSON")["session_id"]
        .as_str()
        .expect("id")
        .to_string();
    // One viewer on the second session.
    let mut ws = WsClient::connect(&server.ws_url(&second, None)).await;
    ws.frames_until(1).await;

    let all: Value = list("").await.json().await.expect("JSON");
    assert_eq!(ids(&all), [other.clone(), second.clone(), first.clone()]);
    let of_scene: Value = list(&format!("?scene={SCENE}"))
        .await
        .json()
        .await
        .expect("JSON");
    assert_eq!(ids(&of_scene), [second.clone(), first.clone()]);
    let entry = &of_scene["sessions"][0];
    assert_eq!(entry["scene"], SCENE);
    assert_eq!(entry["lights_version"], 1);
    assert_eq!(entry["viewers"], 1);
    assert_eq!(of_scene["sessions"][1]["viewers"], 0);
    let entry_keys: Vec<&String> = entry.as_object().expect("object").keys().collect();
    assert_eq!(
        entry_keys,
        ["lights_version", "scene", "session_id", "viewers"]
    );
    let limited: Value = list("?limit=1").await.json().await.expect("JSON");
    assert_eq!(ids(&limited), std::slice::from_ref(&other));
    let limited: Value = list("?limit=1000&scene=bare")
        .await
        .json()
        .await
        .expect("JSON");
    assert_eq!(ids(&limited), [other]);

    for bad in ["?limit=0", "?limit=1001", "?limit=ten", "?limit=-1"] {
        let (status, code, message) = refusal(list(bad).await).await;
        assert_eq!(
            (status, code.as_str()),
            (StatusCode::BAD_REQUEST, "invalid_argument"),
            "{bad}"
        );
        assert!(message.contains("1 to 1000"), "{bad}: {message}");
    }
    let (status, code, message) = refusal(list("?scene=nowhere").await).await;
    assert_eq!(
        (status, code.as_str()),
        (StatusCode::NOT_FOUND, "not_found")
    );
    assert!(message.contains("nowhere"), "{message}");
    drop(ws);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_is_served_from_the_binary_after_the_routes() {
    let server = TestServer::start().await;
    let http = client();
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../web/public");

    let r = http.get(server.url("/")).send().await.expect("GET");
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(header(&r, CONTENT_TYPE), "text/html; charset=utf-8");
    assert_eq!(header(&r, CACHE_CONTROL), "no-cache");
    let etag = header(&r, ETAG);
    let index = std::fs::read(repo.join("index.html")).expect("index.html");
    assert!(r.bytes().await.expect("body").as_ref() == index.as_slice());
    let r = http
        .get(server.url("/index.html"))
        .header(IF_NONE_MATCH, &etag)
        .send()
        .await
        .expect("GET");
    assert_eq!(r.status(), StatusCode::NOT_MODIFIED);

    let js = "/vendor/three/three.module.js";
    let r = http
        .get(server.url(js))
        .header(ACCEPT_ENCODING, "gzip")
        .send()
        .await
        .expect("GET");
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(header(&r, CONTENT_TYPE), "text/javascript; charset=utf-8");
    assert_eq!(header(&r, CONTENT_ENCODING), "gzip");
    let want = std::fs::read(repo.join(&js[1..])).expect("three.module.js");
    assert!(gunzip(&r.bytes().await.expect("body")) == want);

    // Routes win; what is neither a route nor a file is the JSON 404, and no path climbs out.
    let r = http
        .get(server.url("/v1/scenes"))
        .send()
        .await
        .expect("GET");
    assert_eq!(header(&r, CONTENT_TYPE), "application/json");
    for path in [
        "/nothing-here.js",
        "/vendor/",
        "/../Cargo.toml",
        "/%2e%2e/Cargo.toml",
        "/vendor/three/..%2f..%2findex.html",
        "/vendor/%2e%2e/%2e%2e/server/Cargo.toml",
        "/v1/nothing",
    ] {
        let (status, code, message) =
            refusal(http.get(server.url(path)).send().await.expect("GET")).await;
        assert_eq!(
            (status, code.as_str(), message.as_str()),
            (StatusCode::NOT_FOUND, "not_found", "no such route"),
            "{path}"
        );
    }
    let (status, code, _) = refusal(http.post(server.url("/")).send().await.expect("POST")).await;
    assert_eq!(
        (status, code.as_str()),
        (StatusCode::NOT_FOUND, "not_found")
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_web_dir_is_read_on_every_request() {
    let web = tempfile::tempdir().expect("tempdir");
    std::fs::write(web.path().join("index.html"), "<p>one</p>").expect("write");
    std::fs::create_dir(web.path().join("js")).expect("mkdir");
    std::fs::write(web.path().join("js/app.mjs"), "export {};").expect("write");
    let mut config = HubConfig::new(scenes_dir(), EngineChoice::Cpu);
    config.web_dir = Some(web.path().to_path_buf());
    let server = TestServer::start_with(config).await;
    let http = client();

    let get = |path: &str| {
        let http = http.clone();
        let url = server.url(path);
        async move { http.get(url).send().await.expect("GET") }
    };
    let r = get("/").await;
    let first_tag = header(&r, ETAG);
    assert_eq!(r.text().await.expect("body"), "<p>one</p>");
    std::fs::write(web.path().join("index.html"), "<p>two</p>").expect("write");
    let r = get("/").await;
    assert_ne!(header(&r, ETAG), first_tag, "a new tag for new bytes");
    assert_eq!(r.text().await.expect("body"), "<p>two</p>");
    let r = get("/js/app.mjs").await;
    assert_eq!(header(&r, CONTENT_TYPE), "text/javascript; charset=utf-8");
    // The built-in files are not mixed in, and nothing outside the directory is reachable.
    for path in ["/vendor/three/three.module.js", "/js", "/../x.secret"] {
        let (status, _, _) = refusal(get(path).await).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{path}");
    }
    server.stop().await;
}

/// One GLB: the JSON chunk (padded with spaces) and an optional BIN chunk (padded with zeros).
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut json = json.as_bytes().to_vec();
    json.resize(json.len().next_multiple_of(4), b' ');
    let mut bin = bin.to_vec();
    bin.resize(bin.len().next_multiple_of(4), 0);
    let chunks = 8 + json.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend(((12 + chunks) as u32).to_le_bytes());
    out.extend((json.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(&json);
    if !bin.is_empty() {
        out.extend((bin.len() as u32).to_le_bytes());
        out.extend(b"BIN\0");
        out.extend(&bin);
    }
    out
}

/// A model whose one image is `image`, claiming to be a PNG: what a bake before issue 19 packed
/// from a glTF whose image URI was `/etc/passwd` with a `mimeType`.
fn model_with_image(image: &[u8]) -> Vec<u8> {
    let json = json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": image.len()}],
        "bufferViews": [{"buffer": 0, "byteLength": image.len()}],
        "images": [{"bufferView": 0, "mimeType": "image/png"}],
    });
    glb(&json.to_string(), image)
}

/// Issue 19: a model is checked before it is served, whether it is packed in the baked file or
/// lies beside it, and one that fails is not served while its scene is.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_model_that_is_not_a_clean_packed_glb_is_not_served() {
    let root = tempfile::tempdir().expect("tempdir");
    let dir = root.path().join("scenes");
    std::fs::create_dir(&dir).expect("mkdir");
    let secret = b"root:x:0:0:root:/root:/bin/bash\n";
    std::fs::write(root.path().join("secret.txt"), secret).expect("write");

    let mut baked = baked();
    // In the baked file: a file's bytes packed as an image.
    baked.model = Some(model_with_image(secret));
    baked
        .write_atomic(&dir.join("packed.bounce"))
        .expect("write");
    // In the baked file: a model that names a file instead of holding it.
    baked.model = Some(glb(
        &json!({"asset": {"version": "2.0"},
                "buffers": [{"byteLength": secret.len(), "uri": "../secret.txt"}]})
        .to_string(),
        &[],
    ));
    baked.write_atomic(&dir.join("uri.bounce")).expect("write");
    // Beside a file without a model: a GLB holding the same fake image (a GLB without URIs
    // packs as it is, so only the check stops it), and a glTF whose buffer climbs out.
    baked.model = None;
    for name in ["beside-glb", "beside-gltf", "good"] {
        baked
            .write_atomic(&dir.join(format!("{name}.bounce")))
            .expect("write");
    }
    std::fs::write(dir.join("beside-glb.glb"), model_with_image(secret)).expect("write");
    std::fs::write(
        dir.join("beside-gltf.gltf"),
        json!({"asset": {"version": "2.0"},
               "buffers": [{"byteLength": secret.len(), "uri": "../secret.txt"}]})
        .to_string(),
    )
    .expect("write");
    // And one that passes, beside a file, to show the check lets real models through.
    let packed = bounce_core::import::pack_glb(&cornell_gltf()).expect("pack");
    std::fs::write(dir.join("good.glb"), &packed).expect("write");

    let mut config = HubConfig::new(&dir, EngineChoice::Cpu);
    config.reload_interval = None;
    let server = TestServer::start_with(config).await;
    let http = client();
    let scenes: Value = http
        .get(server.url("/v1/scenes"))
        .send()
        .await
        .expect("GET")
        .json()
        .await
        .expect("JSON");
    let has_model = |name: &str| has_model(&scenes, name);
    for name in ["packed", "uri", "beside-glb", "beside-gltf"] {
        // The scene is served, without a model.
        assert_eq!(has_model(name), Some(json!(false)), "{name}: {scenes}");
        let r = http
            .get(server.url(&format!("/v1/scenes/{name}/model")))
            .send()
            .await
            .expect("GET");
        assert_eq!(r.status(), StatusCode::NOT_FOUND, "{name}");
        let body = r.bytes().await.expect("body");
        assert!(
            !body.windows(secret.len()).any(|w| w == secret),
            "{name} served the secret"
        );
        let layout = http
            .get(server.url(&format!("/v1/scenes/{name}/layout")))
            .send()
            .await
            .expect("GET");
        assert_eq!(layout.status(), StatusCode::OK, "{name}'s light is served");
    }
    assert_eq!(has_model("good"), Some(json!(true)));
    let r = http
        .get(server.url("/v1/scenes/good/model"))
        .send()
        .await
        .expect("GET");
    assert_eq!(r.status(), StatusCode::OK);
    assert!(r.bytes().await.expect("body").as_ref() == packed.as_slice());
    server.stop().await;
}

/// A scene's `has_model` in a `/v1/scenes` listing; `None` when the scene is not listed.
fn has_model(scenes: &Value, name: &str) -> Option<Value> {
    scenes["scenes"]
        .as_array()
        .expect("scenes")
        .iter()
        .find(|s| s["name"] == name)
        .map(|s| s["has_model"].clone())
}
