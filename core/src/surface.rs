//! Surface patches at work: form-factor rays between the real pieces patches stand for, and the
//! direct-light sample points a baked file keeps (docs/design.md §2, steps 2–3).
//!
//! A patch ([`crate::voxel::cluster_at`]) is a set of triangle pieces with their true normals.
//! Its form-factor row is estimated from rays whose origins are stratified over those pieces by
//! area and whose directions are cosine-weighted about each origin's own normal, traced against
//! the **original triangles** ([`TriMesh`]). A ray that meets a surface side is credited to the
//! patch owning the piece it met: the patch of the voxel the hit point lies in and the direction
//! the side's normal faces most. A ray that escapes, meets the back of a single-sided triangle, or
//! meets surface that belongs to no patch (a dropped patch's) carries nothing. So a row sums to
//! at most 1, and its samples depend on its index and the seed alone.

use std::collections::HashMap;
use std::sync::Arc;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::formfactor::{RowTracer, row_seed};
use crate::patch::{Face, PatchLayout};
use crate::rays::{RayFate, RayTally};
use crate::scene::Scene;
use crate::trimesh::{TriMesh, extent_of, offset_origin};
use crate::voxel::{PieceTri, Pieces, dominant_face};

/// Direct-light sample points per patch a bake stores unless asked otherwise.
pub const DEFAULT_SURFACE_SAMPLES: u32 = 16;
/// The most sample points per patch a bake stores.
pub const MAX_SURFACE_SAMPLES: u32 = 256;

/// Sobol dimension set of the direct-light sample points (0 is the form factors', 1 the
/// isolated-patch probe's).
const SAMPLE_DIMENSION_SET: u32 = 2;
/// Sobol dimension set of the isolated-patch probe.
const PROBE_DIMENSION_SET: u32 = 1;

/// A point on a patch's surface where direct light is evaluated, with the unit normal of the
/// side the patch stands for. The position is already pushed off the surface along the normal
/// ([`offset_origin`]), so shadow rays start from it as is, on the CPU and the GPU alike.
#[repr(C)]
#[derive(
    Debug, Clone, Copy, PartialEq, Serialize, Deserialize, bytemuck::Pod, bytemuck::Zeroable,
)]
pub struct SamplePoint {
    pub position: [f32; 3],
    pub normal: [f32; 3],
}

/// What a surface-geometry baked file keeps for direct light at run time: the triangles shadow
/// rays are traced against, and `per_patch` sample points for each patch (patch `i` owns
/// `points[i · per_patch..(i + 1) · per_patch]`).
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceData {
    /// Every triangle of the scene with an area, corners in winding order. All of them block
    /// light, from both sides.
    pub triangles: Vec<[[f32; 3]; 3]>,
    pub per_patch: u32,
    pub points: Vec<SamplePoint>,
}

impl SurfaceData {
    /// The sample points of `patch`.
    pub fn samples(&self, patch: usize) -> &[SamplePoint] {
        let k = self.per_patch as usize;
        &self.points[patch * k..(patch + 1) * k]
    }

    /// The triangles as [`TriMesh::new`] takes them.
    pub fn mesh(&self) -> TriMesh {
        TriMesh::new(self.triangles.iter().map(|t| (t.map(Vec3::from), false)))
    }
}

/// The triangles of `scene` as a [`TriMesh`] (its `source` indices are the scene's).
pub fn scene_mesh(scene: &Scene) -> TriMesh {
    TriMesh::new(
        scene
            .triangles
            .iter()
            .map(|t| (t.positions, t.double_sided)),
    )
}

/// The triangles of `mesh` as a [`SurfaceData`] keeps them (in the mesh's order).
pub fn occluder_triangles_of(mesh: &TriMesh) -> Vec<[[f32; 3]; 3]> {
    mesh.triangles()
        .iter()
        .map(|t| {
            let a = Vec3::from(t.p0);
            [
                t.p0,
                (a + Vec3::from(t.e1)).to_array(),
                (a + Vec3::from(t.e2)).to_array(),
            ]
        })
        .collect()
}

