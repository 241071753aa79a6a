//! Voxel simplification: a scene's triangles become axis-aligned voxel-face patches.
//!
//! Every triangle is clipped exactly against the grid planes, so each piece lies in one voxel and
//! areas are conserved. A voxel is occupied when any piece lands in it. A face of an occupied voxel
//! becomes a patch when the neighbouring voxel is empty and original geometry in the voxel faces
//! that way (its area projected on the face direction is not negligible). The remaining exposed
//! faces become black occluders: the voxel solid still blocks light there, but nothing reflects
//! from it, which is what a one-sided wall seen from behind does.

use std::collections::HashMap;

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use thiserror::Error;

use crate::element::{Elements, Refinement, sub_cell};
use crate::patch::{Face, Patch, PatchLayout, Quad};
// What a patch stands for is the patch's vocabulary; these paths stay for the voxeliser's users.
pub use crate::patch::{Geometry, PieceTri, Pieces};
use crate::scene::{Scene, Triangle};
use crate::space::Spaces;
use crate::trimesh::TriMesh;

/// The most patches a bake accepts: the dense transport grows as n², and at this size a
/// three-channel f32 matrix is already 4.8 GB.
pub const MAX_PATCHES: u32 = 20_000;
/// The most candidate patches one voxel size may make before the ones that see nothing are
/// dropped: each is probed with rays, so this bounds the work of every step of the voxel-size
/// search. Real scenes drop a few percent; a stray sliver triangle across the whole scene made
/// 250,000 candidates a step, and minutes of probing (issue 19).
pub const MAX_CANDIDATES: usize = 3 * MAX_PATCHES as usize;

/// The most voxels a grid may span (about 8 GB of nothing if it were ever dense; we keep it
/// sparse, but the count still bounds the clipping work).
const MAX_GRID_CELLS: u64 = 1 << 34;

/// Pieces whose projected area on a face is below this share of the face do not make a patch:
/// slivers of a neighbouring surface would otherwise become patches with meaningless albedo.
const MIN_FACE_COVERAGE: f64 = 1e-3;

/// Clipped pieces smaller than this share of a voxel face are rounding noise, not geometry.
const MIN_PIECE_AREA: f64 = 1e-6;
/// How much finer elements are cut in voxels where surfaces meet (per axis).
pub const REFINE_FACTOR: u32 = 3;
/// The most transport elements refinement may make, as a multiple of the patches.
pub const REFINE_BUDGET: f64 = 1.5;

/// How the voxel size is chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Resolution {
    /// Search for a voxel size whose patch count lands near this.
    TargetPatches(u32),
    /// Use this voxel edge length (world units).
    VoxelSize(f32),
}

#[derive(Debug, Error)]
pub enum VoxelError {
    #[error("the scene has no triangles to voxelise")]
    EmptyScene,
    #[error(
        "patch count {0} is out of range: use 1 to {MAX_PATCHES} patches (the dense transport grows as the square of the count)"
    )]
    PatchCount(u32),
    #[error("voxel size {0} is not a positive finite length")]
    VoxelSize(f32),
    #[error(
        "voxel size {size} is too small for a scene of extent {extent:?}: it would need {cells} voxels; \
         use a larger --voxel-size or --patches"
    )]
    GridTooLarge {
        size: f32,
        extent: [f32; 3],
        cells: u64,
    },
    #[error(
        "voxel size {size} gives about {patches} patches, more than the {MAX_PATCHES} a bake \
         accepts; use a larger --voxel-size or --patches"
    )]
    TooManyPatches { size: f32, patches: usize },
    #[error(
        "voxel size {size} makes {candidates} candidate patches, more than the {max} a bake probes \
         (most would see nothing: usually sliver or stray geometry across the scene); use a larger \
         --voxel-size or fewer --patches"
    )]
    TooManyCandidates {
        size: f32,
        candidates: usize,
        max: usize,
    },
    #[error(
        "all {candidates} candidate patches at voxel size {size} were dropped (none sees another)"
    )]
    AllDropped { candidates: usize, size: f32 },
    #[error("no patches: no surface of the scene faces open space at voxel size {size}")]
    NoPatches { size: f32 },
    #[error(transparent)]
    AbsurdExtent(#[from] crate::extent::AbsurdExtent),
}

/// The result of voxelisation: the patch layout plus what the form-factor rays need.
#[derive(Debug, Clone)]
pub struct Voxelization {
    pub layout: PatchLayout,
    /// Exposed voxel faces that are not patches: they block rays and reflect nothing.
    pub occluders: Vec<Quad>,
    pub occupied_voxels: usize,
    /// Linear indices (`x + dims.x · (y + dims.y · z)`) of the occupied voxels, ascending.
    pub occupied: Vec<u64>,
    /// Candidate patches dropped by a [`Refine`] step (e.g. because they see nothing).
    pub dropped_patches: usize,
    /// Elements dropped because they see nothing (those of dropped patches included).
    pub dropped_elements: usize,
    /// Surface geometry ([`Geometry::Surface`]): per transport row (element), the pieces of
    /// original triangles it stands for. `None` for voxel faces.
    pub pieces: Option<Pieces>,
    /// Surface geometry: the elements the transport runs on ([`crate::element`]). `None` for
    /// voxel faces, whose patches are their own transport rows.
    pub elements: Option<Elements>,
    /// Where elements are cut finer than their voxel.
    pub refinement: Refinement,
    /// Surface area (world units²) that belongs to no patch: pieces of patches that were dropped,
    /// and clipping slivers too small to be geometry. Always 0 for voxel faces, whose patches
    /// stand for projected rather than real area.
    pub unassigned_area: f64,
    /// Surface area of the scene's triangles (both sides of double-sided ones counted once).
    pub total_area: f64,
}

impl Voxelization {
    /// What the transport's rows and columns are: the elements (surface geometry) or the
    /// patches themselves (voxel faces).
    pub fn transport_layout(&self) -> &PatchLayout {
        self.elements.as_ref().map_or(&self.layout, |e| &e.layout)
    }

    /// Drop the transport rows marked in `drop` ([`Voxelization::transport_layout`]'s order).
    /// Voxel faces stay as occluders, so they still block light, but carry no row or column of
    /// the transport. Surface elements' triangles still block rays; only their area now belongs
    /// to no element. A patch goes when all its elements have gone.
    ///
    /// A dropped element marked in `hidden` also leaves its patch's area. A patch's indirect
    /// light is its elements' over its whole area ([`crate::element::Elements::restrict`]),
    /// which counts surface that sees nothing as unlit, as it is. Surface no viewer sees (inside
    /// a closed single-sided solid, in the seam of a cushion) is no part of what a patch's
    /// pixels show, and the reference leaves such points out: counted as unlit, it dimmed the
    /// visible rest of its patch (the sheen chair: one patch's only element covered 5% of its
    /// area, and read a twentieth of its light).
    pub fn drop_patches(&mut self, drop: &[bool], hidden: &[bool]) {
        let dropped = |i: usize| drop.get(i).copied().unwrap_or(false);
        if let Some(elements) = &mut self.elements {
            let mut kept = Vec::with_capacity(elements.len());
            let mut kept_patch = Vec::with_capacity(elements.len());
            let mut has = vec![false; self.layout.len()];
            let mut kept_area = vec![0.0f64; self.layout.len()];
            let mut hidden_area = vec![0.0f64; self.layout.len()];
            for (i, (rec, &p)) in elements
                .layout
                .patches
                .iter()
                .zip(&elements.patch)
                .enumerate()
            {
                if dropped(i) {
                    self.unassigned_area += f64::from(rec.source_area);
                    self.dropped_elements += 1;
                    if hidden.get(i).copied().unwrap_or(false) {
                        hidden_area[p as usize] += f64::from(rec.source_area);
                    }
                } else {
                    kept.push(*rec);
                    kept_patch.push(p);
                    has[p as usize] = true;
                    kept_area[p as usize] += f64::from(rec.source_area);
                }
            }
            // Never below what the kept elements cover (rounding), which `Elements::check`
            // holds a patch to.
            for ((p, hidden), kept) in self
                .layout
                .patches
                .iter_mut()
                .zip(&hidden_area)
                .zip(&kept_area)
            {
                if *hidden > 0.0 {
                    p.source_area = (f64::from(p.source_area) - hidden).max(*kept) as f32;
                }
            }
            // Renumber the patches that keep an element.
            let mut renumber = vec![0u32; self.layout.len()];
            let mut patches = Vec::with_capacity(self.layout.len());
            for (i, p) in self.layout.patches.iter().enumerate() {
                if has[i] {
                    renumber[i] = patches.len() as u32;
                    patches.push(*p);
                } else {
                    self.dropped_patches += 1;
                }
            }
            elements.layout.patches = kept;
            elements.patch = kept_patch.iter().map(|&p| renumber[p as usize]).collect();
            self.layout.patches = patches;
        } else {
            let mut kept = Vec::with_capacity(self.layout.patches.len());
            for (i, p) in self.layout.patches.iter().enumerate() {
                if dropped(i) {
                    self.occluders.push(self.layout.face_quad(p.voxel, p.face));
                    self.dropped_patches += 1;
                } else {
                    kept.push(*p);
                }
            }
            self.layout.patches = kept;
        }
        if let Some(pieces) = &mut self.pieces {
            pieces.retain(|i| !dropped(i));
        }
    }

