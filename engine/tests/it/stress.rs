//! Numerical stress on the relight engines (issue 8, docs/design.md §4): a thousand random light
//! configurations on the baked Cornell box, and the white furnace at albedo 0.999, on the CPU
//! engine and the GPU engine (lavapipe in CI). Irradiance must stay finite and never negative.

use bounce_core::bake::{BakeOptions, NoProgress, bake_scene};
use bounce_core::codec::configured;
use bounce_core::format::Baked;
use bounce_core::light::{Light, LightSet};
use bounce_core::meta::Bounces;
use bounce_core::scene::{Scene, Triangle};
use bounce_core::voxel::Resolution;
use bounce_engine::{Engine, EngineChoice, Irradiance};
use glam::Vec3;

use crate::relight::{baked, gpu_engine};

/// xorshift64*: deterministic, no dependency, good enough to scatter lights.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }
    /// `10^x` with `x` uniform in `[lo, hi]`.
    fn log10_uniform(&mut self, lo: f32, hi: f32) -> f32 {
        10f32.powf(self.range(lo, hi))
    }
}

/// The brightest intensity the random lights use: 10^38.5 ≈ 3.2e38 cd, just below f32::MAX, so
/// the range covers 44 orders of magnitude. Past about 1e33 cd a light a voxel from a patch
/// gives more than f32 holds; the engines must clamp, not overflow into infinity or NaN.
const MAX_LOG10_INTENSITY: f32 = 38.5;

/// `count` light configurations around a scene whose grid spans `lo..hi`: 1 to 4 lights each,
/// of every kind, inside and outside the scene (up to two scene sizes beyond it), colours from
/// black to saturated to over-unit, intensities log-uniform from 1e-6 to 3e38 (and some 0).
fn random_light_sets(count: usize, lo: Vec3, hi: Vec3, seed: u64) -> Vec<LightSet> {
    let mut rng = Rng(seed);
    let size = hi - lo;
    (0..count)
        .map(|_| {
            let lights = (0..1 + rng.next_u64() % 4)
                .map(|_| {
                    // Half inside the grid, half anywhere up to two scene sizes beyond it.
                    let (a, b) = if rng.next_u64().is_multiple_of(2) {
                        (0.05, 0.95)
                    } else {
                        (-2.0, 3.0)
                    };
                    let position = (lo
                        + size * Vec3::new(rng.range(a, b), rng.range(a, b), rng.range(a, b)))
                    .to_array();
                    let direction = [
                        rng.range(-1.0, 1.0),
                        rng.range(-1.0, 1.0),
                        rng.range(-1.0, 1.0),
                    ];
                    // A direction that happens to be zero would be refused: nudge it.
                    let direction = if direction.iter().all(|d| *d == 0.0) {
                        [0.0, -1.0, 0.0]
                    } else {
                        direction
                    };
                    let color = match rng.next_u64() % 4 {
                        0 => [0.0; 3],
                        1 => [rng.unit(), 0.0, 0.0],
                        2 => [rng.unit(), rng.unit(), rng.unit()],
                        _ => [
                            rng.range(0.0, 10.0),
                            rng.range(0.0, 10.0),
                            rng.range(0.0, 10.0),
                        ],
                    };
                    let intensity = if rng.next_u64().is_multiple_of(16) {
                        0.0
                    } else {
                        rng.log10_uniform(-6.0, MAX_LOG10_INTENSITY)
                    };
                    let range = rng
                        .next_u64()
                        .is_multiple_of(3)
                        .then(|| rng.log10_uniform(-2.0, 2.0) * size.max_element());
                    match rng.next_u64() % 3 {
                        0 => Light::Point {
                            position,
                            color,
                            intensity,
                            range,
                            name: None,
                        },
                        1 => {
                            let outer = rng.range(0.01, std::f32::consts::FRAC_PI_2);
                            Light::Spot {
                                position,
                                direction,
                                color,
                                intensity,
                                range,
                                inner_cone_angle: outer * rng.range(0.0, 0.99),
                                outer_cone_angle: outer,
                                name: None,
                            }
                        }
                        _ => Light::Directional {
                            direction,
                            color,
                            intensity,
                            name: None,
                        },
                    }
                })
                .collect();
            LightSet { lights }
        })
        .collect()
}

