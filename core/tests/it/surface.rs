//! Surface patches (docs/design.md §2): clusters of real surface, form factors between them
//! against Howell's catalogue and the white furnace, sidedness, and walls thinner than a voxel
//! that must not let light or form factors through.

use std::sync::Arc;

use bounce_core::direct::{ShadowScene, direct_irradiance};
use bounce_core::formfactor::{RowTracer, form_factors, hidden_patches, isolated_patches, stats};
use bounce_core::light::{Light, LightSet};
use bounce_core::patch::Face;
use bounce_core::scene::{Scene, Triangle};
use bounce_core::surface::{
    SurfaceData, SurfaceScene, occluder_triangles_of, sample_points, scene_mesh,
};
use bounce_core::voxel::{Geometry, Voxelization, cluster_at, dominant_face};
use glam::Vec3;

use crate::furnace::closed_box;

fn no_progress(_: u64) {}

/// Two triangles covering the rectangle `a b c d`, wound to face `normal`.
fn rect(out: &mut Vec<Triangle>, corners: [Vec3; 4], normal: Vec3, double_sided: bool) {
    let start = out.len();
    crate::direct::rect(out, corners, normal);
    for t in &mut out[start..] {
        t.double_sided = double_sided;
    }
}

fn scene(triangles: Vec<Triangle>) -> Scene {
    Scene {
        triangles,
        ..Default::default()
    }
}

fn surface_scene(scene: &Scene, vox: &Voxelization) -> SurfaceScene {
    let pieces = vox.pieces.as_ref().expect("surface clusters have pieces");
    SurfaceScene::new(
        scene,
        Arc::new(scene_mesh(scene)),
        vox.transport_layout(),
        pieces,
    )
}

#[test]
fn every_piece_of_surface_belongs_to_exactly_one_patch() {
    // A closed box, and a tilted double-sided plate inside it.
    let mut box_ = closed_box(2.0, 0.5);
    let v = Vec3::new;
    rect(
        &mut box_.triangles,
        [
            v(0.5, 0.4, 0.5),
            v(1.4, 1.3, 0.5),
            v(1.4, 1.3, 1.5),
            v(0.5, 0.4, 1.5),
        ],
        v(1.0, -1.0, 0.0),
        true,
    );
    let sided: f64 = box_
        .triangles
        .iter()
        .map(|t| t.area() as f64 * if t.double_sided { 2.0 } else { 1.0 })
        .sum();
    for size in [0.13f32, 0.25, 0.6] {
        let vox = cluster_at(&box_, size).unwrap();
        let pieces = vox.pieces.as_ref().unwrap();
        assert_eq!(pieces.patch_count(), vox.transport_layout().len());
        let assigned: f64 = vox
            .layout
            .patches
            .iter()
            .map(|p| p.source_area as f64)
            .sum();
        assert!(
            ((assigned + vox.unassigned_area) / sided - 1.0).abs() < 1e-5,
            "size {size}: {assigned} + {} of {sided}",
            vox.unassigned_area
        );
        assert!(vox.unassigned_area < sided * 1e-5);
        assert!((vox.total_area / sided - 1.0).abs() < 1e-6);
        for (i, p) in vox.layout.patches.iter().enumerate() {
            let mine = pieces.of(i);
            assert!(!mine.is_empty());
            let area: f64 = mine.iter().map(|t| t.area as f64).sum();
            assert!((area / p.source_area as f64 - 1.0).abs() < 1e-4);
            for t in mine {
                // Each piece faces the patch's direction most, and lies in the patch's voxel.
                assert_eq!(dominant_face(t.normal), p.face);
                let lo =
                    Vec3::from(vox.layout.origin) + Vec3::from(p.voxel.map(|c| c as f32)) * size;
                for c in t.corners {
                    let inside = (c - lo).cmpge(Vec3::splat(-1e-4)).all()
                        && (c - lo - Vec3::splat(size)).cmple(Vec3::splat(1e-4)).all();
                    assert!(inside, "corner {c} outside voxel at {lo}");
                }
            }
        }
        // The plate's two sides are patches of their own: its front faces +X or −Y, its back −X
        // or +Y (45°: the tie goes to X).
        let sides = |face: Face| {
            vox.layout
                .patches
                .iter()
                .filter(|p| p.face == face && p.voxel[0] > 0 && p.normal[1].abs() > 0.5)
                .count()
        };
        assert!(
            sides(Face::PosX) > 0 && sides(Face::NegX) > 0,
            "size {size}"
        );
    }
}

