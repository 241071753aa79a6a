//! The reference against closed forms: the white furnace and a point-to-rectangle form factor.

use bounce_core::light::LightSet;
use bounce_core::meta::Bounces;
use bounce_core::scene::{Scene, Triangle};
use bounce_reference::{Options, Point, Reference};
use glam::Vec3;

fn quad(corners: [Vec3; 4], albedo: f32, emission: f32) -> [Triangle; 2] {
    let t = |positions| Triangle {
        positions,
        albedo: Vec3::splat(albedo),
        emission: Vec3::splat(emission),
        double_sided: false,
        material: 0,
    };
    let [a, b, c, d] = corners;
    // Corners go clockwise seen from the side the quad faces; the triangles wind back.
    [t([a, c, b]), t([a, d, c])]
}

/// The unit cube's six faces, wound to face inwards.
fn closed_box(albedo: f32, emission: f32) -> Scene {
    let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    let faces = [
        [v(0., 0., 0.), v(1., 0., 0.), v(1., 0., 1.), v(0., 0., 1.)], // floor, normal +y
        [v(0., 1., 0.), v(0., 1., 1.), v(1., 1., 1.), v(1., 1., 0.)], // ceiling, -y
        [v(0., 0., 0.), v(0., 0., 1.), v(0., 1., 1.), v(0., 1., 0.)], // x = 0, +x
        [v(1., 0., 0.), v(1., 1., 0.), v(1., 1., 1.), v(1., 0., 1.)], // x = 1, -x
        [v(0., 0., 0.), v(0., 1., 0.), v(1., 1., 0.), v(1., 0., 0.)], // z = 0, +z
        [v(0., 0., 1.), v(1., 0., 1.), v(1., 1., 1.), v(0., 1., 1.)], // z = 1, -z
    ];
    let scene = Scene {
        triangles: faces
            .iter()
            .flat_map(|&f| quad(f, albedo, emission))
            .collect(),
        ..Scene::default()
    };
    let centre = Vec3::splat(0.5);
    for t in &scene.triangles {
        let mid = (t.positions[0] + t.positions[1] + t.positions[2]) / 3.0;
        assert!(t.cross().dot(centre - mid) > 0.0, "faces inwards");
    }
    scene
}

fn points() -> Vec<Point> {
    vec![
        Point {
            position: [0.3, 0.0, 0.7],
            normal: [0.0, 1.0, 0.0],
        },
        Point {
            position: [1.0, 0.9, 0.1],
            normal: [-1.0, 0.0, 0.0],
        },
        Point {
            position: [0.5, 1.0, 0.5],
            normal: [0.0, -1.0, 0.0],
        },
    ]
}

/// Closed room, uniform albedo ρ and emitted exitance E, no lights: every surface receives
/// `E (1 − ρ^k) / (1 − ρ)` with k bounces and `E / (1 − ρ)` with all of them
/// (docs/design.md §1). Emission is sampled on the walls as well as met by the paths (multiple
/// importance sampling), so even this room is noisy: the check is the mean within four standard
/// errors, with those errors small.
#[test]
fn white_furnace() {
    let (rho, e) = (0.8f64, 2.0f64);
    let reference = Reference::new(&closed_box(rho as f32, e as f32)).unwrap();
    for k in [1, 3, 7] {
        let options = Options {
            spp: 16_384,
            bounces: Bounces::K(k),
            seed: 5,
        };
        let expected = e * (1.0 - rho.powi(k as i32)) / (1.0 - rho);
        for est in reference
            .estimate(&LightSet::default(), &points(), &options, &|_| {})
            .unwrap()
        {
            for c in 0..3 {
                let (m, s) = (est.mean[c], est.stderr[c]);
                assert!(s > 0.0 && s < 0.01 * expected, "k = {k}: {s}");
                assert!(
                    (m - expected).abs() < 4.0 * s,
                    "k = {k}: {m} ± {s} against {expected}"
                );
            }
        }
    }
    // All bounces: Russian roulette makes it noisy but unbiased.
    let options = Options {
        spp: 20_000,
        bounces: Bounces::All,
        seed: 5,
    };
    let expected = e / (1.0 - rho);
    for est in reference
        .estimate(&LightSet::default(), &points(), &options, &|_| {})
        .unwrap()
    {
        let (m, s) = (est.mean[0], est.stderr[0]);
        eprintln!("all bounces: {m:.4} ± {s:.4}, expected {expected}");
        assert!(s > 0.0 && s < 0.01 * expected, "{s}");
        assert!(
            (m - expected).abs() < 4.0 * s,
            "{m} ± {s} against {expected}"
        );
    }
}