/// The largest value seen, after checking every value is finite and non-negative.
fn check(engine: &Engine, sets: &[LightSet], lit: &[Irradiance]) -> (f32, f32) {
    let (mut max_direct, mut max_indirect) = (0.0f32, 0.0f32);
    for (k, (set, l)) in sets.iter().zip(lit).enumerate() {
        for (what, values, max) in [
            ("direct", &l.direct, &mut max_direct),
            ("indirect", &l.indirect, &mut max_indirect),
        ] {
            for (i, rgb) in values.iter().enumerate() {
                assert!(
                    rgb.iter().all(|v| v.is_finite() && *v >= 0.0),
                    "{}: set {k} patch {i} {what} {rgb:?}; lights {set:?}",
                    engine.describe()
                );
                *max = rgb.iter().fold(*max, |m, v| m.max(*v));
            }
        }
    }
    (max_direct, max_indirect)
}

fn grid_bounds(baked: &Baked) -> (Vec3, Vec3) {
    let l = &baked.layout;
    let lo = Vec3::from(l.origin);
    let dims = Vec3::new(l.dims[0] as f32, l.dims[1] as f32, l.dims[2] as f32);
    (lo, lo + dims * l.voxel_size)
}

/// 1,000 random configurations, in batches as the server sends them, on both engines: no NaN,
/// no infinity, no negative irradiance anywhere; every configuration passes validation.
/// Before the engine clamped `E_ind` to f32::MAX this found infinities (a 2e37 cd light).
#[test]
fn a_thousand_random_light_configurations_stay_finite_and_non_negative() {
    let baked = baked();
    let (lo, hi) = grid_bounds(baked);
    let sets = random_light_sets(1000, lo, hi, 0x5eed_0008);
    for (k, s) in sets.iter().enumerate() {
        s.validate()
            .unwrap_or_else(|e| panic!("random set {k} is invalid: {e}"));
    }
    let lights: usize = sets.iter().map(|s| s.lights.len()).sum();
    let mut engines = vec![Engine::new(EngineChoice::Cpu).unwrap()];
    engines.extend(gpu_engine());
    let mut results = Vec::new();
    // The lossy codecs, on both engines too: their decoded entries must not turn negative. A
    // quarter of the configurations: lavapipe runs their kernels slowly.
    let some = &sets[..sets.len() / 4];
    let lossy: Vec<Baked> = ["bc1-resid", "log8"]
        .iter()
        .map(|name| {
            let mut b = baked.clone();
            let t = b.transport.decode().unwrap();
            b.transport = configured(name, None).unwrap().encode(&t).unwrap();
            b
        })
        .collect();
    for engine in &mut engines {
        // Fewer direct-light samples than the server's default: this counts NaNs, it does not
        // need smooth shadows, and lavapipe runs the kernel on these two cores.
        engine.samples = Some(4);
        for b in &lossy {
            let scene = engine.load(b).unwrap();
            let mut lit = Vec::new();
            for batch in some.chunks(50) {
                lit.extend(engine.relight(&scene, batch).unwrap());
            }
            let (_, max_indirect) = check(engine, some, &lit);
            eprintln!(
                "{} with {}: {} configurations finite and non-negative, largest E_ind {max_indirect:e}",
                engine.describe(),
                b.transport.codec,
                some.len()
            );
        }
        let scene = engine.load(baked).unwrap();
        let mut lit = Vec::new();
        for batch in sets.chunks(50) {
            lit.extend(engine.relight(&scene, batch).unwrap());
        }
        let (max_direct, max_indirect) = check(engine, &sets, &lit);
        let zero = lit
            .iter()
            .filter(|l| l.indirect.iter().flatten().all(|v| *v == 0.0))
            .count();
        eprintln!(
            "{}: {} configurations, {lights} lights, {} patches: largest E_direct {max_direct:e}, \
             largest E_ind {max_indirect:e}; {zero} configurations light nothing indirectly",
            engine.describe(),
            sets.len(),
            baked.layout.len()
        );
        assert!(
            max_indirect > 0.0 && zero < sets.len() / 2,
            "the lights reach the box"
        );
        results.push(lit);
    }
    // The two engines light the same configurations alike (their direct light samples the same
    // points; f32 sums in another order). Compared on the sums over patches, which every
    // configuration has, relative to the configuration's own size.
    if let [cpu, gpu] = &results[..] {
        let mut worst = 0.0f64;
        for (c, g) in cpu.iter().zip(gpu) {
            let total = |l: &Irradiance| {
                l.indirect
                    .iter()
                    .flatten()
                    .map(|v| f64::from(*v))
                    .sum::<f64>()
            };
            let (a, b) = (total(c), total(g));
            if a.max(b) > 0.0 {
                worst = worst.max((a - b).abs() / a.max(b));
            }
        }
        eprintln!("CPU vs GPU engine: worst relative difference of ΣE_ind {worst:.2e}");
        assert!(worst < 1e-3, "CPU and GPU engines disagree: {worst}");
    }
}

