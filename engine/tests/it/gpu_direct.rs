//! The GPU direct-light kernel ([`GpuDirect`]) against its CPU twin
//! (`bounce_core::direct::direct_irradiance` on the grid tracer), on real voxelisations of boxes
//! built in code as `core/tests/direct.rs` builds them: a closed box with a point light, a box with
//! a hole in its ceiling under a sun, a spot light, and a finer room with a pillar and every kind
//! of light at once.
//!
//! **Tolerance.** The kernel takes the same sample points (same hash and jitter bits) and sums in
//! the same order, but f32 division, `sqrt` and fused multiply-adds may round differently on a
//! GPU. So a patch agrees to a relative `1e-4` unless one of its shadow rays grazes a voxel edge
//! and its fate flips; a flipped sample moves the patch by that sample's share, at most the
//! patch's unshadowed sample value over `side²`. We accept such patches when they are at most 1%
//! of the patches and each differs by at most `1.5/side²` of its unshadowed value (the margin
//! covers a flipped sample brighter than the patch mean). Measured on lavapipe: no difference at
//! all, every patch bit-identical and no flipped sample, on every scene below (each comparison
//! prints its `Agreement`); a hardware GPU's `sqrt`, division and contractions may differ.
//!
//! These run on whatever adapter wgpu finds (lavapipe in CI); without one they fail unless
//! `BOUNCE_ALLOW_NO_GPU=1` says skipping is intended.

use bounce_core::direct::{DEFAULT_SAMPLES, ShadowScene, direct_irradiance, samples_side};
use bounce_core::formfactor::Tracer;
use bounce_core::light::{Light, LightSet};
use bounce_core::patch::PatchLayout;
use bounce_core::scene::{Scene, Triangle};
use bounce_core::voxel::{Voxelization, voxelize_at};
use bounce_engine::gpu::{GpuContext, GpuDirect, GpuError};
use glam::Vec3;

use crate::common::context;

pub(crate) const SIZE: f32 = 4.0;

/// Two one-sided triangles covering the rectangle `a b c d`, facing `normal`.
pub(crate) fn rect(out: &mut Vec<Triangle>, corners: [Vec3; 4], normal: Vec3) {
    let [a, b, c, d] = corners;
    for mut tri in [[a, b, c], [a, c, d]] {
        if (tri[1] - tri[0]).cross(tri[2] - tri[0]).dot(normal) < 0.0 {
            tri.swap(1, 2);
        }
        out.push(Triangle {
            positions: tri,
            albedo: Vec3::splat(0.5),
            emission: Vec3::ZERO,
            double_sided: false,
            material: 0,
        });
    }
}

pub(crate) fn horizontal(
    out: &mut Vec<Triangle>,
    y: f32,
    [x0, x1]: [f32; 2],
    [z0, z1]: [f32; 2],
    up: bool,
) {
    let n = if up { Vec3::Y } else { Vec3::NEG_Y };
    rect(
        out,
        [
            Vec3::new(x0, y, z0),
            Vec3::new(x1, y, z0),
            Vec3::new(x1, y, z1),
            Vec3::new(x0, y, z1),
        ],
        n,
    );
}

/// The box `[0, SIZE]³` with inward-facing walls, optionally a square hole `[lo, hi]²` in its
/// ceiling, and optionally an outward-facing pillar `[lo, hi]` in x and z from the floor to `top`.
pub(crate) fn room(hole: Option<[f32; 2]>, pillar: Option<([f32; 2], f32)>) -> Scene {
    let s = SIZE;
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) * s;
    let mut t = Vec::new();
    horizontal(&mut t, 0.0, [0.0, s], [0.0, s], true);
    let walls = [
        (
            [c(0., 0., 0.), c(0., 0., 1.), c(0., 1., 1.), c(0., 1., 0.)],
            Vec3::X,
        ),
        (
            [c(1., 0., 0.), c(1., 1., 0.), c(1., 1., 1.), c(1., 0., 1.)],
            Vec3::NEG_X,
        ),
        (
            [c(0., 0., 0.), c(0., 1., 0.), c(1., 1., 0.), c(1., 0., 0.)],
            Vec3::Z,
        ),
        (
            [c(0., 0., 1.), c(1., 0., 1.), c(1., 1., 1.), c(0., 1., 1.)],
            Vec3::NEG_Z,
        ),
    ];
    for (corners, n) in walls {
        rect(&mut t, corners, n);
    }
    match hole {
        None => horizontal(&mut t, s, [0.0, s], [0.0, s], false),
        Some([lo, hi]) => {
            horizontal(&mut t, s, [0.0, lo], [0.0, s], false);
            horizontal(&mut t, s, [hi, s], [0.0, s], false);
            horizontal(&mut t, s, [lo, hi], [0.0, lo], false);
            horizontal(&mut t, s, [lo, hi], [hi, s], false);
        }
    }
    if let Some(([lo, hi], top)) = pillar {
        let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
        rect(
            &mut t,
            [v(lo, 0., lo), v(lo, top, lo), v(lo, top, hi), v(lo, 0., hi)],
            Vec3::NEG_X,
        );
        rect(
            &mut t,
            [v(hi, 0., lo), v(hi, top, lo), v(hi, top, hi), v(hi, 0., hi)],
            Vec3::X,
        );
        rect(
            &mut t,
            [v(lo, 0., lo), v(lo, top, lo), v(hi, top, lo), v(hi, 0., lo)],
            Vec3::NEG_Z,
        );
        rect(
            &mut t,
            [v(lo, 0., hi), v(lo, top, hi), v(hi, top, hi), v(hi, 0., hi)],
            Vec3::Z,
        );
        horizontal(&mut t, top, [lo, hi], [lo, hi], true);
    }
    Scene {
        triangles: t,
        ..Default::default()
    }
}

