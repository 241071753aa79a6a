//! Surface patches at work: form-factor rays between the real pieces patches stand for, and the
//! direct-light sample points a baked file keeps (docs/design.md §2, steps 2–3).
//!
//! A patch ([`crate::voxel::cluster_at`]) is a set of triangle pieces with their true normals.
//! Its form-factor row is estimated from rays whose origins are stratified over those pieces by
//! area and whose directions are cosine-weighted about each origin's own normal, traced against
//! the **original triangles** ([`TriMesh`]). A ray that meets a surface side is credited to the
//! row owning the piece it met: the piece of that side of that triangle which contains the hit
//! point, found exactly rather than from the voxel, so the rows may cut a voxel's surface however
//! they like. A ray that escapes, meets the back of a single-sided triangle, or meets surface that
//! belongs to no row (a dropped patch's) carries nothing; visible surface left out with an
//! enclosed part beside it goes to its nearest piece ([`SurfaceScene`]'s `owner`). So a row sums to
//! at most 1, and its samples depend on its index and the seed alone. The directions of the rays
//! that escape make the row's view of the sky ([`crate::sky`]).

use std::sync::Arc;

use glam::Vec3;

use crate::formfactor::{RowRays, RowTracer, row_seed};
use crate::patch::{PatchLayout, PieceTri, Pieces};
use crate::rays::{RayFate, RayTally};
pub use crate::sample::SamplePoint;
use crate::scene::Scene;

use crate::openness;
use crate::trimesh::{Hit, TriMesh, extent_of, offset_origin};

/// Direct-light sample points per patch a bake stores unless asked otherwise. The near field's
/// correction is as fine as the samples: on `pandora` 32 take the corridor light from 10.5% to
/// 9.4% and a uniform sky from 10.7% to 10.0% against the reference, for 1.7× the CPU's
/// direct-light time of 16 (README, "Accuracy").
pub const DEFAULT_SURFACE_SAMPLES: u32 = 32;
/// How many of a patch's `direct_samples` a bake places where near-field rays land rather than
/// spread by area ([`SurfaceScene::landing_samples`]) unless asked otherwise: a quarter (8 of
/// the default 32). On `pandora` under a sun, 8 of 32 and 16 of 32 measured alike (12.2% and
/// 12.4%).
pub fn default_landing_samples(direct_samples: u32) -> u32 {
    direct_samples / 4
}
/// The most sample points per patch a bake stores.
pub const MAX_SURFACE_SAMPLES: u32 = 256;

/// Sobol dimension set of the direct-light sample points (0 is the form factors', 1 the
/// isolated-patch probe's).
const SAMPLE_DIMENSION_SET: u32 = 2;
/// Sobol dimension set of the isolated-patch probe.
const PROBE_DIMENSION_SET: u32 = 1;

/// What a surface-geometry baked file keeps for direct light at run time: the triangles shadow
/// rays are traced against, and `per_patch` sample points for each patch (patch `i` owns
/// `points[i · per_patch..(i + 1) · per_patch]`).
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceData {
    /// Every triangle of the scene with an area, corners in winding order. All of them block
    /// light, from both sides.
    pub triangles: Vec<[[f32; 3]; 3]>,
    pub per_patch: u32,
    /// How many of each patch's samples, the first, are stratified over it by area: their
    /// mean is its direct light. The rest (landing samples, [`SurfaceScene::landing_samples`])
    /// lie where near-field rays land on it and serve only the near field's correction. Equal
    /// to `per_patch` in files from before format version 13.
    pub area_samples: u32,
    pub points: Vec<SamplePoint>,
    /// Per sample point, the albedo of the triangle it lies on ([`sample_points_with_albedo`]): a textured
    /// element is not one colour, and the near field reflects a landing's light with the
    /// albedo where it landed (`crate::nearfield`). `None` in files from before format version
    /// 11, whose samples take their row's albedo.
    pub albedo: Option<Vec<[f32; 3]>>,
}