/// The closed box of `furnace.rs` at albedo 0.999, baked with all bounces: the engines stay
/// finite, and energy balance holds. In a closed room of equal patches `F` is symmetric with
/// rows (and so columns) summing to 1, so `1ᵀ T_∞ = 1ᵀ/(1 − ρ)` and
/// `Σ_i E_ind,i = Σ_j B0_j/(1 − ρ) = ρ/(1 − ρ) Σ_j E_direct,j`: a gain of 999.
#[test]
fn the_furnace_at_albedo_0999_stays_finite_on_both_engines() {
    let rho = 0.999f32;
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    let walls = [
        [c(0., 0., 0.), c(1., 0., 0.), c(1., 0., 1.), c(0., 0., 1.)],
        [c(0., 1., 0.), c(0., 1., 1.), c(1., 1., 1.), c(1., 1., 0.)],
        [c(0., 0., 0.), c(0., 0., 1.), c(0., 1., 1.), c(0., 1., 0.)],
        [c(1., 0., 0.), c(1., 1., 0.), c(1., 1., 1.), c(1., 0., 1.)],
        [c(0., 0., 0.), c(0., 1., 0.), c(1., 1., 0.), c(1., 0., 0.)],
        [c(0., 0., 1.), c(1., 0., 1.), c(1., 1., 1.), c(0., 1., 1.)],
    ];
    let mut triangles = Vec::new();
    for w in walls {
        for mut tri in [[w[0], w[1], w[2]], [w[0], w[2], w[3]]] {
            let inward = Vec3::splat(0.5) - (tri[0] + tri[1] + tri[2]) / 3.0;
            if (tri[1] - tri[0]).cross(tri[2] - tri[0]).dot(inward) < 0.0 {
                tri.swap(1, 2);
            }
            triangles.push(Triangle {
                positions: tri,
                albedo: Vec3::splat(rho),
                emission: Vec3::ZERO,
                double_sided: false,
                material: 0,
            });
        }
    }
    let scene = Scene {
        triangles,
        ..Default::default()
    };
    let options = BakeOptions {
        resolution: Resolution::TargetPatches(200),
        rays: 2048,
        bounces: Bounces::All,
        ..BakeOptions::default()
    };
    let baked = bake_scene(&scene, "furnace", &options, &NoProgress).unwrap();
    let (lo, hi) = grid_bounds(&baked);
    let mut sets = vec![LightSet {
        lights: vec![Light::Point {
            position: ((lo + hi) * 0.5).to_array(),
            color: [1.0; 3],
            intensity: 1.0,
            range: None,
            name: None,
        }],
    }];
    sets.extend(random_light_sets(20, lo, hi, 99));
    let mut engines = vec![Engine::new(EngineChoice::Cpu).unwrap()];
    engines.extend(gpu_engine());
    for engine in &engines {
        let scene = engine.load(&baked).unwrap();
        let lit = engine.relight(&scene, &sets).unwrap();
        let (_, max_indirect) = check(engine, &sets, &lit);
        // Energy balance holds for power, not irradiance: surface patches differ in area.
        let areas = baked.layout.areas(baked.meta.settings.geometry);
        let sum = |v: &[[f32; 3]]| {
            v.iter()
                .zip(&areas)
                .map(|(x, a)| f64::from(x[0]) * f64::from(*a))
                .sum::<f64>()
        };
        let albedo = f64::from(baked.layout.patches[0].albedo[0].min(0.999));
        let gain = sum(&lit[0].indirect) / sum(&lit[0].direct);
        let want = albedo / (1.0 - albedo);
        eprintln!(
            "{}: furnace ρ {albedo}, {} patches: ΣE_ind/ΣE_direct {gain:.2} (want ρ/(1−ρ) = \
             {want:.2}); largest E_ind over {} configurations {max_indirect:e}",
            engine.describe(),
            baked.layout.len(),
            sets.len()
        );
        // F's column sums carry the form factors' ray noise, amplified at ρ near 1.
        assert!((gain - want).abs() < 0.05 * want, "gain {gain} vs {want}");
    }
}
