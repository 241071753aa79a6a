//! Patches: the axis-aligned voxel faces that radiosity runs on, and the layout that maps them back
//! onto the original surfaces.
//!
//! A patch is the face of an occupied voxel that looks into empty space and that original geometry
//! faces. The layout (grid origin, voxel size, dimensions, per patch its voxel and face) is everything a
//! client needs to scatter patch irradiance onto its own meshes.

use glam::Vec3;
use serde::{Deserialize, Serialize};

pub use bounce_types::face::Face;

/// An axis-aligned rectangle facing one way: the geometry that form factors are computed on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quad {
    pub face: Face,
    /// Coordinate of the rectangle's plane along `face.axis()`.
    pub plane: f32,
    /// Bounds in the two other axes, in the order `(axis + 1) % 3`, `(axis + 2) % 3`.
    pub lo: [f32; 2],
    pub hi: [f32; 2],
}

impl Quad {
    /// The two in-plane axes, in the order used by `lo` and `hi`.
    pub fn tangent_axes(&self) -> (usize, usize) {
        let a = self.face.axis();
        ((a + 1) % 3, (a + 2) % 3)
    }

    pub fn area(&self) -> f32 {
        (self.hi[0] - self.lo[0]) * (self.hi[1] - self.lo[1])
    }

    pub fn normal(&self) -> Vec3 {
        self.face.normal()
    }

    /// The point at in-plane parameters `(s, t)` in `[0, 1]²`.
    pub fn point(&self, s: f32, t: f32) -> Vec3 {
        let (u, v) = self.tangent_axes();
        let mut p = Vec3::ZERO;
        p[self.face.axis()] = self.plane;
        p[u] = self.lo[0] + s * (self.hi[0] - self.lo[0]);
        p[v] = self.lo[1] + t * (self.hi[1] - self.lo[1]);
        p
    }

    pub fn center(&self) -> Vec3 {
        self.point(0.5, 0.5)
    }

    pub fn aabb_min(&self) -> Vec3 {
        self.point(0.0, 0.0)
    }

    pub fn aabb_max(&self) -> Vec3 {
        self.point(1.0, 1.0)
    }

    /// Distance along the ray to the rectangle, if the ray crosses it at `t > 0`: from its front
    /// side only, or from either side when `two_sided` (occlusion tests need back sides too).
    #[inline]
    pub fn intersect(&self, origin: Vec3, dir: Vec3, two_sided: bool) -> Option<f32> {
        let a = self.face.axis();
        let d = dir[a];
        let facing = d * self.face.sign() < 0.0;
        if d == 0.0 || (!facing && !two_sided) {
            return None;
        }
        let t = (self.plane - origin[a]) / d;
        if t.is_nan() || t <= 0.0 {
            return None;
        }
        let (u, v) = self.tangent_axes();
        let pu = origin[u] + t * dir[u];
        let pv = origin[v] + t * dir[v];
        (pu >= self.lo[0] && pu <= self.hi[0] && pv >= self.lo[1] && pv <= self.hi[1]).then_some(t)
    }
}

/// One patch of a baked scene.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Patch {
    /// Voxel coordinate in the grid.
    pub voxel: [u32; 3],
    pub face: Face,
    /// Area-weighted linear RGB albedo of the original triangles this patch stands for.
    pub albedo: [f32; 3],
    /// Area-weighted centroid of those triangles (where references are evaluated).
    pub centroid: [f32; 3],
    /// Area-weighted unit normal of those triangles.
    pub normal: [f32; 3],
    /// Area of those triangles projected onto the face direction.
    pub source_area: f32,
    /// Area-weighted emitted exitance of those triangles (linear RGB), zero for most patches.
    pub emission: [f32; 3],
}

/// The voxel grid and its patches, in patch index order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PatchLayout {
    /// World position of the grid's minimum corner.
    pub origin: [f32; 3],
    /// Edge length of a voxel, world units.
    pub voxel_size: f32,
    /// Voxel counts along X, Y, Z.
    pub dims: [u32; 3],
    pub patches: Vec<Patch>,
}

impl PatchLayout {
    pub fn len(&self) -> usize {
        self.patches.len()
    }

    pub fn is_empty(&self) -> bool {
        self.patches.is_empty()
    }

