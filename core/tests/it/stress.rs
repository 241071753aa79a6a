//! Numerical stress (issue 8, docs/design.md §4): albedo near 1 in a closed box, scenes of one and
//! two patches and of patches that see nothing, the same scene at 1e-3 and 1e4 units, and
//! non-finite positions. Each case must stay finite and bounded, and say clearly when it cannot
//! work. Every bake here is real (voxeliser, ray caster, transport) and small enough for seconds.

use bounce_core::bake::{BakeError, BakeOptions, NoProgress, bake_scene, simplify};
use bounce_core::codec::decode;
use bounce_core::direct::{DEFAULT_SAMPLES, ShadowScene, direct_irradiance, exitance_b0};
use bounce_core::format::Baked;
use bounce_core::formfactor::{RayScene, form_factors};
use bounce_core::import::{ImportError, import_slice};
use bounce_core::light::{Light, LightSet};
use bounce_core::matrix::DenseMatrix;
use bounce_core::meta::Bounces;
use bounce_core::scene::{Scene, Triangle};
use bounce_core::transport::{MAX_ALBEDO, Tail, choose_channels, transport};
use bounce_core::voxel::{Resolution, voxelize};
use glam::Vec3;
use serde_json::json;

use crate::furnace::closed_box;
use crate::import::Gltf;

fn no_progress(_: u64) {}

/// `T · 1` per row, in f64.
fn row_sums(t: &DenseMatrix) -> Vec<f64> {
    (0..t.n)
        .map(|i| (0..t.n).map(|j| f64::from(t.get(0, i, j))).sum())
        .collect()
}

/// `Σ_{h<k} s (ρ s)^h`: what `T_k · 1` is when every row of `F` sums to `s` (`k = None`: all
/// bounces, `s/(1 − ρ s)`). Derived from `T_k = Σ_{h<k} F (D_ρ F)^h` (docs/design.md §1):
/// with `F 1 = s 1`, each factor `D_ρ F` multiplies the all-ones vector by `ρ s`.
fn furnace_row_sum(rho: f64, s: f64, k: Option<u32>) -> f64 {
    let q = rho * s;
    match k {
        Some(k) => s * (1.0 - q.powi(k as i32)) / (1.0 - q),
        None => s / (1.0 - q),
    }
}

