//! What a ray hits: the closest quad among the patches and occluders, from either of two tracers.
//!
//! - [`Tracer::Bvh`]: an `obvhs` BVH over the quads. Works for any set of quads (the analytic
//!   tests use free rectangles), but in a box-shaped room every wall-sized flat node overlaps
//!   nearly every ray, so it culls poorly.
//! - [`Tracer::Grid`]: a 3-D DDA (Amanatides & Woo) through the voxel grid the patches came from.
//!   Occupied voxels are opaque cubes, so the first occupied voxel a ray enters, and the face it
//!   enters by, is the exact answer for voxel geometry; the cost is the number of empty voxels
//!   crossed. Needs the voxelisation, and a grid small enough for a dense occupancy bitset.
//!
//! Besides where a ray ends ([`RayScene::trace`], for form factors), both answer whether a
//! segment is blocked ([`RayScene::occluded`], for the shadow rays of direct light).
//!
//! Both give the same fate for a ray except on exact edge and corner hits, where they may pick
//! different (equally valid) neighbours. `bounce bench rays` compares their speed and results.

use std::collections::HashMap;

use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::ray::{Ray, RayHit};
use obvhs::{Boundable, BvhBuildParams};
use serde::{Deserialize, Serialize};

use crate::patch::{Face, PatchLayout, Quad};

/// Which ray tracer a bake uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Tracer {
    Bvh,
    Grid,
}

impl std::str::FromStr for Tracer {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "bvh" => Ok(Tracer::Bvh),
            "grid" => Ok(Tracer::Grid),
            _ => Err(format!("tracer must be 'grid' or 'bvh', got '{s}'")),
        }
    }
}

impl std::fmt::Display for Tracer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Tracer::Bvh => "bvh",
            Tracer::Grid => "grid",
        })
    }
}

/// The most voxels the grid tracer accepts (a 32 MiB occupancy bitset); larger grids use the
/// BVH.
pub const MAX_GRID_TRACER_CELLS: u64 = 1 << 28;

/// Where a ray ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RayFate {
    /// On the front of this patch: it carries energy there.
    Patch(usize),
    /// Out of the scene (an open scene, or a level open to the sky).
    Escaped,
    /// On an exposed voxel face that is not a patch (no geometry faces that way).
    Occluder,
    /// On the back of a patch.
    BackFace,
}

/// How many rays ended where: the part of each row sum below 1, explained.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RayTally {
    pub patch: u64,
    pub escaped: u64,
    pub occluder: u64,
    pub back_face: u64,
}

impl std::ops::Add for RayTally {
    type Output = RayTally;
    fn add(self, o: RayTally) -> RayTally {
        RayTally {
            patch: self.patch + o.patch,
            escaped: self.escaped + o.escaped,
            occluder: self.occluder + o.occluder,
            back_face: self.back_face + o.back_face,
        }
    }
}

impl RayTally {
    pub fn count(&mut self, fate: RayFate) {
        match fate {
            RayFate::Patch(_) => self.patch += 1,
            RayFate::Escaped => self.escaped += 1,
            RayFate::Occluder => self.occluder += 1,
            RayFate::BackFace => self.back_face += 1,
        }
    }

    pub fn total(&self) -> u64 {
        self.patch + self.escaped + self.occluder + self.back_face
    }
}

/// Everything a ray can hit. Patches are indices `0..patch_count()`.
pub struct RayScene {
    patches: Vec<Quad>,
    backend: Backend,
}

enum Backend {
    Bvh {
        /// Patches first, then occluders.
        quads: Vec<Quad>,
        bvh: Bvh2,
    },
    Grid(VoxelGrid),
}

struct QuadBound<'a>(&'a Quad);

impl Boundable for QuadBound<'_> {
    fn aabb(&self) -> Aabb {
        Aabb::new(
            Vec3A::from(self.0.aabb_min()),
            Vec3A::from(self.0.aabb_max()),
        )
    }
}

impl RayScene {
    /// A BVH over free quads.
    pub fn new(patches: &[Quad], occluders: &[Quad]) -> RayScene {
        let quads: Vec<Quad> = patches.iter().chain(occluders).copied().collect();
        let bounds: Vec<QuadBound> = quads.iter().map(QuadBound).collect();
        // obvhs builds single-threaded without its `parallel` feature, so the tree (and with it
        // the order ties are broken in) does not depend on the thread count.
        let bvh = obvhs::bvh2::builder::build_bvh2(
            &bounds,
            BvhBuildParams::medium_build(),
            &mut std::time::Duration::default(),
        );
        RayScene {
            patches: patches.to_vec(),
            backend: Backend::Bvh { quads, bvh },
        }
    }