/// A point of a patch drawn from two uniform numbers: the first picks a piece triangle in
/// proportion to its area (and is reused, rescaled, inside it, which keeps 2-D stratification),
/// the pair then places the point uniformly on that triangle.
fn point_on(pieces: &[PieceTri], cdf: &[f64], u: f32, v: f32) -> (Vec3, Vec3) {
    let total = cdf.last().copied().unwrap_or(0.0);
    let x = f64::from(u) * total;
    let k = cdf.partition_point(|&c| c <= x).min(pieces.len() - 1);
    let before = if k == 0 { 0.0 } else { cdf[k - 1] };
    let width = cdf[k] - before;
    let u = if width > 0.0 {
        (((x - before) / width) as f32).clamp(0.0, 1.0)
    } else {
        0.5
    };
    let t = &pieces[k];
    let su = u.sqrt();
    let [a, b, c] = t.corners;
    let p = a * (1.0 - su) + b * (su * (1.0 - v)) + c * (su * v);
    (p, t.normal)
}

/// Cumulative areas of each patch's pieces, restarting at each patch.
fn piece_cdf(pieces: &Pieces) -> Vec<f64> {
    let mut cdf = Vec::with_capacity(pieces.tris.len());
    for i in 0..pieces.patch_count() {
        let mut sum = 0.0f64;
        for t in pieces.of(i) {
            sum += f64::from(t.area);
            cdf.push(sum);
        }
    }
    cdf
}

/// Cosine-weighted direction about unit `n` from two uniform numbers (Malley's method).
#[inline]
fn cosine_direction(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (t, b) = n.any_orthonormal_pair();
    let h = (1.0 - u1).max(0.0).sqrt();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * h).normalize()
}

/// `per_patch` direct-light sample points on every patch: stratified over its pieces by area
/// (an Owen-scrambled Sobol sequence per patch, seeded by the patch index and `seed`), each with
/// its piece's normal, pushed off the surface.
pub fn sample_points(pieces: &Pieces, per_patch: u32, seed: u64) -> Vec<SamplePoint> {
    let cdf = piece_cdf(pieces);
    let extent = extent_of(pieces.tris.iter().flat_map(|t| &t.corners));
    let mut out = Vec::with_capacity(pieces.patch_count() * per_patch as usize);
    for i in 0..pieces.patch_count() {
        let range = pieces.start[i] as usize..pieces.start[i + 1] as usize;
        let (tris, c) = (&pieces.tris[range.clone()], &cdf[range]);
        let s = row_seed(seed, i);
        for k in 0..per_patch {
            let [u, v, _, _] = sobol_burley::sample_4d(k, SAMPLE_DIMENSION_SET, s);
            let (p, n) = point_on(tris, c, u, v);
            out.push(SamplePoint {
                position: offset_origin(p, n, extent).to_array(),
                normal: n.to_array(),
            });
        }
    }
    out
}

/// The surface patches of a layout, ready for form-factor rays.
pub struct SurfaceScene {
    mesh: Arc<TriMesh>,
    /// Per original triangle: the face its front side joins, and its back's for a double-sided
    /// triangle (`None` for a single-sided one: its back is no surface).
    sides: Vec<[Option<Face>; 2]>,
    pieces: Pieces,
    cdf: Vec<f64>,
    origin: Vec3,
    size: f32,
    dims: [u32; 3],
    /// The scene's size, for [`offset_origin`].
    extent: f32,
    /// `linear voxel index · 6 + face code` → patch.
    patches: HashMap<u64, u32>,
}

impl SurfaceScene {
    /// `mesh` must be [`scene_mesh`] of `scene`; `pieces` are `layout`'s.
    pub fn new(
        scene: &Scene,
        mesh: Arc<TriMesh>,
        layout: &PatchLayout,
        pieces: &Pieces,
    ) -> SurfaceScene {
        let sides = scene
            .triangles
            .iter()
            .map(|t| {
                let n = t.cross().normalize_or_zero();
                [
                    Some(dominant_face(n)),
                    t.double_sided.then(|| dominant_face(-n)),
                ]
            })
            .collect();
        let dims = layout.dims;
        let patches = layout
            .patches
            .iter()
            .enumerate()
            .map(|(i, p)| (key(dims, p.voxel) * 6 + u64::from(p.face.code()), i as u32))
            .collect();
        SurfaceScene {
            mesh,
            sides,
            cdf: piece_cdf(pieces),
            pieces: pieces.clone(),
            origin: Vec3::from(layout.origin),
            size: layout.voxel_size,
            dims,
            extent: extent_of(scene.triangles.iter().flat_map(|t| &t.positions)),
            patches,
        }
    }