/// The floor and ceiling of a box with a wall down its middle that is far thinner than a voxel:
/// two single-sided faces back to back, 0.02 apart, with voxels of 0.3.
fn two_rooms() -> Scene {
    let mut tris = closed_box(3.0, 0.5).triangles;
    let v = Vec3::new;
    for (x, n) in [(1.49f32, Vec3::NEG_X), (1.51, Vec3::X)] {
        rect(
            &mut tris,
            [
                v(x, 0.0, 0.0),
                v(x, 3.0, 0.0),
                v(x, 3.0, 3.0),
                v(x, 0.0, 3.0),
            ],
            n,
            false,
        );
    }
    scene(tris)
}

#[test]
fn a_wall_thinner_than_a_voxel_keeps_both_sides_and_lets_nothing_through() {
    let scene = two_rooms();
    let vox = cluster_at(&scene, 0.3).unwrap();
    // Both faces of the wall are patches, though they share voxels.
    let wall = |face: Face| {
        vox.layout
            .patches
            .iter()
            .filter(|p| p.face == face && (p.centroid[0] - 1.5).abs() < 0.1)
            .count()
    };
    assert!(wall(Face::PosX) >= 90 && wall(Face::NegX) >= 90);
    let rays = surface_scene(&scene, &vox);
    let (f, tally) = form_factors(&rays, 256, 3, &no_progress).unwrap();
    // Closed rooms: nothing escapes, and almost nothing meets unowned surface: the strips of
    // floor and ceiling inside the wall (between its two faces) are inside a closed solid and no
    // patch's, and only a ray slipping through the seam at the wall's foot reaches them (1 of
    // 307,200).
    assert_eq!(tally.escaped, 0, "{tally:?}");
    assert!(tally.occluder * 10_000 < tally.total(), "{tally:?}");
    assert!(tally.back_face * 100 < tally.total(), "{tally:?}");
    // Which room each element's pieces lie in; the strips of floor and ceiling inside the wall
    // lie in neither and are left out of the checks.
    let pieces = vox.pieces.as_ref().unwrap();
    let room = |i: usize| {
        let xs = pieces.of(i).iter().flat_map(|t| t.corners.map(|c| c.x));
        let (lo, hi) = xs.fold((f32::MAX, f32::MIN), |(l, h), x| (l.min(x), h.max(x)));
        if hi <= 1.49 + 1e-4 {
            Some(true)
        } else if lo >= 1.51 - 1e-4 {
            Some(false)
        } else {
            None
        }
    };
    let n = vox.transport_layout().len();
    // No element holds surface of both rooms: the two sides of the floor in a voxel the wall
    // runs through face two spaces, so they are two elements (the strips inside the wall, which
    // face neither room, may be a third).
    let both = |i: usize| {
        let xs = pieces.of(i).iter().flat_map(|t| t.corners.map(|c| c.x));
        let (lo, hi) = xs.fold((f32::MAX, f32::MIN), |(l, h), x| (l.min(x), h.max(x)));
        lo < 1.49 - 1e-4 && hi > 1.51 + 1e-4
    };
    let mixed = (0..n).filter(|&i| both(i)).count();
    assert_eq!(
        mixed, 0,
        "{mixed} of {n} elements hold surface of both rooms"
    );
    let straddling = (0..n).filter(|&i| room(i).is_none()).count();
    assert!(
        straddling <= n / 8,
        "{straddling} of {n} patches straddle the wall"
    );
    let mut across = 0.0f64;
    for i in 0..n {
        for j in 0..n {
            if let (Some(a), Some(b)) = (room(i), room(j))
                && a != b
            {
                across += f.channel(0)[i * n + j] as f64;
            }
        }
    }
    assert_eq!(across, 0.0, "form factors cross the wall");
    let left = |i: usize| room(i) == Some(true);
    // A point light in the left room lights nothing in the right one.
    let data = SurfaceData {
        triangles: occluder_triangles_of(&scene_mesh(&scene)),
        per_patch: 16,
        area_samples: 16,
        points: sample_points(vox.pieces.as_ref().unwrap(), 16, 1),
        albedo: None,
    };
    let light = LightSet {
        lights: vec![Light::Point {
            position: [0.75, 1.5, 1.5],
            color: [1.0; 3],
            intensity: 10.0,
            range: None,
            name: None,
        }],
    };
    let e = direct_irradiance(
        &ShadowScene::surface(&data),
        vox.transport_layout(),
        &light,
        16,
    );
    for (i, e) in e.iter().enumerate() {
        if left(i) {
            assert!(e[0] > 0.0, "left patch {i} unlit");
        } else if room(i) == Some(false) {
            assert_eq!(e[0], 0.0, "right patch {i} lit through the wall");
        }
    }
}

