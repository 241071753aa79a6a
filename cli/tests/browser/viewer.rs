//! The browser viewer (web/public, served by `bounce serve`) in headless Chromium against a real
//! server: it loads cleanly, draws the streamed indirect light where it belongs, opens a scene
//! from its name alone (`/?scene=NAME`), shares a session with other tabs and a gRPC subscriber,
//! draws what `bounce render` draws, explains refusals, and rides out a server restart.

use std::path::{Path, PathBuf};
use std::time::Duration;

use bounce_client::volume::Volume;
use bounce_server::frame::Frame;
use bounce_server::proto::{self, bounce_client::BounceClient};
use glam::{Mat4, Vec3};
use image::RgbaImage;
use serde_json::{Value, json};

use crate::cdp::{Browser, MouseButton, MouseKind, Page};
use crate::fixture::{Serve, ServeOptions, bounce, ceiling_light, cornell};

pub(crate) const WAIT: Duration = Duration::from_secs(90);
const W: u32 = 320;
const H: u32 = 240;
/// The camera both viewers use for pictures: the box from the open side.
pub(crate) const EYE: [f32; 3] = [0.0, 1.0, 3.4];
const TARGET: [f32; 3] = [0.0, 1.0, 0.0];
const FOV: f32 = 45.0;

pub(crate) fn camera_param() -> String {
    let v: Vec<String> = EYE
        .iter()
        .chain(&TARGET)
        .chain(&[FOV])
        .map(|x| x.to_string())
        .collect();
    v.join(",")
}

/// Page parameters for a picture comparable with `bounce render`: no overlay, buttons, light
/// markers or antialiasing, one pixel per CSS pixel.
pub(crate) fn picture_params() -> String {
    picture_params_from(&camera_param())
}

fn picture_params_from(camera: &str) -> String {
    format!("&camera={camera}&overlay=off&ui=off&markers=off&aa=off&pixel_ratio=1")
}

pub(crate) async fn open(browser: &Browser, url: &str) -> Page {
    let page = browser.new_page(W, H).await.expect("a page");
    page.goto(url).await.expect("the page loads");
    page
}

/// Waits until the viewer has drawn its first frame of indirect light.
pub(crate) async fn wait_drawn(page: &Page) -> Value {
    page.wait_for(
        "window.bounceError ? {error: window.bounceError} : window.bounce?.drawn",
        WAIT,
    )
    .await
    .map(|v| {
        assert!(v.get("error").is_none(), "the page failed: {v}");
        v
    })
    .expect("the first indirect frame is drawn")
}

/// Two animation frames later: whatever was set is on screen.
pub(crate) async fn settle(page: &Page) {
    page.eval(
        "new Promise(r => requestAnimationFrame(() => requestAnimationFrame(() => r(true))))",
    )
    .await
    .expect("animation frames run");
}

pub(crate) async fn screenshot(page: &Page) -> RgbaImage {
    settle(page).await;
    let png = page.screenshot_png().await.expect("a screenshot");
    image::load_from_memory(&png).expect("a PNG").to_rgba8()
}

pub(crate) fn assert_no_errors(page: &Page) {
    let errors = page.errors();
    assert!(errors.is_empty(), "console errors: {errors:#?}");
}

/// Where a world point lands in a `W`×`H` picture from the test camera (top-left origin).
pub(crate) fn project(p: Vec3) -> (u32, u32) {
    // The native renderer's own camera: the same projection the page must match.
    let camera = bounce_render::Camera {
        eye: Vec3::from(EYE),
        target: Vec3::from(TARGET),
        fov_y: FOV.to_radians(),
    };
    let bounds = (Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 2.0, 1.0));
    let view_proj: Mat4 = camera
        .view_proj(W as f32 / H as f32, bounds)
        .expect("a valid camera");
    let ndc = view_proj.project_point3(p);
    let x = ((ndc.x + 1.0) / 2.0 * W as f32) as u32;
    let y = ((1.0 - ndc.y) / 2.0 * H as f32) as u32;
    (x.min(W - 1), y.min(H - 1))
}

pub(crate) fn rgb(img: &RgbaImage, (x, y): (u32, u32)) -> [f32; 3] {
    let p = img.get_pixel(x, y).0;
    [p[0], p[1], p[2]].map(f32::from)
}