/// The white furnace at the albedo the transport allows at most (0.999): `T_∞` by the direct
/// solve, and `T_k` for a few `k`, against the closed forms. `F`'s row sums are measured and
/// carried into the expected range rather than assumed to be exactly 1, because at ρ = 0.999 a
/// leak of 1e-4 in a row moves `T_∞ 1` by 10%: the bound `s_min/(1−ρ s_min) ≤ T_∞ 1 ≤
/// s_max/(1−ρ s_max)` holds for any non-negative `F` with row sums in `[s_min, s_max]`.
#[test]
fn furnace_at_albedo_0999_is_finite_and_matches_the_closed_forms() {
    let scene = closed_box(2.0, 0.999);
    let vox = voxelize(&scene, Resolution::TargetPatches(150)).unwrap();
    let layout = &vox.layout;
    let n = layout.len();
    let rays = RayScene::new(&layout.quads(), &vox.occluders);
    let (f, tally) = form_factors(&rays, 1024, 3, &no_progress).unwrap();
    assert_eq!(tally.patch, tally.total(), "a closed box loses no ray");
    // Summed here in f64: the bound below needs the row sums closer than f32 stats keep them.
    let f_sums = row_sums(&f);
    let (s_min, s_max) = f_sums
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &s| (a.min(s), b.max(s)));
    assert!(
        s_min > 1.0 - 1e-5 && s_max < 1.0 + 1e-5,
        "F rows of a closed box sum to 1: {s_min} .. {s_max}"
    );
    let albedo: Vec<[f32; 3]> = layout.patches.iter().map(|p| p.albedo).collect();
    // What the transport uses: the voxel's albedo, clamped to MAX_ALBEDO.
    let rho = f64::from(albedo[0][0].min(MAX_ALBEDO));
    assert!(
        albedo
            .iter()
            .all(|a| (f64::from(a[0].min(MAX_ALBEDO)) - rho).abs() < 1e-7)
    );
    assert!((rho - 0.999).abs() < 1e-6, "ρ = {rho}");
    eprintln!("furnace ρ = {rho}, {n} patches, F row sums {s_min:.7} .. {s_max:.7}");

    for k in [Some(1), Some(3), Some(30), None] {
        let bounces = k.map_or(Bounces::All, Bounces::K);
        let channels = choose_channels(&f, &albedo, bounces, &[], 0.0)
            .unwrap()
            .channels;
        let t = transport(&f, &albedo, bounces, Tail::Exact, channels, &no_progress).unwrap();
        assert!(
            t.data.iter().all(|v| v.is_finite() && *v >= 0.0),
            "{bounces}: a negative or non-finite entry"
        );
        let sums = row_sums(&t);
        let (lo, hi) = (
            furnace_row_sum(rho, s_min, k),
            furnace_row_sum(rho, s_max, k),
        );
        let exact = furnace_row_sum(rho, 1.0, k);
        // f32 storage of T and f32 summation order: a part in 1e5 on top of the bound.
        let slack = 1e-5 * exact;
        let (got_min, got_max) = sums
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &s| (a.min(s), b.max(s)));
        eprintln!(
            "furnace {bounces}: T·1 rows {got_min:.4} .. {got_max:.4}, expected {exact:.4} \
             (bound {lo:.4} .. {hi:.4}); E_ind for unit direct light {:.4} .. {:.4}, expected ρ·that = {:.4}",
            rho * got_min,
            rho * got_max,
            rho * exact
        );
        assert!(
            got_min >= lo - slack && got_max <= hi + slack,
            "{bounces}: T·1 in {got_min} .. {got_max}, outside {lo} .. {hi}"
        );
        // And the bound is tight: within 0.2% of the closed form for F rows summing to exactly 1.
        assert!(
            ((got_min - exact) / exact).abs() < 2e-3 && ((got_max - exact) / exact).abs() < 2e-3,
            "{bounces}: {got_min} .. {got_max} vs {exact}"
        );
    }
}

fn plate(corners: [Vec3; 4], normal: Vec3, albedo: f32) -> Vec<Triangle> {
    [[0, 1, 2], [0, 2, 3]]
        .into_iter()
        .map(|[a, b, c]| {
            let mut positions = [corners[a], corners[b], corners[c]];
            if (positions[1] - positions[0])
                .cross(positions[2] - positions[0])
                .dot(normal)
                < 0.0
            {
                positions.swap(1, 2);
            }
            Triangle {
                positions,
                albedo: Vec3::splat(albedo),
                emission: Vec3::ZERO,
                double_sided: false,
                material: 0,
            }
        })
        .collect()
}

/// A square of side `side` in the plane `z = z`, its corners offset by `(x, y)`, facing `normal`.
fn square_z(x: f32, y: f32, z: f32, side: f32, normal: Vec3, albedo: f32) -> Vec<Triangle> {
    let c = |u: f32, v: f32| Vec3::new(x + u * side, y + v * side, z);
    plate([c(0., 0.), c(1., 0.), c(1., 1.), c(0., 1.)], normal, albedo)
}

fn bake(scene: &Scene, resolution: Resolution, bounces: Bounces) -> Result<Baked, BakeError> {
    let options = BakeOptions {
        resolution,
        rays: 1024,
        bounces,
        keep_form_factors: true,
        ..BakeOptions::default()
    };
    bake_scene(scene, "stress", &options, &NoProgress)
}

