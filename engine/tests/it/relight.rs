//! The engine interface end to end on a real bake of the Cornell box: batched relights equal
//! one-by-one relights, the GPU engine agrees with the CPU engine, the classic-radiosity baseline
//! agrees with the precomputed transport, and bad lights are refused.
//!
//! The GPU engine runs on whatever adapter wgpu finds (lavapipe in CI); without one these tests
//! fail unless `BOUNCE_ALLOW_NO_GPU=1` says skipping is intended.

use std::path::Path;
use std::sync::OnceLock;

use bounce_core::bake::{BakeOptions, NoProgress, bake_file};
use bounce_core::codec::logblock::LogBlock;
use bounce_core::codec::{Codec, decode};
use bounce_core::format::Baked;
use bounce_core::light::{Light, LightSet};
use bounce_core::meta::Bounces;
use bounce_core::voxel::Resolution;
use bounce_engine::baseline::jacobi;
use bounce_engine::{Engine, EngineChoice, EngineError, EngineKind, Irradiance};

/// The Cornell box at about 300 patches, 3 bounces, with its form factors.
pub(crate) fn baked() -> &'static Baked {
    static BAKED: OnceLock<Baked> = OnceLock::new();
    BAKED.get_or_init(|| {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box/scene.gltf");
        let options = BakeOptions {
            resolution: Resolution::TargetPatches(300),
            rays: 1024,
            bounces: Bounces::K(3),
            keep_form_factors: true,
            ..BakeOptions::default()
        };
        bake_file(&path, &options, &NoProgress).unwrap()
    })
}

pub(crate) fn gpu_engine() -> Option<Engine> {
    match Engine::new(EngineChoice::Gpu) {
        Ok(e) => Some(e),
        Err(e) => bounce_testkit::missing(bounce_testkit::Tool::GpuAdapter, e),
    }
}

/// Point lights at a few places inside the box (its interior spans the grid's middle).
fn light_sets(count: usize) -> Vec<LightSet> {
    let layout = &baked().layout;
    let s = layout.voxel_size;
    let size: Vec<f32> = layout.dims.iter().map(|&d| d as f32 * s).collect();
    (0..count)
        .map(|k| {
            let u = [
                0.3 + 0.4 * ((k * 7) % 5) as f32 / 4.0,
                0.35 + 0.1 * (k % 3) as f32,
                0.5,
            ];
            let position = std::array::from_fn(|a| layout.origin[a] + size[a] * u[a]);
            LightSet {
                lights: vec![Light::Point {
                    position,
                    color: [1.0, 0.9 - 0.1 * (k % 3) as f32, 0.8],
                    intensity: 2.0 + k as f32,
                    range: None,
                    name: None,
                }],
            }
        })
        .collect()
}

/// The fixture's shadow scene twice: as loaded (remembering answers and blockers between light
/// sets) and with nothing remembered (every ray traced).
fn remembering_and_traced() -> (
    bounce_core::direct::ShadowScene,
    bounce_core::direct::ShadowScene,
) {
    let remembering = bounce_core::direct::ShadowScene::of_baked(baked());
    let mut traced = bounce_core::direct::ShadowScene::of_baked(baked());
    traced.set_visibility_budget(0);
    (remembering, traced)
}

/// Each of `sets` in turn: means and samples of `scene` equal those of `traced`, bit for bit.
fn assert_same_as_every_ray_traced(
    scene: &bounce_core::direct::ShadowScene,
    traced: &bounce_core::direct::ShadowScene,
    sets: &[LightSet],
) {
    use bounce_core::direct::{direct_irradiance, direct_with_samples};
    let baked = baked();
    let rows = baked.transport_layout();
    let samples = baked.surface.as_ref().expect("a surface bake").per_patch;
    for set in sets {
        let want = direct_with_samples(traced, rows, set, samples).unwrap();
        assert_eq!(
            direct_with_samples(scene, rows, set, samples).unwrap(),
            want
        );
        assert_eq!(direct_irradiance(scene, rows, set, samples), want.mean);
    }
}

