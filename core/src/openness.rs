//! How open the space in front of a piece of surface is: how far it sees before meeting other
//! surface (docs/design.md §2, step 2).
//!
//! Spaces ([`crate::space`]) part a patch's surface where a surface separates it at the lattice's
//! scale. They cannot part what the lattice does not resolve, or what connects around an edge
//! within a voxel: the inside of a cavity a little thinner than a lattice step above a lit
//! ceiling, the floor under a low shelf, the underside of a ledge. Those parts see their own
//! surroundings a few units away while the rest of the patch sees the room, and as one element
//! of uniform radiosity they take the room's light into the cavity. So each part also gets an
//! openness class: the mean distance of a few cosine-weighted rays, in powers of
//! [`CLASS_RATIO`] of the voxel size. Parts of a patch in different classes are separate
//! elements. A class boundary across a wall whose view changes gradually costs a row, never an
//! error.

use glam::Vec3;

use crate::trimesh::{TriMesh, offset_origin};

/// Rays per part: a 4 × 4 stratified cosine-weighted pattern, the same for every part so that
/// neighbouring parts are measured alike.
const RAYS: u32 = 16;
/// Classes are this ratio of mean distance apart.
pub const CLASS_RATIO: f32 = 8.0;
/// Distances are counted up to this many voxel sizes (an escaping ray counts as this far): what
/// lies beyond is the open room for every part of a patch alike.
pub const REACH_VOXELS: f32 = 4.0;

/// The mean distance rays from `p` (on a surface facing unit `n`) travel before meeting a
/// triangle of `mesh`, each capped at `reach`.
pub fn mean_distance(mesh: &TriMesh, p: Vec3, n: Vec3, extent: f32, reach: f32) -> f32 {
    look_around(mesh, p, n, extent, reach).0
}

/// [`mean_distance`], and whether most rays ([`ENCLOSED_SHARE`]) met the back of a
/// single-sided triangle within `reach`: the part lies inside a closed solid (the floor running on under a wall built as a
/// closed box), where glTF says no light can reach it and no eye can see it.
fn look_around(mesh: &TriMesh, p: Vec3, n: Vec3, extent: f32, reach: f32) -> (f32, bool) {
    let origin = offset_origin(p, n, extent);
    let mut sum = 0.0f32;
    let mut behind = 0;
    for k in 0..RAYS {
        let hit = mesh.closest(origin, direction(n, k), reach);
        behind += u32::from(hit.is_some_and(|h| !h.front && !h.double_sided));
        sum += hit.map_or(reach, |hit| hit.t);
    }
    (sum / RAYS as f32, behind >= ENCLOSED_SHARE * RAYS / 4)
}

/// Ray `k` of the 4 × 4 stratified cosine-weighted pattern about unit `n`.
fn direction(n: Vec3, k: u32) -> Vec3 {
    let (t, b) = n.any_orthonormal_pair();
    let side = (RAYS as f32).sqrt() as u32;
    let (row, col) = (k / side, k % side);
    let u1 = (row as f32 + 0.5) / side as f32;
    // Each ring turned by a fraction of a step, so no azimuth repeats.
    let u2 = ((col as f32 + 0.5) / side as f32 + row as f32 / (side * side) as f32).fract();
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()).normalize()
}

/// Of every four rays, how many must meet the back of a single-sided triangle for a part to be
/// inside a closed solid. Not all: where closed boxes overlap (walls crossing, furniture pushed
/// into a wall) a ray from inside one meets another's outside, and along a thin wall a ray can
/// run past the reach. Measured on a generated house (`cli/tests/interiors.rs`, house 2): of the
/// parts where at least four rays met a back face, 92% had 12 or more, and a part of a room's
/// floor sees no back face at all.
pub const ENCLOSED_SHARE: u32 = 3;

/// The class of a part that lies inside a closed solid ([`probe`]): it is no element's, and its
/// area belongs to no patch.
pub const ENCLOSED: i8 = i8::MIN;