/// One patch alone, and one open plate: nothing to interreflect, and the bake says so in words
/// a user can act on rather than writing an all-zero matrix.
#[test]
fn a_single_patch_or_an_open_plate_is_a_clear_error() {
    for (what, resolution) in [
        // The grid is centred on the scene with a voxel of margin: a plate exactly one voxel
        // wide fills the middle voxel's face.
        ("one patch", Resolution::VoxelSize(0.5)),
        ("open plate", Resolution::VoxelSize(0.05)),
    ] {
        let scene = Scene {
            triangles: square_z(0.0, 0.0, 0.0, 0.5, Vec3::Z, 0.8),
            ..Default::default()
        };
        let err = bake(&scene, resolution, Bounces::All).unwrap_err();
        let BakeError::NoInterreflection { patches, .. } = &err else {
            panic!("{what}: {err:?}");
        };
        eprintln!("{what}: {err}");
        assert!(*patches >= 1, "{what}: {err}");
        if what == "one patch" {
            assert_eq!(*patches, 1, "{err}");
        }
        assert!(err.to_string().contains("no patch sees another"), "{err}");
    }
}

/// Two patches facing each other: `F = [[0, f01], [f10, 0]]`, whose transport has a closed
/// form, `T_∞ = F (I − ρF)^{-1} = [[ρ f01 f10, f01], [f10, ρ f10 f01]] / (1 − ρ² f01 f10)`,
/// checked at ρ = 0.999; and `f` itself against Howell's parallel squares (C-11): surface
/// patches are the plates themselves, 0.5 squares 0.75 apart, `F = 0.1107`.
#[test]
fn two_patches_match_the_two_by_two_closed_form() {
    let rho = 0.999f32;
    // Plates 0.5 wide, 0.75 apart, voxels of 0.5: the grid (centred, one voxel of margin) puts
    // each plate in its own voxel, so each plate is one patch.
    let mut triangles = square_z(0.0, 0.0, 0.0, 0.5, Vec3::Z, rho);
    triangles.extend(square_z(0.0, 0.0, 0.75, 0.5, -Vec3::Z, rho));
    let scene = Scene {
        triangles,
        ..Default::default()
    };
    let baked = bake(&scene, Resolution::VoxelSize(0.5), Bounces::All).unwrap();
    assert_eq!(baked.layout.len(), 2, "{:?}", baked.layout.patches);
    let gap = (baked.layout.patches[0].centroid[2] - baked.layout.patches[1].centroid[2]).abs();
    let f = baked.form_factors.as_ref().unwrap().decode().unwrap();
    let t = baked.transport.decode().unwrap();
    let (f01, f10) = (f64::from(f.get(0, 0, 1)), f64::from(f.get(0, 1, 0)));
    assert_eq!((f.get(0, 0, 0), f.get(0, 1, 1)), (0.0, 0.0));
    // 1,024 rays: a standard error of √(0.11·0.89/1024) = 0.0098 per row.
    for fij in [f01, f10] {
        assert!(
            (fij - 0.1107).abs() < 0.04,
            "F = {:?}, patch gap {gap}",
            f.data
        );
    }
    let r = f64::from(rho.min(MAX_ALBEDO));
    // General 2×2 (f01 and f10 differ by ray noise): (I − ρF)^{-1} = [[1, ρf01], [ρf10, 1]]/det.
    let det = 1.0 - r * r * f01 * f10;
    let want = [
        [r * f01 * f10 / det, f01 / det],
        [f10 / det, r * f10 * f01 / det],
    ];
    eprintln!(
        "two patches: F01 {f01:.5} F10 {f10:.5}; T_∞ {:?}, want {want:?}",
        t.data
    );
    for (i, row) in want.iter().enumerate() {
        for (j, w) in row.iter().enumerate() {
            let got = f64::from(t.get(0, i, j));
            assert!(got.is_finite(), "T[{i}][{j}] = {got}");
            assert!(
                (got - w).abs() <= 1e-5 * w.max(1e-3),
                "T[{i}][{j}] = {got}, want {w}"
            );
        }
    }
}