impl SurfaceData {
    /// The sample points of `patch`.
    pub fn samples(&self, patch: usize) -> &[SamplePoint] {
        let k = self.per_patch as usize;
        &self.points[patch * k..(patch + 1) * k]
    }

    /// How many of a patch's first `count` samples its direct light is the mean of: those
    /// spread by area ([`Self::area_samples`]), the landing samples after them never.
    pub fn mean_count(&self, count: usize) -> usize {
        count.min(self.area_samples as usize)
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
    let (p, n, _) = point_on_triangle(pieces, cdf, u, v);
    (p, n)
}

/// [`point_on`] with the original triangle of the piece it picked.
fn point_on_triangle(pieces: &[PieceTri], cdf: &[f64], u: f32, v: f32) -> (Vec3, Vec3, u32) {
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
    (p, t.normal, t.triangle)
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
pub(crate) fn cosine_direction(n: Vec3, u1: f32, u2: f32) -> Vec3 {
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
    placed_samples(pieces, per_patch, seed)
        .into_iter()
        .map(|(p, _)| p)
        .collect()
}

/// [`sample_points`] and the albedo of the original triangle (of `scene`) under each, in the
/// same order: what [`SurfaceData::points`] and [`SurfaceData::albedo`] keep, placed once.
pub fn sample_points_with_albedo(
    scene: &Scene,
    pieces: &Pieces,
    per_patch: u32,
    seed: u64,
) -> (Vec<SamplePoint>, Vec<[f32; 3]>) {
    placed_samples(pieces, per_patch, seed)
        .into_iter()
        .map(|(p, t)| (p, scene.triangles[t as usize].albedo.to_array()))
        .unzip()
}

/// How many of a row's form-factor rays [`SurfaceScene::landing_samples`] traces to place its
/// landing samples: a quarter of them (a Sobol prefix, so still spread over the row), at least
/// 64. A few landings a sample are enough to say where landings gather.
pub fn placement_rays(rays: u32) -> u32 {
    (rays / 4).max(64).min(rays)
}

/// [`sample_points`] with the original triangle each point lies on.
fn placed_samples(pieces: &Pieces, per_patch: u32, seed: u64) -> Vec<(SamplePoint, u32)> {
    let cdf = piece_cdf(pieces);
    let extent = extent_of(pieces.tris.iter().flat_map(|t| &t.corners));
    let mut out = Vec::with_capacity(pieces.patch_count() * per_patch as usize);
    for i in 0..pieces.patch_count() {
        let range = pieces.start[i] as usize..pieces.start[i + 1] as usize;
        let (tris, c) = (&pieces.tris[range.clone()], &cdf[range]);
        let s = row_seed(seed, i);
        for k in 0..per_patch {
            let [u, v, _, _] = sobol_burley::sample_4d(k, SAMPLE_DIMENSION_SET, s);
            let (p, n, t) = point_on_triangle(tris, c, u, v);
            out.push((
                SamplePoint {
                    position: offset_origin(p, n, extent).to_array(),
                    normal: n.to_array(),
                },
                t,
            ));
        }
    }
    out
}

/// The surface patches of a layout, ready for form-factor rays.
pub struct SurfaceScene {
    mesh: Arc<TriMesh>,
    /// Per original triangle, whether its front and its back are surfaces (the back only of a
    /// double-sided triangle).
    sides: Vec<[bool; 2]>,
    /// Per original triangle, its albedo: what a near landing on it reflects.
    albedo: Vec<Vec3>,
    pieces: Pieces,
    cdf: Vec<f64>,
    /// Which row owns the surface a ray meets.
    owners: Owners,
    /// The scene's size, for [`offset_origin`].
    extent: f32,
}

impl SurfaceScene {
    /// `mesh` must be [`scene_mesh`] of `scene`; `rows` are the transport's rows (the elements,
    /// [`crate::voxel::Voxelization::transport_layout`]) and `pieces` theirs.
    pub fn new(
        scene: &Scene,
        mesh: Arc<TriMesh>,
        rows: &PatchLayout,
        pieces: &Pieces,
    ) -> SurfaceScene {
        let sides = scene
            .triangles
            .iter()
            .map(|t| [true, t.double_sided])
            .collect();
        SurfaceScene {
            mesh,
            sides,
            albedo: scene.triangles.iter().map(|t| t.albedo).collect(),
            cdf: piece_cdf(pieces),
            owners: Owners::new(scene, rows, pieces),
            pieces: pieces.clone(),
            extent: extent_of(scene.triangles.iter().flat_map(|t| &t.positions)),
        }
    }

    /// Where a ray from a surface point ends.
    #[inline]
    fn fate(&self, origin: Vec3, dir: Vec3) -> RayFate {
        self.fate_at(origin, dir).0
    }

    /// The row a ray that met surface side `hit` at `point` is credited to: the row whose piece
    /// contains the point; else, on surface of no row, the row of the nearest piece of that
    /// side within half a voxel and in view of the point, unless the point lies inside a closed
    /// solid.
    ///
    /// Parts inside closed solids are left out of every row (`openness::probe`), but a part is
    /// tested as a whole, so one straddling a wall's foot leaves out the visible strip of floor
    /// beside it too, and the rays that met that strip carried nothing: on a generated house
    /// under a low sun, a wall's lowest patch read a quarter of its light (README, "Unseen
    /// interiors"). A part is at most a lattice cell wide, a quarter voxel, so such a strip's
    /// light is taken as its nearest piece's. A ray that slipped through a seam into a wall is
    /// told apart by the same probe that left the surface out (and credited to nothing, or it
    /// would carry light across the wall); further than half a voxel from any row's piece, the
    /// surface is a dropped patch's, which carries nothing.
    fn owner(&self, point: Vec3, hit: &Hit) -> Option<u32> {
        let back = !hit.front;
        if let Some(row) = self.owners.row_containing(point, hit.triangle, back) {
            return Some(row);
        }
        let (row, nearest) =
            self.owners
                .nearest_within(point, hit.triangle, back, NEAREST_REACH)?;
        // The piece must be in view along the surface: the nearest owned floor may be the
        // other room's, across a wall thinner than the strip left out.
        let (from, to) = (
            offset_origin(point, hit.normal, self.extent),
            offset_origin(nearest, hit.normal, self.extent),
        );
        let gap = to - from;
        let length = gap.length();
        if length > 0.0 && self.mesh.occluded(from, gap / length, length) {
            return None;
        }
        let voxel = self.owners.size;
        (!openness::enclosed(&self.mesh, point, hit.normal, self.extent, voxel)).then_some(row)
    }

    /// Whether a ray from a row sees another row's surface: as [`Self::fate`], except that
    /// surface of no row is never credited to a piece beside it. A row whose rays reach only
    /// surface left out as enclosed (the top of a wall under the ceiling slab) lies inside a
    /// solid itself, and goes.
    fn sees_a_row(&self, origin: Vec3, dir: Vec3) -> bool {
        let Some(hit) = self.mesh.closest(origin, dir, f32::INFINITY) else {
            return false;
        };
        self.sides[hit.triangle as usize][usize::from(!hit.front)]
            && self
                .owners
                .row_containing(origin + dir * hit.t, hit.triangle, !hit.front)
                .is_some()
    }

    /// [`Self::fate`] and the surface the ray ended on: how far along `dir` (infinite when it
    /// escaped), the unit normal of the side met and its triangle's albedo.
    #[inline]
    fn fate_at(&self, origin: Vec3, dir: Vec3) -> (RayFate, f32, Vec3, Vec3) {
        let Some(hit) = self.mesh.closest(origin, dir, f32::INFINITY) else {
            return (RayFate::Escaped, f32::INFINITY, Vec3::ZERO, Vec3::ZERO);
        };
        let albedo = self.albedo[hit.triangle as usize];
        if !self.sides[hit.triangle as usize][usize::from(!hit.front)] {
            return (RayFate::BackFace, hit.t, hit.normal, albedo);
        }
        let fate = match self.owner(origin + dir * hit.t, &hit) {
            Some(j) => RayFate::Patch(j as usize),
            None => RayFate::Occluder,
        };
        (fate, hit.t, hit.normal, albedo)
    }

    /// Where a ray from a point in free space ends (a probe's: no surface to push off from).
    pub(crate) fn free_fate(&self, origin: Vec3, dir: Vec3) -> RayFate {
        self.fate(origin, dir)
    }

    /// Where form-factor ray `k` of `row` lands (the same ray [`RowTracer::trace_row`] traces
    /// with this seed): the hit point, the unit normal of the side it met, the original triangle
    /// and the row owning that surface. `None` where the ray carries nothing (escaped, a back
    /// face, surface of no row).
    pub(crate) fn landing(&self, row: usize, k: u32, seed: u64) -> Option<Landing> {
        if self.pieces.of(row).is_empty() {
            return None;
        }
        let (origin, _, dir) = self.ray(row, k, 0, row_seed(seed, row));
        let hit = self.mesh.closest(origin, dir, f32::INFINITY)?;
        if !self.sides[hit.triangle as usize][usize::from(!hit.front)] {
            return None;
        }
        let point = origin + dir * hit.t;
        let row = self.owner(point, &hit)? as usize;
        Some(Landing {
            position: offset_origin(point, hit.normal, self.extent),
            normal: hit.normal,
            triangle: hit.triangle,
            row,
        })
    }

    /// Sample points for every row, `area + landing` a row: the first `area` stratified by
    /// area ([`sample_points_with_albedo`]), then `landing` placed where the near-field rays of
    /// every row (the first [`placement_rays`] of each, within `radius`) land on it, evenly
    /// through its landings in row and ray order. A row with fewer landings than that takes
    /// the rest as more area-stratified points, further along its sequence. With the albedo of
    /// the triangle under each.
    ///
    /// Why: a near landing reads the light of the sample that stands for it
    /// ([`crate::sample::nearest_sample`]), and near landings gather where surfaces meet (a
    /// wall's rays land on the floor at its foot), where shadows start and light changes
    /// fastest. Area-stratified samples are spread evenly, so a landing's sample there often
    /// lies on the other side of a shadow edge. On `pandora` under a sun, 24 area and 8 landing
    /// samples a row measured 12.2% against 14.2% for 32 area samples, for the same shadow
    /// rays (README, "Landing samples"). Deterministic: the same rows, rays and seed give the
    /// same points, so every shard of a sharded bake places the same ones.
    pub fn landing_samples(
        &self,
        scene: &Scene,
        area: u32,
        landing: u32,
        rays: u32,
        seed: u64,
        radius: f32,
    ) -> (Vec<SamplePoint>, Vec<[f32; 3]>) {
        use rayon::prelude::*;
        let per_row = area + landing;
        let (mut points, mut albedo) =
            sample_points_with_albedo(scene, &self.pieces, per_row, seed);
        if landing == 0 || radius <= 0.0 {
            return (points, albedo);
        }
        let n = self.row_count();
        let traced = placement_rays(rays);
        // Per row, where its near rays landed: (landed row, point, normal, albedo).
        let per_row_landings: Vec<Vec<(u32, SamplePoint, [f32; 3])>> = (0..n)
            .into_par_iter()
            .map(|i| {
                (0..traced)
                    .filter_map(|k| self.near_landing(i, k, seed, radius))
                    .map(|(p, normal, j, a)| {
                        let at = SamplePoint {
                            position: offset_origin(p, normal, self.extent).to_array(),
                            normal: normal.to_array(),
                        };
                        (j as u32, at, a.to_array())
                    })
                    .collect()
            })
            .collect();
        let mut on: Vec<Vec<(SamplePoint, [f32; 3])>> = vec![Vec::new(); n];
        for (j, at, a) in per_row_landings.into_iter().flatten() {
            on[j as usize].push((at, a));
        }
        let (k, area) = (per_row as usize, area as usize);
        for (j, landed) in on.iter().enumerate() {
            let take = (landing as usize).min(landed.len());
            for m in 0..take {
                let (at, a) = landed[(2 * m + 1) * landed.len() / (2 * take)];
                points[j * k + area + m] = at;
                albedo[j * k + area + m] = a;
            }
        }
        (points, albedo)
    }

    /// Transport rows this scene traces from.
    pub fn row_count(&self) -> usize {
        self.pieces.patch_count()
    }

    /// Where form-factor ray `k` of `row` (the ray [`RowTracer::trace_row`] traces with this
    /// seed) lands, if it lands within `radius` of its origin on surface that a row owns: the
    /// hit point, the unit normal of the side met, that row and the albedo of the triangle met.
    /// Only the first `radius` of the ray is traced.
    pub(crate) fn near_landing(
        &self,
        row: usize,
        k: u32,
        seed: u64,
        radius: f32,
    ) -> Option<(Vec3, Vec3, usize, Vec3)> {
        if self.pieces.of(row).is_empty() {
            return None;
        }
        let (origin, _, dir) = self.ray(row, k, 0, row_seed(seed, row));
        let hit = self.mesh.closest(origin, dir, radius)?;
        if !self.sides[hit.triangle as usize][usize::from(!hit.front)] {
            return None;
        }
        let point = origin + dir * hit.t;
        let j = self.owner(point, &hit)?;
        Some((
            point,
            hit.normal,
            j as usize,
            self.albedo[hit.triangle as usize],
        ))
    }

    /// Ray `k` of row `row` in Sobol dimension set `set`: its origin (off the surface), the
    /// unit normal of the piece it starts on and its direction.
    #[inline]
    fn ray(&self, row: usize, k: u32, set: u32, seed: u32) -> (Vec3, Vec3, Vec3) {
        let range = self.pieces.start[row] as usize..self.pieces.start[row + 1] as usize;
        let [a, b, c, d] = sobol_burley::sample_4d(k, set, seed);
        let (p, n) = point_on(&self.pieces.tris[range.clone()], &self.cdf[range], a, b);
        (
            offset_origin(p, n, self.extent),
            n,
            cosine_direction(n, c, d),
        )
    }
}

impl RowTracer for SurfaceScene {
    fn patch_count(&self) -> usize {
        self.pieces.patch_count()
    }

    fn trace_row_sky(
        &self,
        row: usize,
        rays: u32,
        seed: u64,
        counts: &mut [u32],
        seen: &mut RowRays<'_>,
    ) -> RayTally {
        let s = row_seed(seed, row);
        let mut tally = RayTally::default();
        if self.pieces.of(row).is_empty() {
            tally.escaped += u64::from(rays);
            return tally;
        }
        for k in 0..rays {
            let (origin, normal, dir) = self.ray(row, k, 0, s);
            let (fate, t, landing_normal, albedo) = self.fate_at(origin, dir);
            if let RayFate::Patch(j) = fate {
                counts[j] += 1;
                // The same point and normal `near_landing` takes, for the same bits.
                seen.near
                    .landed(t, origin + dir * t, landing_normal, j, albedo);
            }
            seen.sky.ray(origin, normal, dir, fate == RayFate::Escaped);
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
            let (origin, _, dir) = self.ray(row, k, PROBE_DIMENSION_SET, s);
            self.sees_a_row(origin, dir)
        })
    }

    fn hidden(&self, row: usize, rays: u32, seed: u64) -> bool {
        if self.pieces.of(row).is_empty() || rays == 0 {
            return false;
        }
        let s = row_seed(seed, row);
        let back = (0..rays)
            .filter(|&k| {
                let (origin, _, dir) = self.ray(row, k, PROBE_DIMENSION_SET, s);
                self.fate(origin, dir) == RayFate::BackFace
            })
            .count();
        4 * back >= 3 * rays as usize
    }
}

/// Where a form-factor ray lands ([`SurfaceScene::landing`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Landing {
    /// The hit point, pushed off the surface along `normal` (a shadow ray starts from it).
    pub position: Vec3,
    /// Unit normal of the side the ray met.
    pub normal: Vec3,
    /// The original triangle (index into [`Scene::triangles`]).
    pub triangle: u32,
    /// The transport row owning the surface met.
    pub row: usize,
}

