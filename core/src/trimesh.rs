//! The original triangles in a BVH: what surface-patch form-factor rays and shadow rays are
//! traced against (docs/design.md §2, steps 3 and the relight's direct light).
//!
//! The triangles are stored in the BVH's primitive order, so a leaf's primitive range indexes
//! them directly: the CPU traversal (obvhs) and the GPU twin (`bounce-engine`'s
//! `shaders/direct_surface.wgsl`) read the same two arrays, [`TriMesh::nodes`] and
//! [`TriMesh::triangles`].
//!
//! Every triangle blocks light from both sides. Whether its back is a surface (glTF
//! `doubleSided`) only matters to the caller that credits a hit, so [`Hit::front`] says which side
//! was met.
//!
//! Rays start on surfaces. Rather than an epsilon in world units (which depends on the scene's
//! scale), origins are pushed off their surface by [`offset_origin`]: a fixed share of the
//! coordinates' and the scene's magnitude, so the surface the ray leaves is behind it at any
//! scale (the idea of Wächter and Binder, "A Fast and Robust Method for Avoiding
//! Self-Intersection", Ray Tracing Gems, 2019, made relative to the scene's size as well, since
//! their fixed offset near the origin is a visible distance in a millimetre-sized scene).

use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::ray::{Ray, RayHit};
use obvhs::{Boundable, BvhBuildParams};

/// One triangle as the tracer reads it: a corner and two edges. `#[repr(C)]` and 48 bytes, the
/// layout `direct_surface.wgsl`'s `Tri` has (checked by a naga test in the engine).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MeshTri {
    pub p0: [f32; 3],
    /// The triangle's index in the list the mesh was built from.
    pub source: u32,
    pub e1: [f32; 3],
    /// 1 when the triangle's back is a surface too (glTF `doubleSided`), else 0.
    pub double_sided: u32,
    pub e2: [f32; 3],
    pub pad: u32,
}

/// A BVH node as obvhs lays it out (`Bvh2Node`: min, prim_count, max, first_index; 32 bytes):
/// an inner node when `prim_count` is 0, with children at `first_index` and `first_index + 1`,
/// else a leaf over triangles `first_index..first_index + prim_count`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MeshNode {
    pub min: [f32; 3],
    pub prim_count: u32,
    pub max: [f32; 3],
    pub first_index: u32,
}

/// Where a ray first meets a triangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f32,
    /// Index of the triangle in the list the mesh was built from.
    pub triangle: u32,
    /// Whether the ray met the triangle's front (the side its winding's normal faces).
    pub front: bool,
    /// Whether the triangle is a surface on both sides.
    pub double_sided: bool,
    /// Unit normal of the side the ray met (facing back along the ray).
    pub normal: Vec3,
}

/// The triangles and their BVH.
pub struct TriMesh {
    tris: Vec<MeshTri>,
    bvh: Bvh2,
}

struct Bound(Aabb);

impl Boundable for Bound {
    fn aabb(&self) -> Aabb {
        self.0
    }
}