/// A closed box plus a plate outside it that faces away: the plate's patches see nothing, are
/// dropped and counted, and the box bakes as it would alone.
#[test]
fn patches_that_see_nothing_are_dropped_and_the_rest_bakes() {
    let mut scene = closed_box(1.0, 0.7);
    scene
        .triangles
        .extend(square_z(3.0, 0.0, 0.0, 1.0, -Vec3::Z, 0.7));
    let baked = bake(&scene, Resolution::TargetPatches(200), Bounces::K(3)).unwrap();
    let s = &baked.meta.stats;
    eprintln!(
        "box + outward plate: {} patches kept, {} dropped as seeing nothing, isolated after the \
         drop {}",
        s.patches, s.dropped_patches, s.isolated_patches
    );
    assert!(s.dropped_patches > 0, "{s:?}");
    assert_eq!(s.isolated_patches, 0, "{s:?}");
    // Every kept patch is inside the box.
    for p in &baked.layout.patches {
        assert!(
            p.centroid.iter().all(|c| (-0.01..1.01).contains(c)),
            "{p:?}"
        );
    }
    let t = baked.transport.decode().unwrap();
    assert!(t.data.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(row_sums(&t).iter().all(|s| *s > 0.0));
}

// ---------------------------------------------------------------------------------------------
// Scale
// ---------------------------------------------------------------------------------------------

/// A Cornell-like box as a GLB, scaled by `s` in its positions: five inward walls of the unit box
/// (open at z = 1), red left and green right, and a block on the floor; plus two degenerate
/// triangles (a repeated corner, three collinear corners) that must be dropped and counted.
fn cornell_glb(s: f32) -> Vec<u8> {
    let mut quads: Vec<([Vec3; 4], Vec3, usize)> = Vec::new();
    let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    // (corners, facing, material): 0 white, 1 red, 2 green.
    quads.push((
        [v(0., 0., 0.), v(1., 0., 0.), v(1., 0., 1.), v(0., 0., 1.)],
        Vec3::Y,
        0,
    ));
    quads.push((
        [v(0., 1., 0.), v(1., 1., 0.), v(1., 1., 1.), v(0., 1., 1.)],
        -Vec3::Y,
        0,
    ));
    quads.push((
        [v(0., 0., 0.), v(1., 0., 0.), v(1., 1., 0.), v(0., 1., 0.)],
        Vec3::Z,
        0,
    ));
    quads.push((
        [v(0., 0., 0.), v(0., 1., 0.), v(0., 1., 1.), v(0., 0., 1.)],
        Vec3::X,
        1,
    ));
    quads.push((
        [v(1., 0., 0.), v(1., 1., 0.), v(1., 1., 1.), v(1., 0., 1.)],
        -Vec3::X,
        2,
    ));
    // A block [0.2, 0.5] × [0, 0.45] × [0.3, 0.6], faces outwards.
    let (lo, hi) = (v(0.2, 0.0, 0.3), v(0.5, 0.45, 0.6));
    for axis in 0..3 {
        for (plane, sign) in [(lo[axis], -1.0f32), (hi[axis], 1.0)] {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let corner = |u: f32, w: f32| {
                let mut p = Vec3::ZERO;
                p[axis] = plane;
                p[a] = u;
                p[b] = w;
                p
            };
            let mut n = Vec3::ZERO;
            n[axis] = sign;
            quads.push((
                [
                    corner(lo[a], lo[b]),
                    corner(hi[a], lo[b]),
                    corner(hi[a], hi[b]),
                    corner(lo[a], hi[b]),
                ],
                n,
                0,
            ));
        }
    }
    let mut g = Gltf::default();
    let mut primitives = Vec::new();
    for (corners, normal, material) in quads {
        let mut tri = Vec::new();
        for [a, b, c] in [[0, 1, 2], [0, 2, 3]] {
            let mut t = [corners[a], corners[b], corners[c]];
            if (t[1] - t[0]).cross(t[2] - t[0]).dot(normal) < 0.0 {
                t.swap(1, 2);
            }
            tri.extend(t.map(|p| (p * s).to_array()));
        }
        let pos = g.positions(&tri);
        primitives.push(json!({"attributes": {"POSITION": pos}, "material": material}));
    }
    let junk = [
        [0.5, 0.5, 0.5],
        [0.5, 0.5, 0.5],
        [0.6, 0.5, 0.5], // a repeated corner
        [0.1, 0.1, 0.1],
        [0.2, 0.2, 0.2],
        [0.3, 0.3, 0.3], // collinear
    ]
    .map(|p: [f32; 3]| (Vec3::from(p) * s).to_array());
    let pos = g.positions(&junk);
    primitives.push(json!({"attributes": {"POSITION": pos}, "material": 0}));
    let colour =
        |c: [f32; 3]| json!({"pbrMetallicRoughness": {"baseColorFactor": [c[0], c[1], c[2], 1.0]}});
    g.glb(json!({
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"name": "cornell", "primitives": primitives}],
        "materials": [colour([0.73; 3]), colour([0.63, 0.06, 0.05]), colour([0.15, 0.48, 0.09])]
    }))
}