    /// The patch whose piece holds `p` on a side facing `face`. A point on a voxel boundary
    /// may round into the neighbour; the neighbours across boundaries within a thousandth of a
    /// voxel are tried too.
    fn patch_at(&self, p: Vec3, face: Face) -> Option<u32> {
        let f = (p - self.origin) / self.size;
        let mut cell = [0u32; 3];
        for a in 0..3 {
            cell[a] = (f[a].floor().max(0.0) as u32).min(self.dims[a].saturating_sub(1));
        }
        let look = |c: [u32; 3]| {
            self.patches
                .get(&(key(self.dims, c) * 6 + u64::from(face.code())))
                .copied()
        };
        if let Some(j) = look(cell) {
            return Some(j);
        }
        for a in 0..3 {
            let frac = f[a] - cell[a] as f32;
            let mut c = cell;
            if frac < 1e-3 && cell[a] > 0 {
                c[a] -= 1;
            } else if frac > 1.0 - 1e-3 && cell[a] + 1 < self.dims[a] {
                c[a] += 1;
            } else {
                continue;
            }
            if let Some(j) = look(c) {
                return Some(j);
            }
        }
        None
    }

    /// Where a ray from a surface point ends.
    #[inline]
    fn fate(&self, origin: Vec3, dir: Vec3) -> RayFate {
        let Some(hit) = self.mesh.closest(origin, dir, f32::INFINITY) else {
            return RayFate::Escaped;
        };
        let side = self.sides[hit.triangle as usize][usize::from(!hit.front)];
        let Some(face) = side else {
            return RayFate::BackFace;
        };
        match self.patch_at(origin + dir * hit.t, face) {
            Some(j) => RayFate::Patch(j as usize),
            None => RayFate::Occluder,
        }
    }

    /// Ray `k` of row `row` in Sobol dimension set `set`: its origin (off the surface) and
    /// direction.
    #[inline]
    fn ray(&self, row: usize, k: u32, set: u32, seed: u32) -> (Vec3, Vec3) {
        let range = self.pieces.start[row] as usize..self.pieces.start[row + 1] as usize;
        let [a, b, c, d] = sobol_burley::sample_4d(k, set, seed);
        let (p, n) = point_on(&self.pieces.tris[range.clone()], &self.cdf[range], a, b);
        (offset_origin(p, n, self.extent), cosine_direction(n, c, d))
    }
}

impl RowTracer for SurfaceScene {
    fn patch_count(&self) -> usize {
        self.pieces.patch_count()
    }

    fn trace_row(&self, row: usize, rays: u32, seed: u64, counts: &mut [u32]) -> RayTally {
        let s = row_seed(seed, row);
        let mut tally = RayTally::default();
        if self.pieces.of(row).is_empty() {
            tally.escaped += u64::from(rays);
            return tally;
        }
        for k in 0..rays {
            let (origin, dir) = self.ray(row, k, 0, s);
            let fate = self.fate(origin, dir);
            if let RayFate::Patch(j) = fate {
                counts[j] += 1;
            }
            tally.count(fate);
        }
        tally
    }

    fn sees_another(&self, row: usize, rays: u32, seed: u64) -> bool {
        if self.pieces.of(row).is_empty() {
            return false;
        }
        let s = row_seed(seed, row);
        (0..rays).any(|k| {
            let (origin, dir) = self.ray(row, k, PROBE_DIMENSION_SET, s);
            matches!(self.fate(origin, dir), RayFate::Patch(_))
        })
    }
}

#[inline]
fn key(dims: [u32; 3], c: [u32; 3]) -> u64 {
    (u64::from(c[2]) * u64::from(dims[1]) + u64::from(c[1])) * u64::from(dims[0]) + u64::from(c[0])
}
