//! The browser viewer's probe-lit sphere (issue 22) against a real server whose scene was baked
//! with probes: the page asks for probe frames, holds the ones a gRPC subscriber gets, blends
//! the same ambient cube as the native renderer (`bounce_render::ambient_cube`), draws the sphere
//! with it (the exact colour where its normal faces the camera, redder towards the red wall),
//! and in a headset the sphere rides the controller.

use bounce_server::frame::Frame;
use glam::Vec3;
use serde_json::{Value, json};

use crate::fixture::{Serve, ServeOptions, baked_cornell_probes, ceiling_light};
use crate::viewer::{
    EYE, WAIT, assert_no_errors, checksum, open, picture_params, project, rgb, screenshot,
    wait_drawn,
};
use crate::xr::{click_vr_button, headset_script, place_controller};

/// Where the test pins the sphere: mid-box, a little towards the camera, so the pixel at its
/// projected centre sees the point whose normal is exactly +Z (towards the eye).
const CENTRE: Vec3 = Vec3::new(0.0, 1.0, 0.3);
const RADIUS: f32 = 0.25;
/// `ProbeSphere::ahead_of`'s albedo.
const ALBEDO: f32 = 0.8;

/// three's Reinhard after exposure 1, then the sRGB transfer, as 8-bit: what a linear radiance
/// becomes on the page.
fn displayed(linear: f32) -> f32 {
    let t = (linear / (1.0 + linear)).clamp(0.0, 1.0);
    let s = if t <= 0.003_130_8 {
        12.92 * t
    } else {
        1.055 * t.powf(1.0 / 2.4) - 0.055
    };
    s * 255.0
}

fn cube_of(v: &Value) -> [[f32; 3]; 6] {
    serde_json::from_value(v.clone()).unwrap_or_else(|e| panic!("an ambient cube: {v}: {e}"))
}