fn luma(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_lists_scenes_and_draws_the_indirect_light_where_it_belongs() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let serve = Serve::start(ServeOptions::default());
    let session = serve.create_session(ceiling_light(), None).await;

    // The landing page lists the scene and its session.
    let home = open(&browser, &format!("{}/", serve.http)).await;
    let listed = home
        .wait_for(
            "document.querySelectorAll('.sessions a').length > 0 && \
             [...document.querySelectorAll('#scenes h2')].map(h => h.textContent)",
            WAIT,
        )
        .await
        .expect("the scene list shows");
    assert_eq!(listed, json!(["box"]));
    let link = home
        .eval("document.querySelector('.sessions a').textContent")
        .await
        .unwrap();
    assert_eq!(link, json!(session));
    assert_no_errors(&home);

    let page = open(&browser, &serve.page_url(&session, &picture_params())).await;
    let drawn = wait_drawn(&page).await;
    assert_eq!(drawn["lightsVersion"], 1, "{drawn}");
    let scenes: Value = reqwest::get(format!("{}/v1/scenes", serve.http))
        .await
        .and_then(|r| r.error_for_status())
        .expect("the scene list")
        .json()
        .await
        .expect("JSON");
    let patches = scenes["scenes"][0]["patch_count"]
        .as_u64()
        .expect("a patch count");
    assert_eq!(drawn["bytes"].as_u64(), Some(32 + 4 * patches), "{drawn}");
    assert_no_errors(&page);

    page.eval("window.bounce.setTerms('direct')").await.unwrap();
    let direct = screenshot(&page).await;
    page.eval("window.bounce.setTerms('both')").await.unwrap();
    let both = screenshot(&page).await;

    // Shadowed floor: points the light does not reach (black with direct light only) get
    // light from the walls.
    let mut shadowed = Vec::new();
    for i in 0..=16 {
        for k in 0..=16 {
            let p = Vec3::new(
                -0.95 + 1.9 * i as f32 / 16.0,
                0.001,
                -0.95 + 1.9 * k as f32 / 16.0,
            );
            let px = project(p);
            if luma(rgb(&direct, px)) < 4.0 {
                shadowed.push(px);
            }
        }
    }
    assert!(
        shadowed.len() >= 5,
        "the ceiling light must leave some floor in shadow ({} points)",
        shadowed.len()
    );
    let mean = |img: &RgbaImage| {
        shadowed.iter().map(|&p| luma(rgb(img, p))).sum::<f32>() / shadowed.len() as f32
    };
    let (off, on) = (mean(&direct), mean(&both));
    assert!(
        on > off + 15.0,
        "shadowed floor: {off:.1} without indirect light, {on:.1} with it"
    );

    // The floor beside the red (left, −X) wall turns red with its bounce light.
    // Red over green, averaged over a strip of floor along the wall.
    let redness = |img: &RgbaImage| {
        let strip: Vec<[f32; 3]> = (0..6)
            .map(|k| rgb(img, project(Vec3::new(-0.85, 0.001, -0.6 + 0.2 * k as f32))))
            .collect();
        strip.iter().map(|c| c[0] / c[1].max(1.0)).sum::<f32>() / strip.len() as f32
    };
    let (off, on) = (redness(&direct), redness(&both));
    assert!(
        on > off + 0.02,
        "floor beside the red wall, red/green: {off:.3} without indirect light, {on:.3} with it"
    );
    assert_no_errors(&page);
}