    /// Renumber the patches in `order`; each patch's elements (and their pieces) follow it.
    pub fn reorder(&mut self, order: PatchOrder) {
        let perm = self.layout.order_of(order);
        self.layout.patches = perm.iter().map(|&i| self.layout.patches[i]).collect();
        let Some(elements) = &mut self.elements else {
            if let Some(pieces) = &mut self.pieces {
                *pieces = pieces.permuted(&perm);
            }
            return;
        };
        let mut first = vec![0usize; perm.len() + 1];
        for &p in &elements.patch {
            first[p as usize + 1] += 1;
        }
        for i in 0..perm.len() {
            first[i + 1] += first[i];
        }
        let rows: Vec<usize> = perm.iter().flat_map(|&p| first[p]..first[p + 1]).collect();
        let mut patch = Vec::with_capacity(rows.len());
        for (new, &p) in perm.iter().enumerate() {
            patch.extend(std::iter::repeat_n(new as u32, first[p + 1] - first[p]));
        }
        elements.layout.patches = rows.iter().map(|&r| elements.layout.patches[r]).collect();
        elements.patch = patch;
        if let Some(pieces) = &mut self.pieces {
            *pieces = pieces.permuted(&rows);
        }
    }
}

pub use bounce_types::face::dominant_face;

/// The order patches are numbered in, which is the order of the transport's rows and columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PatchOrder {
    /// Voxel scan order: x fastest, then y, then z; faces in code order within a voxel.
    Scan,
    /// Z-order (Morton) of the voxel coordinates: nearby patches get nearby indices along all
    /// three axes, so nearby rows and columns of `T` tend to be similar (the thesis' reordering,
    /// for free at bake time).
    Morton,
}

impl std::str::FromStr for PatchOrder {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "scan" => Ok(PatchOrder::Scan),
            "morton" => Ok(PatchOrder::Morton),
            _ => Err(format!("patch order must be 'scan' or 'morton', got '{s}'")),
        }
    }
}

impl std::fmt::Display for PatchOrder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            PatchOrder::Scan => "scan",
            PatchOrder::Morton => "morton",
        })
    }
}

