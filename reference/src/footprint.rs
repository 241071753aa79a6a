//! What a patch stands for, as points: its footprint on the original surfaces.
//!
//! A patch's value is the area-weighted average over the pieces of original triangles inside its
//! voxel whose surface side faces its direction more than any other axis direction (both sides
//! of a double-sided triangle, each on its own; docs/design.md §2, restated here from the
//! design, not called from `bounce_core::voxel`), leaving out surface inside a closed solid of
//! single-sided faces, which glTF shows to no eye ([`enclosed`]). That is what the patch's value means to a
//! viewer, whatever geometry the bake used, so voxel-face bakes are measured against the same
//! footprints. One point cannot stand for it where the pieces lie at several depths (a ceiling
//! and a panel a unit below it, in one 15-unit voxel): the pieces in a gap are dark, the others
//! lit. So the reference samples the footprint: lines along the face's axis through uniform
//! points of the voxel's cross-section, and every such triangle piece they cross inside the
//! voxel. A uniform point of the cross-section lands on a piece with probability ∝ its area
//! projected onto the face, area × cos; keeping it with probability `(1/√3) / cos` (a dominant
//! axis has cos ≥ 1/√3) makes the kept points uniform in true area.

use std::collections::{HashMap, HashSet};

use bounce_core::patch::PatchLayout;
use glam::Vec3;
use rayon::prelude::*;

use crate::Point;
use crate::mesh::Mesh;
use crate::rng::{Pcg32, mix};

/// Rays a footprint point looks around with before it is taken as inside a closed solid.
const ENCLOSURE_RAYS: usize = 16;

/// Whether the surface at `p` facing unit `n` lies inside a closed solid: three in four of a few
/// rays over its hemisphere meet the back of a single-sided triangle. glTF draws no such face,
/// so no eye sees that surface and no light reaches it (the floor running on under a wall built
/// as a closed box): it is no part of what a patch's value means. Restated from glTF's
/// sidedness, with rays of unbounded length, not taken from the bake (which looks a few voxels
/// far: a surface inside a larger closed solid stays in the bake's patch and shows as error).
fn enclosed(mesh: &Mesh, p: Vec3, n: Vec3, rng: &mut Pcg32) -> bool {
    let origin = p + n * mesh.epsilon;
    // Three rays in four, not all: where closed boxes overlap a ray from inside one meets
    // another's outside.
    let most = ENCLOSURE_RAYS * 3 / 4;
    let mut behind = 0;
    for k in 0..ENCLOSURE_RAYS {
        // The rest cannot make it: stop.
        if behind + (ENCLOSURE_RAYS - k) < most {
            return false;
        }
        let dir = crate::estimate::cosine_direction(n, rng);
        behind += usize::from(mesh.closest(origin, dir).is_some_and(|hit| {
            let t = &mesh.tris[hit.tri as usize];
            !t.double_sided && t.normal.dot(dir) > 0.0
        }));
    }
    behind >= most
}

/// Lines per wanted point before a patch gives up (its pieces cover little of the voxel).
const TRIES_PER_POINT: usize = 128;

/// The least cosine between a unit vector and the axis direction it faces most: 1/√3.
const MIN_DOMINANT_COS: f32 = 0.577_350_26;

/// Whether unit `n` faces the direction `sign` along `axis` more than any other axis direction
/// (the lower axis wins a tie, as the bake's clustering rule says).
fn faces_most(n: Vec3, axis: usize, sign: f32) -> bool {
    let a = n.abs();
    let most = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    most == axis && n[axis] * sign >= 0.0 && n[axis] != 0.0
}

