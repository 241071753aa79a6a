//! An emissive scene end to end: the Cornell box whose only light is its ceiling lamp, an
//! emissive material, served as it is. A session changes the lamp's colour and strength over
//! HTTP and gets the frames the engine computes for each (within RGB9E5's step); the scene
//! lists its emitter, and a change naming another material is refused naming it.

use crate::common::*;

const LAMP: &str = "Emitter_Light_temp";
const NAME: &str = "lamp-box";

/// A directory holding the emissive box at about 300 patches, baked once per test binary.
fn lamp_dir() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("server-it-lamp");
        std::fs::create_dir_all(&dir).expect("creating the scenes directory");
        let gltf = bounce_testkit::assets().join("cornell-box-emissive/CornellBox.glb");
        let options = BakeOptions {
            resolution: Resolution::TargetPatches(300),
            rays: 512,
            ..BakeOptions::default()
        };
        bake_file(&gltf, &options, &NoProgress)
            .expect("baking the emissive box")
            .write_atomic(&dir.join(format!("{NAME}.bounce")))
            .expect("writing it");
        dir
    })
    .clone()
}

/// The frame of `ws` answering `version` or later, decoded.
async fn frame_for(ws: &mut WsClient, version: u64) -> Vec<[f32; 3]> {
    ws.frames_until(version).await;
    ws.last.as_ref().expect("a frame").irradiance()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_dims_and_recolours_the_lamp() {
    let dir = lamp_dir();
    let server = TestServer::start_with(HubConfig::new(dir.clone(), EngineChoice::Cpu)).await;
    let http = reqwest::Client::new();
    let scenes: Value = http
        .get(server.url("/v1/scenes"))
        .send()
        .await
        .expect("GET")
        .json()
        .await
        .expect("JSON");
    assert_eq!(scenes["scenes"][0]["emitters"], json!([LAMP]), "{scenes}");
    assert_eq!(
        scenes["scenes"][0]["emitter_nodes"],
        json!(["Light"]),
        "{scenes}"
    );

    // No lights of its own: the file's lamp lights the box.
    let created: Value = http
        .post(server.url("/v1/sessions"))
        .json(&json!({"scene": NAME, "lights": []}))
        .send()
        .await
        .expect("POST")
        .json()
        .await
        .expect("JSON");
    let id = created["session_id"].as_str().expect("an id").to_string();
    let mut ws = WsClient::connect(&server.ws_url(&id, None)).await;
    let as_baked = frame_for(&mut ws, 1).await;

    let engine = Engine::new(EngineChoice::Cpu).expect("cpu engine");
    let baked = Baked::read(&dir.join(format!("{NAME}.bounce"))).expect("the file");
    let scene = engine.load(&baked).expect("load");
    let red = LightSet::from_json(&format!(
        r#"{{"lights": [{{"type": "emissive", "material": "{LAMP}", "color": [1, 0, 0]}}]}}"#
    ))
    .unwrap();
    let off = LightSet::from_json(&format!(
        r#"{{"lights": [{{"type": "emissive", "material": "{LAMP}", "strength": 0}}]}}"#
    ))
    .unwrap();
    let want = engine
        .relight(
            &scene,
            &[LightSet { lights: vec![] }, red.clone(), off.clone()],
        )
        .expect("relight");
    assert_within_rgb9e5_step(&as_baked, &want[0].streamed());
    assert!(
        as_baked.iter().any(|v| v[1] > 0.0),
        "the lamp lights the box"
    );

    let put = |set: &LightSet| {
        http.put(server.url(&format!("/v1/sessions/{id}/lights")))
            .json(&json!({"lights": set.lights}))
            .send()
    };
    let answer: Value = put(&red).await.expect("PUT").json().await.expect("JSON");
    let reddened = frame_for(&mut ws, answer["lights_version"].as_u64().unwrap()).await;
    assert_within_rgb9e5_step(&reddened, &want[1].streamed());
    // Red light only: green and blue are gone from every patch, red is where it was.
    assert!(reddened.iter().all(|v| v[1] == 0.0 && v[2] == 0.0));
    assert!(reddened.iter().any(|v| v[0] > 0.0));

    let answer: Value = put(&off).await.expect("PUT").json().await.expect("JSON");
    let dark = frame_for(&mut ws, answer["lights_version"].as_u64().unwrap()).await;
    assert!(dark.iter().flatten().all(|&v| v == 0.0), "the lamp is off");

    // A light the scene has no emitter for: refused with 400, and its message.
    let refused = |light: Value| {
        let request = http
            .put(server.url(&format!("/v1/sessions/{id}/lights")))
            .json(&json!({ "lights": [light] }));
        async move {
            let r = request.send().await.expect("PUT");
            assert_eq!(r.status(), reqwest::StatusCode::BAD_REQUEST);
            let body: Value = r.json().await.expect("JSON");
            body["message"].as_str().unwrap_or_default().to_string()
        }
    };

    // The lamp by its node: green light only.
    let green = LightSet::from_json(
        r#"{"lights": [{"type": "emissive", "node": "Light", "color": [0, 1, 0]}]}"#,
    )
    .unwrap();
    let answer: Value = put(&green).await.expect("PUT").json().await.expect("JSON");
    let greened = frame_for(&mut ws, answer["lights_version"].as_u64().unwrap()).await;
    assert!(greened.iter().all(|v| v[0] == 0.0 && v[2] == 0.0));
    assert!(greened.iter().any(|v| v[1] > 0.0));
    let message = refused(json!({"type": "emissive", "node": "Desk", "strength": 1})).await;
    assert!(
        message.contains("no emissive node 'Desk'") && message.contains("on nodes: Light"),
        "{message}"
    );

    // Another material is refused, naming the lamp; the session keeps its lights.
    let message = refused(json!({"type": "emissive", "material": "Screen", "strength": 1})).await;
    assert!(
        message.contains("no emissive material 'Screen'") && message.contains(LAMP),
        "{message}"
    );
    server.stop().await;
}