/// FNV-1a over a frame's payload words: the page computes the same (viewer.js `checksum`).
pub(crate) fn checksum(frame: &Frame) -> u64 {
    let mut h: u32 = 0x811c_9dc5;
    for w in frame.words() {
        h = (h ^ w).wrapping_mul(0x0100_0193);
    }
    u64::from(h)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tabs_and_a_grpc_subscriber_share_one_session() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let serve = Serve::start(ServeOptions::default());
    let session = serve.create_session(ceiling_light(), None).await;

    // A gRPC subscriber records every frame it gets.
    let mut grpc = BounceClient::connect(serve.grpc.clone())
        .await
        .expect("gRPC connects");
    let mut stream = grpc
        .subscribe(proto::SubscribeRequest {
            session_id: session.clone(),
        })
        .await
        .expect("subscribe")
        .into_inner();
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    tokio::spawn(async move {
        while let Ok(Some(f)) = stream.message().await {
            if let Ok(frame) = Frame::parse(f.data) {
                let _ = tx.send(frame);
            }
        }
    });

    let url = serve.page_url(&session, &picture_params());
    let a = open(&browser, &url).await;
    let b = open(&browser, &url).await;
    wait_drawn(&a).await;
    wait_drawn(&b).await;
    let before = screenshot(&b).await;

    // Tab A moves the light and tints it; tab B draws the new light.
    let moved = json!({"lights": [{"type": "point", "position": [0.6, 1.2, 0.2],
        "intensity": 14.0, "color": [1.0, 0.4, 0.3]}]});
    let edit = a
        .eval(&format!("window.bounce.setLights({moved})"))
        .await
        .expect("A sets lights");
    let version = edit["answer"]["lights_version"]
        .as_u64()
        .expect("a version");
    assert_eq!(version, 2, "{edit}");
    let shown = b
        .eval(&format!("window.bounce.drawnVersion({version})"))
        .await
        .expect("B draws the new light");
    assert_eq!(shown["lightsVersion"], version);
    let b_lights = b
        .wait_for(
            "window.bounce.lights.lights[0]?.intensity === 14 && window.bounce.lights",
            WAIT,
        )
        .await
        .expect("B reads the new lights for its direct light");
    // Compared as lights (JavaScript writes 1.0 as 1).
    let as_lights = |v: Value| -> bounce_core::light::LightSet {
        serde_json::from_value(v).expect("a light set")
    };
    assert_eq!(as_lights(b_lights), as_lights(moved));
    let after = screenshot(&b).await;
    let changed = before
        .pixels()
        .zip(after.pixels())
        .filter(|(p, q)| (0..3).any(|c| p.0[c].abs_diff(q.0[c]) > 20))
        .count();
    assert!(
        changed > (W * H / 10) as usize,
        "B's picture changed in only {changed} pixels"
    );

    // The frames B received are frames the gRPC subscriber received, in the same order, and
    // its newest is the subscriber's newest.
    let received: Vec<(u64, u64, u64)> =
        serde_json::from_value::<Vec<Value>>(b.eval("window.bounce.received").await.unwrap())
            .unwrap()
            .iter()
            .map(|f| {
                (
                    f["lightsVersion"].as_u64().unwrap(),
                    f["sequence"].as_u64().unwrap(),
                    f["checksum"].as_u64().unwrap(),
                )
            })
            .collect();
    let mut seen = Vec::new();
    while seen.last().map(|s: &(u64, u64, u64)| s.0) != Some(version) {
        let frame = tokio::time::timeout(WAIT, rx.recv())
            .await
            .expect("the subscriber gets the new frame")
            .expect("the stream is open");
        let h = frame.header;
        seen.push((h.lights_version, h.sequence, checksum(&frame)));
    }
    let mut rest = seen.iter();
    for r in &received {
        assert!(
            rest.any(|s| s == r),
            "B got {r:?}, which the subscriber did not get in that order: {seen:?}"
        );
    }
    assert_eq!(received.last(), seen.last());

    // A real drag: the mouse moves tab A's light marker, B follows.
    let at = a.eval("window.bounce.markerOnScreen(0)").await.unwrap();
    let (x, y) = (at["x"].as_f64().unwrap(), at["y"].as_f64().unwrap());
    a.mouse(MouseKind::Move, x, y).await.unwrap();
    a.mouse(MouseKind::Down(MouseButton::Left), x, y)
        .await
        .unwrap();
    for step in 1..=5 {
        a.mouse(MouseKind::Move, x - 8.0 * f64::from(step), y)
            .await
            .unwrap();
    }
    a.mouse(MouseKind::Up(MouseButton::Left), x - 40.0, y)
        .await
        .unwrap();
    let dragged = a
        .wait_for(
            "window.bounce.lights.lights[0].position[0] < 0.55 && window.bounce.lights",
            WAIT,
        )
        .await
        .expect("the drag moves the light");
    let dragged_x = dragged["lights"][0]["position"][0].as_f64().unwrap();
    b.wait_for(
        &format!("Math.abs(window.bounce.lights.lights[0].position[0] - {dragged_x}) < 1e-6"),
        WAIT,
    )
    .await
    .expect("B follows A's drag");
    assert_no_errors(&a);
    assert_no_errors(&b);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_browser_draws_what_bounce_render_draws() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let serve = Serve::start(ServeOptions::default());
    let spot = json!([{"type": "spot", "position": [0.0, 1.9, 0.0], "direction": [0.0, -1.0, 0.0],
        "intensity": 15.0, "inner_cone_angle": 0.5, "outer_cone_angle": 0.9}]);
    assert_draws_as_native(&browser, &serve, &cornell(), spot).await;
}