#[test]
fn closed_box_rows_sum_to_one_and_are_reciprocal() {
    let scene = closed_box(1.0, 0.5);
    let vox = cluster_at(&scene, 0.26).unwrap();
    let rays = surface_scene(&scene, &vox);
    assert_eq!(rays.patch_count(), vox.layout.len());
    let (f, tally) = form_factors(&rays, 4096, 5, &no_progress).unwrap();
    // Möller–Trumbore is not watertight: a ray through a shared edge or corner of two
    // triangles may slip between them (measured: 1 of 743,424 here).
    assert!(tally.patch * 100_000 >= tally.total() * 99_999, "{tally:?}");
    let st = stats(&f, &vox.layout.areas(Geometry::Surface));
    assert!(
        st.row_sum_min > 0.999999 && st.row_sum_max < 1.000001,
        "{st:?}"
    );
    // About 40 hits an entry: reciprocity holds to the noise of that.
    assert!(st.reciprocity_error < 0.1, "{st:?}");
    assert!(isolated_patches(&rays, 16, 1).iter().all(|&x| !x));
}

/// `F` from the patches of one surface to those of another, area-weighted: what the catalogue
/// gives for the two surfaces whole.
fn surface_to_surface(scene: &Scene, size: f32, rays: u32, from: Face, to: Face) -> f64 {
    let vox = cluster_at(scene, size).unwrap();
    let tracer = surface_scene(scene, &vox);
    let (f, _) = form_factors(&tracer, rays, 9, &no_progress).unwrap();
    let n = vox.layout.len();
    let p = &vox.layout.patches;
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for i in (0..n).filter(|&i| p[i].face == from) {
        let a = p[i].source_area as f64;
        den += a;
        for j in (0..n).filter(|&j| p[j].face == to) {
            num += a * f.channel(0)[i * n + j] as f64;
        }
    }
    num / den
}

#[test]
fn catalogue_form_factors_between_real_surfaces() {
    let v = Vec3::new;
    // Parallel unit squares one apart; the 1 × 1.5 rectangles 0.5 apart; perpendicular squares
    // sharing an edge. Voxel sizes that cut them at odd places.
    let mut parallel = Vec::new();
    rect(
        &mut parallel,
        [v(0., 0., 0.), v(1., 0., 0.), v(1., 0., 1.), v(0., 0., 1.)],
        Vec3::Y,
        false,
    );
    rect(
        &mut parallel,
        [v(0., 1., 0.), v(1., 1., 0.), v(1., 1., 1.), v(0., 1., 1.)],
        Vec3::NEG_Y,
        false,
    );
    let mut rects = Vec::new();
    rect(
        &mut rects,
        [v(0., 0., 0.), v(1., 0., 0.), v(1., 0., 1.5), v(0., 0., 1.5)],
        Vec3::Y,
        false,
    );
    rect(
        &mut rects,
        [
            v(0., 0.5, 0.),
            v(1., 0.5, 0.),
            v(1., 0.5, 1.5),
            v(0., 0.5, 1.5),
        ],
        Vec3::NEG_Y,
        false,
    );
    let mut perpendicular = Vec::new();
    rect(
        &mut perpendicular,
        [v(0., 0., 0.), v(1., 0., 0.), v(1., 0., 1.), v(0., 0., 1.)],
        Vec3::Y,
        false,
    );
    rect(
        &mut perpendicular,
        [v(0., 0., 0.), v(0., 1., 0.), v(0., 1., 1.), v(0., 0., 1.)],
        Vec3::X,
        false,
    );
    let cases = [
        ("parallel unit squares", scene(parallel), Face::NegY, 0.1998),
        (
            "1 × 1.5 rectangles 0.5 apart",
            scene(rects),
            Face::NegY,
            0.4756,
        ),
        (
            "perpendicular unit squares",
            scene(perpendicular),
            Face::PosX,
            0.2000,
        ),
    ];
    for (name, s, to, want) in cases {
        for size in [0.23f32, 0.4] {
            let got = surface_to_surface(&s, size, 8192, Face::PosY, to);
            assert!(
                (got / want - 1.0).abs() < 0.01,
                "{name} at voxel {size}: {got:.4}, want {want}"
            );
        }
    }
}