/// The openness class of a part at `p` facing `n`, in a grid of voxel size `voxel`: `⌊log_r(d /
/// voxel)⌋` of its mean distance `d` (r = [`CLASS_RATIO`]), at most
/// `⌊log_r REACH_VOXELS⌋`.
pub fn class(mesh: &TriMesh, p: Vec3, n: Vec3, extent: f32, voxel: f32) -> i8 {
    let reach = voxel * REACH_VOXELS;
    let d = mean_distance(mesh, p, n, extent, reach);
    class_of(d, voxel)
}

fn class_of(d: f32, voxel: f32) -> i8 {
    let c = ((d / voxel).max(f32::MIN_POSITIVE).ln() / CLASS_RATIO.ln()).floor();
    c.clamp(-64.0, 63.0) as i8
}

/// [`class`], or [`ENCLOSED`] when most rays from the part ([`ENCLOSED_SHARE`]) met the back of
/// a single-sided triangle within reach. Such a part is inside a closed solid: it was a quarter of the
/// form-factor rays of a house whose walls are closed boxes standing on one floor, each carrying
/// nothing, and as part of a patch it darkened the visible floor beside it by its share, in what a
/// viewer draws and in what the reference averages alike.
pub fn probe(mesh: &TriMesh, p: Vec3, n: Vec3, extent: f32, voxel: f32) -> i8 {
    let reach = voxel * REACH_VOXELS;
    let (d, enclosed) = look_around(mesh, p, n, extent, reach);
    if enclosed {
        ENCLOSED
    } else {
        class_of(d, voxel)
    }
}