/// pandora has no normals and its triangles face either way. Both viewers draw both sides, lit
/// on the side that is seen; the page once offset its shadow lookups along the winding's normal,
/// into the surface wherever that faced away, and such walls went black in direct light. The box
/// here is the Cornell box with every triangle's winding reversed and its normals removed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scene_without_normals_facing_away_is_drawn_as_bounce_render_draws_it() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let (serve, gltf) = Serve::scene_of(crate::fixture::cornell_reversed);
    assert_draws_as_native(&browser, &serve, &gltf, ceiling_light()).await;
    let spot = json!([{"type": "spot", "position": [0.3, 1.9, 0.2], "direction": [0.0, -1.0, 0.0],
        "intensity": 15.0, "inner_cone_angle": 0.5, "outer_cone_angle": 0.9}]);
    assert_draws_as_native(&browser, &serve, &gltf, spot).await;
    // In through the open side, onto the back wall and the floor.
    let sun = json!([{"type": "directional", "direction": [0.2, -0.5, -1.0], "intensity": 3.0}]);
    assert_draws_as_native(&browser, &serve, &gltf, sun).await;
}

/// Two lamps sharing a material (`bounce_testkit::scenes::two_lamps`), one switched off by its
/// node: the page darkens that lamp alone (its material per node), and draws what `bounce
/// render` draws, the room lit by the other lamp through the session's indirect light.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_emissive_change_by_node_darkens_one_lamp_in_both_viewers() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let (serve, gltf) = Serve::scene_of(bounce_testkit::scenes::two_lamps);
    let lights = json!([{"type": "emissive", "node": "Lamp 2", "strength": 0}]);
    let session = serve.create_session(lights.clone(), None).await;
    // From the open side, below both lamps.
    let camera = "-278,274,1100,-278,300,-280,45".to_string();
    let page = browser.new_page(W, H).await.expect("a page");
    page.goto(&serve.page_url(&session, &picture_params_from(&camera)))
        .await
        .expect("the page loads");
    wait_drawn(&page).await;
    let mut drawn = page
        .eval("window.bounce.emissive")
        .await
        .expect("the emissive materials");
    let drawn = drawn.as_array_mut().expect("a list");
    drawn.sort_by_key(|e| e["node"].as_str().unwrap_or_default().to_string());
    assert_eq!(drawn.len(), 2, "one material per lamp: {drawn:?}");
    assert_eq!(drawn[0]["node"], "Lamp 2");
    assert!(
        drawn[0]["emissive"]
            .as_array()
            .is_some_and(|c| c.iter().all(|v| v.as_f64() == Some(0.0))),
        "switched off: {drawn:?}"
    );
    assert_eq!(drawn[1]["node"], "Light");
    assert!(
        drawn[1]["emissive"][0].as_f64().is_some_and(|v| v > 1.0),
        "the other lamp glows as the file says: {drawn:?}"
    );
    let picture = Picture {
        camera,
        width: W,
        height: H,
    };
    let (mean, large) = difference_from_native(&browser, &serve, &gltf, &session, &picture).await;
    assert!(
        mean <= 4.0 && large <= 0.03,
        "two lamps, one off by node: browser against native: mean difference {mean:.2}/255, \
         {:.2}% of pixels off by more than 32",
        large * 100.0
    );
}

/// A session of `serve` with `lights`, drawn by the page and by `bounce render --server` (its
/// indirect light from the same session's frame) from the test camera: the same picture, up to
/// a small mean difference and a few pixels on edges.
async fn assert_draws_as_native(browser: &Browser, serve: &Serve, gltf: &Path, lights: Value) {
    let session = serve.create_session(lights.clone(), None).await;
    let picture = Picture {
        camera: camera_param(),
        width: W,
        height: H,
    };
    let (mean, large) = difference_from_native(browser, serve, gltf, &session, &picture).await;
    assert!(
        mean <= 4.0 && large <= 0.03,
        "{} with {lights}: browser against native: mean difference {mean:.2}/255, {:.2}% of \
         pixels off by more than 32 (pictures saved in the temp dir)",
        gltf.display(),
        large * 100.0
    );
}

/// What both viewers draw: from where, and how big.
struct Picture {
    camera: String,
    width: u32,
    height: u32,
}

