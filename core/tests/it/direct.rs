//! Direct irradiance on real voxelisations of boxes built in code: the glTF point, spot and
//! directional formulas per sample, shadows through the voxel grid (a sun through a hole in a
//! ceiling), and bit-identical results whatever the thread count.

use bounce_core::direct::{
    DEFAULT_SAMPLES, ShadowScene, ShadowSource, direct_irradiance, exitance_b0, sample_uv,
    samples_side,
};
use bounce_core::formfactor::Tracer;
use bounce_core::light::{Light, LightSet};
use bounce_core::patch::{Face, PatchLayout, Quad};
use bounce_core::scene::{Scene, Triangle};
use bounce_core::voxel::{Voxelization, voxelize_at};
use glam::Vec3;

/// Box edge, and a voxel size that leaves the walls 3/4 of a voxel inside their voxels (off the
/// grid planes) and puts grid planes at `ORIGIN + k · VOXEL`.
const SIZE: f32 = 4.0;
const VOXEL: f32 = SIZE / 10.5;
/// The grid's minimum corner on every axis: 12 voxels centred on the box.
const ORIGIN: f32 = SIZE * 0.5 - 6.0 * VOXEL;

fn plane(k: u32) -> f32 {
    ORIGIN + k as f32 * VOXEL
}

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