/// One bounce from an emitting 2 × 2 square one unit above a point under its centre: the
/// irradiance is `E` times the differential-area-to-parallel-rectangle form factor (Howell's
/// catalogue, B-3, summed over four corner rectangles of 1 × 1 at height 1).
#[test]
fn one_bounce_from_an_emitting_square_matches_the_form_factor() {
    let m = 3.0f32;
    let square = quad(
        [
            Vec3::new(-1.0, 1.0, -1.0),
            Vec3::new(-1.0, 1.0, 1.0),
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(1.0, 1.0, -1.0),
        ],
        0.5,
        m,
    );
    assert!(square[0].cross().y < 0.0, "emits downwards");
    // A floor far larger than the square, dark, so nothing comes back.
    let floor = quad(
        [
            Vec3::new(-50.0, 0.0, -50.0),
            Vec3::new(50.0, 0.0, -50.0),
            Vec3::new(50.0, 0.0, 50.0),
            Vec3::new(-50.0, 0.0, 50.0),
        ],
        0.0,
        0.0,
    );
    let scene = Scene {
        triangles: square.into_iter().chain(floor).collect(),
        ..Scene::default()
    };
    let reference = Reference::new(&scene).unwrap();
    let options = Options {
        spp: 40_000,
        bounces: Bounces::K(1),
        seed: 2,
    };
    let at = Point {
        position: [0.0, 0.0, 0.0],
        normal: [0.0, 1.0, 0.0],
    };
    let est = reference
        .estimate(&LightSet::default(), &[at], &options, &|_| {})
        .unwrap()[0];
    let (x, y) = (1.0f64, 1.0f64);
    let corner = (x / (1.0 + x * x).sqrt() * (y / (1.0 + x * x).sqrt()).atan()
        + y / (1.0 + y * y).sqrt() * (x / (1.0 + y * y).sqrt()).atan())
        / (2.0 * std::f64::consts::PI);
    let expected = f64::from(m) * 4.0 * corner;
    let (mean, s) = (est.mean[1], est.stderr[1]);
    eprintln!("form factor 4 × {corner:.5}: {mean:.4} ± {s:.4} against {expected:.4}");
    assert!(
        (mean - expected).abs() < 4.0 * s,
        "{mean} ± {s} against {expected}"
    );
    assert!(s < 0.01 * expected);
}

/// A 2 × 2 plate one unit above a point, facing down at it, alone under a sky. The plate's
/// front sees the whole lower hemisphere open, so it gets the sky's irradiance for its normal,
/// `E(n) = Σ Â_l L_lm Y_lm(n)` with `Â = (π, 2π/3, π/4)` (Ramamoorthi and Hanrahan), and the
/// point's indirect light with any number of bounces is `ρ E(−y) F`, `F` the point's form factor
/// to the plate (as in the test above). The point's own direct sky light is the sky over the
/// hemisphere the plate does not hide: for a uniform sky `π L (1 − F)`.
#[test]
fn a_sky_lights_a_plate_that_lights_a_point() {
    let rho = 0.6f32;
    let plate = quad(
        [
            Vec3::new(-1.0, 1.0, -1.0),
            Vec3::new(-1.0, 1.0, 1.0),
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(1.0, 1.0, -1.0),
        ],
        rho,
        0.0,
    );
    assert!(plate[0].cross().y < 0.0, "faces down");
    let reference = Reference::new(&Scene {
        triangles: plate.to_vec(),
        ..Scene::default()
    })
    .unwrap();
    let corner = (1.0 / 2f64.sqrt() * (1.0 / 2f64.sqrt()).atan()) * 2.0 / std::f64::consts::TAU;
    let f = 4.0 * corner;
    let at = Point {
        position: [0.0, 0.0, 0.0],
        normal: [0.0, 1.0, 0.0],
    };
    let pi = std::f64::consts::PI;
    // A sky brighter above and below than around, tinted: every band of the expansion.
    let mut sh = vec![[0.0f32; 3]; 9];
    sh[0] = [2.0, 2.0, 2.5];
    sh[1] = [-0.8, -0.6, -0.4]; // Y1−1 ∝ y: darker above, brighter below
    sh[3] = [0.3, 0.3, 0.3]; // ∝ x: no net effect on a horizontal plate
    sh[6] = [0.4, 0.2, 0.0]; // ∝ 3z² − 1
    sh[8] = [-0.5, 0.0, 0.5]; // ∝ x² − y²
    let sh_json = serde_json::json!({"lights": [{"type": "sky", "sh": sh}]});
    let n = [0.0f64, -1.0, 0.0];
    let y = bounce_core::sh::sh_basis(n);
    let band = [pi, 2.0 * pi / 3.0, 2.0 * pi / 3.0, 2.0 * pi / 3.0]
        .into_iter()
        .chain([pi / 4.0; 5]);
    let e_plate: Vec<f64> = (0..3)
        .map(|c| {
            band.clone()
                .enumerate()
                .map(|(k, a)| a * f64::from(sh[k][c]) * y[k])
                .sum()
        })
        .collect();
    let uniform = r#"{"lights": [{"type": "sky", "color": [0.5, 1.0, 2.0]}]}"#;
    let uniform_plate = [0.5f64, 1.0, 2.0].map(|l| pi * l);
    for (json, plate_e) in [
        (sh_json.to_string(), e_plate.clone()),
        (uniform.to_string(), uniform_plate.to_vec()),
    ] {
        let lights = LightSet::from_json(&json).unwrap();
        for bounces in [Bounces::K(1), Bounces::K(3)] {
            let options = Options {
                spp: 40_000,
                bounces,
                seed: 4,
            };
            let est = reference
                .estimate(&lights, &[at], &options, &|_| {})
                .unwrap()[0];
            for (c, plate_c) in plate_e.iter().enumerate() {
                let expected = f64::from(rho) * plate_c * f;
                let (mean, s) = (est.mean[c], est.stderr[c]);
                eprintln!("sky {c}: {mean:.4} ± {s:.4} against {expected:.4}");
                assert!(
                    (mean - expected).abs() < 4.0 * s + 1e-9,
                    "{json} {bounces:?} channel {c}: {mean} ± {s} against {expected}"
                );
                assert!(s < 0.02 * expected.abs(), "{s}");
            }
        }
    }
    // Direct: the uniform sky over what the plate leaves open, from SKY_DIRECT_RAYS rays (a
    // Bernoulli mean, its σ at most √(1/4N) of π L).
    let lights = LightSet::from_json(uniform).unwrap();
    let direct = reference.direct(&lights, &[at])[0];
    let sigma = (0.25 / f64::from(bounce_reference::SKY_DIRECT_RAYS)).sqrt();
    for c in 0..3 {
        let open = direct[c] / uniform_plate[c];
        assert!(
            (open - (1.0 - f)).abs() < 4.0 * sigma,
            "channel {c}: open share {open} against {}",
            1.0 - f
        );
    }
}

