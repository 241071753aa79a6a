//! The viewer in a headset. There is no headset here, so an emulated one stands in for the
//! browser's WebXR device: IWER (Meta's Immersive Web Emulation Runtime, vendored from npm and
//! checked by `web/vendor.sh --check`; test-only, never served) installed in the page before its
//! scripts run. The page's own XR code then runs as on a headset: three's VRButton offers the
//! session, three renders both eyes, the frame loop keeps applying the streamed indirect light,
//! and a controller grabs, carries, dims and recolours a light, which reaches the session on the
//! server.

use image::RgbaImage;
use serde_json::{Value, json};

use crate::cdp::Page;
use crate::fixture::{Serve, ServeOptions, ceiling_light};
use crate::viewer::{WAIT, assert_no_errors, camera_param, open, screenshot, settle, wait_drawn};

const IWER: &str = include_str!("vendor/iwer/iwer.min.js");
/// The page for both eyes: each eye gets half the width.
const W: u32 = 640;
const H: u32 = 360;
/// Scene units in a headset's metre (the page's `xr_scale`).
const XR_SCALE: f64 = 2.0;

/// IWER's Quest 3 with both eyes drawn, installed over the browser's own `navigator.xr` (headless
/// chromium has one, with no device behind it).
pub(crate) fn headset_script() -> String {
    format!(
        "{IWER}\n;window.headset = new IWER.XRDevice(IWER.metaQuest3, {{ stereoEnabled: true }});\n\
         window.headset.installRuntime({{ forceInstall: true }});"
    )
}

async fn button_text(page: &Page) -> Value {
    page.eval("document.getElementById('vr-button')?.textContent ?? null")
        .await
        .expect("the page answers")
}

/// Clicks the VR button with the mouse: requestSession needs a user's gesture.
pub(crate) async fn click_vr_button(page: &Page) {
    let r = page
        .eval(
            "(() => { const r = document.getElementById('vr-button').getBoundingClientRect(); \
             return [r.left + r.width / 2, r.top + r.height / 2]; })()",
        )
        .await
        .expect("the button's place");
    let (x, y) = (r[0].as_f64().unwrap(), r[1].as_f64().unwrap());
    page.click(x, y).await.expect("a click");
}

/// The right controller at `position` in the session's reference space, pointing along -z (its
/// ray straight ahead of it), then two animation frames so the page has seen the pose.
pub(crate) async fn place_controller(page: &Page, position: [f64; 3]) {
    page.eval(&format!(
        "(() => {{ const c = window.headset.controllers.right; \
         c.position.set({}, {}, {}); c.quaternion.set(0, 0, 0, 1); }})()",
        position[0], position[1], position[2]
    ))
    .await
    .expect("the controller moves");
    settle(page).await;
}

async fn trigger(page: &Page, value: f64) {
    button(page, "trigger", value).await;
}

/// The right controller's `id` button ("trigger", "squeeze") pressed to `value`, then two
/// animation frames so the session has reported it.
async fn button(page: &Page, id: &str, value: f64) {
    page.eval(&format!(
        "window.headset.controllers.right.updateButtonValue('{id}', {value})"
    ))
    .await
    .expect("the button");
    settle(page).await;
}

