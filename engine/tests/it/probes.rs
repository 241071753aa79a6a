//! Irradiance probes through the engine, on a real bake of the Cornell box: probes sit inside
//! the box, their light matches the reference path tracer at the same points and directions,
//! it is exactly linear in the light, and both engines give the same probes.

use std::path::Path;
use std::sync::OnceLock;

use bounce_core::bake::{BakeOptions, NoProgress, bake_file};
use bounce_core::format::Baked;
use bounce_core::import::import_path;
use bounce_core::light::{Light, LightSet};
use bounce_core::meta::Bounces;
use bounce_core::patch::Face;
use bounce_core::probe::{DIRECTIONS, ProbeOptions};
use bounce_core::voxel::Resolution;
use bounce_engine::{Engine, EngineChoice};
use bounce_reference::{Options, Point, Reference};

fn scene_path() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box/scene.gltf")
}

/// The box at about 1,000 patches, three bounces, probes at the default spacing (2 voxels).
fn baked() -> &'static Baked {
    static BAKED: OnceLock<Baked> = OnceLock::new();
    BAKED.get_or_init(|| {
        let options = BakeOptions {
            resolution: Resolution::TargetPatches(1000),
            rays: 1024,
            bounces: Bounces::K(3),
            probes: Some(ProbeOptions::default()),
            ..BakeOptions::default()
        };
        bake_file(&scene_path(), &options, &NoProgress).unwrap()
    })
}

/// The point light the README's Cornell box figures use, scaled by `k`.
fn point(k: f32) -> LightSet {
    LightSet {
        lights: vec![Light::Point {
            position: [0.0, 1.5, 0.0],
            color: [1.0, 1.0, 1.0],
            intensity: 10.0 * k,
            range: None,
            name: None,
        }],
    }
}

