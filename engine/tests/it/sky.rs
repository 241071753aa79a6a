//! A sky through the engines, on a real bake of an open box (a unit box without its top): each
//! row's direct light is its sky view's closed form, the CPU and GPU engines agree, the indirect
//! light matches the reference path tracer under the same sky, and a file without a sky view
//! gets nothing from a sky.

use std::sync::OnceLock;

use bounce_core::bake::{BakeOptions, NoProgress, bake_scene};
use bounce_core::format::Baked;
use bounce_core::light::LightSet;
use bounce_core::meta::Bounces;
use bounce_core::scene::{Scene, Triangle};
use bounce_core::voxel::{Geometry, Resolution};
use bounce_engine::{Engine, EngineChoice};
use bounce_reference::{Options, Reference};
use glam::Vec3;

/// The unit box `[0, 1]³` with inward-facing one-sided walls of albedo 0.5 and no top.
fn open_box() -> Scene {
    let v = Vec3::new;
    let walls = [
        [v(0., 0., 0.), v(1., 0., 0.), v(1., 0., 1.), v(0., 0., 1.)],
        [v(0., 0., 0.), v(0., 0., 1.), v(0., 1., 1.), v(0., 1., 0.)],
        [v(1., 0., 0.), v(1., 1., 0.), v(1., 1., 1.), v(1., 0., 1.)],
        [v(0., 0., 0.), v(0., 1., 0.), v(1., 1., 0.), v(1., 0., 0.)],
        [v(0., 0., 1.), v(1., 0., 1.), v(1., 1., 1.), v(0., 1., 1.)],
    ];
    let inside = v(0.5, 0.5, 0.5);
    let mut triangles = Vec::new();
    for [a, b, c, d] in walls {
        for mut t in [[a, b, c], [a, c, d]] {
            let mid = (t[0] + t[1] + t[2]) / 3.0;
            if (t[1] - t[0]).cross(t[2] - t[0]).dot(inside - mid) < 0.0 {
                t.swap(1, 2);
            }
            triangles.push(Triangle {
                positions: t,
                albedo: Vec3::splat(0.5),
                emission: Vec3::ZERO,
                double_sided: false,
                material: 0,
            });
        }
    }
    Scene {
        triangles,
        ..Default::default()
    }
}

fn baked() -> &'static Baked {
    static BAKED: OnceLock<Baked> = OnceLock::new();
    BAKED.get_or_init(|| {
        let options = BakeOptions {
            resolution: Resolution::VoxelSize(0.125),
            rays: 2048,
            seed: 3,
            bounces: Bounces::K(3),
            geometry: Geometry::Surface,
            ..BakeOptions::default()
        };
        bake_scene(&open_box(), "open-box", &options, &NoProgress).unwrap()
    })
}

fn white_sky() -> LightSet {
    LightSet::from_json(r#"{"lights": [{"type": "sky", "color": [1, 1, 1]}]}"#).unwrap()
}

/// Relative L2 distance of `a` from `b` over every patch and channel.
fn rel_l2(a: &[[f32; 3]], b: &[[f64; 3]]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            num += (f64::from(x[c]) - y[c]).powi(2);
            den += y[c] * y[c];
        }
    }
    (num / den).sqrt()
}