#[test]
fn the_same_seed_gives_the_same_values_and_bad_input_is_an_error() {
    let reference = Reference::new(&closed_box(0.5, 1.0)).unwrap();
    let options = Options {
        spp: 100,
        bounces: Bounces::All,
        seed: 9,
    };
    let run = || {
        reference
            .estimate(&LightSet::default(), &points(), &options, &|_| {})
            .unwrap()
    };
    assert_eq!(run(), run());
    let bad = Point {
        position: [f32::NAN, 0.0, 0.0],
        normal: [0.0, 1.0, 0.0],
    };
    let err = reference
        .estimate(&LightSet::default(), &[bad], &options, &|_| {})
        .unwrap_err();
    assert!(err.to_string().contains("point 0"), "{err}");
    assert!(Reference::new(&Scene::default()).is_err());
}

/// A patch's reference is a mean over points drawn on its footprint. Under a small emitter the
/// floor's irradiance falls several times from the middle of the patch to its corners, so a few
/// points stand for the patch far worse than their paths' noise says. The standard error must
/// count that: independent estimates (other seeds, other points) disagree within what their
/// errors claim, at 16 points a patch and at one path a point.
#[test]
fn the_standard_error_counts_how_the_value_varies_over_the_footprint() {
    use bounce_core::patch::{Face, Patch, PatchLayout};
    let square = quad(
        [
            Vec3::new(-0.5, 1.0, -0.5),
            Vec3::new(-0.5, 1.0, 0.5),
            Vec3::new(0.5, 1.0, 0.5),
            Vec3::new(0.5, 1.0, -0.5),
        ],
        0.0,
        3.0,
    );
    let floor = quad(
        [
            Vec3::new(-50.0, 0.0, -50.0),
            Vec3::new(50.0, 0.0, -50.0),
            Vec3::new(50.0, 0.0, 50.0),
            Vec3::new(-50.0, 0.0, 50.0),
        ],
        0.0,
        0.0,
    );
    let scene = Scene {
        triangles: square.into_iter().chain(floor).collect(),
        ..Scene::default()
    };
    let reference = Reference::new(&scene).unwrap();
    // One patch: the floor over [-2, 2]² facing up.
    let layout = PatchLayout {
        origin: [-2.0, -0.5, -2.0],
        voxel_size: 4.0,
        dims: [1, 1, 1],
        patches: vec![Patch {
            voxel: [0, 0, 0],
            face: Face::PosY,
            albedo: [0.0; 3],
            centroid: [0.0, 0.0, 0.0],
            normal: [0.0, 1.0, 0.0],
            source_area: 16.0,
            emission: [0.0; 3],
        }],
    };
    let estimate = |points: usize, spp: u32, seed: u64| {
        let options = Options {
            spp,
            bounces: Bounces::K(1),
            seed,
        };
        let (e, _, _) = reference
            .estimate_footprints(&LightSet::default(), &layout, points, &options, &|_| {})
            .unwrap();
        (e[0].mean[1], e[0].stderr[1])
    };
    let truth = estimate(20_000, 20_000, 1000).0;
    for (points, spp) in [(16, 16_000), (400, 400)] {
        let mut within = 0;
        let mut spread = 0.0;
        for seed in 0..40 {
            let (mean, se) = estimate(points, spp, seed);
            spread += (mean - truth).powi(2) / 40.0;
            if (mean - truth).abs() < 3.0 * se {
                within += 1;
            }
        }
        eprintln!(
            "{points} points, {spp} paths: {within} of 40 within 3 standard errors, rms {:.4} of {truth:.4}",
            spread.sqrt()
        );
        assert!(within >= 36, "{points} points: {within} of 40 within 3σ");
    }
}