#[test]
fn the_back_of_a_single_sided_surface_blocks_and_reflects_nothing() {
    // A floor facing up, and above it a single-sided panel facing up too, covering a third of
    // the floor's view (more, and the floor would count as inside a closed solid and be no
    // patch: `openness::ENCLOSED`): the floor's rays that meet the panel meet only its back,
    // which carries nothing; made double-sided, its underside is a patch those rays reach.
    let v = Vec3::new;
    let mut tallies = Vec::new();
    for double_sided in [false, true] {
        let mut tris = Vec::new();
        rect(
            &mut tris,
            [v(0., 0., 0.), v(1., 0., 0.), v(1., 0., 1.), v(0., 0., 1.)],
            Vec3::Y,
            false,
        );
        rect(
            &mut tris,
            [
                v(0.1, 0.5, 0.1),
                v(0.9, 0.5, 0.1),
                v(0.9, 0.5, 0.9),
                v(0.1, 0.5, 0.9),
            ],
            Vec3::Y,
            double_sided,
        );
        let s = scene(tris);
        let vox = cluster_at(&s, 0.37).unwrap();
        let tracer = surface_scene(&s, &vox);
        let floor: Vec<usize> = (0..vox.layout.len())
            .filter(|&i| vox.layout.patches[i].centroid[1] < 0.25)
            .collect();
        assert!(!floor.is_empty(), "the floor is patches");
        let mut tally_sum = bounce_core::rays::RayTally::default();
        for &i in &floor {
            let mut counts = vec![0u32; vox.layout.len()];
            tally_sum = tally_sum + tracer.trace_row(i, 512, 1, &mut counts);
        }
        if double_sided {
            assert_eq!(tally_sum.back_face, 0, "{tally_sum:?}");
        } else {
            assert_eq!(tally_sum.patch, 0, "{tally_sum:?}");
        }
        tallies.push(tally_sum);
    }
    // The same rays: those that met the panel's back met its underside's patch (but for a ray
    // or two on the panel's edge, where the two scenes' elements part the floor alike but not
    // bit for bit).
    let (single, double) = (tallies[0], tallies[1]);
    assert_eq!(single.total(), double.total());
    assert!(
        single.back_face.abs_diff(double.patch) * 1000 <= single.total(),
        "{single:?} vs {double:?}"
    );
    assert!(
        single.back_face * 5 > single.total(),
        "the panel covers much of the view: {single:?}"
    );
}

/// A floor under the ceiling of the fixture tests, so that the grid (centred on the scene) puts
/// the ceiling and the fixture in one voxel layer.
fn floor(t: &mut Vec<Triangle>) {
    let v = Vec3::new;
    rect(
        t,
        [v(0., 0., 0.), v(2., 0., 0.), v(2., 0., 2.), v(0., 0., 2.)],
        Vec3::Y,
        false,
    );
}