    /// The scene of a voxelisation, traced by `tracer`. `occupied` are the grid's occupied voxels
    /// (linear indices) and `occluders` the exposed faces that are not patches. The grid tracer
    /// falls back to the BVH for grids too large for its bitset; [`RayScene::tracer`] says which
    /// was used.
    pub fn voxels(
        layout: &PatchLayout,
        occupied: &[u64],
        occluders: &[Quad],
        tracer: Tracer,
    ) -> RayScene {
        let cells = layout.dims.iter().map(|&d| d as u64).product::<u64>();
        if tracer == Tracer::Bvh || cells > MAX_GRID_TRACER_CELLS {
            return RayScene::new(&layout.quads(), occluders);
        }
        RayScene {
            patches: layout.quads(),
            backend: Backend::Grid(VoxelGrid::new(layout, occupied)),
        }
    }

    pub fn tracer(&self) -> Tracer {
        match self.backend {
            Backend::Bvh { .. } => Tracer::Bvh,
            Backend::Grid(_) => Tracer::Grid,
        }
    }

    pub fn patch_count(&self) -> usize {
        self.patches.len()
    }

    pub fn patch(&self, i: usize) -> &Quad {
        &self.patches[i]
    }

    /// Where a ray from `origin` (on patch `from`, or anywhere for the BVH) ends.
    #[inline]
    pub fn trace(&self, from: usize, origin: Vec3, dir: Vec3) -> RayFate {
        match &self.backend {
            Backend::Bvh { quads, bvh } => trace_bvh(quads, self.patches.len(), bvh, origin, dir),
            Backend::Grid(grid) => grid.trace(&self.patches[from], origin, dir),
        }
    }
}

impl RayScene {
    /// Whether anything blocks the ray from `origin` (on patch `from`, or anywhere for the BVH)
    /// along the unit vector `dir` before distance `max_t`; `f32::INFINITY` asks whether the ray
    /// leaves the scene. Every quad blocks from either side, patches and occluders alike: this is
    /// the shadow-ray query of direct lighting.
    #[inline]
    pub fn occluded(&self, from: usize, origin: Vec3, dir: Vec3, max_t: f32) -> bool {
        match &self.backend {
            Backend::Bvh { quads, bvh } => occluded_bvh(quads, bvh, origin, dir, max_t),
            Backend::Grid(grid) => grid.occluded(&self.patches[from], origin, dir, max_t),
        }
    }
}

/// The voxel a walk from a point on `quad` starts in: the one in front of the face. The origin
/// lies on the patch's plane, a grid plane, inside the patch's face; taking the cell from the
/// quad rather than from the origin keeps rounding (an origin on the face's far edge) out of it.
/// Shared with the GPU shadow walk, which takes its start cells from here.
pub fn start_cell(quad: &Quad, origin: [f32; 3], size: f32) -> [i32; 3] {
    let a = quad.face.axis();
    let index = |coord: f32, ax: usize| ((coord - origin[ax]) / size).round() as i32;
    let mut cell = [0i32; 3];
    let plane = index(quad.plane, a);
    cell[a] = if quad.face.sign() > 0.0 {
        plane
    } else {
        plane - 1
    };
    let (u, v) = quad.tangent_axes();
    cell[u] = index(quad.lo[0], u);
    cell[v] = index(quad.lo[1], v);
    cell
}

fn occluded_bvh(quads: &[Quad], bvh: &Bvh2, origin: Vec3, dir: Vec3, max_t: f32) -> bool {
    if quads.is_empty() || max_t.is_nan() || max_t <= 0.0 {
        return false;
    }
    let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), 0.0, max_t);
    // The origin's own patch (and coplanar neighbours) meet the ray at t = 0, which `intersect`
    // does not count; any other crossing before `max_t` is a blocker, and the first one found
    // ends the traversal.
    !bvh.ray_traverse_miss(ray, |_, prim| {
        let q = &quads[bvh.primitive_indices[prim] as usize];
        q.intersect(origin, dir, true).unwrap_or(f32::INFINITY)
    })
}

fn trace_bvh(quads: &[Quad], patches: usize, bvh: &Bvh2, origin: Vec3, dir: Vec3) -> RayFate {
    if quads.is_empty() {
        return RayFate::Escaped;
    }
    let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), 0.0, f32::INFINITY);
    let mut hit = RayHit::none();
    let found = bvh.ray_traverse(ray, &mut hit, |_, prim| {
        let q = &quads[bvh.primitive_indices[prim] as usize];
        q.intersect(origin, dir, true).unwrap_or(f32::INFINITY)
    });
    if !found {
        return RayFate::Escaped;
    }
    let k = bvh.primitive_indices[hit.primitive_id as usize] as usize;
    if k >= patches {
        RayFate::Occluder
    } else if dir.dot(quads[k].normal()) < 0.0 {
        RayFate::Patch(k)
    } else {
        RayFate::BackFace
    }
}

/// Dense occupancy of the voxel grid plus the patch on each patch face.
struct VoxelGrid {
    origin: Vec3,
    size: f32,
    dims: [i32; 3],
    /// One bit per voxel, x fastest.
    occupied: Vec<u64>,
    /// `voxel index · 6 + face code` → patch.
    faces: HashMap<u64, u32>,
}