/// The shadow-ray answers kept from one light set to the next (`bounce_core::visibility`)
/// change no value: point lights, a narrow spot where the first point light stands (whose
/// answers the point's serve, and which needs only some of them), a wider and brighter spot
/// there (which needs rays neither traced before) and a sun, each asked for again and again,
/// give the same bits as tracing every ray, means and samples; and the answers were kept, one
/// entry a place.
#[test]
fn kept_shadow_answers_change_no_value() {
    let (kept, traced) = remembering_and_traced();
    assert!(kept.visibility_budget() > 0);
    let mut sets = light_sets(3);
    let Light::Point { position, .. } = sets[0].lights[0] else {
        unreachable!()
    };
    let spot = |intensity: f32, outer_cone_angle: f32| Light::Spot {
        position,
        direction: [0.2, -1.0, 0.1],
        color: [1.0; 3],
        intensity,
        range: None,
        inner_cone_angle: 0.1,
        outer_cone_angle,
        name: None,
    };
    let sun = Light::Directional {
        direction: [-0.3, -1.0, -0.2],
        color: [1.0; 3],
        intensity: 2.0,
        name: None,
    };
    sets.push(LightSet {
        lights: vec![spot(3.0, 0.4), sun.clone()],
    });
    sets.push(LightSet {
        lights: vec![sun, spot(5.0, 1.2)],
    });
    for _ in 0..3 {
        assert_same_as_every_ray_traced(&kept, &traced, &sets);
    }
    // Three point lights' places and the sun's: the spots stand where the first point light
    // does, and share its answers (they depend on the place alone).
    assert_eq!(kept.visibility_kept(), 4);
    assert_eq!(traced.visibility_kept(), 0);
}

/// A light that moves a little each set reads the last set's blockers as hints: the values
/// are those of every ray traced, bit for bit, whether a hint blocks again, was carried over a
/// set whose answers were kept, or comes from the other of two moving lights.
#[test]
fn the_last_sets_blockers_change_no_value() {
    let (mut hinted, traced) = remembering_and_traced();
    let Light::Point { position, .. } = light_sets(1)[0].lights[0] else {
        unreachable!()
    };
    let point = |step: f32| Light::Point {
        position: [
            position[0] + 0.07 * step,
            position[1],
            position[2] - 0.05 * step,
        ],
        color: [1.0; 3],
        intensity: 2.0,
        range: None,
        name: None,
    };
    let sun = |step: f32| Light::Directional {
        direction: [-0.3 + 0.02 * step, -1.0, -0.2],
        color: [1.0; 3],
        intensity: 2.0,
        name: None,
    };
    let mut sets: Vec<LightSet> = (0..4)
        .map(|k| LightSet {
            lights: vec![point(k as f32), sun(k as f32)],
        })
        .collect();
    // The third set again (its answers kept, its hints carried), then the lights in the other
    // order and one more point light.
    sets.push(sets[2].clone());
    sets.push(LightSet {
        lights: vec![sun(5.0), point(5.0), point(-3.0)],
    });
    assert_same_as_every_ray_traced(&hinted, &traced, &sets);
    assert_eq!(hinted.blockers_kept(), 3, "the last set's three lights");
    assert_eq!(traced.blockers_kept(), 0);
    // Forgotten (what `bounce bench direct` does before each motion): nothing kept, the budget
    // as it was, and the sets from the start give the same bits again.
    let budget = hinted.visibility_budget();
    assert!(hinted.visibility_kept() > 0);
    hinted.forget_kept();
    assert_eq!((hinted.visibility_kept(), hinted.blockers_kept()), (0, 0));
    assert_eq!(hinted.visibility_budget(), budget);
    assert_same_as_every_ray_traced(&hinted, &traced, &sets);
    assert_eq!(hinted.blockers_kept(), 3, "kept again after forgetting");
}

fn rel_l2(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
        num += (f64::from(*x) - f64::from(*y)).powi(2);
        den += f64::from(*y).powi(2);
    }
    (num / den.max(1e-300)).sqrt()
}

fn with_codec(codec: &dyn Codec) -> Baked {
    let mut b = baked().clone();
    b.transport = codec.encode(&b.transport.decode().unwrap()).unwrap();
    b
}

fn relight(engine: &Engine, baked: &Baked, sets: &[LightSet]) -> Vec<Irradiance> {
    let scene = engine.load(baked).unwrap();
    engine.relight(&scene, sets).unwrap()
}