#[test]
fn elements_split_patches_by_surface_and_conserve_area() {
    let v = Vec3::new;
    let mut t = Vec::new();
    rect(
        &mut t,
        [v(0., 1., 0.), v(2., 1., 0.), v(2., 1., 2.), v(0., 1., 2.)],
        Vec3::NEG_Y,
        true,
    );
    rect(
        &mut t,
        [
            v(0.7, 0.99, 0.7),
            v(1.3, 0.99, 0.7),
            v(1.3, 0.99, 1.3),
            v(0.7, 0.99, 1.3),
        ],
        Vec3::NEG_Y,
        true,
    );
    floor(&mut t);
    let scene = scene(t);
    let sided: f64 = scene
        .triangles
        .iter()
        .map(|t| t.area() as f64 * if t.double_sided { 2.0 } else { 1.0 })
        .sum();
    for factor in [1, 3] {
        let vox = bounce_core::voxel::cluster_refined_at(&scene, 0.45, factor).unwrap();
        let e = vox
            .elements
            .as_ref()
            .expect("surface clusters have elements");
        e.check(&vox.layout).unwrap();
        assert!(
            e.len() > vox.layout.len(),
            "the fixture makes elements of its own"
        );
        assert_eq!(vox.pieces.as_ref().unwrap().patch_count(), e.len());
        let total: f64 = e.layout.patches.iter().map(|p| p.source_area as f64).sum();
        assert!(((total + vox.unassigned_area) / sided - 1.0).abs() < 1e-5);
        for (p, patch) in vox.layout.patches.iter().enumerate() {
            let mine: f64 = e
                .patch
                .iter()
                .zip(&e.layout.patches)
                .filter(|(q, _)| **q as usize == p)
                .map(|(_, r)| r.source_area as f64)
                .sum();
            assert!((mine / patch.source_area as f64 - 1.0).abs() < 1e-5);
        }
        assert_eq!(vox.refinement.voxels.is_empty(), factor == 1);
    }
}

/// `bounce verify`'s source split (`bounce_core::pointwise`): the element-constant sum is `F · B0`
/// on the very rays of `F`; a source that is uniform over its elements gives the two sums alike;
/// a point light close to one wall does not, and the pointwise sum is what a finer source would
/// converge to: the same light in total, placed where it falls.
#[test]
fn the_pointwise_first_bounce_retraces_the_form_factor_rays() {
    use bounce_core::pointwise::first_bounce;
    let mut scene = closed_box(1.0, 0.5);
    let vox = cluster_at(&scene, 0.26).unwrap();
    let rows = vox.transport_layout();
    let pieces = vox.pieces.as_ref().unwrap();
    let (rays, seed) = (512, 3);
    let (f, _) = form_factors(&surface_scene(&scene, &vox), rays, seed, &no_progress).unwrap();
    let n = rows.len();
    // Any per-row B0 will do for the identity with F: make every row different.
    let b0: Vec<[f32; 3]> = (0..n)
        .map(|i| [1.0 + i as f32, 2.0 * i as f32, 0.5])
        .collect();
    let dark = first_bounce(&scene, rows, pieces, &LightSet::default(), &b0, rays, seed);
    for (i, row) in dark.element.iter().enumerate() {
        for (c, &got) in row.iter().enumerate() {
            let fb: f32 = (0..n).map(|j| f.get(0, i, j) * b0[j][c]).sum();
            assert!(
                (got - fb).abs() <= 1e-4 * fb.abs().max(1.0),
                "row {i}: {got} against F·B0 {fb}"
            );
        }
    }
    // No light, every wall emitting alike: B0 is uniform, where it lands or as a mean.
    for t in &mut scene.triangles {
        t.emission = Vec3::splat(2.0);
    }
    let uniform = vec![[2.0f32; 3]; n];
    let same = first_bounce(
        &scene,
        rows,
        pieces,
        &LightSet::default(),
        &uniform,
        rays,
        seed,
    );
    assert_eq!(same.pointwise, same.element);
    // A point light a hand's breadth from the floor: the floor's elements are far from uniform.
    for t in &mut scene.triangles {
        t.emission = Vec3::ZERO;
    }
    let light = LightSet {
        lights: vec![Light::Point {
            position: [0.5, 0.1, 0.5],
            color: [1.0; 3],
            intensity: 1.0,
            range: None,
            name: None,
        }],
    };
    let data = SurfaceData {
        triangles: occluder_triangles_of(&scene_mesh(&scene)),
        per_patch: 64,
        area_samples: 64,
        points: sample_points(pieces, 64, 1),
        albedo: None,
    };
    let e = direct_irradiance(&ShadowScene::surface(&data), rows, &light, 64);
    let b0: Vec<[f32; 3]> = rows
        .patches
        .iter()
        .zip(&e)
        .map(|(p, e)| std::array::from_fn(|c| p.albedo[c] * e[c]))
        .collect();
    let lit = first_bounce(&scene, rows, pieces, &light, &b0, rays, seed);
    let total = |v: &[[f32; 3]]| -> f64 { v.iter().map(|x| f64::from(x[0])).sum() };
    let (pw, el) = (total(&lit.pointwise), total(&lit.element));
    assert!(
        (pw - el).abs() < 0.1 * el,
        "in total alike: {pw} against {el}"
    );
    let moved = (0..n)
        .filter(|&i| (lit.pointwise[i][0] - lit.element[i][0]).abs() > 0.1 * lit.element[i][0])
        .count();
    assert!(
        moved > 0,
        "some receiver sees the lit spot, not the floor's mean"
    );
}