/// The box's interior: the bounds of its triangles.
fn bounds() -> ([f32; 3], [f32; 3]) {
    let scene = import_path(&scene_path()).unwrap();
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in scene.triangles.iter().flat_map(|t| t.positions) {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

/// The reference's points for probes `chosen`: each probe's six directions, in face order.
fn probe_points(probes: &bounce_core::probe::Probes, chosen: &[usize]) -> Vec<Point> {
    chosen
        .iter()
        .flat_map(|&i| {
            Face::ALL.map(|f| Point {
                position: probes.positions[i],
                normal: f.normal().to_array(),
            })
        })
        .collect()
}

/// A relight's probe values for probes `chosen`, in the order of [`probe_points`].
fn probe_values(lit: &[[f32; 3]], chosen: &[usize]) -> Vec<[f32; 3]> {
    chosen
        .iter()
        .flat_map(|&i| lit[i * DIRECTIONS..(i + 1) * DIRECTIONS].to_vec())
        .collect()
}

#[test]
fn probes_fill_the_box_and_only_the_box() {
    let probes = baked().probes.as_ref().expect("baked with probes");
    probes.check(baked().transport_layout().len()).unwrap();
    let (lo, hi) = bounds();
    // The box is about 2 units a side and the voxels about a tenth of that at 1,000 patches:
    // a 2-voxel grid holds some 100 points, most of them inside it (60 measured).
    assert!(probes.len() > 30, "{} probes", probes.len());
    for p in &probes.positions {
        for a in 0..3 {
            assert!(
                p[a] > lo[a] && p[a] < hi[a],
                "probe {p:?} outside the box {lo:?}..{hi:?}"
            );
        }
    }
    // Inside a box open at most on one side, most of each direction's rays meet a wall.
    let mean_sum: f64 = (0..probes.len() * DIRECTIONS)
        .map(|r| {
            let (a, b) = (probes.row_ptr[r] as usize, probes.row_ptr[r + 1] as usize);
            probes.values[a..b]
                .iter()
                .map(|&v| f64::from(v))
                .sum::<f64>()
        })
        .sum::<f64>()
        / (probes.len() * DIRECTIONS) as f64;
    assert!(mean_sum > 0.7, "mean gather sum {mean_sum}");
}

/// Probe irradiance against the reference at the same points, each direction a point whose
/// normal is that axis, with one bounce more than the bake's (a probe gathers the surfaces'
/// exitance, which holds their indirect light of three bounces). The bound is issue 22's target
/// for probes in the Cornell box (10% relative L2).
#[test]
fn probes_match_the_reference() {
    let baked = baked();
    let engine = Engine::new(EngineChoice::Cpu).unwrap();
    let scene = engine.load(baked).unwrap();
    let set = point(1.0);
    let lit = engine
        .relight(&scene, std::slice::from_ref(&set))
        .unwrap()
        .remove(0);
    let probes = baked.probes.as_ref().unwrap();
    assert_eq!(lit.probes.len(), probes.len() * DIRECTIONS);
    // Every second probe keeps the reference's time in bounds.
    let chosen: Vec<usize> = (0..probes.len()).step_by(2).collect();
    let points = probe_points(probes, &chosen);
    let reference = Reference::new(&import_path(&scene_path()).unwrap()).unwrap();
    let options = Options {
        spp: 4096,
        bounces: Bounces::K(4),
        seed: 7,
    };
    let estimates = reference
        .estimate(&set, &points, &options, &|_| {})
        .unwrap();
    let got = probe_values(&lit.probes, &chosen);
    let (mut num, mut den, mut var) = (0.0f64, 0.0f64, 0.0f64);
    for (g, e) in got.iter().zip(&estimates) {
        for ((g, m), se) in g.iter().zip(e.mean).zip(e.stderr) {
            num += (f64::from(*g) - m).powi(2);
            den += m * m;
            var += se * se;
        }
    }
    let err = (num / den).sqrt();
    let noise = (var / den).sqrt();
    let total = got.iter().map(|g| f64::from(g[1])).sum::<f64>()
        / estimates.iter().map(|e| e.mean[1]).sum::<f64>();
    eprintln!(
        "probes: {} of {} against the reference: rel L2 {:.2}% (its noise {:.2}%), total {:.4} \
         of the reference's",
        chosen.len(),
        probes.len(),
        err * 100.0,
        noise * 100.0,
        total
    );
    assert!(noise < 0.03, "reference noise {noise}");
    assert!(err < 0.10, "probe error {err}");
}

/// A uniform sky of radiance `l` (grey).
fn sky(l: f32) -> LightSet {
    LightSet::from_json(&format!(
        r#"{{"lights": [{{"type": "sky", "color": [{l}, {l}, {l}]}}]}}"#
    ))
    .unwrap()
}

/// Each probe direction's sky view counts the rays that escaped through the box's open side:
/// with the rays that met a row it makes at most all of them, a uniform sky gives it `π L`
/// times that share (the closed form), and a relight under the sky adds it to what the surfaces
/// send.
#[test]
fn probes_see_the_sky_through_the_opening() {
    let baked = baked();
    let probes = baked.probes.as_ref().unwrap();
    let view = probes
        .sky
        .as_ref()
        .expect("a new bake keeps the probes' sky view");
    assert_eq!(view.len(), probes.len() * DIRECTIONS);
    let mut open = 0;
    for r in 0..view.len() {
        let (a, b) = (probes.row_ptr[r] as usize, probes.row_ptr[r + 1] as usize);
        let met: f64 = probes.values[a..b].iter().map(|&v| f64::from(v)).sum();
        let escaped = view.escaped_fraction(r);
        assert!(
            met + escaped <= 1.0 + 1e-4,
            "row {r}: {met} met + {escaped} escaped"
        );
        if escaped > 0.1 {
            open += 1;
            // The box is open towards +Z only: a direction that sees the sky faces that way.
            assert_ne!(
                r % DIRECTIONS,
                5,
                "a probe's −Z side sees the sky (row {r})"
            );
        }
    }
    assert!(open > probes.len() / 4, "{open} directions see the sky");
    let engine = Engine::new(EngineChoice::Cpu).unwrap();
    let scene = engine.load(baked).unwrap();
    assert!(scene.probes_see_the_sky());
    let lit = engine.relight(&scene, &[sky(2.0)]).unwrap().remove(0);
    let through = probes.sky_irradiance(&sky(2.0).sky_sh().unwrap()).unwrap();
    for (r, (e, s)) in lit.probes.iter().zip(&through).enumerate() {
        let want = 2.0 * std::f64::consts::PI * view.escaped_fraction(r);
        assert!(
            (f64::from(s[1]) - want).abs() < 1e-4 * want.max(1.0),
            "{s:?} {want}"
        );
        // Off the surfaces it gets more, never less.
        assert!(e[1] >= s[1], "row {r}: {e:?} below the sky it sees {s:?}");
    }
    // A file without the view: the probes get the sky only off the surfaces.
    let mut old = baked.clone();
    old.probes.as_mut().unwrap().sky = None;
    let scene = engine.load(&old).unwrap();
    assert!(!scene.probes_see_the_sky());
    let without = engine.relight(&scene, &[sky(2.0)]).unwrap().remove(0);
    for ((a, b), s) in lit.probes.iter().zip(&without.probes).zip(&through) {
        assert!((a[1] - b[1] - s[1]).abs() <= 1e-4 * a[1].max(1.0));
    }
}

/// Under a uniform sky, probes against the reference: its indirect light at the probe plus
/// the sky it sees directly (the reference's direct light of the sky alone), a quarter of the
/// probes.
#[test]
fn probes_under_a_sky_match_the_reference() {
    let baked = baked();
    let engine = Engine::new(EngineChoice::Cpu).unwrap();
    let scene = engine.load(baked).unwrap();
    let set = sky(1.0);
    let lit = engine
        .relight(&scene, std::slice::from_ref(&set))
        .unwrap()
        .remove(0);
    let probes = baked.probes.as_ref().unwrap();
    let chosen: Vec<usize> = (0..probes.len()).step_by(4).collect();
    let points = probe_points(probes, &chosen);
    let reference = Reference::new(&import_path(&scene_path()).unwrap()).unwrap();
    let options = Options {
        spp: 2048,
        bounces: Bounces::K(4),
        seed: 11,
    };
    let estimates = reference
        .estimate(&set, &points, &options, &|_| {})
        .unwrap();
    let seen = reference.direct(&set, &points);
    let got = probe_values(&lit.probes, &chosen);
    let (mut num, mut den, mut var) = (0.0f64, 0.0f64, 0.0f64);
    for ((g, e), d) in got.iter().zip(&estimates).zip(&seen) {
        for c in 0..3 {
            let m = e.mean[c] + d[c];
            num += (f64::from(g[c]) - m).powi(2);
            den += m * m;
            var += e.stderr[c] * e.stderr[c];
        }
    }
    let err = (num / den).sqrt();
    let noise = (var / den).sqrt();
    eprintln!(
        "probes under a sky: {} of {} against the reference: rel L2 {:.2}% (its noise {:.2}%)",
        chosen.len(),
        probes.len(),
        err * 100.0,
        noise * 100.0
    );
    assert!(noise < 0.03, "reference noise {noise}");
    assert!(err < 0.10, "probe error under a sky {err}");
}

/// No light, no probe light; twice the light, twice the probe light (the gather is linear).
#[test]
fn probe_light_is_linear_in_the_light() {
    let engine = Engine::new(EngineChoice::Cpu).unwrap();
    let scene = engine.load(baked()).unwrap();
    let lit = engine
        .relight(
            &scene,
            &[LightSet { lights: vec![] }, point(1.0), point(2.0)],
        )
        .unwrap();
    assert!(lit[0].probes.iter().flatten().all(|&v| v == 0.0));
    assert!(lit[1].probes.iter().flatten().any(|&v| v > 0.0));
    for (a, b) in lit[1]
        .probes
        .iter()
        .flatten()
        .zip(lit[2].probes.iter().flatten())
    {
        assert!((2.0 * a - b).abs() <= 1e-5 * b.abs().max(1e-6), "{a} {b}");
    }
}

/// The GPU engine's probes: the same gather over its own `B0` and `T · B0`.
#[test]
fn gpu_probes_match_the_cpu() {
    let Some(gpu) = crate::relight::gpu_engine() else {
        return;
    };
    let cpu = Engine::new(EngineChoice::Cpu).unwrap();
    let sets = [point(1.0), point(0.5)];
    let a = cpu.relight(&cpu.load(baked()).unwrap(), &sets).unwrap();
    let b = gpu.relight(&gpu.load(baked()).unwrap(), &sets).unwrap();
    for (x, y) in a.iter().zip(&b) {
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (p, q) in x.probes.iter().flatten().zip(y.probes.iter().flatten()) {
            num += (f64::from(*p) - f64::from(*q)).powi(2);
            den += f64::from(*p).powi(2);
        }
        let d = (num / den).sqrt();
        assert!(d < 2e-3, "GPU probes differ from the CPU's by {d}");
    }
}