/// Spread the low 21 bits of `v` to every third bit.
fn spread3(v: u32) -> u64 {
    let mut x = u64::from(v) & 0x1f_ffff;
    x = (x | x << 32) & 0x1f_0000_0000_ffff;
    x = (x | x << 16) & 0x1f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// Morton code of a voxel (grids up to 2^21 voxels a side).
pub fn morton(voxel: [u32; 3]) -> u64 {
    spread3(voxel[0]) | spread3(voxel[1]) << 1 | spread3(voxel[2]) << 2
}

impl PatchLayout {
    /// Renumber the patches in `order`. Ties (the faces of one voxel) keep face-code order.
    pub fn reorder(&mut self, order: PatchOrder) {
        let perm = self.order_of(order);
        self.patches = perm.iter().map(|&i| self.patches[i]).collect();
    }

    /// The patch indices in `order`: entry `k` is the patch that becomes patch `k`.
    pub fn order_of(&self, order: PatchOrder) -> Vec<usize> {
        let mut perm: Vec<usize> = (0..self.patches.len()).collect();
        let p = &self.patches;
        if order == PatchOrder::Morton {
            perm.sort_by_key(|&i| (morton(p[i].voxel), p[i].face.code()));
        } else {
            let dims = self.dims.map(u64::from);
            perm.sort_by_key(|&i| {
                let v = p[i].voxel.map(u64::from);
                ((v[2] * dims[1] + v[1]) * dims[0] + v[0], p[i].face.code())
            });
        }
        perm
    }
}

/// A step applied to every candidate voxelisation before its patches are counted, so that the
/// voxel-size search aims at the patches that will really be used.
pub type Refine<'a> = &'a dyn Fn(Voxelization) -> Voxelization;

/// Per voxel, per face direction: sums over the clipped pieces weighted by the piece's area
/// projected on that direction.
#[derive(Debug, Clone, Copy, Default)]
struct FaceAccum {
    weight: f64,
    albedo: DVec3,
    emission: DVec3,
    centroid: DVec3,
    normal: DVec3,
}

impl FaceAccum {
    fn add(&mut self, tri: &Triangle, area: f64, centroid: DVec3, normal: DVec3) {
        self.weight += area;
        self.albedo += tri.albedo.as_dvec3() * area;
        self.emission += tri.emission.as_dvec3() * area;
        self.centroid += centroid * area;
        self.normal += normal * area;
    }

    fn merge(&mut self, o: &FaceAccum) {
        self.weight += o.weight;
        self.albedo += o.albedo;
        self.emission += o.emission;
        self.centroid += o.centroid;
        self.normal += o.normal;
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct VoxelAccum {
    faces: [FaceAccum; 6],
}

/// Voxelise `scene` at the requested resolution.
pub fn voxelize(scene: &Scene, resolution: Resolution) -> Result<Voxelization, VoxelError> {
    voxelize_refined(scene, resolution, &|v| v)
}

/// Voxelise `scene` into voxel-face patches, applying `refine` to every candidate before its
/// patches are counted.
pub fn voxelize_refined(
    scene: &Scene,
    resolution: Resolution,
    refine: Refine<'_>,
) -> Result<Voxelization, VoxelError> {
    simplify_refined(scene, resolution, Geometry::VoxelFaces, refine)
}

/// Cluster `scene` into surface patches at the requested resolution.
pub fn cluster(scene: &Scene, resolution: Resolution) -> Result<Voxelization, VoxelError> {
    simplify_refined(scene, resolution, Geometry::Surface, &|v| v)
}

/// Simplify `scene` into patches of `geometry`, applying `refine` to every candidate before its
/// patches are counted.
pub fn simplify_refined(
    scene: &Scene,
    resolution: Resolution,
    geometry: Geometry,
    refine: Refine<'_>,
) -> Result<Voxelization, VoxelError> {
    crate::extent::check(scene)?;
    // The search counts patches, which the spaces surfaces face do not change: it clusters
    // without them, and only the chosen size is clustered again with them.
    let (count_at, final_at): (At, At) = match geometry {
        Geometry::Surface => (cluster_patches_at, cluster_at),
        Geometry::VoxelFaces => (voxelize_at, voxelize_at),
    };
    match resolution {
        Resolution::VoxelSize(size) => {
            if !(size.is_finite() && size > 0.0) {
                return Err(VoxelError::VoxelSize(size));
            }
            accepted(refine(probeable(final_at(scene, size)?)?))
        }
        Resolution::TargetPatches(n) => {
            if n == 0 || n > MAX_PATCHES {
                return Err(VoxelError::PatchCount(n));
            }
            let found = search_voxel_size(scene, n, count_at, refine)?;
            if geometry == Geometry::VoxelFaces {
                return accepted(found);
            }
            // Should the elements by space pass the most rows a bake accepts, the elements
            // without them (which the search kept within it) stand.
            let spaced = refine(probeable(final_at(scene, found.layout.voxel_size)?)?);
            if spaced.transport_layout().len() > MAX_PATCHES as usize {
                tracing::warn!(
                    rows = spaced.transport_layout().len(),
                    max = MAX_PATCHES,
                    "elements by the space they face would pass the most rows a bake accepts: \
                     elements by surface alone"
                );
                return accepted(found);
            }
            accepted(spaced)
        }
    }
}

/// `v` if a bake can use it: some patch is left, and the transport's rows (the elements: they
/// are what must fit) are within [`MAX_PATCHES`].
fn accepted(v: Voxelization) -> Result<Voxelization, VoxelError> {
    let size = v.layout.voxel_size;
    if v.layout.is_empty() {
        return Err(VoxelError::AllDropped {
            candidates: v.dropped_patches,
            size,
        });
    }
    if v.transport_layout().len() > MAX_PATCHES as usize {
        return Err(VoxelError::TooManyPatches {
            size,
            patches: v.transport_layout().len(),
        });
    }
    Ok(v)
}

/// `v` if its candidate patches are few enough to probe ([`MAX_CANDIDATES`]).
fn probeable(v: Voxelization) -> Result<Voxelization, VoxelError> {
    if v.layout.len() > MAX_CANDIDATES {
        return Err(VoxelError::TooManyCandidates {
            size: v.layout.voxel_size,
            candidates: v.layout.len(),
            max: MAX_CANDIDATES,
        });
    }
    Ok(v)
}

/// Simplification at one voxel size.
type At = fn(&Scene, f32) -> Result<Voxelization, VoxelError>;

/// Patch count falls roughly as 1/size², so the first steps scale the size by
/// `sqrt(count / target)`. The count is not monotonic (grid alignment; surfaces that merge into
/// one voxel layer at coarse sizes and separate at finer ones), so every result also narrows a
/// bracket `[too fine, too coarse]`, and a step that would leave the bracket bisects it in log
/// space instead. The closest count seen wins.
fn search_voxel_size(
    scene: &Scene,
    target: u32,
    at: At,
    refine: Refine<'_>,
) -> Result<Voxelization, VoxelError> {
    let area = scene.total_area();
    if scene.triangles.is_empty() || area <= 0.0 {
        return Err(VoxelError::EmptyScene);
    }
    // Both sides of a closed surface rarely become patches; half the surface area is a fair start.
    let mut size = ((area * 0.5) / target as f64).sqrt() as f32;
    let (lo, hi) = scene.bounds().ok_or(VoxelError::EmptyScene)?;
    let extent = (hi - lo).max_element().max(f32::MIN_POSITIVE);
    size = size.clamp(extent * 1e-4, extent);
    // Sizes known to give too many patches (or too big a grid) and too few (or none).
    let mut too_fine = 0.0f32;
    let mut too_coarse = f32::INFINITY;
    let mut best: Option<Voxelization> = None;
    let mut best_err = f64::INFINITY;
    let mut all_dropped = None;
    let mut too_many = None;
    for _ in 0..16 {
        let wanted = match at(scene, size).and_then(probeable).map(refine) {
            Err(VoxelError::GridTooLarge { .. } | VoxelError::TooManyPatches { .. }) => {
                too_fine = too_fine.max(size);
                size * 2.0
            }
            Err(e @ VoxelError::TooManyCandidates { .. }) => {
                too_fine = too_fine.max(size);
                too_many = Some(e);
                size * 2.0
            }
            Err(e) => return Err(e),
            Ok(v) if v.layout.is_empty() => {
                // Every candidate was dropped (nothing sees anything); finer voxels may
                // separate surfaces that one voxel layer merged.
                all_dropped = Some((v.dropped_patches, size));
                too_coarse = too_coarse.min(size);
                size * 0.5
            }
            Ok(v) => {
                let count = v.layout.len() as f64;
                let err = (count / target as f64).ln().abs();
                if count > target as f64 {
                    too_fine = too_fine.max(size);
                } else {
                    too_coarse = too_coarse.min(size);
                }
                let next = size * (count / target as f64).sqrt() as f32;
                if err < best_err && v.transport_layout().len() <= MAX_PATCHES as usize {
                    best_err = err;
                    best = Some(v);
                }
                if err < 0.02 {
                    break;
                }
                next
            }
        };
        let inside = wanted > too_fine && wanted < too_coarse;
        size = if inside {
            wanted
        } else if too_fine > 0.0 && too_coarse.is_finite() {
            (too_fine * too_coarse).sqrt()
        } else {
            wanted
        };
        if too_coarse.is_finite() && too_coarse / too_fine.max(f32::MIN_POSITIVE) < 1.001 {
            break; // the bracket has closed: no size in between gives anything new
        }
    }
    match (best, all_dropped, too_many) {
        (Some(v), _, _) => Ok(v),
        (None, Some((candidates, size)), _) => Err(VoxelError::AllDropped { candidates, size }),
        (None, None, Some(e)) => Err(e),
        (None, None, None) => Err(VoxelError::NoPatches { size }),
    }
}

/// Voxelise at one voxel size.
pub fn voxelize_at(scene: &Scene, size: f32) -> Result<Voxelization, VoxelError> {
    // A closed surface of area A makes about A/(2 s²) voxel-face patches.
    let grid = grid_for(scene, size, scene.total_area() / 2.0)?;
    let (origin, dims) = (grid.origin, grid.dims);
    let face_area = size as f64 * size as f64;
    let mut voxels: HashMap<u64, VoxelAccum> = HashMap::new();
    grid.pieces(scene, |_, tri, n, _, area, centroid| {
        let (albedo, emission) = (tri.albedo.as_dvec3(), tri.emission.as_dvec3());
        // Clipping through a grid edge or corner leaves rounding-error slivers in the
        // neighbouring voxels; counted, they would mark those voxels occupied and hide faces
        // that are really open.
        if area.is_nan() || area <= MIN_PIECE_AREA * face_area {
            return;
        }
        let key = grid.key(grid.cell_of(centroid));
        let acc = voxels.entry(key).or_default();
        for face in Face::ALL {
            let c = n.dot(face.normal().as_dvec3());
            let (c, normal) = if c > 0.0 {
                (c, n)
            } else if tri.double_sided && c < 0.0 {
                (-c, -n)
            } else {
                continue;
            };
            let w = area * c;
            let f = &mut acc.faces[face as usize];
            f.weight += w;
            f.albedo += albedo * w;
            f.emission += emission * w;
            f.centroid += centroid * w;
            f.normal += normal * w;
        }
    });

    let mut keys: Vec<u64> = voxels.keys().copied().collect();
    keys.sort_unstable();
    let mut patches = Vec::new();
    let mut occluders = Vec::new();
    let mut layout = PatchLayout {
        origin: origin.to_array(),
        voxel_size: size,
        dims,
        patches: Vec::new(),
    };
    for &key in &keys {
        let cell = grid.unkey(key);
        let acc = &voxels[&key];
        for face in Face::ALL {
            if grid
                .neighbour(cell, face)
                .is_some_and(|nb| voxels.contains_key(&grid.key(nb)))
            {
                continue;
            }
            let f = &acc.faces[face as usize];
            if f.weight > MIN_FACE_COVERAGE * face_area {
                let inv = 1.0 / f.weight;
                let normal = f.normal.normalize_or(face.normal().as_dvec3());
                patches.push(Patch {
                    voxel: cell,
                    face,
                    albedo: (f.albedo * inv)
                        .clamp(DVec3::ZERO, DVec3::ONE)
                        .as_vec3()
                        .to_array(),
                    centroid: (f.centroid * inv).as_vec3().to_array(),
                    normal: normal.as_vec3().to_array(),
                    source_area: f.weight as f32,
                    emission: (f.emission * inv).max(DVec3::ZERO).as_vec3().to_array(),
                });
            } else {
                occluders.push(layout.face_quad(cell, face));
            }
        }
    }
    if patches.is_empty() {
        return Err(VoxelError::NoPatches { size });
    }
    layout.patches = patches;
    Ok(Voxelization {
        layout,
        occluders,
        occupied_voxels: keys.len(),
        occupied: keys,
        dropped_patches: 0,
        dropped_elements: 0,
        pieces: None,
        elements: None,
        refinement: Refinement::default(),
        unassigned_area: 0.0,
        total_area: scene.total_area(),
    })
}

/// The grid at voxel size `size` around `scene`, refused before any clipping work when a
/// surface of `patch_area` (the area that makes patches: about one patch per `size²` of it)
/// would make far more patches than a bake accepts, or when the grid is absurdly large.
fn grid_for(scene: &Scene, size: f32, patch_area: f64) -> Result<Grid, VoxelError> {
    let (lo, hi) = scene.bounds().ok_or(VoxelError::EmptyScene)?;
    // The margin leaves room for the candidates that a refinement step drops again.
    let estimate = patch_area / (size as f64 * size as f64);
    if estimate > 4.0 * MAX_PATCHES as f64 {
        return Err(VoxelError::TooManyPatches {
            size,
            patches: estimate as usize,
        });
    }
    let extent = hi - lo;
    // One voxel of margin on each side keeps every surface strictly inside the grid, and
    // centring the grid on the scene keeps axis-aligned walls off the grid planes in the common
    // case of a scene whose extent is a whole number of voxels.
    let dims_f = (extent / size).floor() + Vec3::splat(2.0);
    let cells = dims_f.x as f64 * dims_f.y as f64 * dims_f.z as f64;
    if !cells.is_finite()
        || cells > MAX_GRID_CELLS as f64
        || dims_f.max_element() > u32::MAX as f32 / 2.0
    {
        return Err(VoxelError::GridTooLarge {
            size,
            extent: extent.to_array(),
            cells: if cells.is_finite() {
                cells as u64
            } else {
                u64::MAX
            },
        });
    }
    let dims = [dims_f.x as u32, dims_f.y as u32, dims_f.z as u32];
    let center = (lo + hi) * 0.5;
    Ok(Grid {
        origin: center - dims_f * size * 0.5,
        size,
        dims,
    })
}

/// Area of every surface side: a double-sided triangle is a surface on both sides.
fn sided_area(scene: &Scene) -> f64 {
    scene
        .triangles
        .iter()
        .map(|t| t.area() as f64 * if t.double_sided { 2.0 } else { 1.0 })
        .sum()
}

/// Fold the parts of a connected surface in one voxel, face and sub-cell that face a space of
/// their own into its largest part when they are smaller than [`MIN_SPACE_SHARE`] of the patch:
/// a sliver carries too little light to leak much, and every element is a row of the transport.
/// `component[id]` is the connected surface of element id `id`.
fn merge_small_spaces(
    groups: HashMap<(u64, Face, u32, u32), Group>,
    component: &[u32],
) -> HashMap<(u64, Face, u32, u32), Group> {
    let mut groups: Vec<((u64, Face, u32, u32), Group)> = groups.into_iter().collect();
    groups.sort_unstable_by_key(|g| g.0);
    let mut patch_area: HashMap<(u64, Face), f64> = HashMap::new();
    // The largest part of each (voxel, face, component, sub-cell); the first on a tie.
    let mut largest: HashMap<(u64, Face, u32, u32), (f64, u32)> = HashMap::new();
    for ((v, face, id, sub), g) in &groups {
        *patch_area.entry((*v, *face)).or_default() += g.acc.weight;
        let whole = (*v, *face, component[*id as usize], *sub);
        let best = largest.entry(whole).or_insert((g.acc.weight, *id));
        if g.acc.weight > best.0 {
            *best = (g.acc.weight, *id);
        }
    }
    let mut out: HashMap<(u64, Face, u32, u32), Group> = HashMap::with_capacity(groups.len());
    for ((v, face, id, sub), g) in groups {
        let (_, big) = largest[&(v, face, component[id as usize], sub)];
        let small = g.acc.weight < MIN_SPACE_SHARE * patch_area[&(v, face)];
        let id = if small { big } else { id };
        let e = out.entry((v, face, id, sub)).or_default();
        e.acc.merge(&g.acc);
        e.tris.extend(g.tris);
    }
    out
}

/// Keep the cuts of the refined voxels that matter most while the elements stay within
/// `budget` × the patches; merge the sub-cells of the others back into one element each.
///
/// First the voxels where two surfaces face each other across a gap inside the voxel, narrowest
/// gap first (a fixture under a ceiling, a panel against a wall: the gap is dark, the surfaces'
/// other parts lit), then those with the most connected surfaces. Cluttered scenes have far more
/// such voxels than a budget allows; the budget keeps their transport's size predictable.
fn within_budget(
    groups: HashMap<(u64, Face, u32, u32), Group>,
    refined: &mut Vec<u64>,
    budget: f64,
) -> HashMap<(u64, Face, u32, u32), Group> {
    // Per (voxel, face, component): its sub-cells and where it lies along its face's axis.
    #[derive(Default)]
    struct Coarse {
        subs: usize,
        weight: f64,
        along: f64,
    }
    // Sorted, so that every sum below is taken in one order: the bake is deterministic.
    let mut groups: Vec<((u64, Face, u32, u32), Group)> = groups.into_iter().collect();
    groups.sort_unstable_by_key(|g| g.0);
    let mut coarse: HashMap<(u64, Face, u32), Coarse> = HashMap::new();
    for &((v, face, comp, _), ref g) in &groups {
        let c = coarse.entry((v, face, comp)).or_default();
        c.subs += 1;
        c.weight += g.acc.weight;
        c.along += g.acc.centroid[face.axis()];
    }
    let patches = coarse
        .keys()
        .map(|&(v, f, _)| (v, f))
        .collect::<std::collections::HashSet<_>>()
        .len();
    // Per refined voxel: the elements its cuts add, its narrowest facing gap, its components.
    struct Candidate {
        voxel: u64,
        extra: usize,
        gap: f64,
        components: usize,
    }
    let mut by_voxel: std::collections::BTreeMap<u64, Vec<(Face, u32, f64, usize)>> =
        Default::default();
    let mut sorted: Vec<_> = coarse.iter().collect();
    sorted.sort_unstable_by_key(|c| c.0);
    for (&(v, face, comp), c) in sorted {
        if refined.binary_search(&v).is_ok() {
            by_voxel
                .entry(v)
                .or_default()
                .push((face, comp, c.along / c.weight, c.subs));
        }
    }
    let mut candidates: Vec<Candidate> = by_voxel
        .into_iter()
        .map(|(voxel, els)| {
            let mut gap = f64::INFINITY;
            for &(fa, ca, pa, _) in &els {
                for &(fb, cb, pb, _) in &els {
                    // `fa` faces up its axis and `fb` down it, above it: they face each other.
                    if ca != cb && fa.axis() == fb.axis() && fa.sign() > 0.0 && fb.sign() < 0.0 {
                        let d = pb - pa;
                        if d >= 0.0 {
                            gap = gap.min(d);
                        }
                    }
                }
            }
            let mut comps: Vec<u32> = els.iter().map(|e| e.1).collect();
            comps.sort_unstable();
            comps.dedup();
            Candidate {
                voxel,
                extra: els.iter().map(|e| e.3 - 1).sum(),
                gap,
                components: comps.len(),
            }
        })
        .collect();
    candidates.sort_by(|a, b| {
        a.gap
            .total_cmp(&b.gap)
            .then(b.components.cmp(&a.components))
            .then(a.voxel.cmp(&b.voxel))
    });
    let allowed = (budget * patches as f64) as usize;
    let mut elements = coarse.len();
    let mut kept = Vec::new();
    for c in candidates {
        if elements + c.extra <= allowed {
            elements += c.extra;
            kept.push(c.voxel);
        }
    }
    kept.sort_unstable();
    let mut out: HashMap<(u64, Face, u32, u32), Group> = HashMap::with_capacity(elements);
    for ((v, face, comp, sub), g) in groups {
        let sub = if kept.binary_search(&v).is_ok() {
            sub
        } else {
            0
        };
        let e = out.entry((v, face, comp, sub)).or_default();
        e.acc.merge(&g.acc);
        e.tris.extend(g.tris);
    }
    *refined = kept;
    out
}

/// One (voxel, face) group of surface pieces while clustering.
#[derive(Default)]
struct Group {
    acc: FaceAccum,
    tris: Vec<PieceTri>,
}

/// Cluster `scene` into surface patches at one voxel size (docs/design.md §2, step 2).
///
/// Every triangle is clipped exactly against the grid planes. Each piece, on each of its
/// surface sides (both for a double-sided triangle), joins the patch `(voxel, face)` of the voxel
/// it lies in and the direction its side's normal faces most ([`dominant_face`]). So every piece
/// of surface belongs to exactly one patch, whatever its neighbours; a patch's albedo, emission,
/// centroid and normal are area-weighted over its pieces, and its `source_area` is their true
/// area. Within a patch, elements ([`crate::element`]) part its pieces by connected surface, by
/// the open space each part faces ([`crate::space`]), and into sub-cells where surfaces meet.
pub fn cluster_at(scene: &Scene, size: f32) -> Result<Voxelization, VoxelError> {
    cluster_refined_at(scene, size, REFINE_FACTOR)
}

/// [`cluster_at`] without telling apart the spaces surfaces face: the same patches, fewer
/// elements, at a fraction of the cost. The voxel-size search counts patches with it.
fn cluster_patches_at(scene: &Scene, size: f32) -> Result<Voxelization, VoxelError> {
    cluster_with(scene, size, REFINE_FACTOR, false)
}

/// [`cluster_at`] with elements in voxels where surfaces meet cut `factor` times finer along each
/// axis (1: not at all).
pub fn cluster_refined_at(
    scene: &Scene,
    size: f32,
    factor: u32,
) -> Result<Voxelization, VoxelError> {
    cluster_with(scene, size, factor, true)
}

fn cluster_with(
    scene: &Scene,
    size: f32,
    factor: u32,
    by_space: bool,
) -> Result<Voxelization, VoxelError> {
    let total_area = sided_area(scene);
    let grid = grid_for(scene, size, total_area)?;
    let face_area = size as f64 * size as f64;
    let component = crate::element::components(scene);
    // Voxels where more than one connected surface lies: there one object's surface meets or
    // hides another's (a fixture under a ceiling, a box on a floor), and the light of a patch
    // changes abruptly across it.
    let mut first: HashMap<u64, Option<u32>> = HashMap::new();
    grid.pieces(scene, |index, _, _, _, area, centroid| {
        if area > MIN_PIECE_AREA * face_area {
            let c = component[index];
            first
                .entry(grid.key(grid.cell_of(centroid)))
                .and_modify(|seen| {
                    if *seen != Some(c) {
                        *seen = None;
                    }
                })
                .or_insert(Some(c));
        }
    });
    let mut refined: Vec<u64> = if factor > 1 {
        first
            .iter()
            .filter(|(_, c)| c.is_none())
            .map(|(&k, _)| k)
            .collect()
    } else {
        Vec::new()
    };
    refined.sort_unstable();
    let fine = Grid {
        origin: grid.origin,
        size: size / factor as f32,
        dims: grid.dims.map(|d| d.saturating_mul(factor)),
    };
    let spaces = if by_space {
        spaces_of(scene, &grid)
    } else {
        None
    };
    let extent = scene
        .bounds()
        .map_or(0.0, |(lo, hi)| (hi - lo).max_element());
    // Elements are told apart by (connected surface, space faced, openness), numbered as first
    // met. The labels cost rays (a space's facing point, 16 openness rays a part), so the walk
    // over the pieces first records every side and its parts in order, the parts' labels are
    // found in parallel (in that order), and the parts are then grouped in the recorded order:
    // the same numbering, whatever the thread count.
    let mut pending: Vec<Pending> = Vec::new();
    let mut parts: Vec<(Poly, f64, DVec3)> = Vec::new();
    let mut unassigned = 0.0f64;
    let mut stack = Vec::new();
    let mut fine_polys = Vec::new();
    grid.pieces(scene, |index, tri, n, poly, area, centroid| {
        let sides: &[f64] = if tri.double_sided {
            &[1.0, -1.0]
        } else {
            &[1.0]
        };
        if area.is_nan() || area <= 0.0 {
            return;
        }
        // Rounding-error slivers of clipping through a grid edge or corner are not geometry;
        // their (negligible) area is reported as belonging to no patch.
        if area <= MIN_PIECE_AREA * face_area {
            unassigned += area * sides.len() as f64;
            return;
        }
        let cell = grid.cell_of(centroid);
        let key = grid.key(cell);
        stack.clear();
        if refined.binary_search(&key).is_ok() {
            fine.split_all(poly, &mut stack);
        } else {
            stack.push(*poly);
        }
        let whole = stack.len() == 1;
        for piece in &stack {
            let (area, centroid) = if whole {
                (area, centroid)
            } else {
                piece.area_centroid(n)
            };
            if area.is_nan() || area <= 0.0 {
                continue;
            }
            if area <= MIN_PIECE_AREA * face_area {
                unassigned += area * sides.len() as f64;
                continue;
            }
            let sub = if whole && refined.binary_search(&key).is_err() {
                0
            } else {
                sub_cell(fine.cell_of(centroid), cell, factor)
            };
            fine_polys.clear();
            if let Some((_, g, _, _)) = &spaces {
                g.split_all(piece, &mut fine_polys);
            }
            for &sign in sides {
                let normal = n * sign;
                // The space each fine part of the piece faces; one group when they agree.
                let first = parts.len();
                if spaces.is_some() {
                    for f in &fine_polys {
                        let (a, c) = f.area_centroid(n);
                        if a > 0.0 {
                            parts.push((*f, a, c));
                        }
                    }
                }
                pending.push(Pending {
                    index,
                    key,
                    cell,
                    sub,
                    n,
                    normal,
                    piece: *piece,
                    area,
                    centroid,
                    parts: first..parts.len(),
                });
            }
        }
    });
    // Per part, its leaves: the part itself, or the pieces it was cut into where its points face
    // different spaces ([`one_space_each`]), each with its label.
    let labels: Vec<Vec<(Facing, Poly, f64, DVec3)>> = match &spaces {
        Some((spaces, _, mesh, factor)) => {
            let mut cells: Vec<(u64, [u32; 3])> = pending
                .iter()
                .filter(|item| !item.parts.is_empty())
                .map(|item| (item.key, item.cell))
                .collect();
            cells.sort_unstable_by_key(|&(key, _)| key);
            cells.dedup_by_key(|&mut (key, _)| key);
            let locals: HashMap<u64, crate::space::Local> = cells
                .par_iter()
                .map(|&(key, cell)| {
                    let lo = cell.map(|c| (c * factor).saturating_sub(SPACE_MARGIN));
                    let hi = cell.map(|c| (c + 1) * factor + SPACE_MARGIN);
                    (key, spaces.local(lo, hi))
                })
                .collect();
            // Rayon's collect keeps the parts' order.
            pending
                .par_iter()
                .flat_map_iter(|item| {
                    let normal = item.normal.as_vec3();
                    let local = locals.get(&item.key);
                    let space = move |p: DVec3| {
                        spaces
                            .facing(mesh, p.as_vec3(), normal)
                            .and_then(|point| local?.label(spaces, point))
                    };
                    parts[item.parts.clone()].iter().map(move |&part| {
                        let mut leaves = Vec::with_capacity(1);
                        one_space_each(part, item.n, &space, SPACE_SPLITS, &mut leaves);
                        leaves
                            .into_iter()
                            .map(|(space, poly, a, c)| {
                                let open =
                                    crate::openness::probe(mesh, c.as_vec3(), normal, extent, size);
                                ((space, open), poly, a, c)
                            })
                            .collect::<Vec<_>>()
                    })
                })
                .collect()
        }
        None => Vec::new(),
    };
    let mut sides_of: HashMap<(u32, Facing), u32> = HashMap::new();
    let mut id_of: Vec<u32> = Vec::new();
    let mut groups: HashMap<(u64, Face, u32, u32), Group> = HashMap::new();
    for item in &pending {
        let mut leaves = labels[item.parts.clone()].iter().flatten();
        let first = leaves.clone().next().map(|l| l.0);
        let whole = leaves.all(|l| Some(l.0) == first);
        let split: Vec<(Facing, Poly, f64, DVec3)> = if whole {
            let label = first.unwrap_or((None, 0));
            vec![(label, item.piece, item.area, item.centroid)]
        } else {
            labels[item.parts.clone()]
                .iter()
                .flatten()
                .copied()
                .collect()
        };
        let tri = &scene.triangles[item.index];
        let face = dominant_face(item.normal.as_vec3());
        for (label, part, area, centroid) in split {
            // Inside a closed solid: no light reaches it and no eye sees it.
            if label.1 == crate::openness::ENCLOSED {
                unassigned += area;
                continue;
            }
            let next = sides_of.len() as u32;
            let id = *sides_of
                .entry((component[item.index], label))
                .or_insert_with(|| {
                    id_of.push(component[item.index]);
                    next
                });
            let g = groups.entry((item.key, face, id, item.sub)).or_default();
            g.acc.add(tri, area, centroid, item.normal);
            g.tris
                .extend(part.fan(item.n).iter().map(|&(corners, a)| PieceTri {
                    corners,
                    normal: item.normal.as_vec3(),
                    area: a,
                    triangle: item.index as u32,
                }));
        }
    }
    let groups = merge_small_spaces(groups, &id_of);
    let groups = within_budget(groups, &mut refined, REFINE_BUDGET);
    // Sorted keys put each patch's elements together, in component then sub-cell order.
    let mut keys: Vec<(u64, Face, u32, u32)> = groups.keys().copied().collect();
    keys.sort_unstable();
    let record = |key: (u64, Face), f: &FaceAccum| {
        let inv = 1.0 / f.weight;
        Patch {
            voxel: grid.unkey(key.0),
            face: key.1,
            albedo: (f.albedo * inv)
                .clamp(DVec3::ZERO, DVec3::ONE)
                .as_vec3()
                .to_array(),
            centroid: (f.centroid * inv).as_vec3().to_array(),
            normal: f
                .normal
                .normalize_or(key.1.normal().as_dvec3())
                .as_vec3()
                .to_array(),
            source_area: f.weight as f32,
            emission: (f.emission * inv).max(DVec3::ZERO).as_vec3().to_array(),
        }
    };
    let mut patches: Vec<Patch> = Vec::new();
    let mut elements = Vec::with_capacity(keys.len());
    let mut element_patch = Vec::with_capacity(keys.len());
    let mut pieces = Pieces {
        start: vec![0],
        tris: Vec::new(),
    };
    let mut k = 0;
    while k < keys.len() {
        let patch = (keys[k].0, keys[k].1);
        let mut whole = FaceAccum::default();
        while k < keys.len() && (keys[k].0, keys[k].1) == patch {
            let g = &groups[&keys[k]];
            whole.merge(&g.acc);
            elements.push(record(patch, &g.acc));
            element_patch.push(patches.len() as u32);
            pieces.tris.extend_from_slice(&g.tris);
            pieces.start.push(pieces.tris.len() as u32);
            k += 1;
        }
        patches.push(record(patch, &whole));
    }
    if patches.is_empty() {
        return Err(VoxelError::NoPatches { size });
    }
    let mut occupied: Vec<u64> = keys.iter().map(|k| k.0).collect();
    occupied.dedup();
    refined.retain(|k| occupied.binary_search(k).is_ok());
    let layout = PatchLayout {
        origin: grid.origin.to_array(),
        voxel_size: size,
        dims: grid.dims,
        patches,
    };
    let elements = Elements {
        layout: PatchLayout {
            patches: elements,
            ..layout.clone()
        },
        patch: element_patch,
    };
    Ok(Voxelization {
        layout,
        occluders: Vec::new(),
        occupied_voxels: occupied.len(),
        occupied,
        dropped_patches: 0,
        dropped_elements: 0,
        pieces: Some(pieces),
        elements: Some(elements),
        refinement: Refinement {
            factor,
            voxels: refined,
        },
        unassigned_area: unassigned,
        total_area,
    })
}

/// What a part of a patch faces: its space ([`crate::space`], `None` where no lattice point is
/// in view) and its openness class ([`crate::openness`]).
type Facing = (Option<u32>, i8);

/// One side of one piece of surface, recorded in walk order before its labels are known, with
/// the fine parts whose labels decide whether it is one element or several.
struct Pending {
    index: usize,
    key: u64,
    /// The voxel, whose neighbourhood tells the spaces its parts face apart.
    cell: [u32; 3],
    sub: u32,
    /// The triangle's normal, and the side's (`±` it).
    n: DVec3,
    normal: DVec3,
    piece: Poly,
    area: f64,
    centroid: DVec3,
    /// Its fine parts in `parts`, and their labels at the same indices.
    parts: std::ops::Range<usize>,
}

/// How many times a lattice part whose points face different spaces is halved, at most: a
/// quarter-voxel part down to a 32nd of a voxel.
pub const SPACE_SPLITS: u32 = 3;

/// `part` (a polygon, its area and centroid, on a surface of normal `n`) as pieces that each face
/// one space, with that space, pushed onto `out`. A part is labelled by the space its centroid
/// faces; when a point near one of its corners faces another, it is halved across the axis along
/// which those points lie and each half labelled again, at most `splits` times deep. Without this, a lattice part that a thin wall
/// stands on (a floor running on under the wall, found in any level built of closed boxes) holds
/// floor on both sides of the wall and one label, so the lit room's floor and the dark room's
/// were one element and its light leaked through the wall.
fn one_space_each(
    part: (Poly, f64, DVec3),
    n: DVec3,
    space: &impl Fn(DVec3) -> Option<u32>,
    splits: u32,
    out: &mut Vec<(Option<u32>, Poly, f64, DVec3)>,
) {
    let (poly, area, centroid) = part;
    let label = space(centroid);
    let pts = poly.points();
    // Where a point near each corner looks, and how far the ones that see another space lie
    // from the centroid, summed with their signs.
    let (mut agree, mut toward) = (true, DVec3::ZERO);
    if splits > 0 {
        for &corner in pts {
            let p = centroid + (corner - centroid) * 0.75;
            if space(p) != label {
                agree = false;
                toward += p - centroid;
            }
        }
    }
    if agree {
        out.push((label, poly, area, centroid));
        return;
    }
    let (lo, hi) = pts.iter().fold(
        (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let extent = hi - lo;
    let longest = extent.max_element();
    // Cut across the axis the other space lies along (a wall's foot runs across it), measured
    // against the part's extent: a floor part whose far side is under a wall running along z is
    // cut in x, three times at most, down to an eighth. Scores that tie (one corner of a square
    // part) are rounding's choice, which differs at another scale: take the first axis within a
    // hair of the best.
    let score: [f64; 3] = std::array::from_fn(|a| {
        if extent[a] > longest * 1e-9 {
            (toward[a] / extent[a]).abs()
        } else {
            0.0
        }
    });
    let best = score.iter().copied().fold(0.0, f64::max);
    // Points that see another space on opposite sides cancel out: then halve the longest way.
    let (score, best) = if best > 0.0 {
        (score, best)
    } else {
        (extent.to_array(), longest)
    };
    let axis = (0..3)
        .find(|&a| score[a] >= best * (1.0 - 1e-4))
        .unwrap_or(0);
    let (below, above) = poly.clip(axis, 0.5 * (lo[axis] + hi[axis]));
    for half in [below, above] {
        let (a, c) = half.area_centroid(n);
        if a > 0.0 {
            one_space_each((half, a, c), n, space, splits - 1, out);
        }
    }
}

/// Lattice points per voxel edge for finding the spaces surfaces face ([`crate::space`]).
pub const SPACE_FACTOR: u32 = 4;
/// Lattice points beyond a voxel on each side that count as its neighbourhood: surfaces of a
/// voxel face one space when their fronts connect within it.
pub const SPACE_MARGIN: u32 = 1;
/// Parts of a patch facing a space of their own smaller than this share of it join its largest.
pub const MIN_SPACE_SHARE: f64 = 0.03;

/// The spaces of `scene` on a lattice [`SPACE_FACTOR`] times finer than `grid` (coarser when
/// that would be too many points), and the grid of cells around its points.
fn spaces_of(scene: &Scene, grid: &Grid) -> Option<(Spaces, Grid, TriMesh, u32)> {
    let (lo, hi) = scene.bounds()?;
    let extent = (hi - lo).max_element();
    let voxels = grid.dims.iter().map(|&d| u64::from(d)).product::<u64>();
    let mut factor = SPACE_FACTOR;
    while factor > 1 && voxels * u64::from(factor).pow(3) > crate::space::MAX_LATTICE_POINTS {
        factor -= 1;
    }
    let fine = Grid {
        origin: grid.origin,
        size: grid.size / factor as f32,
        dims: grid.dims.map(|d| d.saturating_mul(factor)),
    };
    let mesh = crate::surface::scene_mesh(scene);
    let spaces = Spaces::new(&mesh, fine.origin, fine.size, fine.dims, extent)?;
    Some((spaces, fine, mesh, factor))
}

struct Grid {
    origin: Vec3,
    size: f32,
    dims: [u32; 3],
}

impl Grid {
    /// Every triangle of `scene` with an area, clipped exactly against the grid planes: `f` gets
    /// the triangle's index, the triangle, its unit normal, and each piece with its area and
    /// centroid (each piece lies in one voxel).
    fn pieces(&self, scene: &Scene, mut f: impl FnMut(usize, &Triangle, DVec3, &Poly, f64, DVec3)) {
        let mut stack = Vec::new();
        for (index, tri) in scene.triangles.iter().enumerate() {
            let cross = tri.cross();
            let len = cross.length();
            if !(len > 0.0 && len.is_finite()) {
                continue;
            }
            let n = (cross / len).as_dvec3();
            stack.clear();
            stack.push(Poly::from_slice(&tri.positions));
            while let Some(poly) = stack.pop() {
                if let Some((a, b)) = self.split(&poly) {
                    stack.push(a);
                    stack.push(b);
                    continue;
                }
                let (area, centroid) = poly.area_centroid(n);
                f(index, tri, n, &poly, area, centroid);
            }
        }
    }

    /// `poly` cut at every plane of this grid it crosses, into `out`.
    fn split_all(&self, poly: &Poly, out: &mut Vec<Poly>) {
        let mut todo = vec![*poly];
        while let Some(p) = todo.pop() {
            match self.split(&p) {
                Some((a, b)) => {
                    todo.push(a);
                    todo.push(b);
                }
                None => out.push(p),
            }
        }
    }

    fn key(&self, c: [u32; 3]) -> u64 {
        // z-major so that sorted keys walk the grid in x-fastest order.
        (c[2] as u64 * self.dims[1] as u64 + c[1] as u64) * self.dims[0] as u64 + c[0] as u64
    }

    fn unkey(&self, key: u64) -> [u32; 3] {
        let x = key % self.dims[0] as u64;
        let yz = key / self.dims[0] as u64;
        let y = yz % self.dims[1] as u64;
        let z = yz / self.dims[1] as u64;
        [x as u32, y as u32, z as u32]
    }

    fn cell_coord(&self, p: f64, axis: usize) -> u32 {
        let t = (p - self.origin[axis] as f64) / self.size as f64;
        (t.floor().max(0.0) as u32).min(self.dims[axis] - 1)
    }

    fn cell_of(&self, p: DVec3) -> [u32; 3] {
        [
            self.cell_coord(p.x, 0),
            self.cell_coord(p.y, 1),
            self.cell_coord(p.z, 2),
        ]
    }

    fn neighbour(&self, c: [u32; 3], face: Face) -> Option<[u32; 3]> {
        let a = face.axis();
        let mut n = c;
        if face.sign() > 0.0 {
            n[a] = c[a].checked_add(1).filter(|&v| v < self.dims[a])?;
        } else {
            n[a] = c[a].checked_sub(1)?;
        }
        Some(n)
    }

    /// Split a polygon at a grid plane strictly inside its extent, if any. Strictness is what ends
    /// the recursion: a piece that only touches a plane is never split at it again.
    fn split(&self, poly: &Poly) -> Option<(Poly, Poly)> {
        for axis in 0..3 {
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for p in poly.points() {
                lo = lo.min(p[axis]);
                hi = hi.max(p[axis]);
            }
            let o = self.origin[axis] as f64;
            let s = self.size as f64;
            let k_lo = ((lo - o) / s).floor() as i64 + 1;
            let k_hi = ((hi - o) / s).ceil() as i64 - 1;
            if k_hi < k_lo {
                continue;
            }
            // The middle plane keeps the recursion depth logarithmic in the planes crossed.
            let k = k_lo + (k_hi - k_lo) / 2;
            let plane = o + k as f64 * s;
            if plane > lo && plane < hi {
                return Some(poly.clip(axis, plane));
            }
            for k in k_lo..=k_hi {
                let plane = o + k as f64 * s;
                if plane > lo && plane < hi {
                    return Some(poly.clip(axis, plane));
                }
            }
        }
        None
    }
}

/// A small convex polygon: a triangle clipped by at most six planes has at most nine vertices.
#[derive(Clone, Copy)]
struct Poly {
    pts: [DVec3; 12],
    len: usize,
}

impl Poly {
    fn from_slice(p: &[Vec3; 3]) -> Poly {
        let mut pts = [DVec3::ZERO; 12];
        for (d, s) in pts.iter_mut().zip(p) {
            *d = s.as_dvec3();
        }
        Poly { pts, len: 3 }
    }

    fn points(&self) -> &[DVec3] {
        &self.pts[..self.len]
    }

    fn push(&mut self, p: DVec3) {
        if self.len < self.pts.len() {
            self.pts[self.len] = p;
            self.len += 1;
        }
    }

    /// Sutherland–Hodgman split into the parts below and above `plane` on `axis`.
    fn clip(&self, axis: usize, plane: f64) -> (Poly, Poly) {
        let empty = Poly {
            pts: [DVec3::ZERO; 12],
            len: 0,
        };
        let (mut below, mut above) = (empty, empty);
        let pts = self.points();
        for (k, &a) in pts.iter().enumerate() {
            let b = pts[(k + 1) % pts.len()];
            let (da, db) = (a[axis] - plane, b[axis] - plane);
            if da <= 0.0 {
                below.push(a);
            }
            if da >= 0.0 {
                above.push(a);
            }
            if (da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0) {
                let t = da / (da - db);
                let mut p = a + (b - a) * t;
                p[axis] = plane;
                below.push(p);
                above.push(p);
            }
        }
        (below, above)
    }

    /// The polygon as a fan of triangles (corners in f32) with their areas; triangles with no
    /// area are left out.
    fn fan(&self, n: DVec3) -> Vec<([Vec3; 3], f32)> {
        let pts = self.points();
        let mut out = Vec::with_capacity(pts.len().saturating_sub(2));
        for k in 1..pts.len().saturating_sub(1) {
            let (a, b, c) = (pts[0], pts[k], pts[k + 1]);
            let area = 0.5 * (b - a).cross(c - a).dot(n);
            if area > 0.0 {
                out.push(([a.as_vec3(), b.as_vec3(), c.as_vec3()], area as f32));
            }
        }
        out
    }

    /// Area and centroid of the (planar, convex) polygon with unit normal `n`.
    fn area_centroid(&self, n: DVec3) -> (f64, DVec3) {
        let pts = self.points();
        if pts.len() < 3 {
            return (0.0, DVec3::ZERO);
        }
        let o = pts[0];
        let (mut area, mut c) = (0.0, DVec3::ZERO);
        for k in 1..pts.len() - 1 {
            let a = 0.5 * (pts[k] - o).cross(pts[k + 1] - o).dot(n);
            area += a;
            c += (o + pts[k] + pts[k + 1]) / 3.0 * a;
        }
        if area > 0.0 {
            (area, c / area)
        } else {
            (0.0, o)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Triangle;

    fn quad_tris(corners: [Vec3; 4], albedo: Vec3) -> [Triangle; 2] {
        let t = |a, b, c| Triangle {
            positions: [a, b, c],
            albedo,
            emission: Vec3::ZERO,
            double_sided: false,
            material: 0,
        };
        [
            t(corners[0], corners[1], corners[2]),
            t(corners[0], corners[2], corners[3]),
        ]
    }

    #[test]
    fn a_floor_becomes_upward_patches_that_conserve_its_area() {
        // A 2 × 2 floor facing +Y at y = 0.3.
        let c = [
            Vec3::new(0.0, 0.3, 0.0),
            Vec3::new(0.0, 0.3, 2.0),
            Vec3::new(2.0, 0.3, 2.0),
            Vec3::new(2.0, 0.3, 0.0),
        ];
        let scene = Scene {
            triangles: quad_tris(c, Vec3::splat(0.5)).to_vec(),
            ..Default::default()
        };
        let v = voxelize_at(&scene, 0.25).unwrap();
        assert!(v.layout.patches.iter().all(|p| p.face == Face::PosY));
        let total: f32 = v.layout.patches.iter().map(|p| p.source_area).sum();
        assert!((total - 4.0).abs() < 1e-4, "area {total}");
        // The floor spans 8 × 8 voxel columns (perhaps 9 where the grid is not aligned).
        assert!((64..=81).contains(&v.layout.len()), "{}", v.layout.len());
        for p in &v.layout.patches {
            assert!((p.albedo[0] - 0.5).abs() < 1e-6);
            assert!((p.centroid[1] - 0.3).abs() < 1e-5);
            assert!((p.normal[1] - 1.0).abs() < 1e-6);
        }
        // The one-sided floor's underside blocks light but is no patch.
        assert!(v.occluders.iter().any(|q| q.face == Face::NegY));
    }

    #[test]
    fn a_tilted_double_sided_plate_records_its_true_normal_on_both_sides() {
        // A 45° plate whose normal is (1, 1, 0)/√2, double-sided.
        let c = [
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(0.0, 1.0, 1.0),
        ];
        let mut tris = quad_tris(c, Vec3::new(0.2, 0.4, 0.6));
        for t in &mut tris {
            t.double_sided = true;
            if t.cross().x < 0.0 {
                t.positions.swap(1, 2);
            }
        }
        let scene = Scene {
            triangles: tris.to_vec(),
            ..Default::default()
        };
        let v = voxelize_at(&scene, 0.1).unwrap();
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let mut area_by_face = [0.0f32; 6];
        for p in &v.layout.patches {
            area_by_face[p.face as usize] += p.source_area;
            let n = Vec3::from(p.normal);
            // Each patch stands for the side of the plate that faces its direction.
            let want = if p.face.sign() > 0.0 {
                Vec3::new(s, s, 0.0)
            } else {
                Vec3::new(-s, -s, 0.0)
            };
            assert!((n - want).length() < 1e-4, "{:?} normal {n}", p.face);
            // The centroid lies on the plate.
            let q = Vec3::from(p.centroid);
            assert!((q.x + q.y - 1.0).abs() < 1e-4, "{q}");
            assert_eq!(p.albedo, [0.2, 0.4, 0.6]);
        }
        // The plate's √2 area projects to 1 on each of ±X and ±Y (where the faces are exposed;
        // the staircase hides some faces behind neighbouring voxels, never adds area).
        for face in [Face::PosX, Face::PosY, Face::NegX, Face::NegY] {
            let a = area_by_face[face as usize];
            assert!(a > 0.3 && a <= 1.0 + 1e-4, "{face:?}: {a}");
        }
        assert_eq!(area_by_face[Face::PosZ as usize], 0.0);
    }

    #[test]
    fn morton_order_interleaves_the_axes_and_keeps_every_patch() {
        assert_eq!(morton([1, 0, 0]), 1);
        assert_eq!(morton([0, 1, 0]), 2);
        assert_eq!(morton([0, 0, 1]), 4);
        assert_eq!(morton([3, 3, 3]), 63);
        assert_eq!(morton([0x1f_ffff, 0, 0]), 0x1249_2492_4924_9249);
        let c = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, 2.0),
            Vec3::new(2.0, 0.0, 2.0),
            Vec3::new(2.0, 0.0, 0.0),
        ];
        let scene = Scene {
            triangles: quad_tris(c, Vec3::splat(0.5)).to_vec(),
            ..Default::default()
        };
        let v = voxelize_at(&scene, 0.25).unwrap();
        let mut m = v.layout.clone();
        m.reorder(PatchOrder::Morton);
        assert_ne!(
            m.patches, v.layout.patches,
            "a 9×9 floor is not already in Morton order"
        );
        let codes: Vec<u64> = m.patches.iter().map(|p| morton(p.voxel)).collect();
        assert!(codes.windows(2).all(|w| w[0] <= w[1]));
        m.reorder(PatchOrder::Scan);
        assert_eq!(
            m.patches, v.layout.patches,
            "scan order is the voxeliser's own"
        );
    }

    #[test]
    fn target_patch_count_lands_near_the_target() {
        let c = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, 3.0),
            Vec3::new(3.0, 0.0, 3.0),
            Vec3::new(3.0, 0.0, 0.0),
        ];
        let scene = Scene {
            triangles: quad_tris(c, Vec3::splat(0.5)).to_vec(),
            ..Default::default()
        };
        let v = voxelize(&scene, Resolution::TargetPatches(400)).unwrap();
        let n = v.layout.len() as f32;
        assert!((n / 400.0 - 1.0).abs() < 0.15, "got {n} patches");
    }

    #[test]
    fn absurd_requests_are_refused() {
        let scene = Scene::default();
        assert!(matches!(
            voxelize(&scene, Resolution::TargetPatches(0)),
            Err(VoxelError::PatchCount(0))
        ));
        assert!(matches!(
            voxelize(&scene, Resolution::TargetPatches(10_000_000)),
            Err(VoxelError::PatchCount(_))
        ));
        assert!(matches!(
            voxelize(&scene, Resolution::VoxelSize(f32::NAN)),
            Err(VoxelError::VoxelSize(_))
        ));
        assert!(matches!(
            voxelize(&scene, Resolution::VoxelSize(1.0)),
            Err(VoxelError::EmptyScene)
        ));
        // A voxel far too small for the scene is refused before any clipping work.
        let c = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, 2.0),
            Vec3::new(2.0, 0.0, 2.0),
            Vec3::new(2.0, 0.0, 0.0),
        ];
        let plate = Scene {
            triangles: quad_tris(c, Vec3::splat(0.5)).to_vec(),
            ..Default::default()
        };
        let start = std::time::Instant::now();
        assert!(matches!(
            voxelize(&plate, Resolution::VoxelSize(1e-4)),
            Err(VoxelError::TooManyPatches { .. })
        ));
        assert!(start.elapsed().as_secs_f32() < 1.0);
    }

    /// A unit square on the floor (normal +Y) as a part: its polygon, area and centroid.
    fn floor_part(scale: f64) -> (Poly, f64, DVec3) {
        let mut poly = Poly {
            pts: [DVec3::ZERO; 12],
            len: 0,
        };
        for (x, z) in [(0.0, 0.0), (0.0, 1.0), (1.0, 1.0), (1.0, 0.0)] {
            // Off the origin, so the extents are differences that round.
            poly.push(DVec3::new(x + 0.2, 0.0, z + 0.4) * scale);
        }
        let (a, c) = poly.area_centroid(DVec3::Y);
        (poly, a, c)
    }

    #[test]
    fn a_part_facing_two_spaces_is_cut_where_they_part() {
        // A wall's foot at x = 0.5 parts the floor's spaces: 0 west of it, 1 east.
        let space = |p: DVec3| Some(u32::from(p.x >= 0.5));
        let mut leaves = Vec::new();
        one_space_each(floor_part(1.0), DVec3::Y, &space, SPACE_SPLITS, &mut leaves);
        assert!(leaves.len() > 1, "{} leaves", leaves.len());
        let total: f64 = leaves.iter().map(|l| l.2).sum();
        assert!((total - 1.0).abs() < 1e-12, "area kept: {total}");
        // Each leaf carries its centroid's space, and the area on the west side is the wall's
        // position to within the finest cut (an eighth of the part).
        for (label, _, _, c) in &leaves {
            assert_eq!(*label, space(*c));
        }
        let west: f64 = leaves.iter().filter(|l| l.0 == Some(0)).map(|l| l.2).sum();
        assert!((west - 0.3).abs() <= 0.125, "west area {west}");
        // Every cut runs along the wall (across x): each leaf keeps the part's whole depth in z.
        for (_, poly, _, _) in &leaves {
            let (lo, hi) = poly
                .points()
                .iter()
                .fold((f64::MAX, f64::MIN), |(lo, hi), p| {
                    (lo.min(p.z), hi.max(p.z))
                });
            assert!(
                (lo - 0.4).abs() < 1e-12 && (hi - 1.4).abs() < 1e-12,
                "{lo}..{hi}"
            );
        }
        // Uncut, the whole part would have been east's (its centroid's).
        assert_eq!(space(floor_part(1.0).2), Some(1));
    }

    #[test]
    fn a_part_facing_one_space_is_kept_whole_and_cuts_do_not_depend_on_scale() {
        let mut leaves = Vec::new();
        one_space_each(
            floor_part(1.0),
            DVec3::Y,
            &|_| Some(7),
            SPACE_SPLITS,
            &mut leaves,
        );
        assert_eq!(leaves.len(), 1);
        assert_eq!((leaves[0].0, leaves[0].1.points().len()), (Some(7), 4));
        // The square's two extents tie; at a thousandth of its size rounding must not pick
        // another axis to cut first (the scale stress test caught that: core/tests/it/stress.rs).
        let cut = |scale: f64| {
            let space = |p: DVec3| Some(u32::from(p.x + p.z >= 1.05 * scale));
            let mut leaves = Vec::new();
            one_space_each(
                floor_part(scale),
                DVec3::Y,
                &space,
                SPACE_SPLITS,
                &mut leaves,
            );
            leaves
                .iter()
                .map(|l| {
                    (
                        l.0,
                        (l.2 / (scale * scale) * 1e6).round(),
                        (l.3 / scale * 1e6).round(),
                    )
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(cut(1.0), cut(1e-3));
        assert_eq!(cut(1.0), cut(1e4));
    }
}