#[test]
fn a_sky_is_direct_light_through_each_rows_view() {
    let baked = baked();
    let engine = Engine::new(EngineChoice::Cpu).unwrap();
    let scene = engine.load(baked).unwrap();
    assert!(scene.has_sky_view());
    let rows = engine
        .direct_on_rows(&scene, &[white_sky()])
        .unwrap()
        .remove(0);
    let view = baked.sky.as_ref().unwrap();
    for (i, e) in rows.iter().enumerate() {
        // White radiance 1: E = π · the share of the row's rays that escaped.
        let want = std::f64::consts::PI * view.escaped_fraction(i);
        assert!(
            (f64::from(e[1]) - want).abs() < 1e-5,
            "row {i}: {e:?} {want}"
        );
    }
    // The floor's middle sees the opening best, a wall's foot least.
    let lit = engine.relight(&scene, &[white_sky()]).unwrap().remove(0);
    assert!(
        lit.direct
            .iter()
            .all(|d| d[0] > 0.0 && d[0] < std::f32::consts::PI)
    );
    assert!(lit.indirect.iter().all(|d| d[0] > 0.0));
    // The sky's share of direct light is kept apart, and what a viewer is streamed adds it to
    // the bounces: a viewer draws only the punctual lights itself.
    assert_eq!(lit.sky, lit.direct, "a sky alone is all the direct light");
    let streamed = lit.streamed();
    for ((s, i), k) in streamed.iter().zip(&lit.indirect).zip(&lit.sky) {
        assert_eq!(*s, [i[0] + k[0], i[1] + k[1], i[2] + k[2]]);
    }
    // With a point light beside it the sky's share is the same; without a sky there is none,
    // and the stream is E_ind itself.
    let point = r#"{"type": "point", "position": [0.5, 0.8, 0.5], "intensity": 2}"#;
    let both = LightSet::from_json(&format!(
        r#"{{"lights": [{point}, {{"type": "sky", "color": [1, 1, 1]}}]}}"#
    ))
    .unwrap();
    let alone = LightSet::from_json(&format!(r#"{{"lights": [{point}]}}"#)).unwrap();
    let lit2 = engine.relight(&scene, &[both, alone]).unwrap();
    assert_eq!(lit2[0].sky, lit.sky);
    assert!(
        lit2[0]
            .direct
            .iter()
            .zip(&lit.sky)
            .any(|(d, k)| d[0] > k[0])
    );
    assert!(lit2[1].sky.is_empty());
    assert!(matches!(lit2[1].streamed(), std::borrow::Cow::Borrowed(_)));
    assert_eq!(*lit2[1].streamed(), lit2[1].indirect[..]);
}

/// The engine's `E_ind` under a uniform white sky against the reference path tracer's, patch
/// by patch over each patch's footprint, with the same three bounces. The issue asks that a new
/// term stay within the point lights' method error; the bound is the Cornell box's target under
/// a point light at 2,000 patches (5% relative L2). Measured here: 1.41%, of which the
/// reference's own noise is 1.36% (0.37% with it removed), total light within 0.2%; 1.49% without
/// the near field, which corrects the sky by each sample's own view (format version 9).
#[test]
fn an_open_box_under_a_sky_matches_the_reference() {
    let baked = baked();
    let engine = Engine::new(EngineChoice::Cpu).unwrap();
    let scene = engine.load(baked).unwrap();
    let lit = engine.relight(&scene, &[white_sky()]).unwrap().remove(0);
    let mut flat = engine.load(baked).unwrap();
    flat.disable_near_field();
    let flat = engine.relight(&flat, &[white_sky()]).unwrap().remove(0);
    let reference = Reference::new(&open_box()).unwrap();
    let options = Options {
        spp: 16_384,
        bounces: Bounces::K(3),
        seed: 11,
    };
    let (estimates, _, fallbacks) = reference
        .estimate_footprints(&white_sky(), &baked.layout, 1024, &options, &|_| {})
        .unwrap();
    assert_eq!(fallbacks, 0);
    let want: Vec<[f64; 3]> = estimates.iter().map(|e| e.mean).collect();
    let err = rel_l2(&lit.indirect, &want);
    let err_flat = rel_l2(&flat.indirect, &want);
    // How much of that is the reference's own noise.
    let noise = {
        let var: f64 = estimates.iter().map(|e| e.stderr[1].powi(2)).sum();
        let norm: f64 = want.iter().map(|w| w[1] * w[1]).sum();
        (var / norm).sqrt()
    };
    let sum = |v: &mut dyn Iterator<Item = f64>| v.sum::<f64>();
    let ratio = sum(&mut lit.indirect.iter().map(|e| f64::from(e[1])))
        / sum(&mut want.iter().map(|w| w[1]));
    eprintln!(
        "open box under a white sky: {} patches, E_ind rel L2 {:.2}% against the reference \
         (its noise {:.2}%, {:.2}% with that removed; {:.2}% without the near field), total \
         {ratio:.4} of the reference's",
        baked.layout.len(),
        err * 100.0,
        noise * 100.0,
        (err * err - noise * noise).max(0.0).sqrt() * 100.0,
        err_flat * 100.0
    );
    assert!(noise < 0.02, "reference noise {noise}");
    assert!(err < 0.05, "method error {err}");
    // The corners see less sky than their rows' means: the near field's sky view must bring
    // the gather closer, not further.
    assert!(
        err < err_flat,
        "with the samples' sky view {err}, without the near field {err_flat}"
    );
    assert!((ratio - 1.0).abs() < 0.05, "total {ratio}");
}

#[test]
fn gpu_and_cpu_engines_agree_under_a_sky() {
    let Some(gpu) = crate::relight::gpu_engine() else {
        return;
    };
    let baked = baked();
    let cpu = Engine::new(EngineChoice::Cpu).unwrap();
    let mut sets = vec![white_sky()];
    sets.push(
        LightSet::from_json(
            r#"{"lights": [{"type": "point", "position": [0.5, 0.8, 0.5], "intensity": 2},
                           {"type": "sky", "sh": [[1,1,1],[0.5,0.5,0.5],[0,0,0],[0,0,0],
                            [0,0,0],[0,0,0],[0.2,0.2,0.2],[0,0,0],[0,0,0]]}]}"#,
        )
        .unwrap(),
    );
    let a = cpu.relight(&cpu.load(baked).unwrap(), &sets).unwrap();
    let b = gpu.relight(&gpu.load(baked).unwrap(), &sets).unwrap();
    for (x, y) in a.iter().zip(&b) {
        for (p, q) in x
            .indirect
            .iter()
            .zip(&y.indirect)
            .chain(x.direct.iter().zip(&y.direct))
        {
            for c in 0..3 {
                assert!(
                    (p[c] - q[c]).abs() <= 2e-3 * p[c].abs().max(1e-2),
                    "{p:?} {q:?}"
                );
            }
        }
    }
}

/// A file from before the sky view (read with none): a sky lights nothing, other lights as
/// before.
#[test]
fn without_a_sky_view_a_sky_adds_nothing() {
    let mut old = baked().clone();
    old.sky = None;
    let engine = Engine::new(EngineChoice::Cpu).unwrap();
    let scene = engine.load(&old).unwrap();
    assert!(!scene.has_sky_view());
    let lit = engine.relight(&scene, &[white_sky()]).unwrap().remove(0);
    assert!(
        lit.direct
            .iter()
            .chain(&lit.indirect)
            .all(|d| *d == [0.0; 3])
    );
    assert!(lit.sky.is_empty(), "no view, no sky to stream");
    let with_point = LightSet::from_json(
        r#"{"lights": [{"type": "point", "position": [0.5, 0.5, 0.5], "intensity": 1},
                       {"type": "sky", "color": [1, 1, 1]}]}"#,
    )
    .unwrap();
    let point_only = LightSet {
        lights: with_point.lights[..1].to_vec(),
    };
    let both = engine.relight(&scene, &[with_point, point_only]).unwrap();
    assert_eq!(both[0], both[1]);
}