/// The voxel size of `core/tests/direct.rs`: walls 3/4 of a voxel inside their voxels.
pub(crate) const VOXEL: f32 = SIZE / 10.5;

fn voxelize(scene: &Scene, size: f32) -> Voxelization {
    voxelize_at(scene, size).expect("the room voxelises")
}

fn closed_box() -> Voxelization {
    voxelize(&room(None, None), VOXEL)
}

fn box_with_hole() -> Voxelization {
    let origin = SIZE * 0.5 - 6.0 * VOXEL;
    voxelize(
        &room(Some([origin + 4.0 * VOXEL, origin + 8.0 * VOXEL]), None),
        VOXEL,
    )
}

/// About 2,000 patches: a finer room with a pillar that casts shadows at every angle.
fn room_with_pillar() -> Voxelization {
    voxelize(&room(None, Some(([1.4, 2.2], 2.5))), SIZE / 18.5)
}

pub(crate) fn set(lights: Vec<Light>) -> LightSet {
    let set = LightSet { lights };
    set.validate().expect("test lights are valid");
    set
}

pub(crate) fn point(position: [f32; 3], intensity: f32, range: Option<f32>) -> Light {
    Light::Point {
        position,
        color: [1.0, 0.5, 0.25],
        intensity,
        range,
        name: None,
    }
}

pub(crate) fn spot(position: [f32; 3], direction: [f32; 3]) -> Light {
    Light::Spot {
        position,
        direction,
        color: [0.8, 1.0, 0.9],
        intensity: 40.0,
        range: None,
        inner_cone_angle: 0.3,
        outer_cone_angle: 0.6,
        name: None,
    }
}

pub(crate) fn sun(direction: [f32; 3]) -> Light {
    Light::Directional {
        direction,
        color: [1.0, 0.9, 0.8],
        intensity: 5.0,
        name: None,
    }
}

/// What a comparison found.
#[derive(Debug, Default)]
pub(crate) struct Agreement {
    pub(crate) patches: usize,
    /// Largest relative difference over the patches within `1e-4`.
    pub(crate) worst_rel: f32,
    /// Patches beyond `1e-4` (taken as flipped shadow rays).
    pub(crate) flipped: usize,
    /// Largest difference of a flipped patch, in units of its unshadowed value / samples.
    pub(crate) worst_flip: f32,
}

/// Per patch and channel, GPU against CPU with the tolerance of the module doc; `open` is the
/// unshadowed CPU result (the same lights through an empty grid), `count` the samples per patch.
pub(crate) fn compare(
    gpu: &[[f32; 3]],
    cpu: &[[f32; 3]],
    open: &[[f32; 3]],
    count: u32,
) -> Agreement {
    assert_eq!(gpu.len(), cpu.len());
    let mut a = Agreement {
        patches: cpu.len(),
        ..Agreement::default()
    };
    let floor = cpu.iter().flatten().fold(0.0f32, |m, v| m.max(*v)) * 1e-7;
    let share = 1.0 / count as f32;
    for (i, ((g, c), o)) in gpu.iter().zip(cpu).zip(open).enumerate() {
        let mut flip = false;
        for ch in 0..3 {
            assert!(g[ch].is_finite() && g[ch] >= 0.0, "patch {i}: {g:?}");
            let diff = (g[ch] - c[ch]).abs();
            if diff <= 1e-4 * c[ch] + floor {
                a.worst_rel = a
                    .worst_rel
                    .max(diff / c[ch].max(floor.max(f32::MIN_POSITIVE)));
            } else {
                flip = true;
                let units = diff / (o[ch] * share).max(f32::MIN_POSITIVE);
                assert!(
                    units <= 1.5,
                    "patch {i} channel {ch}: GPU {} vs CPU {}, {units} sample shares off \
                     (unshadowed {})",
                    g[ch],
                    c[ch],
                    o[ch]
                );
                a.worst_flip = a.worst_flip.max(units);
            }
        }
        a.flipped += usize::from(flip);
    }
    assert!(
        a.flipped * 100 <= a.patches,
        "{} of {} patches differ beyond 1e-4",
        a.flipped,
        a.patches
    );
    a
}