/// Whether the surface at `p` facing `n` lies inside a closed solid, as [`probe`] decides it,
/// tracing only the rays that take to decide it (a point in the open is settled after five).
pub fn enclosed(mesh: &TriMesh, p: Vec3, n: Vec3, extent: f32, voxel: f32) -> bool {
    let origin = offset_origin(p, n, extent);
    let reach = voxel * REACH_VOXELS;
    let needed = ENCLOSED_SHARE * RAYS / 4;
    let (mut behind, mut other) = (0, 0);
    for k in 0..RAYS {
        let hit = mesh.closest(origin, direction(n, k), reach);
        if hit.is_some_and(|h| !h.front && !h.double_sided) {
            behind += 1;
            if behind >= needed {
                return true;
            }
        } else {
            other += 1;
            if other > RAYS - needed {
                return false;
            }
        }
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two parallel squares `gap` apart (the lower facing up, the upper facing down), `size` wide.
    fn plates(gap: f32, size: f32) -> TriMesh {
        let quad = |y: f32| {
            let (a, b, c, d) = (
                Vec3::new(0.0, y, 0.0),
                Vec3::new(size, y, 0.0),
                Vec3::new(size, y, size),
                Vec3::new(0.0, y, size),
            );
            [[a, c, b], [a, d, c]]
        };
        TriMesh::new(quad(0.0).into_iter().chain(quad(gap)).map(|t| (t, true)))
    }

    #[test]
    fn a_thin_gap_and_the_open_side_are_different_classes() {
        let voxel = 10.0;
        let mesh = plates(1.0, 100.0);
        let centre = Vec3::new(50.0, 0.0, 50.0);
        // Above the lower plate: the upper one is a unit away.
        let inside = class(&mesh, centre, Vec3::Y, 100.0, voxel);
        // Below it: nothing at all.
        let outside = class(&mesh, centre, -Vec3::Y, 100.0, voxel);
        assert!(inside < outside, "{inside} vs {outside}");
        assert_eq!(
            outside,
            (REACH_VOXELS.ln() / CLASS_RATIO.ln()).floor() as i8
        );
        let d = mean_distance(&mesh, centre, Vec3::Y, 100.0, 40.0);
        // A cosine-weighted mean of 1/cos θ over the hemisphere is 2; 16 rays come close.
        assert!((1.5..2.5).contains(&d), "{d}");
    }

    /// A closed single-sided box (outward normals) on a floor, 2 units on a side.
    fn box_on_floor(double_sided: bool) -> TriMesh {
        let (lo, hi) = (Vec3::new(4.0, 0.0, 4.0), Vec3::new(6.0, 2.0, 6.0));
        let c = |x: bool, y: bool, z: bool| {
            Vec3::new(
                if x { hi.x } else { lo.x },
                if y { hi.y } else { lo.y },
                if z { hi.z } else { lo.z },
            )
        };
        // Each face as a quad wound counter-clockwise seen from outside.
        let faces = [
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
        ];
        let mut tris = Vec::new();
        for [a, b, c, d] in faces {
            tris.push(([a, b, c], double_sided));
            tris.push(([a, c, d], double_sided));
        }
        // The floor, facing up, running on under the box.
        let f = |x: f32, z: f32| Vec3::new(x, 0.0, z);
        tris.push(([f(0.0, 0.0), f(0.0, 10.0), f(10.0, 10.0)], false));
        tris.push(([f(0.0, 0.0), f(10.0, 10.0), f(10.0, 0.0)], false));
        TriMesh::new(tris)
    }

    #[test]
    fn floor_inside_a_closed_single_sided_box_is_enclosed_and_beside_it_is_not() {
        let voxel = 1.0;
        let mesh = box_on_floor(false);
        assert_eq!(
            probe(&mesh, Vec3::new(5.0, 0.0, 5.0), Vec3::Y, 10.0, voxel),
            ENCLOSED
        );
        // Right beside the box, half the sky is the box's front: open.
        let beside = probe(&mesh, Vec3::new(3.9, 0.0, 5.0), Vec3::Y, 10.0, voxel);
        assert_ne!(beside, ENCLOSED);
        assert_eq!(
            beside,
            class(&mesh, Vec3::new(3.9, 0.0, 5.0), Vec3::Y, 10.0, voxel)
        );
        // A double-sided box is a surface inside too: glTF lets light live in it.
        let open_box = box_on_floor(true);
        assert_ne!(
            probe(&open_box, Vec3::new(5.0, 0.0, 5.0), Vec3::Y, 10.0, voxel),
            ENCLOSED
        );
        // A box bigger than the rays' reach is not known to be closed: kept.
        assert_ne!(
            probe(&mesh, Vec3::new(5.0, 0.0, 5.0), Vec3::Y, 10.0, 0.2),
            ENCLOSED
        );
    }

    /// `enclosed` stops tracing once the answer is settled; it must be `probe`'s answer.
    #[test]
    fn enclosed_decides_as_the_probe_does() {
        let mut seen = [0; 2];
        for double_sided in [false, true] {
            let mesh = box_on_floor(double_sided);
            for voxel in [0.2f32, 1.0] {
                for i in 0..=40 {
                    // Across the floor under the box and out beside it, and on its walls.
                    let x = 3.0 + i as f32 * 0.1;
                    for (p, n) in [
                        (Vec3::new(x, 0.0, 5.0), Vec3::Y),
                        (Vec3::new(x, 0.0, 4.01), Vec3::Y),
                        (Vec3::new(4.0, x - 3.0, 5.0), Vec3::NEG_X),
                        (Vec3::new(4.0, x - 3.0, 5.0), Vec3::X),
                    ] {
                        let e = enclosed(&mesh, p, n, 10.0, voxel);
                        assert_eq!(e, probe(&mesh, p, n, 10.0, voxel) == ENCLOSED, "{p} {n}");
                        seen[usize::from(e)] += 1;
                    }
                }
            }
        }
        assert!(seen[0] > 0 && seen[1] > 0, "{seen:?}");
    }

    #[test]
    fn the_class_does_not_change_with_the_scene_scale() {
        let unit = class(
            &plates(3.0, 100.0),
            Vec3::new(50.0, 0.0, 50.0),
            Vec3::Y,
            100.0,
            10.0,
        );
        // Three units of gap under a ten-unit voxel: rays travel about six.
        assert_eq!(unit, -1);
        for scale in [1e-3f32, 1e3] {
            let mesh = plates(3.0 * scale, 100.0 * scale);
            let p = Vec3::new(50.0, 0.0, 50.0) * scale;
            assert_eq!(
                class(&mesh, p, Vec3::Y, 100.0 * scale, 10.0 * scale),
                unit,
                "scale {scale}"
            );
        }
    }
}