/// Issue 19's bake amplification: a sliver triangle running from a one-unit room to 1e5 units
/// away (under the stray-vertex ratio, so not refused outright) cut into a candidate patch per
/// voxel along its length, every one probed with rays: minutes at a fine size. Each step of the
/// voxel-size search now stops at `MAX_CANDIDATES` candidates before probing any.
#[test]
fn a_sliver_across_the_scene_bounds_the_voxel_size_search() {
    use bounce_core::bake::{BakeError, BakeOptions, simplify};
    use bounce_core::voxel::{MAX_CANDIDATES, Resolution, VoxelError};
    let mut scene = closed_box(1.0, 0.5);
    let sliver = Triangle {
        positions: [
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.02),
            Vec3::new(1e5, 0.0, 0.0),
        ],
        double_sided: true,
        ..scene.triangles[0]
    };
    scene.triangles.push(sliver);
    let at = |resolution| {
        simplify(
            &scene,
            &BakeOptions {
                resolution,
                ..BakeOptions::default()
            },
        )
    };
    // Half-unit voxels: some 400,000 candidates along the sliver, refused before probing.
    match at(Resolution::VoxelSize(0.5)) {
        Err(BakeError::Voxel(VoxelError::TooManyCandidates {
            candidates, max, ..
        })) => assert!(candidates > max && max == MAX_CANDIDATES),
        other => panic!(
            "expected too many candidates, got {:?}",
            other.map(|v| v.layout.len())
        ),
    }
    // A patch count: the search settles on a size it could probe.
    let v = at(Resolution::TargetPatches(200)).expect("a size within the probe budget");
    assert!(v.layout.len() + v.dropped_patches <= MAX_CANDIDATES);
}