/// The session once the server holds `light` (the page's newest edit; writes are coalesced, so
/// the last one sent is the page's last).
async fn until_stored(serve: &Serve, session: &str, light: &Value) -> Value {
    let close = |a: &Value, b: &Value| match (a.as_f64(), b.as_f64()) {
        (Some(a), Some(b)) => (a - b).abs() <= 1e-4 * b.abs().max(1.0),
        _ => false,
    };
    let start = std::time::Instant::now();
    loop {
        let stored = serve.session(session).await;
        let l = &stored["lights"][0];
        let same = close(&l["intensity"], &light["intensity"])
            && (0..3).all(|i| close(&l["position"][i], &light["position"][i]))
            && (0..3).all(|i| close(&l["color"][i], &light["color"][i]));
        if same {
            return stored;
        }
        assert!(
            start.elapsed() < WAIT,
            "the server holds {l}, the page {light}"
        );
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
}

async fn lights_version(serve: &Serve, session: &str) -> u64 {
    serve.session(session).await["lights_version"]
        .as_u64()
        .expect("a lights version")
}

/// The mean x (in its own half) of the red wall's pixels in each eye's half of the picture.
fn red_wall_x_per_eye(img: &RgbaImage) -> [f64; 2] {
    let half = img.width() / 2;
    [0, 1].map(|eye| {
        let (mut sum, mut n) = (0.0, 0u32);
        for y in 0..img.height() {
            for x in 0..half {
                let [r, g, b, _] = img.get_pixel(eye * half + x, y).0;
                if r > 60 && u16::from(r) > 2 * u16::from(g) && u16::from(r) > 2 * u16::from(b) {
                    sum += f64::from(x);
                    n += 1;
                }
            }
        }
        assert!(n > 100, "eye {eye} sees the red wall ({n} red pixels)");
        sum / f64::from(n)
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_headset_enters_vr_and_its_controller_carries_dims_and_recolours_a_light() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let serve = Serve::start(ServeOptions::default());
    let session = serve.create_session(ceiling_light(), None).await;
    let url = serve.page_url(&session, &format!("&camera={}", camera_param()));
    // A headset metre is two scene units here: grabbing and carrying are in metres of the
    // headset, the light moves in scene units.
    let xr_url = format!("{url}&xr_scale={XR_SCALE}");

    // Without a headset the button says why there is no VR.
    let plain = open(&browser, &url).await;
    wait_drawn(&plain).await;
    assert_eq!(button_text(&plain).await, json!("VR NOT SUPPORTED"));
    assert_no_errors(&plain);
    drop(plain);

    let page = browser.new_page(W, H).await.expect("a page");
    page.add_init_script(&headset_script())
        .await
        .expect("the headset is installed first");
    page.goto(&xr_url).await.expect("the page loads");
    wait_drawn(&page).await;
    assert_eq!(button_text(&page).await, json!("ENTER VR"));
    click_vr_button(&page).await;
    page.wait_for("window.bounce.xr.presenting", WAIT)
        .await
        .expect("an immersive session starts");
    assert_eq!(button_text(&page).await, json!("EXIT VR"));

    // Both eyes see the box, from places an eye distance apart: the left eye sees it further
    // right than the right eye does.
    let [left, right] = red_wall_x_per_eye(&screenshot(&page).await);
    let parallax = left - right;
    assert!(
        (0.5..40.0).contains(&parallax),
        "the red wall at x {left:.1} (left eye) and {right:.1} (right eye)"
    );

    let xr = page.eval("window.bounce.xr").await.unwrap();
    let rig: Vec<f64> = serde_json::from_value(xr["rig"].clone()).expect("the rig's place");
    assert_eq!(xr["scale"].as_f64(), Some(XR_SCALE));
    // The ceiling light, in the reference space (the rig is never rotated, only scaled).
    let light = [0.0, 1.5, 0.0].map(|v| v / XR_SCALE);
    let light = [0, 1, 2].map(|i| light[i] - rig[i] / XR_SCALE);
    let version = lights_version(&serve, &session).await;

    // A ray that passes 0.8 m from the light grabs nothing (it reaches 25 cm).
    place_controller(&page, [light[0] + 0.8, light[1], light[2] + 0.5]).await;
    trigger(&page, 1.0).await;
    assert_eq!(page.eval("window.bounce.xr.held").await.unwrap(), json!([]));
    trigger(&page, 0.0).await;
    assert_eq!(lights_version(&serve, &session).await, version);

    // Half a metre in front of the light, pointing at it: the trigger grabs it.
    place_controller(&page, [light[0], light[1], light[2] + 0.5]).await;
    trigger(&page, 1.0).await;
    page.wait_for("window.bounce.xr.held.length === 1", WAIT)
        .await
        .expect("the light is grabbed");
    // Held still, it sends nothing.
    for _ in 0..5 {
        settle(&page).await;
    }
    assert_eq!(lights_version(&serve, &session).await, version);

    // Carried 0.3 m to the right, 0.6 scene units: the light goes with the controller.
    place_controller(&page, [light[0] + 0.3, light[1], light[2] + 0.5]).await;
    page.wait_for(
        "Math.abs(window.bounce.lights.lights[0].position[0] - 0.6) < 1e-4",
        WAIT,
    )
    .await
    .expect("the light follows the controller");

    // The thumbstick pulled back dims it while held.
    page.eval("window.headset.controllers.right.updateAxes('thumbstick', 0, 1)")
        .await
        .unwrap();
    page.wait_for("window.bounce.lights.lights[0].intensity < 9", WAIT)
        .await
        .expect("the thumbstick dims the light");
    page.eval("window.headset.controllers.right.updateAxes('thumbstick', 0, 0)")
        .await
        .unwrap();
    // The grip recolours it: white steps to the warm white.
    button(&page, "squeeze", 1.0).await;
    button(&page, "squeeze", 0.0).await;
    page.wait_for(
        "JSON.stringify(window.bounce.lights.lights[0].color) === '[1,0.75,0.5]'",
        WAIT,
    )
    .await
    .expect("the grip recolours the light");
    trigger(&page, 0.0).await;
    page.wait_for("window.bounce.xr.held.length === 0", WAIT)
        .await
        .expect("the light is let go");

    // The session on the server has the carried and dimmed light, and the page, still in VR,
    // draws the indirect light the server solved for it.
    let held = page.eval("window.bounce.lights").await.unwrap();
    let stored = until_stored(&serve, &session, &held["lights"][0]).await;
    let light_now = &stored["lights"][0];
    let position: Vec<f64> = serde_json::from_value(light_now["position"].clone()).unwrap();
    assert!(
        (position[0] - 0.6).abs() < 1e-4
            && (position[1] - 1.5).abs() < 1e-4
            && position[2].abs() < 1e-4,
        "the light the server holds: {light_now}"
    );
    assert_eq!(light_now["color"], json!([1.0, 0.75, 0.5]), "{light_now}");
    let intensity = light_now["intensity"].as_f64().unwrap();
    assert!(
        (0.5..9.0).contains(&intensity),
        "dimmed from 10: {intensity}"
    );
    let version = stored["lights_version"].as_u64().unwrap();
    let drawn = page
        .eval(&format!("window.bounce.drawnVersion({version})"))
        .await
        .expect("the new indirect light is drawn");
    assert!(drawn["lightsVersion"].as_u64() >= Some(version), "{drawn}");
    assert_eq!(
        page.eval("window.bounce.xr.presenting").await.unwrap(),
        json!(true)
    );

    // Leaving VR from the headset (its system button ends the session; the emulator's view
    // covers the page, as a headset's does) gives the desktop camera back.
    page.eval("window.headset.activeSession.end()")
        .await
        .expect("the headset ends the session");
    page.wait_for("!window.bounce.xr.presenting", WAIT)
        .await
        .expect("the session ends");
    assert_eq!(button_text(&page).await, json!("ENTER VR"));
    assert_no_errors(&page);
}