#[test]
fn batched_relights_equal_one_by_one() {
    let sets = light_sets(9);
    let mut engines = vec![Engine::new(EngineChoice::Cpu).unwrap()];
    engines.extend(gpu_engine());
    for engine in &engines {
        for codec in [
            Box::new(bounce_core::codec::dense::DenseF32) as Box<dyn Codec>,
            Box::new(LogBlock::bc1()),
        ] {
            let baked = with_codec(codec.as_ref());
            let batch = relight(engine, &baked, &sets);
            assert_eq!(batch.len(), sets.len());
            for (k, set) in sets.iter().enumerate() {
                let one = relight(engine, &baked, std::slice::from_ref(set));
                assert_eq!(
                    one[0].direct,
                    batch[k].direct,
                    "{} {}",
                    engine.describe(),
                    codec.name()
                );
                // The GPU's matrix-vector kernels and the CPU row kernels sum each output in one
                // order whatever the batch, so they give the same bits. Past CHUNK sets the GPU
                // runs the tiled kernel, which sums in another (batch-independent) order, and
                // from GEMM_FROM sets on the CPU product is a blocked matrix product whose order
                // depends on the batch: f32 rounding.
                let bit_exact = if engine.kind() == EngineKind::Gpu {
                    sets.len() <= bounce_engine::gpu::CHUNK as usize
                } else {
                    sets.len() < bounce_core::codec::dense::GEMM_FROM
                };
                if bit_exact {
                    assert_eq!(
                        one[0].indirect,
                        batch[k].indirect,
                        "{} {} set {k}",
                        engine.describe(),
                        codec.name()
                    );
                } else {
                    // A GPU with tensor cores runs the block codecs' large batches with f16
                    // inputs (f32 sums): about 1e-4 here, where FP32 kernels differ by rounding.
                    let tensor = engine.kind() == EngineKind::Gpu
                        && engine.adapter().is_some_and(|a| a.tensor_cores)
                        && codec.name() != "dense-f32";
                    let close = if tensor { 3e-3 } else { 1e-5 };
                    let err = rel_l2(&batch[k].indirect, &one[0].indirect);
                    assert!(
                        err < close,
                        "{} {} set {k}: rel L2 {err:e}",
                        engine.describe(),
                        codec.name()
                    );
                }
            }
        }
    }
}

#[test]
fn gpu_engine_agrees_with_cpu_engine() {
    let Some(gpu) = gpu_engine() else { return };
    assert_eq!(gpu.kind(), EngineKind::Gpu);
    let cpu = Engine::new(EngineChoice::Cpu).unwrap();
    let sets = light_sets(4);
    // Dense: same products in another summation order. bc1: the texture unit may decode a texel
    // a code (10%) off the CPU decoder; over a whole row that averages to about 1% (engine/tests/gpu.rs
    // bounds it per output).
    for (codec, tolerance) in [
        (
            Box::new(bounce_core::codec::dense::DenseF32) as Box<dyn Codec>,
            1e-4,
        ),
        (Box::new(LogBlock::bc1()), 0.05),
    ] {
        let baked = with_codec(codec.as_ref());
        let a = relight(&gpu, &baked, &sets);
        let scene = gpu.load(&baked).unwrap();
        assert_eq!(
            gpu.direct_engine(&scene),
            EngineKind::Gpu,
            "surface geometry: GPU direct"
        );
        let b = relight(&cpu, &baked, &sets);
        for (x, y) in a.iter().zip(&b) {
            // Direct light: the GPU kernel against its CPU twin, with the tolerance of
            // engine/tests/it/gpu_direct_surface.rs (1e-4 relative per patch, at most 1% of
            // patches off by a flipped grazing shadow ray).
            direct_agrees(&x.direct, &y.direct);
            let err = rel_l2(&x.indirect, &y.indirect);
            assert!(
                err <= tolerance,
                "{}: GPU vs CPU rel L2 {err:e}",
                codec.name()
            );
        }
    }
}