/// The page's and `bounce render --server`'s pictures of `session`'s current frame: the mean of
/// the per-pixel largest channel difference (of 255), and the share of pixels off by more than 32.
/// Over 4/255 or 3%, both pictures are saved in the temp dir.
async fn difference_from_native(
    browser: &Browser,
    serve: &Serve,
    gltf: &Path,
    session: &str,
    picture: &Picture,
) -> (f64, f64) {
    let params = picture_params_from(&picture.camera);
    let page = browser
        .new_page(picture.width, picture.height)
        .await
        .expect("a page");
    page.goto(&serve.page_url(session, &params))
        .await
        .expect("the page loads");
    let drawn = wait_drawn(&page).await;
    let browser_img = screenshot(&page).await;
    assert_no_errors(&page);
    let lights = serve.session(session).await["lights"].clone();

    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("native.png");
    let lights_file = dir.path().join("lights.json");
    std::fs::write(&lights_file, json!({ "lights": lights }).to_string()).unwrap();
    let out = bounce()
        .arg("render")
        .arg(gltf)
        .args(["--server", &serve.grpc, "--scene-name", "box"])
        .args(["--session", session])
        .arg("--lights")
        .arg(&lights_file)
        .args(["--camera", &picture.camera])
        .args(["--width", &picture.width.to_string()])
        .args(["--height", &picture.height.to_string(), "--out"])
        .arg(&png)
        .env("XDG_RUNTIME_DIR", dir.path())
        .output()
        .expect("bounce render runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let native = image::open(&png).expect("a PNG").to_rgba8();
    assert_eq!(native.dimensions(), browser_img.dimensions());

    let diffs: Vec<u8> = native
        .pixels()
        .zip(browser_img.pixels())
        .map(|(p, q)| (0..3).map(|c| p.0[c].abs_diff(q.0[c])).max().unwrap_or(0))
        .collect();
    let mean = diffs.iter().map(|&d| f64::from(d)).sum::<f64>() / diffs.len() as f64;
    let large = diffs.iter().filter(|&&d| d > 32).count() as f64 / diffs.len() as f64;
    eprintln!(
        "{} with {lights} (frame {}): mean difference {mean:.2}/255, {:.2}% of pixels off by more \
         than 32",
        gltf.display(),
        drawn["sequence"],
        large * 100.0
    );
    if mean > 4.0 || large > 0.03 {
        let _ = native.save(std::env::temp_dir().join("bounce-native.png"));
        let _ = browser_img.save(std::env::temp_dir().join("bounce-browser.png"));
    }
    (mean, large)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_pages_volume_samples_as_the_client_library_does() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let serve = Serve::start(ServeOptions::default());
    let session = serve.create_session(ceiling_light(), None).await;
    let page = open(&browser, &serve.page_url(&session, "&overlay=off")).await;
    wait_drawn(&page).await;

    let layout = serve.layout().await;
    let frame = Frame::parse(serve.first_frame(&session).await.data).unwrap();
    let mut volume = Volume::new(&layout).unwrap();
    volume.apply(&frame).unwrap();
    let drawn = page.eval("window.bounce.received.at(-1)").await.unwrap();
    assert_eq!(drawn["checksum"].as_u64(), Some(checksum(&frame)));

    let points = [
        (Vec3::new(-0.5, 0.01, 0.2), Vec3::Y),
        (Vec3::new(-0.98, 1.0, -0.3), Vec3::X),
        (Vec3::new(0.3, 1.98, 0.1), Vec3::NEG_Y),
        (
            Vec3::new(0.2, 0.7, -0.99),
            Vec3::new(0.3, 0.2, 0.93).normalize(),
        ),
        (Vec3::new(0.95, 0.4, 0.5), Vec3::NEG_X),
    ];
    for (p, n) in points {
        let js = page
            .eval(&format!(
                "window.bounce.sample([{},{},{}],[{},{},{}])",
                p.x, p.y, p.z, n.x, n.y, n.z
            ))
            .await
            .unwrap();
        let js: Vec<f32> = serde_json::from_value(js).unwrap();
        let rust = volume.sample(p, n);
        for c in 0..3 {
            assert!(
                (js[c] - rust[c]).abs() <= 1e-5 * rust[c].abs().max(1.0),
                "at {p} {n}: page {js:?}, client {rust:?}"
            );
        }
    }
}

/// A server with a read token: the page without one says which token to bring; with it (in the
/// page's URL, as for writes) the page reads the scene, its model and its frames and draws.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_read_token_is_asked_for_and_used() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let serve = Serve::start(ServeOptions {
        read_token: Some("peek"),
        ..ServeOptions::default()
    });
    let session = serve.create_session(ceiling_light(), None).await;
    let refused = open(&browser, &serve.page_url(&session, "")).await;
    let text = refused
        .wait_for("window.bounceError", WAIT)
        .await
        .expect("an error is shown");
    assert!(
        text.as_str()
            .is_some_and(|t| t.contains("token for reads") && t.contains("?token=")),
        "{text}"
    );
    let reader = open(&browser, &serve.page_url(&session, "&token=peek")).await;
    wait_drawn(&reader).await;
    assert_no_errors(&reader);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn refusals_and_missing_sessions_are_explained() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let serve = Serve::start(ServeOptions {
        token: Some("sesame"),
        ..ServeOptions::default()
    });
    let session = serve.create_session(ceiling_light(), Some("sesame")).await;

    // No token: the page watches, and says why a light does not move.
    let spectator = open(&browser, &serve.page_url(&session, "")).await;
    wait_drawn(&spectator).await;
    assert_eq!(
        spectator.eval("window.bounce.writable").await.unwrap(),
        json!(false)
    );
    spectator
        .eval("window.bounce.setLights({lights: []})")
        .await
        .unwrap();
    let message = spectator.eval("window.bounce.message").await.unwrap();
    assert!(
        message.as_str().is_some_and(|m| m.contains("read-only")),
        "{message}"
    );

    // A wrong token: the server refuses the write, the page says so and keeps the session's
    // lights.
    let wrong = open(&browser, &serve.page_url(&session, "&token=wrong")).await;
    wait_drawn(&wrong).await;
    wrong
        .eval("window.bounce.setLights({lights: []})")
        .await
        .unwrap();
    let state = wrong
        .wait_for(
            "window.bounce.lights.lights.length === 1 && !window.bounce.writable && \
             window.bounce.message",
            WAIT,
        )
        .await
        .expect("the refusal is shown");
    assert!(
        state.as_str().is_some_and(|m| m.contains("read-only")),
        "{state}"
    );

    // The right token writes.
    let writer = open(&browser, &serve.page_url(&session, "&token=sesame")).await;
    wait_drawn(&writer).await;
    let edit = writer
        .eval("window.bounce.setLights({lights: [{type: 'point', position: [0, 1, 0], intensity: 3}]})")
        .await
        .unwrap();
    assert_eq!(edit["answer"]["lights_version"], 2, "{edit}");
    assert_no_errors(&writer);

    // An unknown session.
    let lost = open(&browser, &serve.page_url("0123456789abcdef", "")).await;
    let text = lost
        .wait_for("window.bounceError", WAIT)
        .await
        .expect("an error is shown");
    assert!(
        text.as_str()
            .is_some_and(|t| t.contains("0123456789abcdef")),
        "{text}"
    );
    let shown = lost
        .eval("document.getElementById('message').textContent")
        .await
        .unwrap();
    assert_eq!(shown, text);
}