impl TriMesh {
    /// A BVH over `triangles` (corners in winding order, with whether each is double-sided).
    /// Triangles with no area or non-finite corners are left out: nothing can hit them.
    pub fn new(triangles: impl IntoIterator<Item = ([Vec3; 3], bool)>) -> TriMesh {
        let mut kept: Vec<MeshTri> = Vec::new();
        for (source, ([a, b, c], double_sided)) in triangles.into_iter().enumerate() {
            let (e1, e2) = (b - a, c - a);
            let cross = e1.cross(e2);
            let usable = a.is_finite()
                && b.is_finite()
                && c.is_finite()
                && cross.length_squared() > 0.0
                && cross.is_finite();
            if !usable {
                continue;
            }
            kept.push(MeshTri {
                p0: a.to_array(),
                source: source as u32,
                e1: e1.to_array(),
                double_sided: u32::from(double_sided),
                e2: e2.to_array(),
                pad: 0,
            });
        }
        let bounds: Vec<Bound> = kept
            .iter()
            .map(|t| {
                let a = Vec3::from(t.p0);
                let (b, c) = (a + Vec3::from(t.e1), a + Vec3::from(t.e2));
                Bound(Aabb::new(
                    Vec3A::from(a.min(b).min(c)),
                    Vec3A::from(a.max(b).max(c)),
                ))
            })
            .collect();
        // obvhs builds single-threaded without its `parallel` feature: the tree, and with it
        // which of two equally near triangles a ray reports, does not depend on the thread count.
        let bvh = obvhs::bvh2::builder::build_bvh2(
            &bounds,
            BvhBuildParams::medium_build(),
            &mut std::time::Duration::default(),
        );
        // Triangles in primitive order, so leaves index them directly (on the GPU too).
        let tris = bvh
            .primitive_indices
            .iter()
            .map(|&i| kept[i as usize])
            .collect();
        TriMesh { tris, bvh }
    }

    /// How many triangles are traced.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// The triangles in BVH primitive order.
    pub fn triangles(&self) -> &[MeshTri] {
        &self.tris
    }

    /// The BVH's nodes; node 0 is the root.
    pub fn nodes(&self) -> Vec<MeshNode> {
        self.bvh
            .nodes
            .iter()
            .map(|n| MeshNode {
                min: n.aabb.min.to_array(),
                prim_count: n.prim_count,
                max: n.aabb.max.to_array(),
                first_index: n.first_index,
            })
            .collect()
    }

    /// The deepest leaf's depth: a GPU traversal's stack needs this many entries at most.
    pub fn max_depth(&self) -> usize {
        self.bvh.max_depth
    }

    /// The nearest triangle crossed at `t` in `(0, t_max)`, either side.
    #[inline]
    pub fn closest(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        if self.tris.is_empty() || t_max.is_nan() || t_max <= 0.0 {
            return None;
        }
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), 0.0, t_max);
        let mut hit = RayHit::none();
        let found = self.bvh.ray_traverse(ray, &mut hit, |r, prim| {
            intersect(&self.tris[prim], origin, dir, r.tmax).unwrap_or(f32::INFINITY)
        });
        if !found {
            return None;
        }
        let t = &self.tris[hit.primitive_id as usize];
        let normal = Vec3::from(t.e1).cross(Vec3::from(t.e2));
        let front = dir.dot(normal) < 0.0;
        let unit = normal.normalize_or_zero();
        Some(Hit {
            t: hit.t,
            triangle: t.source,
            front,
            double_sided: t.double_sided != 0,
            normal: if front { unit } else { -unit },
        })
    }

    /// Whether any triangle crosses the ray at `t` in `(0, t_max)`: the shadow-ray query.
    #[inline]
    pub fn occluded(&self, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
        self.blocker(origin, dir, t_max, &[]).is_some()
    }

    /// Whether triangle `tri` (an index as [`TriMesh::blocker`] gives them) crosses the ray at
    /// `t` in `(0, t_max)`: `false` for an index that is no triangle.
    #[inline]
    pub fn blocks(&self, tri: u32, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
        self.tris
            .get(tri as usize)
            .is_some_and(|t| intersect(t, origin, dir, t_max).is_some())
    }

    /// [`TriMesh::occluded`], saying which triangle blocked the ray (an opaque index for a later
    /// call's `hints`). The `hints` are tried before the tree: shadow rays from neighbouring
    /// points towards one light are mostly blocked by the same few triangles (Haines and
    /// Greenberg's shadow cache), and one triangle test then stands for a whole traversal. The
    /// answer does not depend on the hints: a ray none of them blocks is traced through the
    /// tree.
    #[inline]
    pub fn blocker(&self, origin: Vec3, dir: Vec3, t_max: f32, hints: &[u32]) -> Option<u32> {
        if self.tris.is_empty() || t_max.is_nan() || t_max <= 0.0 {
            return None;
        }
        for &h in hints {
            if let Some(tri) = self.tris.get(h as usize)
                && intersect(tri, origin, dir, t_max).is_some()
            {
                return Some(h);
            }
        }
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), 0.0, t_max);
        let mut blocker = None;
        self.bvh.ray_traverse_miss(ray, |r, prim| {
            let t = intersect(&self.tris[prim], origin, dir, r.tmax).unwrap_or(f32::INFINITY);
            if t < r.tmax {
                blocker = Some(prim as u32);
            }
            t
        });
        blocker
    }
}