/// Landing samples (`SurfaceScene::landing_samples`): a row's first samples are the plain
/// area-stratified ones, bit for bit; the others lie on the row's own surface, gathered where
/// the near-field rays land, which in a box is along its edges, where the walls meet; the same
/// inputs place the same points. A row's direct light is then the mean of its area samples
/// alone, the landing samples lit beside them for the near field.
#[test]
fn landing_samples_follow_the_area_samples_and_gather_where_surfaces_meet() {
    use bounce_core::surface::sample_points_with_albedo;
    let scene = closed_box(1.0, 0.5);
    let voxel = 0.26;
    let vox = cluster_at(&scene, voxel).unwrap();
    let rows = vox.transport_layout();
    let pieces = vox.pieces.as_ref().unwrap();
    let tracer = surface_scene(&scene, &vox);
    let (area, landing, seed) = (12u32, 4u32, 3);
    let (points, albedo) = tracer.landing_samples(&scene, area, landing, 512, seed, voxel);
    let k = (area + landing) as usize;
    let a = area as usize;
    assert_eq!(
        (points.len(), albedo.len()),
        (rows.len() * k, rows.len() * k)
    );
    let (plain, plain_albedo) = sample_points_with_albedo(&scene, pieces, area, seed);
    // How far a point of the unit box lies from the nearest face it does not lie on. Measured:
    // 0.091 for the landing samples, 0.119 for the area samples (voxels of 0.26: every row is
    // near an edge, and a near ray may land up to a voxel away).
    let to_edge = |p: [f32; 3], n: [f32; 3]| {
        (0..3)
            .filter(|&a| n[a].abs() < 0.5)
            .map(|a| p[a].min(1.0 - p[a]))
            .fold(f32::INFINITY, f32::min)
    };
    let (mut near_area, mut near_landing) = (0.0f64, 0.0f64);
    for j in 0..rows.len() {
        let row = &points[j * k..(j + 1) * k];
        assert_eq!(&row[..a], &plain[j * a..(j + 1) * a]);
        assert_eq!(&albedo[j * k..j * k + a], &plain_albedo[j * a..(j + 1) * a]);
        let facing = rows.patches[j].face.normal();
        for s in &row[a..] {
            // On the row's own side of the box: its normal, and within its face's plane.
            assert!(Vec3::from(s.normal).dot(facing) > 0.999, "{s:?} on row {j}");
            let depth = Vec3::from(s.position).dot(facing.abs());
            let plane = Vec3::from(row[0].position).dot(facing.abs());
            assert!((depth - plane).abs() < 1e-3, "{s:?} off row {j}'s plane");
            near_landing += f64::from(to_edge(s.position, s.normal));
        }
        near_area += row[..a]
            .iter()
            .map(|s| f64::from(to_edge(s.position, s.normal)))
            .sum::<f64>();
    }
    let mean_area = near_area / (a * rows.len()) as f64;
    let mean_landing = near_landing / ((k - a) * rows.len()) as f64;
    eprintln!("mean distance to an edge: area samples {mean_area}, landing samples {mean_landing}");
    assert!(
        mean_landing < 0.85 * mean_area,
        "landing samples at {mean_landing} from an edge, area samples at {mean_area}"
    );
    assert_eq!(
        tracer.landing_samples(&scene, area, landing, 512, seed, voxel),
        (points.clone(), albedo.clone())
    );

    let data = SurfaceData {
        triangles: occluder_triangles_of(&scene_mesh(&scene)),
        per_patch: area + landing,
        area_samples: area,
        points,
        albedo: Some(albedo),
    };
    let shadow = ShadowScene::surface(&data);
    let set = LightSet {
        lights: vec![Light::Point {
            position: [0.2, 0.8, 0.3],
            color: [1.0; 3],
            intensity: 1.0,
            range: None,
            name: None,
        }],
    };
    let sampled =
        bounce_core::direct::direct_with_samples(&shadow, rows, &set, area + landing).unwrap();
    assert_eq!(sampled.count, area + landing);
    assert_eq!(
        direct_irradiance(&shadow, rows, &set, area + landing),
        sampled.mean
    );
    let mean_of =
        |v: &[[f32; 3]]| v.iter().fold(Vec3::ZERO, |s, e| s + Vec3::from(*e)) / v.len() as f32;
    let mut differ = 0;
    for (j, mean) in sampled.mean.iter().enumerate() {
        let values = &sampled.samples[j * k..(j + 1) * k];
        let want = mean_of(&values[..a]);
        assert!(
            (Vec3::from(*mean) - want).length() <= 1e-6 * want.length().max(1e-3),
            "row {j}: {mean:?} against {want}"
        );
        differ += usize::from((mean_of(values) - want).length() > 1e-3 * want.length());
    }
    assert!(
        differ > 0,
        "the landing samples' light differs from the means somewhere"
    );
}