/// The session ids the server lists for scene `box`, newest first.
async fn box_sessions(serve: &Serve) -> Vec<String> {
    let answer: Value = reqwest::get(format!("{}/v1/sessions?scene=box", serve.http))
        .await
        .and_then(|r| r.error_for_status())
        .expect("the session list")
        .json()
        .await
        .expect("JSON");
    answer["sessions"]
        .as_array()
        .expect("a list of sessions")
        .iter()
        .map(|s| s["session_id"].as_str().expect("an id").to_owned())
        .collect()
}

/// The session the page's address bar names.
async fn session_in_address_bar(page: &Page) -> String {
    let search = page.eval("location.search").await.expect("the address bar");
    let search = search.as_str().expect("a string").to_owned();
    search
        .trim_start_matches('?')
        .split('&')
        .find_map(|kv| kv.strip_prefix("session="))
        .unwrap_or_else(|| panic!("no session in {search}"))
        .to_owned()
}

/// `/?scene=NAME`, the URL a newcomer types, opens the scene, not the list: on a new session
/// when the scene has none, on its newest one otherwise; and it explains what it cannot do.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_scene_url_opens_the_scene_on_its_newest_session_or_a_new_one() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let serve = Serve::start(ServeOptions::default());
    assert!(box_sessions(&serve).await.is_empty());

    // No session yet: the page starts one, draws it, and names it in the address bar.
    let url = format!("{}/?scene=box", serve.http);
    let first = open(&browser, &url).await;
    let drawn = wait_drawn(&first).await;
    assert_eq!(drawn["lightsVersion"], 1, "{drawn}");
    let made = box_sessions(&serve).await;
    assert_eq!(made.len(), 1, "one session made: {made:?}");
    assert_eq!(session_in_address_bar(&first).await, made[0]);
    assert_no_errors(&first);

    // A newer session: the same URL joins it rather than making a third.
    let newer = serve.create_session(ceiling_light(), None).await;
    let second = open(&browser, &url).await;
    wait_drawn(&second).await;
    assert_eq!(session_in_address_bar(&second).await, newer);
    assert_eq!(box_sessions(&serve).await.len(), 2, "no session made");
    assert_no_errors(&second);

    // An unknown scene is named, with the ones there are.
    let lost = open(&browser, &format!("{}/?scene=nope", serve.http)).await;
    let text = lost
        .wait_for("window.bounceError", WAIT)
        .await
        .expect("an error is shown");
    assert!(
        text.as_str()
            .is_some_and(|t| t.contains("\"nope\"") && t.contains("box")),
        "{text}"
    );

    // A server that needs a token for writes cannot start a session without one: the page says
    // so; with the token it starts one, and the token leaves the address bar.
    let guarded = Serve::start(ServeOptions {
        token: Some("sesame"),
        ..ServeOptions::default()
    });
    let url = format!("{}/?scene=box", guarded.http);
    let refused = open(&browser, &url).await;
    let text = refused
        .wait_for("window.bounceError", WAIT)
        .await
        .expect("an error is shown");
    assert!(text.as_str().is_some_and(|t| t.contains("token")), "{text}");
    assert!(box_sessions(&guarded).await.is_empty());
    let writer = open(&browser, &format!("{url}&token=sesame")).await;
    wait_drawn(&writer).await;
    assert_eq!(
        session_in_address_bar(&writer).await,
        box_sessions(&guarded).await[0]
    );
    let search = writer.eval("location.search").await.unwrap();
    assert!(
        search.as_str().is_some_and(|s| !s.contains("sesame")),
        "{search}"
    );
    assert_no_errors(&writer);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_keeps_its_light_through_a_restart_and_reconnects() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let serve = Serve::start(ServeOptions::default());
    let port = serve.port();
    let session = serve.create_session(ceiling_light(), None).await;
    let page = open(&browser, &serve.page_url(&session, "")).await;
    let first = wait_drawn(&page).await;

    let dir = serve.kill();
    let state = page
        .wait_for(
            "window.bounce.connection.state === 'disconnected' && window.bounce.connection",
            WAIT,
        )
        .await
        .expect("the page notices");
    assert!(state["detail"].is_string(), "{state}");
    // Still lit by the last frame.
    assert_eq!(
        page.eval("window.bounce.drawn").await.unwrap()["sequence"],
        first["sequence"]
    );

    let serve = Serve::start(ServeOptions {
        http_port: Some(port),
        dir: Some(dir),
        ..ServeOptions::default()
    });
    page.wait_for("window.bounce.connection.state === 'live'", WAIT)
        .await
        .expect("the page reconnects");
    let version = serve
        .set_lights(
            &session,
            json!([{"type": "point", "position": [0.2, 1.4, 0.0], "intensity": 8.0}]),
            None,
        )
        .await;
    page.eval(&format!("window.bounce.drawnVersion({version})"))
        .await
        .expect("frames flow again");
    let errors: Vec<String> = page
        .errors()
        .into_iter()
        // The browser reports the refused reconnection attempts while the server is down.
        .filter(|e| !e.contains("WebSocket") && !e.contains("ERR_CONNECTION_REFUSED"))
        .collect();
    assert!(errors.is_empty(), "{errors:#?}");
}