/// Which transport row owns each point of surface: per side of each original triangle, the piece
/// triangles of that side with their rows, grouped by the voxel they lie in. A hit is credited to
/// the piece that contains it, so elements may cut a voxel's surface any way (by connected
/// surface, by sub-cell, by the space each part faces) and the lookup needs to know none of it.
struct Owners {
    /// Per `2 · triangle + side` (side 1: the back), the range of `entries` on that side, sorted
    /// by voxel.
    start: Vec<u32>,
    entries: Vec<Owned>,
    origin: Vec3,
    size: f32,
    dims: [u32; 3],
}

#[derive(Debug, Clone, Copy)]
struct Owned {
    voxel: u64,
    row: u32,
    corners: [Vec3; 3],
}

/// A hit this far outside every piece of its triangle's side (in barycentric units of the
/// nearest piece) meets surface that belongs to no row; closer, it is rounding on a shared edge.
const OUTSIDE: f32 = 1e-3;
/// Sides with more pieces than this are searched in the hit's voxel first.
const SCAN_ALL: usize = 16;
/// How far (in voxels) a hit on surface of no row may lie from a piece of its side that a row
/// owns and still be that row's ([`SurfaceScene::owner`]).
const NEAREST_REACH: f32 = 0.5;

impl Owners {
    fn new(scene: &Scene, rows: &PatchLayout, pieces: &Pieces) -> Owners {
        let origin = Vec3::from(rows.origin);
        let (size, dims) = (rows.voxel_size, rows.dims);
        let slots = scene.triangles.len() * 2;
        let mut tagged: Vec<(usize, Owned)> = Vec::with_capacity(pieces.tris.len());
        for row in 0..pieces.patch_count() {
            for t in pieces.of(row) {
                let Some(tri) = scene.triangles.get(t.triangle as usize) else {
                    continue;
                };
                let back = t.normal.dot(tri.cross()) < 0.0;
                let centroid = (t.corners[0] + t.corners[1] + t.corners[2]) / 3.0;
                let voxel = key(dims, cell(centroid, origin, size, dims));
                tagged.push((
                    2 * t.triangle as usize + usize::from(back),
                    Owned {
                        voxel,
                        row: row as u32,
                        corners: t.corners,
                    },
                ));
            }
        }
        tagged.sort_by_key(|(slot, o)| (*slot, o.voxel));
        let mut start = vec![0u32; slots + 1];
        for (slot, _) in &tagged {
            start[slot + 1] += 1;
        }
        for i in 0..slots {
            start[i + 1] += start[i];
        }
        Owners {
            start,
            entries: tagged.into_iter().map(|(_, o)| o).collect(),
            origin,
            size,
            dims,
        }
    }