impl VoxelGrid {
    fn new(layout: &PatchLayout, occupied: &[u64]) -> VoxelGrid {
        let dims = layout.dims.map(|d| d as i32);
        let cells = layout.dims.iter().map(|&d| d as u64).product::<u64>();
        let mut bits = vec![0u64; cells.div_ceil(64) as usize];
        for &k in occupied {
            if k < cells {
                bits[(k / 64) as usize] |= 1 << (k % 64);
            }
        }
        let faces = layout
            .patches
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let k = linear(layout.dims.map(|d| d as i32), p.voxel.map(|v| v as i32));
                (k * 6 + p.face.code() as u64, i as u32)
            })
            .collect();
        VoxelGrid {
            origin: Vec3::from(layout.origin),
            size: layout.voxel_size,
            dims,
            occupied: bits,
            faces,
        }
    }

    #[inline]
    fn is_occupied(&self, c: [i32; 3]) -> bool {
        let k = linear(self.dims, c);
        self.occupied[(k / 64) as usize] >> (k % 64) & 1 == 1
    }

    /// Walk from the empty voxel in front of `quad` until an occupied voxel or the grid's edge.
    fn trace(&self, quad: &Quad, origin: Vec3, dir: Vec3) -> RayFate {
        match self.walk(quad, origin, dir, f32::INFINITY) {
            Walk::Escaped | Walk::Reached => RayFate::Escaped,
            Walk::StartOccupied => RayFate::Occluder,
            Walk::Entered { cell, face } => {
                let key = linear(self.dims, cell) * 6 + face.code() as u64;
                match self.faces.get(&key) {
                    Some(&p) => RayFate::Patch(p as usize),
                    None => RayFate::Occluder,
                }
            }
        }
    }

    /// Whether the walk meets an occupied voxel before distance `max_t` (`dir` is a unit
    /// vector, so distances along the ray are world lengths).
    fn occluded(&self, quad: &Quad, origin: Vec3, dir: Vec3, max_t: f32) -> bool {
        match self.walk(quad, origin, dir, max_t) {
            Walk::Escaped | Walk::Reached => false,
            Walk::StartOccupied | Walk::Entered { .. } => true,
        }
    }

    /// The DDA shared by [`VoxelGrid::trace`] and [`VoxelGrid::occluded`]: stops at the first
    /// occupied voxel entered before `max_t`, at the grid's edge, or once the next voxel
    /// boundary lies at or beyond `max_t`.
    fn walk(&self, quad: &Quad, origin: Vec3, dir: Vec3, max_t: f32) -> Walk {
        let mut cell = start_cell(quad, self.origin.to_array(), self.size);

        let mut step = [0i32; 3];
        let mut t_max = [f32::INFINITY; 3];
        let mut t_delta = [f32::INFINITY; 3];
        for ax in 0..3 {
            let d = dir[ax];
            if d > 0.0 {
                step[ax] = 1;
                let boundary = self.origin[ax] + (cell[ax] + 1) as f32 * self.size;
                t_max[ax] = (boundary - origin[ax]) / d;
                t_delta[ax] = self.size / d;
            } else if d < 0.0 {
                step[ax] = -1;
                let boundary = self.origin[ax] + cell[ax] as f32 * self.size;
                t_max[ax] = (boundary - origin[ax]) / d;
                t_delta[ax] = -self.size / d;
            }
        }
        if cell.iter().zip(&self.dims).any(|(&c, &d)| c < 0 || c >= d) {
            return Walk::Escaped;
        }
        if self.is_occupied(cell) {
            // Only for a start cell that is not empty, which a layout from the voxeliser
            // never has (patches face empty voxels).
            return Walk::StartOccupied;
        }
        loop {
            let ax = if t_max[0] < t_max[1] {
                if t_max[0] < t_max[2] { 0 } else { 2 }
            } else if t_max[1] < t_max[2] {
                1
            } else {
                2
            };
            // The ray enters the next voxel at `t_max[ax]`: the end of the segment, if that
            // is not before `max_t` (infinite for a ray that never leaves the voxel).
            if t_max[ax] >= max_t || !t_max[ax].is_finite() {
                return Walk::Reached;
            }
            cell[ax] += step[ax];
            t_max[ax] += t_delta[ax];
            if cell[ax] < 0 || cell[ax] >= self.dims[ax] {
                return Walk::Escaped;
            }
            if self.is_occupied(cell) {
                // Entered through the face looking back along the step.
                let face = Face::from_axis_sign(ax, step[ax] < 0);
                return Walk::Entered { cell, face };
            }
        }
    }
}

/// How a grid walk ended.
enum Walk {
    /// Left the grid.
    Escaped,
    /// Got to the segment's end without meeting an occupied voxel.
    Reached,
    /// Started in an occupied voxel.
    StartOccupied,
    /// Entered the occupied voxel `cell` through its face `face`.
    Entered { cell: [i32; 3], face: Face },
}

#[inline]
fn linear(dims: [i32; 3], c: [i32; 3]) -> u64 {
    (c[0] as u64) + dims[0] as u64 * (c[1] as u64 + dims[1] as u64 * c[2] as u64)
}