/// GPU against CPU direct light per patch: relative `1e-4`, except for at most 1% of the
/// patches, where a shadow ray grazing a triangle (or voxel) edge may flip (each sample is 1/16
/// of a patch here, so such a patch may move by up to about a quarter of its value, never more
/// than half).
fn direct_agrees(gpu: &[[f32; 3]], cpu: &[[f32; 3]]) {
    assert_eq!(gpu.len(), cpu.len());
    let floor = cpu.iter().flatten().fold(0.0f32, |m, v| m.max(*v)) * 1e-7;
    let mut flipped = 0;
    for (i, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        let off = (0..3).any(|ch| (g[ch] - c[ch]).abs() > 1e-4 * c[ch] + floor);
        if off {
            flipped += 1;
            let (g, c) = (g[0] + g[1] + g[2], c[0] + c[1] + c[2]);
            assert!(
                (g - c).abs() <= 0.5 * g.max(c),
                "patch {i}: GPU {g} vs CPU {c}"
            );
        }
    }
    assert!(
        flipped * 100 <= cpu.len(),
        "{flipped} of {} patches differ beyond 1e-4",
        cpu.len()
    );
}

#[test]
fn cpu_engine_computes_direct_light_on_the_cpu() {
    let cpu = Engine::new(EngineChoice::Cpu).unwrap();
    let scene = cpu.load(baked()).unwrap();
    assert_eq!(cpu.direct_engine(&scene), EngineKind::Cpu);
    assert_eq!(scene.direct_fallback(), None);
    let Some(gpu) = gpu_engine() else { return };
    // A file without surface geometry or occupancy casts shadows from its patches alone: the
    // CPU's BVH, on either engine, saying why.
    let mut old = baked().clone();
    old.surface = None;
    old.occupancy = None;
    let scene = gpu.load(&old).unwrap();
    assert_eq!(gpu.direct_engine(&scene), EngineKind::Cpu);
    assert!(
        scene
            .direct_fallback()
            .is_some_and(|w| w.contains("occupancy"))
    );
    let sets = light_sets(2);
    let on_gpu = gpu.relight(&scene, &sets).unwrap();
    let on_cpu = relight(&cpu, &old, &sets);
    for (g, c) in on_gpu.iter().zip(&on_cpu) {
        assert_eq!(g.direct, c.direct, "the same CPU code on both engines");
    }
}

#[test]
fn auto_says_what_it_took() {
    let engine = Engine::new(EngineChoice::Auto).unwrap();
    match engine.kind() {
        EngineKind::Gpu => {
            assert!(engine.describe().starts_with("gpu ("));
            assert!(
                !engine.describe().contains("software"),
                "auto never takes lavapipe"
            );
        }
        EngineKind::Cpu => {
            assert!(engine.describe().starts_with("cpu"));
            assert!(engine.fallback().is_some(), "a CPU fallback must say why");
        }
    }
    // Where the GPU is software (CI's lavapipe), auto says so and `gpu` still opens it.
    if let Some(gpu) = gpu_engine()
        && gpu.describe().contains("software")
    {
        assert_eq!(engine.kind(), EngineKind::Cpu);
        assert!(engine.fallback().is_some_and(|w| w.contains("software")));
    }
}

#[test]
fn classic_radiosity_agrees_with_the_precomputed_transport() {
    let baked = baked();
    let Some(k) = (match baked.meta.settings.bounces {
        Bounces::K(k) => Some(k),
        Bounces::All => None,
    }) else {
        panic!("the fixture bakes a fixed bounce count")
    };
    let cpu = Engine::new(EngineChoice::Cpu).unwrap();
    let mut scene = cpu.load(baked).unwrap();
    let sets = light_sets(3);
    let with_near = cpu.relight(&scene, &sets).unwrap();
    // Jacobi iterates `F` on element means: the near-field first bounce is not part of it.
    assert_eq!(
        cpu.near_field(&scene),
        Ok(true),
        "the fixture has a near field"
    );
    scene.disable_near_field();
    let lit = cpu.relight(&scene, &sets).unwrap();
    assert_ne!(lit, with_near, "the near field changes the first bounce");
    // The iteration runs on the transport's rows (the elements), from their own direct light,
    // and is restricted to the patches as a relight is.
    let rows = baked.transport_layout();
    let shadow = bounce_core::direct::ShadowScene::of_baked(baked);
    let b0: Vec<[f32; 3]> = sets
        .iter()
        .flat_map(|set| {
            let e =
                bounce_core::direct::direct_irradiance(&shadow, rows, set, cpu.samples_for(&scene));
            bounce_core::direct::exitance_b0(rows, &e)
        })
        .collect();
    let f = decode(baked.form_factors.as_ref().unwrap()).unwrap();
    let mut by_jacobi = jacobi(f.as_ref(), rows, &b0, k).unwrap();
    if let Some(e) = &baked.elements {
        by_jacobi = e.restrict(&baked.layout, &by_jacobi);
    }
    let by_t: Vec<[f32; 3]> = lit.iter().flat_map(|l| l.indirect.clone()).collect();
    let err = rel_l2(&by_jacobi, &by_t);
    // Same sums, associated differently (f32): well under a part in ten thousand.
    assert!(err < 1e-5, "Jacobi vs T_k rel L2 {err:e}");
    assert!(
        by_t.iter().flatten().any(|v| *v > 0.0),
        "the lights reach the box"
    );
}