/// The figures the README quotes, on a baked scene of your choice (not run by default: it is a
/// measurement, not a check). `BOUNCE_FIGURES_BAKED=pandora.bounce BOUNCE_FIGURES_CAMERA=...
/// BOUNCE_FIGURES_LIGHTS='[...]' cargo test --release -p bounce-cli --test browser -- --ignored
/// --nocapture figures`: page load to the first lit frame, frame interval and draw time in
/// headless chromium, bytes per frame, and a light moved in one tab to the new indirect light
/// drawn in another (median of `BOUNCE_FIGURES_MOVES`, 10 by default).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "a measurement; run it by name"]
async fn figures() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let baked = std::env::var("BOUNCE_FIGURES_BAKED").ok();
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("scenes")).unwrap();
    let source = baked
        .clone()
        .map_or_else(|| crate::fixture::baked_cornell().to_path_buf(), Into::into);
    std::fs::copy(&source, dir.path().join("scenes/box.bounce")).expect("copy the baked file");
    // A file baked before models were kept: its model beside it. `bounce render` needs it too.
    let model = std::env::var("BOUNCE_FIGURES_MODEL")
        .ok()
        .map(PathBuf::from);
    if let Some(model) = &model {
        std::fs::copy(model, dir.path().join("scenes/box.glb")).expect("copy the model");
    }
    let model = model.or_else(|| baked.is_none().then(cornell));
    let serve = Serve::start(ServeOptions {
        dir: Some(dir),
        ..ServeOptions::default()
    });
    let lights: Value = std::env::var("BOUNCE_FIGURES_LIGHTS")
        .ok()
        .map(|l| serde_json::from_str(&l).expect("BOUNCE_FIGURES_LIGHTS is a JSON array"))
        .unwrap_or_else(ceiling_light);
    let camera_value = std::env::var("BOUNCE_FIGURES_CAMERA").ok();
    let camera = camera_value
        .as_ref()
        .map_or(String::new(), |c| format!("&camera={c}"));
    let moves: usize = std::env::var("BOUNCE_FIGURES_MOVES")
        .ok()
        .and_then(|m| m.parse().ok())
        .unwrap_or(10);
    let session = serve.create_session(lights.clone(), None).await;
    let url = serve.page_url(&session, &format!("{camera}&pixel_ratio=1"));
    let a = browser.new_page(960, 540).await.unwrap();
    let started = std::time::Instant::now();
    a.goto(&url).await.unwrap();
    let first = wait_drawn(&a).await;
    let wall_first = started.elapsed();
    let b = open(&browser, &url).await;
    wait_drawn(&b).await;
    let mut latencies = Vec::new();
    for i in 0..moves {
        let mut set = lights.clone();
        if let Some(p) = set[0]["position"].as_array_mut() {
            let x = p[0].as_f64().unwrap_or(0.0);
            p[0] = json!(x + if i % 2 == 0 { 0.05 } else { -0.05 } * (1.0 + x.abs()));
        }
        let edit = a
            .eval(&format!(
                "window.bounce.setLights({})",
                json!({"lights": set})
            ))
            .await
            .unwrap();
        let version = edit["answer"]["lights_version"].as_u64().unwrap();
        let shown = b
            .eval(&format!("window.bounce.drawnVersion({version})"))
            .await
            .unwrap();
        latencies.push(
            shown["at_epoch_ms"].as_f64().unwrap() - edit["edited_at_epoch_ms"].as_f64().unwrap(),
        );
    }
    tokio::time::sleep(Duration::from_secs(3)).await;
    let stats = a.eval("window.bounce.stats").await.unwrap();
    latencies.sort_by(f64::total_cmp);
    let median = latencies[latencies.len() / 2];
    println!("figure,value");
    println!(
        "page load to first lit frame (performance.now at draw) ms,{:.0}",
        first["at"].as_f64().unwrap()
    );
    println!(
        "page load to first lit frame (test wall clock) ms,{:.0}",
        wall_first.as_secs_f64() * 1e3
    );
    println!(
        "frame interval median ms,{:.1}",
        stats["frame_interval_ms"].as_f64().unwrap_or(f64::NAN)
    );
    println!(
        "draw call median ms,{:.1}",
        stats["draw_ms"].as_f64().unwrap_or(f64::NAN)
    );
    println!("bytes per frame,{}", first["bytes"]);
    println!(
        "tab to tab latency median ms ({} moves),{median:.0}",
        latencies.len()
    );
    println!(
        "tab to tab latency min/max ms,{:.0}/{:.0}",
        latencies[0],
        latencies[latencies.len() - 1]
    );
    match model {
        Some(gltf) => {
            let picture = Picture {
                camera: camera_value.unwrap_or_else(camera_param),
                width: 640,
                height: 400,
            };
            let (mean, large) =
                difference_from_native(&browser, &serve, &gltf, &session, &picture).await;
            println!("page against bounce render 640x400 mean difference /255,{mean:.2}");
            println!(
                "page against bounce render 640x400 pixels off by more than 32 %,{:.2}",
                large * 100.0
            );
        }
        None => eprintln!(
            "no comparison with bounce render: it needs the scene's file (BOUNCE_FIGURES_MODEL)"
        ),
    }
}