/// A horizontal rectangle `[x0, x1] × [z0, z1]` at height `y`.
fn horizontal(out: &mut Vec<Triangle>, y: f32, [x0, x1]: [f32; 2], [z0, z1]: [f32; 2], up: bool) {
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

/// The box `[0, SIZE]³` with inward-facing walls, and optionally a square hole
/// `[lo, hi] × [lo, hi]` in its ceiling.
fn closed_box(hole: Option<[f32; 2]>) -> Scene {
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
    Scene {
        triangles: t,
        ..Default::default()
    }
}

fn voxelize(scene: &Scene) -> Voxelization {
    let vox = voxelize_at(scene, VOXEL).expect("the box voxelises");
    let o = vox.layout.origin;
    assert!(
        o.iter().all(|&v| (v - ORIGIN).abs() < 1e-5),
        "grid origin {o:?}, expected {ORIGIN} on every axis"
    );
    assert_eq!(vox.layout.dims, [12; 3]);
    vox
}

fn lights(lights: Vec<Light>) -> LightSet {
    let set = LightSet { lights };
    set.validate().expect("test lights are valid");
    set
}

/// The unshadowed point-light irradiance at `p` on a surface facing `n`, straight from glTF.
fn point_formula(pos: Vec3, intensity: f32, range: Option<f32>, p: Vec3, n: Vec3) -> f32 {
    let to = pos - p;
    let d = to.length();
    let cos = n.dot(to / d).max(0.0);
    let window = range.map_or(1.0, |r| (1.0 - (d / r).powi(4)).clamp(0.0, 1.0).powi(2));
    intensity * cos / (d * d) * window
}

/// The mean of `f` over the sample points `direct` uses on patch `i`.
fn over_samples(layout: &PatchLayout, i: usize, samples: u32, f: impl Fn(Vec3) -> f32) -> f32 {
    let q = layout.quad(i);
    let side = samples_side(samples);
    let sum: f32 = (0..side * side)
        .map(|k| {
            let [u, v] = sample_uv(i as u32, k, side);
            f(q.point(u, v))
        })
        .sum();
    sum / (side * side) as f32
}

/// The mean of `f` over the patch by a fine midpoint rule: the integral the samples estimate.
fn over_patch(q: &Quad, f: impl Fn(Vec3) -> f32) -> f64 {
    let m = 48;
    let mut sum = 0.0f64;
    for a in 0..m {
        for b in 0..m {
            let p = q.point((a as f32 + 0.5) / m as f32, (b as f32 + 0.5) / m as f32);
            sum += f64::from(f(p));
        }
    }
    sum / (m * m) as f64
}

#[test]
fn point_light_in_a_closed_box_matches_the_inverse_square_law() {
    let vox = voxelize(&closed_box(None));
    let layout = &vox.layout;
    let scene = ShadowScene::new(layout, Some(&vox.occupied));
    assert_eq!(scene.source(), ShadowSource::Occupancy);
    assert_eq!(scene.tracer(), Tracer::Grid);
    // Inside the room, in an empty voxel; every wall beyond it must not shadow the segment.
    let pos = Vec3::new(2.1, 2.6, 1.9);
    let color = [1.0, 0.5, 0.25];
    for range in [None, Some(3.0)] {
        let set = lights(vec![Light::Point {
            position: pos.to_array(),
            color,
            intensity: 10.0,
            range,
            name: None,
        }]);
        for samples in [DEFAULT_SAMPLES, 64] {
            let e = direct_irradiance(&scene, layout, &set, samples);
            let mut lit = 0;
            let mut zero = 0;
            let mut worst = 0.0f64;
            for (i, p) in layout.patches.iter().enumerate() {
                let n = p.face.normal();
                let f = |x: Vec3| point_formula(pos, 10.0, range, x, n);
                // A convex room: nothing shadows, so `E` is the formula at the same points...
                let want = over_samples(layout, i, samples, f);
                for c in 0..3 {
                    let w = want * color[c];
                    assert!(
                        (e[i][c] - w).abs() <= 1e-5 * w + 1e-7,
                        "patch {i} channel {c}: {} vs {w} (range {range:?})",
                        e[i][c]
                    );
                }
                if want == 0.0 {
                    assert_eq!(e[i], [0.0; 3], "patch {i}");
                    zero += 1;
                    continue;
                }
                lit += 1;
                if range.is_some() {
                    // Near the window's edge the relative error of any estimate is large.
                    continue;
                }
                // ...and estimates the formula's patch mean as well as stratified sampling
                // does.
                let exact = over_patch(&layout.quad(i), f);
                let err = (f64::from(e[i][0]) - exact).abs() / exact;
                worst = worst.max(err);
            }
            let tolerance = if samples == 64 { 0.01 } else { 0.03 };
            assert!(
                worst < tolerance,
                "worst relative error against the patch mean {worst} ({samples} samples, \
                 range {range:?})"
            );
            assert!(lit > 300, "{lit} lit patches");
            if range.is_some() {
                assert!(zero > 30, "the range window zeroes far patches: {zero}");
            } else {
                assert_eq!(zero, 0, "every wall faces a light inside the room");
            }
        }
    }
}

#[test]
fn spot_is_dark_outside_its_outer_cone_and_full_inside_its_inner_cone() {
    let vox = voxelize(&closed_box(None));
    let layout = &vox.layout;
    let scene = ShadowScene::new(layout, Some(&vox.occupied));
    let pos = Vec3::new(2.05, 3.0, 1.95);
    let (inner, outer) = (0.3f32, 0.5f32);
    let spot = lights(vec![Light::Spot {
        position: pos.to_array(),
        direction: [0.0, -1.0, 0.0],
        color: [1.0; 3],
        intensity: 40.0,
        range: None,
        inner_cone_angle: inner,
        outer_cone_angle: outer,
        name: None,
    }]);
    let point = lights(vec![Light::Point {
        position: pos.to_array(),
        color: [1.0; 3],
        intensity: 40.0,
        range: None,
        name: None,
    }]);
    let es = direct_irradiance(&scene, layout, &spot, DEFAULT_SAMPLES);
    let ep = direct_irradiance(&scene, layout, &point, DEFAULT_SAMPLES);
    let angle = |x: Vec3| {
        (x - pos)
            .normalize()
            .dot(Vec3::NEG_Y)
            .clamp(-1.0, 1.0)
            .acos()
    };
    let (mut inside, mut outside, mut between) = (0, 0, 0);
    for i in 0..layout.len() {
        // The angle's range over the patch, on a grid fine enough that the margins below cover
        // what falls between its points.
        let q = layout.quad(i);
        let m = 24;
        let angles: Vec<f32> = (0..=m * m + m)
            .map(|k| {
                angle(q.point(
                    (k % (m + 1)) as f32 / m as f32,
                    (k / (m + 1)) as f32 / m as f32,
                ))
            })
            .collect();
        let max_angle = angles.iter().copied().fold(0.0, f32::max);
        let min_angle = angles.iter().copied().fold(9.0, f32::min);
        if max_angle < inner - 0.01 {
            assert_eq!(
                es[i], ep[i],
                "patch {i} inside the inner cone gets the full point light"
            );
            assert!(es[i][0] > 0.0);
            inside += 1;
        } else if min_angle > outer + 0.01 {
            assert_eq!(es[i], [0.0; 3], "patch {i} outside the outer cone");
            outside += 1;
        } else {
            assert!(es[i][0] <= ep[i][0], "patch {i}: the cone only attenuates");
            between += 1;
        }
    }
    assert!(
        inside >= 4 && outside > 100 && between > 10,
        "{inside} {outside} {between}"
    );
}

/// The box with a square hole of 4 × 4 voxels in the middle of its ceiling.
fn box_with_hole() -> (Voxelization, [f32; 2]) {
    let hole = [plane(4), plane(8)];
    let vox = voxelize(&closed_box(Some(hole)));
    (vox, hole)
}

/// Overlap length of `[a0, a1]` and `[b0, b1]`.
fn overlap(a: [f32; 2], b: [f32; 2]) -> f32 {
    (a[1].min(b[1]) - a[0].max(b[0])).max(0.0)
}

#[test]
fn sun_through_a_hole_lights_only_the_footprint() {
    let (vox, hole) = box_with_hole();
    let layout = &vox.layout;
    for (direction, tracer) in [
        ([0.0, -1.0, 0.0], Tracer::Grid),
        // Slants small enough that no wall patch sees the sky through the hole.
        ([0.2, -1.0, 0.15], Tracer::Grid),
        ([0.2, -1.0, 0.15], Tracer::Bvh),
        ([-0.2, -1.0, 0.1], Tracer::Grid),
    ] {
        let scene = ShadowScene::with_tracer(layout, Some(&vox.occupied), tracer);
        assert_eq!(scene.tracer(), tracer);
        let set = lights(vec![Light::Directional {
            direction,
            color: [1.0, 0.9, 0.8],
            intensity: 5.0,
            name: None,
        }]);
        let e = direct_irradiance(&scene, layout, &set, DEFAULT_SAMPLES);
        let to_light = -Vec3::from(direction).normalize();
        let full = 5.0 * to_light.y;
        // The ceiling's voxel layer is the grid's top one; a ray from the floor gets out iff it
        // is inside the hole's columns where it enters that layer and where it leaves it. The
        // lit part of the floor is the intersection of the two shifted hole squares.
        let (y0, y1) = (plane(11), plane(12));
        let mut lit_area = 0.0f64;
        let mut sum = 0.0f64;
        let mut fractional = 0;
        for (i, p) in layout.patches.iter().enumerate() {
            if p.face != Face::PosY || p.voxel[1] != 0 {
                assert_eq!(e[i], [0.0; 3], "patch {i} is not floor and sees no sun");
                continue;
            }
            let q = layout.quad(i);
            let shift = |y: f32, axis: usize| to_light[axis] / to_light.y * (y - q.plane);
            let lit = |axis: usize| {
                let a = [hole[0] - shift(y0, axis), hole[1] - shift(y0, axis)];
                let b = [hole[0] - shift(y1, axis), hole[1] - shift(y1, axis)];
                [a[0].max(b[0]), a[1].min(b[1])]
            };
            // Quad bounds are in the order z, x for a Y face.
            let fz = overlap([q.lo[0], q.hi[0]], lit(2)) / VOXEL;
            let fx = overlap([q.lo[1], q.hi[1]], lit(0)) / VOXEL;
            let f = fx * fz;
            let got = e[i][0] / full;
            if f > 1.0 - 1e-4 {
                assert!(
                    (got - 1.0).abs() < 1e-5,
                    "patch {i} fully in the sun: {got}"
                );
                assert!((e[i][1] / e[i][0] - 0.9).abs() < 1e-6, "colour");
            } else if f < 1e-4 {
                assert_eq!(e[i], [0.0; 3], "patch {i} fully in the shade");
            } else {
                // 4 × 4 stratified samples: a straight edge through the patch is off by at
                // most a row of cells.
                assert!(
                    (got - f).abs() <= 0.25 + 1e-4,
                    "patch {i}: {got} lit, {f} expected"
                );
                if got > 0.0 && got < 1.0 {
                    fractional += 1;
                }
            }
            lit_area += f64::from(f);
            sum += f64::from(got);
        }
        assert!(lit_area > 4.0, "the footprint covers patches: {lit_area}");
        assert!(
            (sum - lit_area).abs() < 0.05 * lit_area,
            "total sun {sum} vs footprint {lit_area} ({direction:?}, {tracer})"
        );
        if direction[0] == 0.0 {
            assert_eq!(fractional, 0, "a vertical sun casts voxel-aligned edges");
        } else {
            assert!(fractional >= 4, "slanted edges are soft: {fractional}");
        }
    }
}

#[test]
fn without_occupancy_the_patches_alone_cast_shadows() {
    let (vox, _) = box_with_hole();
    let layout = &vox.layout;
    let scene = ShadowScene::new(layout, None);
    assert_eq!(scene.source(), ShadowSource::PatchesOnly);
    assert_eq!(scene.tracer(), Tracer::Bvh);
    let set = lights(vec![Light::Directional {
        direction: [0.0, -1.0, 0.0],
        color: [1.0; 3],
        intensity: 2.0,
        name: None,
    }]);
    let e = direct_irradiance(&scene, layout, &set, DEFAULT_SAMPLES);
    let full = ShadowScene::new(layout, Some(&vox.occupied));
    let want = direct_irradiance(&full, layout, &set, DEFAULT_SAMPLES);
    // Straight down, the ceiling patches block exactly what the ceiling voxels do.
    assert_eq!(e, want);
    assert!(e.iter().any(|v| v[0] == 2.0));
}

#[test]
fn same_bits_on_one_and_two_threads() {
    let (vox, _) = box_with_hole();
    let layout = &vox.layout;
    let scene = ShadowScene::new(layout, Some(&vox.occupied));
    let set = lights(vec![
        Light::Directional {
            direction: [0.3, -1.0, 0.2],
            color: [1.0, 0.95, 0.9],
            intensity: 3.0,
            name: None,
        },
        Light::Point {
            position: [1.0, 1.5, 2.5],
            color: [1.0; 3],
            intensity: 10.0,
            range: Some(3.5),
            name: None,
        },
        Light::Spot {
            position: [2.0, 3.5, 2.0],
            direction: [0.2, -1.0, 0.0],
            color: [0.5, 1.0, 1.0],
            intensity: 50.0,
            range: None,
            inner_cone_angle: 0.3,
            outer_cone_angle: 0.6,
            name: None,
        },
    ]);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| direct_irradiance(&scene, layout, &set, 25))
    };
    let one = run(1);
    let two = run(2);
    let bits = |v: &[[f32; 3]]| -> Vec<u32> { v.iter().flatten().map(|x| x.to_bits()).collect() };
    assert_eq!(bits(&one), bits(&two));
    assert_eq!(bits(&one), bits(&run(3)));
    assert!(one.iter().filter(|v| v[0] > 0.0).count() > 100);
}

