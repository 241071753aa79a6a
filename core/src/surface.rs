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

use crate::element::{Refinement, sub_cell};
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
    /// Per original triangle, its connected surface ([`crate::element::components`]).
    component: Vec<u32>,
    pieces: Pieces,
    cdf: Vec<f64>,
    origin: Vec3,
    size: f32,
    dims: [u32; 3],
    /// The scene's size, for [`offset_origin`].
    extent: f32,
    /// (`linear voxel index · 6 + face code`, component, sub-cell) → transport row.
    rows: HashMap<(u64, u32, u32), u32>,
    /// (`linear voxel index · 6 + face code`, component) → the first of its sub-cells' rows: for
    /// a point that rounds into a sub-cell its surface has no piece in (a surface lying on a
    /// sub-cell plane), so that no light meeting real surface is lost.
    any_sub: HashMap<(u64, u32), u32>,
    /// Where elements are cut finer than their voxel.
    refinement: Refinement,
}

impl SurfaceScene {
    /// `mesh` must be [`scene_mesh`] of `scene`; `rows` are the transport's rows (the elements,
    /// [`crate::voxel::Voxelization::transport_layout`]), `pieces` theirs, and `refinement` says
    /// where they are cut finer than their voxel.
    pub fn new(
        scene: &Scene,
        mesh: Arc<TriMesh>,
        rows: &PatchLayout,
        pieces: &Pieces,
        refinement: &Refinement,
    ) -> SurfaceScene {
        let component = crate::element::components(scene);
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
        let dims = rows.dims;
        let origin = Vec3::from(rows.origin);
        let rows_at = rows
            .patches
            .iter()
            .enumerate()
            .filter_map(|(i, p)| {
                let first = pieces.of(i).first()?;
                let voxel = key(dims, p.voxel);
                let sub = if refinement.cuts(voxel) {
                    let c = first.corners;
                    let at = ((c[0] + c[1] + c[2]) / 3.0 - origin) / rows.voxel_size;
                    fine_sub(at, p.voxel, refinement.factor)
                } else {
                    0
                };
                let cell = voxel * 6 + u64::from(p.face.code());
                Some(((cell, component[first.triangle as usize], sub), i as u32))
            })
            .collect::<HashMap<(u64, u32, u32), u32>>();
        let mut any_sub = HashMap::new();
        for (&(cell, comp, _), &row) in &rows_at {
            let first = any_sub.entry((cell, comp)).or_insert(row);
            *first = (*first).min(row);
        }
        SurfaceScene {
            any_sub,
            mesh,
            sides,
            cdf: piece_cdf(pieces),
            pieces: pieces.clone(),
            origin: Vec3::from(rows.origin),
            size: rows.voxel_size,
            dims,
            extent: extent_of(scene.triangles.iter().flat_map(|t| &t.positions)),
            rows: rows_at,
            component,
            refinement: refinement.clone(),
        }
    }

    /// The transport row whose piece of connected surface `component` holds `p` on a side
    /// facing `face`. A point on a voxel boundary may round into the neighbour; the neighbours
    /// across boundaries within a thousandth of a voxel are tried too.
    fn row_at(&self, p: Vec3, face: Face, component: u32) -> Option<u32> {
        let f = (p - self.origin) / self.size;
        let mut cell = [0u32; 3];
        for a in 0..3 {
            cell[a] = (f[a].floor().max(0.0) as u32).min(self.dims[a].saturating_sub(1));
        }
        if let Some(j) = self.row_in(f, cell, face, component) {
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
            if let Some(j) = self.row_in(f, c, face, component) {
                return Some(j);
            }
        }
        None
    }

    /// The row of voxel `cell` for a point at `f` (in voxel units from the grid's origin): its
    /// sub-cell's where the voxel is cut, trying the sub-cells across boundaries within a
    /// thousandth of a sub-cell too.
    fn row_in(&self, f: Vec3, cell: [u32; 3], face: Face, component: u32) -> Option<u32> {
        let voxel = key(self.dims, cell);
        let look = |sub: u32| {
            self.rows
                .get(&(voxel * 6 + u64::from(face.code()), component, sub))
                .copied()
        };
        if !self.refinement.cuts(voxel) {
            return look(0);
        }
        let k = self.refinement.factor;
        let sub = fine_sub(f, cell, k);
        if let Some(j) = look(sub) {
            return Some(j);
        }
        let local = |a: usize| (f[a] - cell[a] as f32) * k as f32;
        for (a, stride) in [1, k, k * k].into_iter().enumerate() {
            let l = local(a);
            let i = (l.floor().max(0.0) as u32).min(k - 1);
            let frac = l - i as f32;
            let other = if frac < 1e-3 && i > 0 {
                sub - stride
            } else if frac > 1.0 - 1e-3 && i + 1 < k {
                sub + stride
            } else {
                continue;
            };
            if let Some(j) = look(other) {
                return Some(j);
            }
        }
        self.any_sub
            .get(&(voxel * 6 + u64::from(face.code()), component))
            .copied()
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
        let component = self.component[hit.triangle as usize];
        match self.row_at(origin + dir * hit.t, face, component) {
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

/// The sub-cell of voxel `cell` a point at `f` (voxel units from the grid's origin) lies in.
fn fine_sub(f: Vec3, cell: [u32; 3], factor: u32) -> u32 {
    let k = factor as f32;
    let fine = [0, 1, 2].map(|a| (f[a] * k).floor().max(0.0) as u32);
    sub_cell(fine, cell, factor)
}

#[inline]
fn key(dims: [u32; 3], c: [u32; 3]) -> u64 {
    (u64::from(c[2]) * u64::from(dims[1]) + u64::from(c[1])) * u64::from(dims[0]) + u64::from(c[0])
}