/// `count` points on each patch's footprint; an empty list for a patch none could be drawn for.
pub(crate) fn footprints(
    mesh: &Mesh,
    layout: &PatchLayout,
    count: usize,
    seed: u64,
) -> Vec<Vec<Point>> {
    let size = layout.voxel_size;
    let origin = Vec3::from(layout.origin);
    let wanted: HashSet<[u32; 3]> = layout.patches.iter().map(|p| p.voxel).collect();
    // Triangles by the voxels their bounds touch, for the voxels that hold patches only.
    let mut by_voxel: HashMap<[u32; 3], Vec<u32>> = HashMap::new();
    let dims = layout.dims;
    for (i, t) in mesh.tris.iter().enumerate() {
        let (a, b, c) = (t.p0, t.p0 + t.e1, t.p0 + t.e2);
        let cell = |p: Vec3| ((p - origin) / size).floor();
        let (lo, hi) = (cell(a.min(b).min(c)), cell(a.max(b).max(c)));
        let clamp = |v: f32, d: u32| v.clamp(0.0, d.saturating_sub(1) as f32) as u32;
        let lo = [0, 1, 2].map(|k| clamp(lo[k], dims[k]));
        let hi = [0, 1, 2].map(|k| clamp(hi[k], dims[k]));
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    if wanted.contains(&[x, y, z]) {
                        by_voxel.entry([x, y, z]).or_default().push(i as u32);
                    }
                }
            }
        }
    }
    // Each patch draws from its own generator, so the points do not depend on the threads.
    layout
        .patches
        .par_iter()
        .enumerate()
        .map(|(index, patch)| {
            let dir = patch.face.normal();
            let lo = origin + Vec3::from(patch.voxel.map(|v| v as f32)) * size;
            let hi = lo + Vec3::splat(size);
            // Triangle sides that face this direction most, with their cosine to it.
            let mut candidates: Vec<(u32, Vec3, f32)> = Vec::new();
            for &i in by_voxel.get(&patch.voxel).into_iter().flatten() {
                let t = &mesh.tris[i as usize];
                for (n, surface) in [(t.normal, true), (-t.normal, t.double_sided)] {
                    if surface && faces_most(n, patch.face.axis(), patch.face.sign()) {
                        candidates.push((i, n, n.dot(dir)));
                    }
                }
            }
            let mut points = Vec::with_capacity(count);
            if candidates.is_empty() {
                return points;
            }
            let axis = patch.face.axis();
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut along = Vec3::ZERO;
            along[axis] = 1.0;
            // A hair beyond the voxel's faces, so a surface lying on one is crossed.
            let slack = size * 1e-6;
            let mut rng = Pcg32::new(mix(seed ^ 0x5EED_F007), mix(index as u64));
            // Its own stream, so the points drawn elsewhere do not move.
            let mut look = Pcg32::new(mix(seed ^ 0xC105_ED00), mix(index as u64));
            let mut tries = 0;
            while points.len() < count && tries < count * TRIES_PER_POINT {
                tries += 1;
                let mut start = lo;
                start[axis] -= slack;
                start[u] += rng.next_f32() * size;
                start[v] += rng.next_f32() * size;
                for &(i, n, cos) in &candidates {
                    let t = &mesh.tris[i as usize];
                    if let Some(d) = t.intersect(start, along, 0.0, size + 2.0 * slack) {
                        let p = start + along * d;
                        let keep = rng.next_f32() * cos < MIN_DOMINANT_COS;
                        if keep
                            && p.cmpge(lo).all()
                            && p.cmplt(hi).all()
                            && points.len() < count
                            && !enclosed(mesh, p, n, &mut look)
                        {
                            points.push(Point {
                                position: p.to_array(),
                                normal: n.to_array(),
                            });
                        }
                    }
                }
            }
            points
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounce_core::patch::{Face, Patch};
    use bounce_core::scene::{Scene, Triangle};

    fn tri(positions: [Vec3; 3], double_sided: bool) -> Triangle {
        Triangle {
            positions,
            albedo: Vec3::splat(0.5),
            emission: Vec3::ZERO,
            double_sided,
            material: 0,
        }
    }

    fn patch(voxel: [u32; 3], face: Face) -> Patch {
        Patch {
            voxel,
            face,
            albedo: [0.5; 3],
            centroid: [0.0; 3],
            normal: face.normal().to_array(),
            source_area: 1.0,
            emission: [0.0; 3],
        }
    }

    #[test]
    fn footprints_keep_to_the_voxel_and_the_facing_side() {
        // A big floor facing +Y at y = 0.25 (wound counter-clockwise from above), a one-sided
        // ceiling facing down at y = 0.75 and a two-sided panel facing down at y = 0.5, all
        // crossing the voxel [0, 1)³ and its neighbours.
        let v = Vec3::new;
        let floor = [
            tri(
                [v(-5., 0.25, -5.), v(-5., 0.25, 5.), v(5., 0.25, 5.)],
                false,
            ),
            tri(
                [v(-5., 0.25, -5.), v(5., 0.25, 5.), v(5., 0.25, -5.)],
                false,
            ),
        ];
        let ceiling = tri(
            [v(-5., 0.75, -5.), v(5., 0.75, 5.), v(-5., 0.75, 5.)],
            false,
        );
        let panel = tri([v(-5., 0.5, -5.), v(5., 0.5, 5.), v(-5., 0.5, 5.)], true);
        assert!(floor[0].cross().y > 0.0 && ceiling.cross().y < 0.0);
        let scene = Scene {
            triangles: vec![floor[0], floor[1], ceiling, panel],
            ..Scene::default()
        };
        let mesh = Mesh::new(&scene).unwrap();
        let layout = PatchLayout {
            origin: [-2.0, -2.0, -2.0],
            voxel_size: 1.0,
            dims: [4, 4, 4],
            patches: vec![patch([2, 2, 2], Face::PosY), patch([2, 2, 2], Face::NegY)],
        };
        let sets = footprints(&mesh, &layout, 64, 1);
        let (up, down) = (&sets[0], &sets[1]);
        assert_eq!((up.len(), down.len()), (64, 64));
        let inside = |p: &Point| p.position.iter().all(|&c| (0.0..1.0).contains(&c));
        let at = |p: &Point, y: f32| (p.position[1] - y).abs() < 1e-5;
        // Facing up: the floor, and the two-sided panel's upper side; never the ceiling.
        assert!(up.iter().all(inside));
        assert!(up.iter().all(|p| p.normal == [0.0, 1.0, 0.0]));
        assert!(up.iter().all(|p| at(p, 0.25) || at(p, 0.5)));
        // The floor covers the voxel's cross-section, the panel (one triangle, cut by the
        // diagonal x = z) half of it: two thirds of the points are on the floor.
        let floor = up.iter().filter(|p| at(p, 0.25)).count();
        assert!((36..=50).contains(&floor), "{floor} of 64 on the floor");
        // Facing down: the ceiling and the panel's own side; never the floor.
        assert!(down.iter().all(inside));
        assert!(down.iter().all(|p| p.normal == [0.0, -1.0, 0.0]));
        assert!(down.iter().all(|p| at(p, 0.75) || at(p, 0.5)));
        // A voxel no triangle crosses has no footprint.
        let empty = PatchLayout {
            patches: vec![patch([0, 0, 0], Face::PosX)],
            ..layout
        };
        assert!(footprints(&mesh, &empty, 8, 1)[0].is_empty());
    }

    #[test]
    fn surface_inside_a_closed_single_sided_box_is_no_footprint() {
        // A floor facing up at y = 0.25 and, standing on it over x in [0, 0.5), a closed box of
        // single-sided faces looking out: the floor under the box is enclosed.
        let v = Vec3::new;
        let mut triangles = vec![
            tri(
                [v(-5., 0.25, -5.), v(-5., 0.25, 5.), v(5., 0.25, 5.)],
                false,
            ),
            tri(
                [v(-5., 0.25, -5.), v(5., 0.25, 5.), v(5., 0.25, -5.)],
                false,
            ),
        ];
        let (lo, hi) = (v(-3.0, 0.25, -3.0), v(0.5, 2.0, 3.0));
        let c = |x: bool, y: bool, z: bool| {
            v(
                if x { hi.x } else { lo.x },
                if y { hi.y } else { lo.y },
                if z { hi.z } else { lo.z },
            )
        };
        for [a, b, cc, d] in [
            [
                c(false, false, false),
                c(false, false, true),
                c(false, true, true),
                c(false, true, false),
            ],
            [
                c(true, false, false),
                c(true, true, false),
                c(true, true, true),
                c(true, false, true),
            ],
            [
                c(false, false, false),
                c(true, false, false),
                c(true, false, true),
                c(false, false, true),
            ],
            [
                c(false, true, false),
                c(false, true, true),
                c(true, true, true),
                c(true, true, false),
            ],
            [
                c(false, false, false),
                c(false, true, false),
                c(true, true, false),
                c(true, false, false),
            ],
            [
                c(false, false, true),
                c(true, false, true),
                c(true, true, true),
                c(false, true, true),
            ],
        ] {
            triangles.push(tri([a, b, cc], false));
            triangles.push(tri([a, cc, d], false));
        }
        let scene = Scene {
            triangles,
            ..Scene::default()
        };
        let mesh = Mesh::new(&scene).unwrap();
        let layout = PatchLayout {
            origin: [-2.0, -2.0, -2.0],
            voxel_size: 1.0,
            dims: [4, 4, 4],
            patches: vec![patch([2, 2, 2], Face::PosY)],
        };
        let up = &footprints(&mesh, &layout, 64, 1)[0];
        assert_eq!(up.len(), 64);
        // Every point on the floor beside the box, none under it (nor on its faces looking up:
        // its top is above the voxel).
        assert!(
            up.iter()
                .all(|p| (p.position[1] - 0.25).abs() < 1e-5 && p.position[0] >= 0.5),
            "{:?}",
            up.iter().find(|p| p.position[0] < 0.5)
        );
        // The same box two-sided is a surface inside as well: its floor stays.
        let open = Scene {
            triangles: scene
                .triangles
                .iter()
                .enumerate()
                .map(|(i, t)| Triangle {
                    double_sided: i >= 2,
                    ..*t
                })
                .collect(),
            ..Scene::default()
        };
        let mesh = Mesh::new(&open).unwrap();
        let up = &footprints(&mesh, &layout, 64, 1)[0];
        assert!(up.iter().any(|p| p.position[0] < 0.5));
    }
}
