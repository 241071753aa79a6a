//! A real `bounce serve` child process on loopback, with a baked Cornell box, for the browser
//! tests: the page is served by the binary users run.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use serde_json::{Value, json};

use crate::common::{ServeChild, serve_command};
pub use crate::common::{bounce, cornell};

/// One Cornell box bake shared by every test of this binary (baking is the slow part): 600
/// patches keeps the page and the server quick on CI's two cores. It is baked afresh on each run
/// (so it is always this binary's format) into cargo's target tmp directory, where the next run
/// replaces it: a temporary directory in a static would never be removed.
pub fn baked_cornell() -> &'static Path {
    static BAKED: OnceLock<PathBuf> = OnceLock::new();
    BAKED.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR"));
        let path = dir.join("browser-cornell-600.bounce");
        // Baked beside its final name and renamed, so two runs at once never read half a file.
        let part = dir.join(format!("browser-cornell-600.{}.part", std::process::id()));
        bake_small(&cornell(), &part);
        std::fs::rename(&part, &path).expect("rename the bake into place");
        path
    })
}

/// The same box baked with irradiance probes (`--probes`, the default spacing), for the
/// probe-lit sphere's tests; the other tests keep a scene without probes, so a page that never
/// asks for probe frames stays tested.
pub fn baked_cornell_probes() -> &'static Path {
    static BAKED: OnceLock<PathBuf> = OnceLock::new();
    BAKED.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR"));
        let path = dir.join("browser-cornell-600-probes.bounce");
        let part = dir.join(format!(
            "browser-cornell-600-probes.{}.part",
            std::process::id()
        ));
        crate::common::ok(bake_small_command(&cornell(), &part).arg("--probes"));
        std::fs::rename(&part, &path).expect("rename the bake into place");
        path
    })
}

/// `gltf` baked into `out` at 600 patches: quick for the page and the server on CI's two cores.
pub fn bake_small(gltf: &Path, out: &Path) {
    crate::common::ok(&mut bake_small_command(gltf, out));
}

fn bake_small_command(gltf: &Path, out: &Path) -> std::process::Command {
    let mut cmd = bounce();
    cmd.args(["bake", "--patches", "600", "--rays", "512", "--quiet", "-o"])
        .arg(out)
        .arg(gltf);
    cmd
}

/// The light every test starts from: the README's point light under the ceiling.
pub fn ceiling_light() -> Value {
    json!([{"type": "point", "position": [0.0, 1.5, 0.0], "intensity": 10.0}])
}

pub struct Serve {
    child: ServeChild,
    pub http: String,
    pub grpc: String,
    pub dir: tempfile::TempDir,
}

#[derive(Default)]
pub struct ServeOptions<'a> {
    pub token: Option<&'a str>,
    /// `--read-token`.
    pub read_token: Option<&'a str>,
    /// A fixed HTTP port (to restart on the same address); a free one when `None`.
    pub http_port: Option<u16>,
    /// Reuse a previous server's directory (scenes and stored sessions).
    pub dir: Option<tempfile::TempDir>,
    /// The baked file served as `box` ([`baked_cornell`] when `None`).
    pub scene: Option<&'a Path>,
}

impl Serve {
    pub fn start(options: ServeOptions<'_>) -> Serve {
        let dir = options.dir.unwrap_or_else(|| {
            let dir = tempfile::tempdir().expect("a temporary directory");
            std::fs::create_dir_all(dir.path().join("scenes")).expect("scenes dir");
            let scene = options.scene.unwrap_or_else(|| baked_cornell());
            std::fs::copy(scene, dir.path().join("scenes/box.bounce")).expect("copy the baked box");
            dir
        });
        let http = format!("127.0.0.1:{}", options.http_port.unwrap_or(0));
        let mut cmd = serve_command(&dir.path().join("scenes"), &dir.path().join("data"), &http);
        if let Some(t) = options.token {
            cmd.args(["--token", t]);
        }
        if let Some(t) = options.read_token {
            cmd.args(["--read-token", t]);
        }
        let child = ServeChild::spawn(cmd);
        Serve {
            http: child.http.clone(),
            grpc: child.grpc.clone(),
            child,
            dir,
        }
    }

    /// A server of one scene, `box`: the glTF `model` writes into the directory it is given,
    /// baked as [`bake_small`] bakes; with that glTF's path.
    pub fn scene_of(model: impl FnOnce(&Path) -> PathBuf) -> (Serve, PathBuf) {
        let dir = tempfile::tempdir().expect("a temporary directory");
        let gltf = model(&dir.path().join("model"));
        let scenes = dir.path().join("scenes");
        std::fs::create_dir_all(&scenes).expect("scenes dir");
        bake_small(&gltf, &scenes.join("box.bounce"));
        let serve = Serve::start(ServeOptions {
            dir: Some(dir),
            ..ServeOptions::default()
        });
        (serve, gltf)
    }

    /// SIGKILL: nothing of the server's shutdown runs, as in a crash. The directory (scenes and
    /// stored sessions) is kept for a restart.
    pub fn kill(self) -> tempfile::TempDir {
        let Serve { mut child, dir, .. } = self;
        child.kill();
        dir
    }

    pub fn port(&self) -> u16 {
        self.http
            .rsplit(':')
            .next()
            .and_then(|p| p.trim_end_matches('/').parse().ok())
            .expect("a port in the HTTP address")
    }