/// Möller–Trumbore: where the ray crosses `tri` (either side) at `t` in `(0, t_max)`. The WGSL
/// twin (`tri_hit` in `direct_surface.wgsl`) is the same arithmetic in the same order.
#[inline]
pub fn intersect(tri: &MeshTri, origin: Vec3, dir: Vec3, t_max: f32) -> Option<f32> {
    let (e1, e2) = (Vec3::from(tri.e1), Vec3::from(tri.e2));
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - Vec3::from(tri.p0);
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = dir.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0 && t < t_max).then_some(t)
}

/// `p`, a point on a surface, pushed off it along unit `n` (the side rays leave by) far enough
/// that the surface is behind any ray from it, at any scale: by `2⁻¹⁷` (about 64 ulps) of the
/// larger of `p`'s largest coordinate and `extent`, the scene's size. Intersection rounding grows
/// with both (the coordinates, and the edge lengths a triangle test multiplies), so neither a
/// scene far from the origin nor one a millimetre wide gets too small or too large a push.
#[inline]
pub fn offset_origin(p: Vec3, n: Vec3, extent: f32) -> Vec3 {
    let magnitude = p.abs().max_element().max(extent);
    p + n * (magnitude * (1.0 / 131_072.0))
}

/// The size of a set of triangles for [`offset_origin`]: the largest extent of their bounds.
pub fn extent_of<'a>(corners: impl IntoIterator<Item = &'a Vec3>) -> f32 {
    let (lo, hi) = corners
        .into_iter()
        .fold((Vec3::MAX, Vec3::MIN), |(lo, hi), &c| {
            (lo.min(c), hi.max(c))
        });
    (hi - lo).max_element().max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(y: f32, up: bool) -> [([Vec3; 3], bool); 2] {
        let v = |x, z| Vec3::new(x, y, z);
        let (a, b, c, d) = (v(-1.0, -1.0), v(-1.0, 1.0), v(1.0, 1.0), v(1.0, -1.0));
        if up {
            [([a, b, c], false), ([a, c, d], false)]
        } else {
            [([a, c, b], false), ([a, d, c], false)]
        }
    }

    #[test]
    fn the_nearest_crossing_and_its_side() {
        let mut tris = square(0.0, true).to_vec();
        tris.extend(square(2.0, true));
        let mesh = TriMesh::new(tris);
        assert_eq!(mesh.len(), 4);
        let from_below = mesh.closest(Vec3::new(0.3, -1.0, 0.2), Vec3::Y, f32::INFINITY);
        let h = from_below.unwrap();
        assert!(
            (h.t - 1.0).abs() < 1e-6 && !h.front && h.triangle < 2,
            "{h:?}"
        );
        let from_above = mesh
            .closest(Vec3::new(0.3, 1.0, 0.2), Vec3::NEG_Y, f32::INFINITY)
            .unwrap();
        assert!(from_above.front && from_above.triangle < 2);
        // The normal is the side met's, whichever side that is.
        assert!(h.normal.distance(Vec3::NEG_Y) < 1e-6, "{h:?}");
        assert!(from_above.normal.distance(Vec3::Y) < 1e-6, "{from_above:?}");
        let between_up = mesh
            .closest(Vec3::new(0.3, 1.0, 0.2), Vec3::Y, f32::INFINITY)
            .unwrap();
        assert!(between_up.triangle >= 2 && !between_up.front);
        assert_eq!(
            mesh.closest(Vec3::new(3.0, 1.0, 0.0), Vec3::Y, f32::INFINITY),
            None
        );
        // Blocked from either side, within the segment only.
        assert!(mesh.occluded(Vec3::new(0.0, 1.0, 0.0), Vec3::Y, 1.5));
        assert!(!mesh.occluded(Vec3::new(0.0, 1.0, 0.0), Vec3::Y, 0.9));
        assert!(mesh.occluded(Vec3::new(0.0, 1.0, 0.0), Vec3::NEG_Y, 1.5));
    }

    #[test]
    fn hints_change_the_cost_not_the_answer() {
        let mut tris = Vec::new();
        for y in [0.0, 1.0, 2.0] {
            tris.extend(square(y, true));
        }
        let mesh = TriMesh::new(tris);
        let up = Vec3::Y;
        let from = Vec3::new(0.3, -1.0, 0.2);
        let Some(first) = mesh.blocker(from, up, 10.0, &[]) else {
            panic!("the squares block the ray");
        };
        // A hint that blocks is the answer; hints that do not (or name no triangle) are passed
        // over to the tree, which finds a blocker all the same.
        assert_eq!(mesh.blocker(from, up, 10.0, &[first]), Some(first));
        let others: Vec<u32> = (0..mesh.len() as u32).filter(|&i| i != first).collect();
        assert!(mesh.blocker(from, up, 10.0, &others).is_some());
        assert!(mesh.blocker(from, up, 10.0, &[u32::MAX]).is_some());
        // Short of the first square, nothing blocks, whatever the hints.
        let all: Vec<u32> = (0..mesh.len() as u32).collect();
        assert_eq!(mesh.blocker(from, up, 0.5, &all), None);
        // A ray beside the squares passes the hints that would block its neighbour.
        assert_eq!(
            mesh.blocker(Vec3::new(5.0, -1.0, 0.2), up, 10.0, &all),
            None
        );
    }

    #[test]
    fn degenerate_triangles_are_left_out() {
        let z = Vec3::ZERO;
        let mesh = TriMesh::new([
            ([z, z, Vec3::X], false),
            ([z, Vec3::X, Vec3::splat(f32::NAN)], true),
            ([z, Vec3::X, Vec3::Y], true),
        ]);
        assert_eq!(mesh.len(), 1);
        assert_eq!(mesh.triangles()[0].source, 2);
        assert_eq!(mesh.triangles()[0].double_sided, 1);
    }

    #[test]
    fn offset_origins_leave_their_surface_at_any_scale() {
        for scale in [1e-6f32, 1e-3, 1.0, 1e3, 1e5] {
            // A tilted plate far from the origin; rays leave it at grazing angles.
            let c = Vec3::new(0.37, 0.61, -0.23) * scale * 3.0;
            let (a, b) = (Vec3::new(1.0, 0.2, 0.0), Vec3::new(0.0, 0.3, 1.0));
            let tri = [
                c - (a + b) * scale,
                c + a * scale * 2.0,
                c + b * scale * 2.0,
            ];
            let mesh = TriMesh::new([(tri, false)]);
            let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
            let mut blocked = 0;
            for k in 0..1000 {
                let (s, t) = ((k % 31) as f32 / 31.0 * 0.3, (k / 31) as f32 / 33.0 * 0.3);
                let p = tri[0] + (tri[1] - tri[0]) * s + (tri[2] - tri[0]) * t;
                let tangent = (tri[1] - tri[0]).normalize();
                let dir = (tangent + n * 1e-3 * (1 + k % 7) as f32).normalize();
                let o = offset_origin(p, n, extent_of(&tri));
                // Pushed off by a hair of the scene's size, never a visible distance.
                assert!((o - p).length() < scale * 1e-4);
                if mesh.occluded(o, dir, f32::INFINITY) {
                    blocked += 1;
                }
            }
            assert_eq!(blocked, 0, "scale {scale}");
        }
    }
}