/// A floor facing up and, standing on it, a tall closed box of single-sided faces facing out:
/// the floor inside the box is surface no viewer sees. Its middle is open to the short
/// openness probe (the walls and roof are more than its reach away), so it is clustered into
/// elements, which see nothing but the back of the box's faces.
fn box_on_floor() -> Scene {
    let v = Vec3::new;
    let mut t = Vec::new();
    rect(
        &mut t,
        [v(0., 0., 0.), v(4., 0., 0.), v(4., 0., 4.), v(0., 0., 4.)],
        Vec3::Y,
        false,
    );
    let (lo, hi, top) = (1.1f32, 2.9f32, 3.0f32);
    let faces = [
        (
            [v(lo, 0., lo), v(lo, top, lo), v(lo, top, hi), v(lo, 0., hi)],
            Vec3::NEG_X,
        ),
        (
            [v(hi, 0., lo), v(hi, 0., hi), v(hi, top, hi), v(hi, top, lo)],
            Vec3::X,
        ),
        (
            [v(lo, 0., lo), v(hi, 0., lo), v(hi, top, lo), v(lo, top, lo)],
            Vec3::NEG_Z,
        ),
        (
            [v(lo, 0., hi), v(lo, top, hi), v(hi, top, hi), v(hi, 0., hi)],
            Vec3::Z,
        ),
        (
            [
                v(lo, top, lo),
                v(hi, top, lo),
                v(hi, top, hi),
                v(lo, top, hi),
            ],
            Vec3::Y,
        ),
    ];
    for (corners, normal) in faces {
        rect(&mut t, corners, normal, false);
    }
    scene(t)
}

#[test]
fn hidden_surface_leaves_its_patch_and_surface_in_the_open_stays() {
    let scene = box_on_floor();
    let mut vox = cluster_at(&scene, 0.25).unwrap();
    let rays = surface_scene(&scene, &vox);
    let isolated = isolated_patches(&rays, 64, 1);
    let hidden = hidden_patches(&rays, &isolated, 64, 1);
    let pieces = vox.pieces.as_ref().unwrap();
    // Where each element's pieces lie: all on the floor strictly inside the box, or anywhere
    // outside it (the floor beyond, the box's own faces).
    let inside = |i: usize| {
        pieces.of(i).iter().all(|t| {
            t.corners.iter().all(|c| {
                c.y.abs() < 1e-4 && (1.1..=2.9).contains(&c.x) && (1.1..=2.9).contains(&c.z)
            })
        })
    };
    let n = vox.transport_layout().len();
    let inner: Vec<usize> = (0..n).filter(|&i| inside(i)).collect();
    assert!(inner.len() >= 8, "{} elements inside the box", inner.len());
    for &i in &inner {
        assert!(isolated[i] && hidden[i], "inner element {i} is not hidden");
    }
    let open_hidden = (0..n).filter(|&i| !inside(i) && hidden[i]).count();
    assert_eq!(open_hidden, 0, "surface a viewer sees was taken as hidden");
    assert!(
        (0..n).any(|i| !inside(i) && !isolated[i]),
        "the floor outside sees the box"
    );

    // A patch keeps the area of its kept elements and of those dropped in the open (unlit
    // surface of its own), and loses that of its hidden ones.
    let e = vox.elements.as_ref().unwrap();
    let mut kept = vec![false; vox.layout.len()];
    let mut want = vec![0.0f64; vox.layout.len()];
    let mut lost = vec![0.0f64; vox.layout.len()];
    for (i, (&p, rec)) in e.patch.iter().zip(&e.layout.patches).enumerate() {
        let a = f64::from(rec.source_area);
        kept[p as usize] |= !isolated[i];
        if hidden[i] {
            lost[p as usize] += a;
        } else {
            want[p as usize] += a;
        }
    }
    let straddling = (0..want.len())
        .filter(|&p| kept[p] && lost[p] > 0.0)
        .count();
    assert!(
        straddling > 0,
        "no patch holds both surface in view and hidden floor"
    );
    let want: Vec<f64> = (0..want.len())
        .filter(|&p| kept[p])
        .map(|p| want[p])
        .collect();
    vox.drop_patches(&isolated, &hidden);
    assert_eq!(vox.layout.len(), want.len());
    for (p, (patch, want)) in vox.layout.patches.iter().zip(&want).enumerate() {
        assert!(
            (f64::from(patch.source_area) / want - 1.0).abs() < 1e-5,
            "patch {p}: area {} against {want}",
            patch.source_area
        );
    }
    vox.elements.as_ref().unwrap().check(&vox.layout).unwrap();
}