/// GPU and CPU direct light for `sets` on `vox`, compared; returns the GPU result.
fn check(
    ctx: &GpuContext,
    name: &str,
    vox: &Voxelization,
    sets: &[LightSet],
    samples: u32,
) -> Vec<Vec<[f32; 3]>> {
    let layout = &vox.layout;
    let shadow = ShadowScene::new(layout, Some(&vox.occupied));
    assert_eq!(shadow.tracer(), Tracer::Grid);
    let empty = ShadowScene::new(layout, Some(&[]));
    let gpu = GpuDirect::upload(ctx, layout, &vox.occupied).unwrap();
    let got = gpu.irradiance(sets, samples).unwrap();
    assert_eq!(got.len(), sets.len());
    for (k, s) in sets.iter().enumerate() {
        let want = direct_irradiance(&shadow, layout, s, samples);
        let open = direct_irradiance(&empty, layout, s, samples);
        let a = compare(&got[k], &want, &open, samples_side(samples).pow(2));
        eprintln!("{name} set {k} ({samples} samples): {a:?}");
        assert!(
            want.iter().flatten().any(|v| *v > 0.0),
            "{name}: the lights reach patches"
        );
    }
    got
}

#[test]
fn point_light_in_a_closed_box_matches_the_cpu() {
    let Some(ctx) = context() else { return };
    let vox = closed_box();
    let sets = [
        set(vec![point([2.1, 2.6, 1.9], 10.0, None)]),
        set(vec![point([2.1, 2.6, 1.9], 10.0, Some(3.0))]),
    ];
    for samples in [DEFAULT_SAMPLES, 64] {
        check(ctx, "closed box", &vox, &sets, samples);
    }
}

/// A lamp just under the ceiling, inside the voxel the ceiling made occupied and on grid planes
/// in x and z: the GPU must stop its shadow rays short of the lamp's voxel as the CPU does
/// (`shadow_length`), or the room would go dark on one engine only.
#[test]
fn a_lamp_in_an_occupied_voxel_matches_the_cpu() {
    let Some(ctx) = context() else { return };
    let vox = closed_box();
    let sets = [set(vec![point([2.0, SIZE - 0.05, 2.0], 10.0, None)])];
    let got = check(ctx, "lamp under the ceiling", &vox, &sets, DEFAULT_SAMPLES);
    let lit = got[0].iter().filter(|v| v[0] > 0.0).count();
    assert!(
        lit * 2 > vox.layout.len(),
        "only {lit} of {} patches lit",
        vox.layout.len()
    );
}

#[test]
fn sun_through_a_hole_matches_the_cpu() {
    let Some(ctx) = context() else { return };
    let vox = box_with_hole();
    let sets: Vec<LightSet> = [[0.0, -1.0, 0.0], [0.2, -1.0, 0.15], [-0.2, -1.0, 0.1]]
        .into_iter()
        .map(|d| set(vec![sun(d)]))
        .collect();
    let got = check(ctx, "hole", &vox, &sets, DEFAULT_SAMPLES);
    // Only the footprint on the floor is lit.
    assert!(got[0].iter().filter(|e| e[0] > 0.0).count() >= 16);
}

#[test]
fn spot_light_matches_the_cpu() {
    let Some(ctx) = context() else { return };
    let vox = closed_box();
    let sets = [
        set(vec![spot([2.05, 3.0, 1.95], [0.0, -1.0, 0.0])]),
        set(vec![spot([1.0, 3.0, 1.0], [0.5, -1.0, 0.3])]),
    ];
    check(ctx, "spot", &vox, &sets, DEFAULT_SAMPLES);
}