/// Per patch direct and indirect irradiance of `baked` under `lights`, through the core's CPU
/// direct light and the decoded transport (what the CPU engine does).
fn relight(baked: &Baked, lights: &LightSet) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let rows = baked.transport_layout();
    let shadow = ShadowScene::new(rows, baked.occupancy.as_deref());
    let direct = direct_irradiance(&shadow, rows, lights, DEFAULT_SAMPLES);
    let b0 = exitance_b0(rows, &direct);
    let t = decode(&baked.transport).unwrap();
    let mut indirect = vec![[0.0; 3]; b0.len()];
    t.matvec_batch(&b0, &mut indirect).unwrap();
    match &baked.elements {
        Some(e) => (
            e.restrict_sampled(&baked.layout, &direct),
            e.restrict(&baked.layout, &indirect),
        ),
        None => (direct, indirect),
    }
}

fn rel_l2(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
        num += (f64::from(*x) - f64::from(*y)).powi(2);
        den += f64::from(*y).powi(2);
    }
    (num / den.max(1e-300)).sqrt()
}

/// The same box at 1, 1e-3 and 1e4 units, with the light's intensity scaled by `s²` so that the
/// irradiance is the same. At a voxel size in proportion (0.13 units of the unit box) the
/// patches are the same, and so must be `E_direct` and `E_ind`, within the bake's noise;
/// tolerances or ray offsets fixed in world units would show here as lost or extra light. A
/// patch-count target lands near its target at every scale (the search's path differs in the
/// last bits, so not on the same voxel size).
#[test]
fn the_box_at_a_thousandth_and_ten_thousand_units_gives_the_same_irradiance() {
    let run = |s: f32| {
        let scene = import_slice(&cornell_glb(s), None).unwrap();
        assert_eq!(scene.report.degenerate_triangles, 2, "scale {s}");
        assert_eq!(scene.triangles.len(), 22, "scale {s}");
        let target = BakeOptions {
            resolution: Resolution::TargetPatches(300),
            ..BakeOptions::default()
        };
        let searched = simplify(&scene, &target).unwrap().layout;
        // 1/0.13 = 7.7 voxels across: no grid plane near a wall at any scale's rounding.
        let baked = bake(&scene, Resolution::VoxelSize(0.13 * s), Bounces::K(3)).unwrap();
        let lights = LightSet {
            lights: vec![Light::Point {
                position: [0.5 * s, 0.85 * s, 0.5 * s],
                color: [1.0, 0.95, 0.9],
                intensity: 4.0 * s * s,
                range: None,
                name: None,
            }],
        };
        let (direct, indirect) = relight(&baked, &lights);
        eprintln!(
            "scale {s:e}: target 300 → {} patches at voxel {:e}; voxel {:e} → {} patches",
            searched.len(),
            searched.voxel_size,
            baked.layout.voxel_size,
            baked.layout.len()
        );
        assert!(
            (270..=330).contains(&searched.len()),
            "scale {s}: {} patches for a target of 300",
            searched.len()
        );
        (baked, direct, indirect)
    };
    let (b1, d1, i1) = run(1.0);
    let sum = |v: &[[f32; 3]]| v.iter().flatten().map(|x| f64::from(*x)).sum::<f64>();
    assert!(sum(&i1) > 0.0);
    for s in [1e-3f32, 1e4] {
        let (b, d, i) = run(s);
        assert_eq!(b.layout.len(), b1.layout.len(), "scale {s}: patch count");
        for (p, q) in b.layout.patches.iter().zip(&b1.layout.patches) {
            assert_eq!((p.voxel, p.face), (q.voxel, q.face), "scale {s}");
        }
        for x in d.iter().chain(&i).flatten() {
            assert!(x.is_finite() && *x >= 0.0, "scale {s}: {x}");
        }
        let (ed, ei) = (rel_l2(&d, &d1), rel_l2(&i, &i1));
        eprintln!(
            "scale {s:e}: E_direct rel L2 {ed:.2e}, E_ind rel L2 {ei:.2e} against scale 1; \
             ΣE_ind {:.4} vs {:.4}",
            sum(&i),
            sum(&i1)
        );
        // Same seed, same patches: only f32 rounding differs. Direct light measured ~1e-7; the
        // form-factor rays that pass through a triangle edge or corner land on one side or the
        // other as rounding differs at each scale, which moves E_ind by ~2e-4 (measured 1.7e-4
        // at 1e-3 units), far below the bake's own noise.
        assert!(ed < 1e-4, "scale {s}: E_direct rel L2 {ed}");
        assert!(ei < 1e-3, "scale {s}: E_ind rel L2 {ei}");
    }
}