    /// The row of the piece of `triangle`'s back (`back`) or front side nearest to `p`, if one
    /// lies within `reach` voxels, and that piece's point nearest to `p`.
    fn nearest_within(
        &self,
        p: Vec3,
        triangle: u32,
        back: bool,
        reach: f32,
    ) -> Option<(u32, Vec3)> {
        let reach = self.size * reach;
        self.side(triangle, back)?
            .iter()
            .filter_map(|o| closest_on_triangle(p, o.corners).map(|q| (o.row, q, p.distance(q))))
            .filter(|&(_, _, d)| d <= reach)
            .min_by(|a, b| a.2.total_cmp(&b.2))
            .map(|(row, q, _)| (row, q))
    }

    /// The pieces of `triangle`'s back (`back`) or front side that rows own.
    fn side(&self, triangle: u32, back: bool) -> Option<&[Owned]> {
        let slot = 2 * triangle as usize + usize::from(back);
        let (lo, hi) = (*self.start.get(slot)?, *self.start.get(slot + 1)?);
        Some(&self.entries[lo as usize..hi as usize])
    }

    /// The row whose piece contains point `p` on `triangle`'s back (`back`) or front side, if
    /// any row's does.
    fn row_containing(&self, p: Vec3, triangle: u32, back: bool) -> Option<u32> {
        let all = self.side(triangle, back)?;
        if all.len() > SCAN_ALL {
            let voxel = key(self.dims, cell(p, self.origin, self.size, self.dims));
            let from = all.partition_point(|o| o.voxel < voxel);
            let to = from + all[from..].partition_point(|o| o.voxel == voxel);
            if let Some((row, d)) = nearest(&all[from..to], p)
                && d >= 0.0
            {
                return Some(row);
            }
        }
        // The hit's voxel held no piece containing it (a point on a voxel boundary, or surface
        // of no row): every piece of the side decides.
        nearest(all, p).and_then(|(row, d)| (d >= -OUTSIDE).then_some(row))
    }
}