#[test]
fn the_later_bounces_carry_the_near_fields_first_bounce() {
    let baked = baked();
    let Bounces::K(k) = baked.meta.settings.bounces else {
        panic!("the fixture bakes a fixed bounce count")
    };
    let cpu = Engine::new(EngineChoice::Cpu).unwrap();
    let mut scene = cpu.load(baked).unwrap();
    assert!(scene.near_carried(), "3 bounces and a near field");
    let sets = light_sets(3);
    let carried = cpu.relight(&scene, &sets).unwrap();
    let (_, corrections) = cpu.direct_and_near(&scene, &sets).unwrap();
    let corrections = corrections.expect("the fixture's near field applies");
    // ΔE through the later bounces by iterating `F` (not `T`): Σ_{h=1..k} (F R)^h ΔE, which is
    // Jacobi's `k` gathers of `ρ ⊙ ΔE`.
    let rows = baked.transport_layout();
    let reflected: Vec<[f32; 3]> = corrections
        .iter()
        .flat_map(|set| {
            set.iter()
                .zip(&rows.patches)
                .map(|(d, p)| std::array::from_fn(|c| p.albedo[c] * d[c]))
        })
        .collect();
    let f = decode(baked.form_factors.as_ref().unwrap()).unwrap();
    let later = jacobi(f.as_ref(), rows, &reflected, k).unwrap();
    let elements = baked
        .elements
        .as_ref()
        .expect("a surface bake has elements");
    scene.first_bounce_near_field();
    assert!(!scene.near_carried());
    let first_only = cpu.relight(&scene, &sets).unwrap();
    let n = rows.len();
    for (s, ((c, f), d)) in carried
        .iter()
        .zip(&first_only)
        .zip(&corrections)
        .enumerate()
    {
        assert!(
            d.iter().flatten().any(|v| *v != 0.0),
            "set {s}: a correction to carry"
        );
        let added = elements.restrict(&baked.layout, &later[s * n..(s + 1) * n]);
        let expected: Vec<[f32; 3]> = f
            .indirect
            .iter()
            .zip(&added)
            .map(|(e, a)| std::array::from_fn(|ch| (e[ch] + a[ch]).max(0.0)))
            .collect();
        // `T` against `F` iterated, in f32, and the clamp at zero taken once instead of twice.
        let err = rel_l2(&c.indirect, &expected);
        assert!(err < 1e-5, "set {s}: carried vs F iterated rel L2 {err:e}");
        // What carrying adds is no rounding: the test fails if the later bounces drop it.
        let gain = rel_l2(&c.indirect, &f.indirect);
        assert!(
            gain > 1e-3,
            "set {s}: carrying ΔE moved E_ind by only {gain:e}"
        );
    }
    // A one-bounce transport has no later bounce to carry it into.
    let mut one = baked.clone();
    one.meta.settings.bounces = Bounces::K(1);
    assert!(!cpu.load(&one).unwrap().near_carried());
}

#[test]
fn bad_lights_are_refused_with_their_place_in_the_batch() {
    let cpu = Engine::new(EngineChoice::Cpu).unwrap();
    let scene = cpu.load(baked()).unwrap();
    let mut sets = light_sets(3);
    sets[2].lights.push(Light::Point {
        position: [0.0, f32::NAN, 0.0],
        color: [1.0; 3],
        intensity: 1.0,
        range: None,
        name: None,
    });
    match cpu.relight(&scene, &sets) {
        Err(EngineError::Lights { index, error }) => {
            assert_eq!(index, 2);
            assert!(error.to_string().contains("lights[1].position"), "{error}");
        }
        other => panic!("expected a light error, got {:?}", other.map(|_| ())),
    }
}