#[test]
fn infinite_positions_are_an_error_naming_the_mesh() {
    for bad in [f32::INFINITY, f32::NEG_INFINITY] {
        let mut g = Gltf::default();
        let good = g.positions(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        let broken = g.positions(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, bad, 0.0]]);
        let doc = g.glb(json!({
            "nodes": [{"mesh": 0}, {"mesh": 1}],
            "meshes": [
                {"name": "fine", "primitives": [{"attributes": {"POSITION": good}}]},
                {"name": "broken", "primitives": [{"attributes": {"POSITION": broken}}]}
            ]
        }));
        let err = import_slice(&doc, None).unwrap_err();
        let ImportError::NonFinitePosition { mesh, vertex, .. } = &err else {
            panic!("{bad}: {err:?}");
        };
        assert!(mesh.contains("broken") && *vertex == 2, "{err}");
        assert!(err.to_string().contains("non-finite"), "{err}");
    }
}

/// Finite positions under a finite node transform can still overflow to infinity in world space
/// (1e20 × 1e20). That is the same error as an infinite position, not a pile of triangles
/// counted as "degenerate".
#[test]
fn positions_that_overflow_under_their_transform_are_an_error() {
    let mut g = Gltf::default();
    let pos = g.positions(&[[0.0, 0.0, 0.0], [1e20, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let doc = g.json(json!({
        "nodes": [{"mesh": 0, "scale": [1e20, 1.0, 1.0]}],
        "meshes": [{"name": "huge", "primitives": [{"attributes": {"POSITION": pos}}]}]
    }));
    let err = import_slice(&doc, None).unwrap_err();
    let ImportError::NonFiniteWorldPosition { mesh, vertex, .. } = &err else {
        panic!("{err:?}");
    };
    assert!(mesh.contains("huge") && *vertex == 1, "{err}");
    assert!(err.to_string().contains("overflows"), "{err}");
    eprintln!("overflow: {err}");
}