/// The page blends in f64, the native renderer in f32: equal to f32's rounding.
fn assert_same_cube(page: &[[f32; 3]; 6], native: &[[f32; 3]; 6], what: &str) {
    for (a, b) in page.iter().flatten().zip(native.iter().flatten()) {
        assert!(
            (a - b).abs() <= 1e-5 * b.abs().max(1e-3),
            "{what}: page {page:?}, native {native:?}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_lights_a_sphere_from_the_probe_frames_and_a_headset_carries_it() {
    let Some(browser) = crate::browser().await else {
        return;
    };
    let serve = Serve::start(ServeOptions {
        scene: Some(baked_cornell_probes()),
        ..ServeOptions::default()
    });
    let session = serve.create_session(ceiling_light(), None).await;
    let page = open(
        &browser,
        &serve.page_url(&session, &format!("{}&terms=indirect", picture_params())),
    )
    .await;
    wait_drawn(&page).await;
    let held = page
        .wait_for("window.bounce.probes?.frame", WAIT)
        .await
        .expect("a probe frame is drawn");

    // The same probe light as a gRPC subscriber's probe frame, at the probes the layout names.
    let layout = serve.layout().await;
    let positions = layout.probes().to_vec();
    assert!(positions.len() > 10, "{} probes", positions.len());
    assert_eq!(
        page.eval("window.bounce.probes.count").await.unwrap(),
        json!(positions.len())
    );
    let message = serve.first_frame(&session).await;
    let probe_frame = Frame::parse_probes(message.probes).expect("a probe frame beside it");
    assert_eq!(held["checksum"].as_u64(), Some(checksum(&probe_frame)));
    let irradiance = probe_frame.irradiance();
    assert_eq!(irradiance.len(), 6 * positions.len());

    // The page's ambient cube is the native renderer's: on a probe, between probes, near a wall.
    let points = [
        positions[positions.len() / 2],
        CENTRE,
        Vec3::new(-0.8, 0.4, -0.6),
        Vec3::new(0.7, 1.7, 0.2),
    ];
    for p in points {
        let page_cube = page
            .eval(&format!(
                "window.bounce.ambientCube([{},{},{}])",
                p.x, p.y, p.z
            ))
            .await
            .unwrap();
        let page_cube = cube_of(&page_cube);
        let native = bounce_render::ambient_cube(&positions, &irradiance, p).expect("a cube");
        assert_same_cube(&page_cube, &native, &format!("at {p}"));
    }

    // Pinned mid-box, indirect light only: the pixel at its centre sees normal +Z, so it shows
    // albedo/π · E[+Z] after the tone map.
    page.eval(&format!(
        "window.bounce.placeObject([{},{},{}], {RADIUS})",
        CENTRE.x, CENTRE.y, CENTRE.z
    ))
    .await
    .unwrap();
    let object = page
        .wait_for(
            &format!(
                "(o => o.visible && Math.abs(o.centre[2] - {}) < 1e-6 && o)(window.bounce.object)",
                CENTRE.z
            ),
            WAIT,
        )
        .await
        .expect("the sphere is drawn where it was pinned");
    let cube = cube_of(&object["cube"]);
    let native = bounce_render::ambient_cube(&positions, &irradiance, CENTRE).unwrap();
    assert_same_cube(&cube, &native, "the sphere's cube, for its centre");
    let img = screenshot(&page).await;
    let at = project(CENTRE);
    let got = rgb(&img, at);
    let e = bounce_render::cube_irradiance(&cube, Vec3::Z);
    let want = [0, 1, 2].map(|c| displayed(ALBEDO / std::f32::consts::PI * e[c]));
    for c in 0..3 {
        assert!(
            (got[c] - want[c]).abs() <= 3.0,
            "the sphere's centre pixel {got:?}, from its ambient cube {want:?} (E {e})"
        );
    }
    assert!(want.iter().any(|&v| v > 20.0), "too dark to tell: {want:?}");
    // Its side towards the red wall (−X) is redder than its side towards the green one.
    let (x, y) = at;
    let side = |dx: i64| {
        let px = u32::try_from(i64::from(x) + dx).expect("on screen");
        rgb(&img, (px, y))
    };
    let reach = {
        let edge = project(CENTRE + Vec3::X * RADIUS);
        i64::from(edge.0) - i64::from(x)
    };
    let (left, right) = (side(-reach * 3 / 4), side(reach * 3 / 4));
    let redness = |c: [f32; 3]| c[0] / c[1].max(1.0);
    assert!(
        redness(left) > redness(right) * 1.1,
        "left {left:?} is not redder than right {right:?}"
    );
    // Switched off with P, the pixel shows the back wall instead.
    page.key("p").await.expect("a key press");
    let off = rgb(&screenshot(&page).await, at);
    assert_eq!(
        page.eval("window.bounce.object.visible").await.unwrap(),
        json!(false)
    );
    assert!(
        off.iter().zip(&got).any(|(a, b)| (a - b).abs() > 3.0),
        "the pixel did not change: {off:?}"
    );
    page.key("p").await.expect("a key press");

    // Unpinned it floats ahead of the camera: six radii of 3% of the model's diagonal (the box's
    // 2 m cube, √12 m, and a little for its walls' thickness).
    page.eval("window.bounce.placeObject(null)").await.unwrap();
    let object = page
        .wait_for(
            "(o => o.radius < 0.2 && o.visible && o)(window.bounce.object)",
            WAIT,
        )
        .await
        .expect("the sphere follows the camera");
    let radius = object["radius"].as_f64().expect("a radius") as f32;
    assert!(
        (1.0..1.02).contains(&(radius / (0.03 * 12f32.sqrt()))),
        "radius {radius}"
    );
    let centre: [f32; 3] = serde_json::from_value(object["centre"].clone()).unwrap();
    let want = Vec3::from(EYE) + Vec3::NEG_Z * radius * 6.0;
    assert!(
        Vec3::from(centre).distance(want) < 1e-3,
        "ahead of the camera at {want}, not {centre:?}"
    );
    assert_no_errors(&page);
    drop(page);

    // In a headset the sphere rides just ahead of the right controller.
    let page = browser
        .new_page(640, 360)
        .await
        .expect("a page for the headset");
    page.add_init_script(&headset_script())
        .await
        .expect("the headset is installed first");
    page.goto(&serve.page_url(
        &session,
        &format!("&camera={}", crate::viewer::camera_param()),
    ))
    .await
    .expect("the page loads");
    wait_drawn(&page).await;
    click_vr_button(&page).await;
    page.wait_for("window.bounce.xr.presenting", WAIT)
        .await
        .expect("an immersive session starts");
    let rig: Vec<f32> =
        serde_json::from_value(page.eval("window.bounce.xr.rig").await.unwrap()).unwrap();
    for hand in [[0.2f32, 1.1, -1.0], [-0.3, 0.9, -1.5]] {
        place_controller(&page, hand.map(f64::from)).await;
        let want = Vec3::from(hand) + Vec3::from_slice(&rig) + Vec3::NEG_Z * radius * 1.5;
        let got = page
            .wait_for(
                &format!(
                    "(o => o.visible && Math.hypot(o.centre[0] - {}, o.centre[1] - {}, o.centre[2] - {}) < 1e-3 && o)(window.bounce.object)",
                    want.x, want.y, want.z
                ),
                WAIT,
            )
            .await
            .unwrap_or_else(|e| panic!("the sphere rides the controller to {want}: {e}"));
        assert!(got["cube"].is_array(), "lit by the probes there: {got}");
    }
    assert_no_errors(&page);
}