#[test]
fn b0_is_emission_plus_albedo_times_direct() {
    let (vox, _) = box_with_hole();
    let mut layout = vox.layout.clone();
    layout.patches[3].emission = [1.0, 2.0, 3.0];
    layout.patches[3].albedo = [0.5, 0.25, 0.0];
    let e: Vec<[f32; 3]> = (0..layout.len()).map(|i| [i as f32, 1.0, 2.0]).collect();
    let b0 = exitance_b0(&layout, &e);
    assert_eq!(b0[3], [1.0 + 0.5 * 3.0, 2.0 + 0.25, 3.0]);
    assert_eq!(b0[7], [0.5 * 7.0, 0.5, 1.0]);
}

#[test]
fn no_lights_no_light() {
    let (vox, _) = box_with_hole();
    let scene = ShadowScene::new(&vox.layout, Some(&vox.occupied));
    let e = direct_irradiance(&scene, &vox.layout, &LightSet::default(), 4);
    assert!(e.iter().all(|v| *v == [0.0; 3]));
}

/// A lamp hung just under the ceiling sits in the voxel the ceiling made occupied; it must still
/// light the room (the light's own voxel does not block its shadow rays).
#[test]
fn a_light_in_an_occupied_voxel_still_lights_the_room() {
    let vox = voxelize(&closed_box(None));
    let layout = &vox.layout;
    let scene = ShadowScene::new(layout, Some(&vox.occupied));
    // On grid planes in x and z (a light's voxel is then ambiguous), just under the ceiling.
    let pos = Vec3::new(2.0, SIZE - 0.05, 2.0);
    let cell = ((pos - Vec3::splat(ORIGIN)) / VOXEL).floor();
    let index = cell.x as u64 + 12 * (cell.y as u64 + 12 * cell.z as u64);
    assert!(
        vox.occupied.binary_search(&index).is_ok(),
        "the lamp's voxel is occupied"
    );
    let set = lights(vec![Light::Point {
        position: pos.to_array(),
        color: [1.0; 3],
        intensity: 10.0,
        range: None,
        name: None,
    }]);
    let e = direct_irradiance(&scene, layout, &set, 64);
    let floor: Vec<usize> = (0..layout.len())
        .filter(|&i| layout.patches[i].face == Face::PosY && layout.patches[i].centroid[1] < 0.5)
        .collect();
    assert!(!floor.is_empty());
    for &i in &floor {
        let n = layout.patches[i].face.normal();
        let want = over_samples(layout, i, 64, |x| point_formula(pos, 10.0, None, x, n));
        let got = f64::from(e[i][0]);
        assert!(
            (got - f64::from(want)).abs() <= 1e-4 * f64::from(want),
            "floor patch {i}: {got} against the unshadowed {want}"
        );
    }
}