/// The row of the piece in `owned` that contains `p` most deeply, with that depth: the smallest
/// barycentric coordinate of `p` in it (negative outside).
fn nearest(owned: &[Owned], p: Vec3) -> Option<(u32, f32)> {
    let mut best: Option<(u32, f32)> = None;
    for o in owned {
        let d = depth(p, o.corners);
        if best.is_none_or(|(_, b)| d > b) {
            best = Some((o.row, d));
        }
    }
    best
}

/// The nearest point to `p` of triangle `[a, b, c]` (Ericson, "Real-Time Collision Detection",
/// 5.1.5); `None` for a triangle with no area.
fn closest_on_triangle(p: Vec3, [a, b, c]: [Vec3; 3]) -> Option<Vec3> {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    if ab.cross(ac).length_squared() <= 0.0 {
        return None;
    }
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return Some(a);
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return Some(b);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return Some(a + ab * (d1 / (d1 - d3)));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return Some(c);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return Some(a + ac * (d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return Some(b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
    }
    let denom = 1.0 / (va + vb + vc);
    Some(a + ab * (vb * denom) + ac * (vc * denom))
}

/// The smallest barycentric coordinate of `p` (projected onto the triangle's plane) in triangle
/// `[a, b, c]`; `-inf` for a triangle with no area.
fn depth(p: Vec3, [a, b, c]: [Vec3; 3]) -> f32 {
    let (v0, v1, v2) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (v0.dot(v0), v0.dot(v1), v1.dot(v1));
    let (d20, d21) = (v2.dot(v0), v2.dot(v1));
    let den = d00 * d11 - d01 * d01;
    if !(den > 0.0 && den.is_finite()) {
        return f32::NEG_INFINITY;
    }
    let v = (d11 * d20 - d01 * d21) / den;
    let w = (d00 * d21 - d01 * d20) / den;
    (1.0 - v - w).min(v).min(w)
}

/// The voxel of a grid that `p` lies in, clamped into the grid.
fn cell(p: Vec3, origin: Vec3, size: f32, dims: [u32; 3]) -> [u32; 3] {
    let f = (p - origin) / size;
    [0, 1, 2].map(|a| (f[a].floor().max(0.0) as u32).min(dims[a].saturating_sub(1)))
}

#[inline]
fn key(dims: [u32; 3], c: [u32; 3]) -> u64 {
    (u64::from(c[2]) * u64::from(dims[1]) + u64::from(c[1])) * u64::from(dims[0]) + u64::from(c[0])
}