/// Every kind at once, shadows cast by a pillar at every angle: the case where grazing rays flip.
pub(crate) fn pillar_sets() -> Vec<LightSet> {
    vec![
        set(vec![
            point([0.7, 3.0, 0.8], 12.0, None),
            spot([3.2, 3.5, 3.1], [-0.6, -1.0, -0.5]),
        ]),
        set(vec![point([3.1, 1.2, 2.9], 8.0, Some(5.0))]),
        set(vec![
            spot([0.5, 3.6, 3.5], [0.4, -1.0, -0.4]),
            point([2.0, 3.5, 0.5], 6.0, None),
            point([3.5, 0.5, 3.5], 3.0, None),
        ]),
    ]
}

#[test]
fn pillar_room_with_several_lights_matches_the_cpu() {
    let Some(ctx) = context() else { return };
    let vox = room_with_pillar();
    eprintln!("pillar room: {} patches", vox.layout.len());
    check(ctx, "pillar", &vox, &pillar_sets(), DEFAULT_SAMPLES);
}

#[test]
fn a_batch_equals_one_set_at_a_time() {
    let Some(ctx) = context() else { return };
    let vox = room_with_pillar();
    let gpu = GpuDirect::upload(ctx, &vox.layout, &vox.occupied).unwrap();
    let mut sets = pillar_sets();
    // A set with nothing that lights, between lit ones.
    sets.insert(1, LightSet { lights: vec![] });
    let batch = gpu.irradiance(&sets, DEFAULT_SAMPLES).unwrap();
    for (k, s) in sets.iter().enumerate() {
        let one = gpu
            .irradiance(std::slice::from_ref(s), DEFAULT_SAMPLES)
            .unwrap();
        assert_eq!(one.len(), 1);
        // Each (patch, set) is one thread's fixed-order sum: the same bits in any batch.
        assert_eq!(one[0], batch[k], "set {k}");
    }
    assert!(batch[1].iter().all(|e| *e == [0.0; 3]));
}

#[test]
fn no_sets_no_lights_no_patches_and_a_single_patch() {
    let Some(ctx) = context() else { return };
    let vox = closed_box();
    let gpu = GpuDirect::upload(ctx, &vox.layout, &vox.occupied).unwrap();
    assert!(gpu.irradiance(&[], DEFAULT_SAMPLES).unwrap().is_empty());
    let dark = gpu
        .irradiance(&[LightSet { lights: vec![] }], DEFAULT_SAMPLES)
        .unwrap();
    assert_eq!(dark, vec![vec![[0.0; 3]; vox.layout.len()]]);

    // No patches: one empty result per set.
    let empty = PatchLayout {
        patches: Vec::new(),
        ..vox.layout.clone()
    };
    let none = GpuDirect::upload(ctx, &empty, &vox.occupied).unwrap();
    let lit = [set(vec![point([2.1, 2.6, 1.9], 10.0, None)])];
    assert_eq!(
        none.irradiance(&lit, 16).unwrap(),
        vec![Vec::<[f32; 3]>::new()]
    );

    // One patch (the middle of the floor), one light, one sample and 16 samples.
    let floor = vox
        .layout
        .patches
        .iter()
        .position(|p| p.face == bounce_core::patch::Face::PosY && p.voxel == [5, 0, 5])
        .expect("a floor patch");
    let single = PatchLayout {
        patches: vec![vox.layout.patches[floor]],
        ..vox.layout.clone()
    };
    let one = GpuDirect::upload(ctx, &single, &vox.occupied).unwrap();
    let shadow = ShadowScene::new(&single, Some(&vox.occupied));
    let empty_grid = ShadowScene::new(&single, Some(&[]));
    for samples in [1, 16] {
        let got = one.irradiance(&lit, samples).unwrap();
        let want = direct_irradiance(&shadow, &single, &lit[0], samples);
        let open = direct_irradiance(&empty_grid, &single, &lit[0], samples);
        assert!(want[0][0] > 0.0);
        let a = compare(&got[0], &want, &open, samples_side(samples).pow(2));
        assert_eq!(a.flipped, 0, "{a:?}");
    }
}

#[test]
fn a_grid_past_u32_indices_is_refused() {
    let Some(ctx) = context() else { return };
    let layout = PatchLayout {
        origin: [0.0; 3],
        voxel_size: 1.0,
        dims: [1 << 16, 1 << 16, 2],
        patches: Vec::new(),
    };
    match GpuDirect::upload(ctx, &layout, &[]) {
        Err(e @ GpuError::TooLarge { .. }) => {
            assert!(e.to_string().contains("voxel grid"), "{e}");
        }
        Err(e) => panic!("expected TooLarge, got {e}"),
        Ok(_) => panic!("a 2^33-cell grid was accepted"),
    }
}