    /// `POST /v1/sessions` with `lights`; the new session's id.
    pub async fn create_session(&self, lights: Value, token: Option<&str>) -> String {
        let client = reqwest::Client::new();
        let request = client
            .post(format!("{}/v1/sessions", self.http))
            .json(&json!({"scene": "box", "lights": lights}));
        let answer = send(request, token, "POST /v1/sessions").await;
        answer["session_id"]
            .as_str()
            .expect("a session id")
            .to_owned()
    }

    /// `PUT /v1/sessions/{id}/lights`; the new lights version.
    pub async fn set_lights(&self, session: &str, lights: Value, token: Option<&str>) -> u64 {
        let client = reqwest::Client::new();
        let request = client
            .put(format!("{}/v1/sessions/{session}/lights", self.http))
            .json(&json!({"lights": lights}));
        let answer = send(request, token, "PUT lights").await;
        answer["lights_version"].as_u64().expect("a lights version")
    }

    /// `GET /v1/sessions/{id}`: the session as the server holds it.
    pub async fn session(&self, session: &str) -> Value {
        reqwest::get(format!("{}/v1/sessions/{session}", self.http))
            .await
            .expect("GET the session")
            .error_for_status()
            .expect("the session exists")
            .json()
            .await
            .expect("the session as JSON")
    }

    /// `GET /v1/scenes/box/layout`, read by the client library.
    pub async fn layout(&self) -> bounce_client::layout::Layout {
        let bytes = reqwest::get(format!("{}/v1/scenes/box/layout", self.http))
            .await
            .and_then(|r| r.error_for_status())
            .expect("the layout")
            .bytes()
            .await
            .expect("its bytes");
        bounce_client::layout::Layout::from_json(&bytes).expect("a valid layout")
    }

    /// The first frame a gRPC subscriber to `session` gets.
    pub async fn first_frame(&self, session: &str) -> bounce_server::proto::Frame {
        use bounce_server::proto::{self, bounce_client::BounceClient};
        let mut grpc = BounceClient::connect(self.grpc.clone())
            .await
            .expect("a gRPC connection");
        grpc.subscribe(proto::SubscribeRequest {
            session_id: session.to_string(),
        })
        .await
        .expect("a subscription")
        .into_inner()
        .message()
        .await
        .expect("the stream")
        .expect("a frame")
    }

    pub fn page_url(&self, session: &str, extra: &str) -> String {
        format!("{}/?scene=box&session={session}{extra}", self.http)
    }
}

/// Sends a write (with the token, if any) and returns its JSON answer; a refusal fails the test.
async fn send(mut request: reqwest::RequestBuilder, token: Option<&str>, what: &str) -> Value {
    if let Some(t) = token {
        request = request.bearer_auth(t);
    }
    request
        .send()
        .await
        .and_then(|r| r.error_for_status())
        .unwrap_or_else(|e| panic!("{what}: {e}"))
        .json()
        .await
        .unwrap_or_else(|e| panic!("{what}: not JSON: {e}"))
}

/// The Cornell box written into `dir` with every triangle's winding reversed and its normals
/// removed: glTF then asks for flat normals from the winding, which now faces out of the box.
/// Returns the new `scene.gltf`.
pub fn cornell_reversed(dir: &Path) -> PathBuf {
    let source = cornell();
    let mut gltf: Value = serde_json::from_slice(&std::fs::read(&source).expect("read the box"))
        .expect("the box is JSON");
    let uri = gltf["buffers"][0]["uri"]
        .as_str()
        .expect("one external buffer")
        .to_owned();
    let mut bin = std::fs::read(source.with_file_name(&uri)).expect("read the buffer");
    let mut reversed = std::collections::HashSet::new();
    let meshes = gltf["meshes"].as_array().expect("meshes").len();
    for m in 0..meshes {
        let primitives = gltf["meshes"][m]["primitives"]
            .as_array_mut()
            .expect("primitives");
        for p in primitives {
            p["attributes"]
                .as_object_mut()
                .expect("attributes")
                .remove("NORMAL");
            // Swapped below, once per accessor however many primitives share it.
            reversed.insert(p["indices"].as_u64().expect("indexed triangles") as usize);
        }
    }
    for indices in reversed {
        let accessor = &gltf["accessors"][indices];
        let view = &gltf["bufferViews"][accessor["bufferView"].as_u64().expect("a view") as usize];
        let offset = view["byteOffset"].as_u64().unwrap_or(0) as usize
            + accessor["byteOffset"].as_u64().unwrap_or(0) as usize;
        let size = match accessor["componentType"].as_u64() {
            Some(5121) => 1,
            Some(5123) => 2,
            Some(5125) => 4,
            other => panic!("index component type {other:?}"),
        };
        let count = accessor["count"].as_u64().expect("a count") as usize;
        for t in 0..count / 3 {
            let (b, c) = (offset + (3 * t + 1) * size, offset + (3 * t + 2) * size);
            for k in 0..size {
                bin.swap(b + k, c + k);
            }
        }
    }
    std::fs::create_dir_all(dir).expect("the model directory");
    std::fs::write(dir.join(&uri), &bin).expect("write the buffer");
    let path = dir.join("scene.gltf");
    std::fs::write(&path, serde_json::to_vec(&gltf).expect("JSON")).expect("write the glTF");
    path
}