    /// Area of a voxel face: every patch's area in voxel-face geometry.
    pub fn patch_area(&self) -> f32 {
        self.voxel_size * self.voxel_size
    }

    /// Each patch's area as its form factors see it: the true area of its surface pieces
    /// (`source_area`) when it stands for them, else the voxel face's. Reciprocity
    /// (`A_i F_ij = A_j F_ji`) holds with these.
    pub fn areas(&self, geometry: Geometry) -> Vec<f32> {
        let surface = geometry == Geometry::Surface;
        self.patches
            .iter()
            .map(|p| {
                if surface && p.source_area > 0.0 {
                    p.source_area
                } else {
                    self.patch_area()
                }
            })
            .collect()
    }

    /// The rectangle of a voxel face in world space.
    pub fn face_quad(&self, voxel: [u32; 3], face: Face) -> Quad {
        let s = self.voxel_size;
        let o = Vec3::from(self.origin);
        let a = face.axis();
        let (u, v) = ((a + 1) % 3, (a + 2) % 3);
        let lo = o + Vec3::new(voxel[0] as f32, voxel[1] as f32, voxel[2] as f32) * s;
        let plane = if face.sign() > 0.0 { lo[a] + s } else { lo[a] };
        Quad {
            face,
            plane,
            lo: [lo[u], lo[v]],
            hi: [lo[u] + s, lo[v] + s],
        }
    }

    pub fn quad(&self, patch: usize) -> Quad {
        let p = &self.patches[patch];
        self.face_quad(p.voxel, p.face)
    }

    pub fn quads(&self) -> Vec<Quad> {
        (0..self.len()).map(|i| self.quad(i)).collect()
    }
}

/// What geometry patches stand for and rays are traced against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Geometry {
    /// A patch is the pieces of original triangles in its voxel whose normal faces its direction
    /// most; rays run between those pieces against the original triangles (docs/design.md §2).
    #[default]
    Surface,
    /// The thesis' method: a patch is the exposed voxel face itself, and rays walk the voxel
    /// occupancy. Kept as the baseline the surface method is measured against.
    VoxelFaces,
}

impl Geometry {
    /// What files from before the choice existed were baked with.
    pub fn voxel_faces() -> Geometry {
        Geometry::VoxelFaces
    }
}

impl std::str::FromStr for Geometry {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "surface" => Ok(Geometry::Surface),
            "voxel-faces" => Ok(Geometry::VoxelFaces),
            _ => Err(format!(
                "geometry must be 'surface' or 'voxel-faces', got '{s}'"
            )),
        }
    }
}

impl std::fmt::Display for Geometry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Geometry::Surface => "surface",
            Geometry::VoxelFaces => "voxel-faces",
        })
    }
}

/// One triangle of a patch's surface: a fan triangle of a clipped piece of an original triangle,
/// with the unit normal of the side the patch stands for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PieceTri {
    pub corners: [Vec3; 3],
    pub normal: Vec3,
    pub area: f32,
    /// The original triangle (index into [`crate::scene::Scene::triangles`]).
    pub triangle: u32,
}

/// Per patch, the triangles of real surface it stands for (compressed rows: patch `i` owns
/// `tris[start[i]..start[i + 1]]`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Pieces {
    pub start: Vec<u32>,
    pub tris: Vec<PieceTri>,
}

impl Pieces {
    pub fn of(&self, patch: usize) -> &[PieceTri] {
        &self.tris[self.start[patch] as usize..self.start[patch + 1] as usize]
    }

    pub fn patch_count(&self) -> usize {
        self.start.len().saturating_sub(1)
    }

    pub(crate) fn retain(&mut self, keep: impl Fn(usize) -> bool) {
        let mut out = Pieces {
            start: vec![0],
            tris: Vec::with_capacity(self.tris.len()),
        };
        for i in 0..self.patch_count() {
            if keep(i) {
                out.tris.extend_from_slice(self.of(i));
                out.start.push(out.tris.len() as u32);
            }
        }
        *self = out;
    }

    pub(crate) fn permuted(&self, perm: &[usize]) -> Pieces {
        let mut out = Pieces {
            start: vec![0],
            tris: Vec::with_capacity(self.tris.len()),
        };
        for &i in perm {
            out.tris.extend_from_slice(self.of(i));
            out.start.push(out.tris.len() as u32);
        }
        out
    }
}
