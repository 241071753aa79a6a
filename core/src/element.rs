//! Transport elements: the pieces of a patch that the transport resolves separately
//! (docs/design.md §2, step 2).
//!
//! A patch is `(voxel, direction)`: what the layout, the frames and the clients' six-direction
//! volume are made of. Its surface can hold separate objects: a light fixture's underside a
//! centimetre below the ceiling, both facing down in one voxel, and the fixture's top facing the
//! ceiling across that centimetre. As one patch of uniform radiosity they pour the fixture's
//! bright underside into the closed gap, whose two sides then light each other at a form factor
//! near 1, and the ceiling patch reads many times its true indirect light. So within a patch the
//! transport runs on **elements**: the patch's pieces grouped by the connected surface (object)
//! they belong to. Direct light, `B0` and `E_ind = T · B0` are per element; what a patch streams
//! is its elements' irradiance averaged over the patch's true area ([`Elements::restrict`]),
//! which is what a reference averaging over the patch's surface measures.
//!
//! Surfaces are connected when their triangles share a vertex position: the same point, bit for
//! bit, which is how exporters write shared vertices.
//!
//! Connection is not enough in a level whose walls, floors and ceilings are one welded mesh: a
//! wall running up past a ceiling, or the floor either side of a thin wall, is one connected
//! surface in one voxel but faces two rooms, and one element for it carries the lit room's light
//! into the dark one. So a patch's pieces are also told apart by the open space each part faces
//! nearby ([`crate::space`]) and by how open the space in front of them is
//! ([`crate::openness`]); parts too small to matter join their surface's largest part
//! ([`crate::voxel::MIN_SPACE_SHARE`]).

use std::collections::HashMap;

use crate::patch::PatchLayout;
use crate::scene::Scene;
use crate::space::{find, union};

/// The elements of a layout's patches, in patch order: patch `p` owns the contiguous run of
/// elements whose `patch` entry is `p` (every patch at least one).
#[derive(Debug, Clone, PartialEq)]
pub struct Elements {
    /// One record per element, on the patches' grid: its patch's voxel and face, and its own
    /// albedo, emission, centroid, normal and true area (`source_area`).
    pub layout: PatchLayout,
    /// Per element, the patch it belongs to; non-decreasing.
    pub patch: Vec<u32>,
}

impl Elements {
    pub fn len(&self) -> usize {
        self.patch.len()
    }

    pub fn is_empty(&self) -> bool {
        self.patch.is_empty()
    }

    /// Why these elements do not fit `patches`, if they do not: each patch owns a contiguous,
    /// non-empty run of elements on its own voxel and face, on the same grid, and its elements'
    /// area does not exceed its own.
    pub fn check(&self, patches: &PatchLayout) -> Result<(), String> {
        let e = &self.layout;
        if e.origin != patches.origin
            || e.voxel_size != patches.voxel_size
            || e.dims != patches.dims
        {
            return Err("elements are on another grid than their patches".into());
        }
        if self.patch.len() != e.len() {
            return Err(format!(
                "{} element records but {} patch indices",
                e.len(),
                self.patch.len()
            ));
        }
        let mut area = vec![0.0f64; patches.len()];
        let mut next = 0u32;
        for (i, (&p, rec)) in self.patch.iter().zip(&e.patches).enumerate() {
            let continues = next.checked_sub(1) == Some(p);
            if !(p == next || continues) || p as usize >= patches.len() {
                return Err(format!(
                    "element {i} belongs to patch {p}: elements must cover patches 0.. in order"
                ));
            }
            if p == next {
                next += 1;
            }
            let owner = &patches.patches[p as usize];
            if rec.voxel != owner.voxel || rec.face != owner.face {
                return Err(format!(
                    "element {i} is not on its patch {p}'s voxel and face"
                ));
            }
            area[p as usize] += f64::from(rec.source_area);
        }
        if next as usize != patches.len() {
            return Err(format!(
                "patches {next}.. have no element ({} patches)",
                patches.len()
            ));
        }
        for (p, (a, owner)) in area.iter().zip(&patches.patches).enumerate() {
            if *a > f64::from(owner.source_area) * (1.0 + 1e-4) + 1e-12 {
                return Err(format!(
                    "patch {p}'s elements cover {a} of its {} area",
                    owner.source_area
                ));
            }
        }
        Ok(())
    }

    /// Per-patch irradiance from per-element irradiance (`sets × elements` in, `sets × patches`
    /// out): each element weighted by its area over its patch's whole area. Surface of a patch
    /// that belongs to no element (it sees nothing, so it was dropped) counts as unlit, which is
    /// right for indirect light: a surface that sees no patch receives none.
    pub fn restrict(&self, patches: &PatchLayout, per_element: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let whole: Vec<f64> = patches
            .patches
            .iter()
            .map(|p| f64::from(p.source_area))
            .collect();
        self.restrict_over(&whole, per_element)
    }

    /// [`Elements::restrict`] normalised by the elements' own area instead: for direct light,
    /// which surface left out of every element may still receive (the average is then over the
    /// surface that was sampled).
    pub fn restrict_sampled(
        &self,
        patches: &PatchLayout,
        per_element: &[[f32; 3]],
    ) -> Vec<[f32; 3]> {
        let mut covered = vec![0.0f64; patches.len()];
        for (&p, e) in self.patch.iter().zip(&self.layout.patches) {
            covered[p as usize] += f64::from(e.source_area);
        }
        self.restrict_over(&covered, per_element)
    }

    /// Area-weighted sums of each patch's elements over `total[patch]`, set by set.
    fn restrict_over(&self, total: &[f64], per_element: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let (m, n) = (self.len(), total.len());
        let sets = per_element.len().checked_div(m).unwrap_or(0);
        let mut out = vec![[0.0f32; 3]; sets * n];
        let mut sum = vec![[0.0f64; 3]; n];
        for (values, out) in per_element
            .chunks_exact(m.max(1))
            .zip(out.chunks_exact_mut(n.max(1)))
        {
            sum.iter_mut().for_each(|v| *v = [0.0; 3]);
            for ((&p, rec), v) in self.patch.iter().zip(&self.layout.patches).zip(values) {
                let a = f64::from(rec.source_area);
                for c in 0..3 {
                    sum[p as usize][c] += a * f64::from(v[c]);
                }
            }
            for ((o, acc), &t) in out.iter_mut().zip(&sum).zip(total) {
                // An area sum a hair over the patch's (rounding) must not turn f32::MAX, which
                // relights clamp to, into infinity; NaN is left alone, a bug to see.
                *o = if t > 0.0 {
                    acc.map(|v| match (v / t) as f32 {
                        f32::INFINITY => f32::MAX,
                        x => x,
                    })
                } else {
                    [0.0; 3]
                };
            }
        }
        out
    }

    /// Per-element values from per-patch values: each element takes its patch's.
    pub fn spread<T: Copy>(&self, per_patch: &[T]) -> Vec<T> {
        self.patch.iter().map(|&p| per_patch[p as usize]).collect()
    }
}

/// Where elements are cut finer than their voxel: in voxels where more than one connected
/// surface lies, each element is cut into the `factor³` sub-cells of its voxel
/// ([`crate::voxel::cluster_at`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Refinement {
    pub factor: u32,
    /// Linear voxel indices (the layout's `x + dims.x · (y + dims.y · z)`), ascending.
    pub voxels: Vec<u64>,
}

impl Refinement {
    /// Whether elements in voxel `key` are cut.
    pub fn cuts(&self, key: u64) -> bool {
        self.factor > 1 && self.voxels.binary_search(&key).is_ok()
    }
}

/// The sub-cell of coarse voxel `cell` that fine cell `fine` (of a grid `factor` times finer,
/// same origin) lies in, numbered x fastest; clamped into the voxel, as points on its boundary
/// may round to the neighbour's fine cell.
pub fn sub_cell(fine: [u32; 3], cell: [u32; 3], factor: u32) -> u32 {
    let f = factor.max(1);
    let local = |a: usize| fine[a].saturating_sub(cell[a].saturating_mul(f)).min(f - 1);
    local(0) + f * (local(1) + f * local(2))
}

/// Per triangle of `scene`, the connected surface it belongs to: triangles sharing a vertex
/// position are connected. Components are numbered in the order of their first triangle, so the
/// numbering depends on the scene alone.
pub fn components(scene: &Scene) -> Vec<u32> {
    let n = scene.triangles.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    // -0.0 and 0.0 are the same point.
    let bits = |v: glam::Vec3| v.to_array().map(|c| (c + 0.0).to_bits());
    let mut first: HashMap<[u32; 3], u32> = HashMap::with_capacity(n * 3 / 2);
    for (t, tri) in scene.triangles.iter().enumerate() {
        for p in tri.positions {
            let owner = *first.entry(bits(p)).or_insert(t as u32);
            // The smaller root wins, so roots are each component's first triangle.
            union(&mut parent, owner, t as u32);
        }
    }
    let mut number: HashMap<u32, u32> = HashMap::new();
    (0..n as u32)
        .map(|t| {
            let root = find(&mut parent, t);
            let next = number.len() as u32;
            *number.entry(root).or_insert(next)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::patch::{Face, Patch};
    use crate::scene::Triangle;
    use glam::Vec3;

    fn patch(voxel: [u32; 3], area: f32) -> Patch {
        Patch {
            voxel,
            face: Face::PosY,
            albedo: [0.5; 3],
            centroid: [0.0; 3],
            normal: [0.0, 1.0, 0.0],
            source_area: area,
            emission: [0.0; 3],
        }
    }

    fn layout(patches: Vec<Patch>) -> PatchLayout {
        PatchLayout {
            origin: [0.0; 3],
            voxel_size: 1.0,
            dims: [4, 4, 4],
            patches,
        }
    }

    /// Two patches: the first of area 4 split into elements of area 1 and 2 (1 dropped), the
    /// second one element covering it.
    fn sample() -> (PatchLayout, Elements) {
        let patches = layout(vec![patch([0, 0, 0], 4.0), patch([1, 0, 0], 3.0)]);
        let elements = Elements {
            layout: layout(vec![
                patch([0, 0, 0], 1.0),
                patch([0, 0, 0], 2.0),
                patch([1, 0, 0], 3.0),
            ]),
            patch: vec![0, 0, 1],
        };
        (patches, elements)
    }

    #[test]
    fn restriction_weights_elements_by_area() {
        let (patches, e) = sample();
        e.check(&patches).unwrap();
        // Two light sets.
        let per_element = [[4.0; 3], [1.0; 3], [2.0; 3], [0.0; 3], [8.0; 3], [1.0; 3]];
        let ind = e.restrict(&patches, &per_element);
        // (1·4 + 2·1) / 4 over the whole patch; the dropped quarter counts as unlit.
        assert_eq!(ind, vec![[1.5; 3], [2.0; 3], [4.0; 3], [1.0; 3]]);
        let direct = e.restrict_sampled(&patches, &per_element);
        assert_eq!(direct[0], [2.0; 3], "(4 + 2) / 3 over the sampled area");
        assert_eq!(e.spread(&[7, 9]), vec![7, 7, 9]);
    }

    #[test]
    fn check_refuses_elements_that_do_not_fit() {
        let (patches, e) = sample();
        let mut gap = e.clone();
        gap.patch = vec![0, 0, 0];
        assert!(gap.check(&patches).is_err());
        let mut back = e.clone();
        back.patch = vec![0, 1, 0];
        assert!(back.check(&patches).is_err());
        let mut moved = e.clone();
        moved.layout.patches[0].voxel = [2, 0, 0];
        assert!(moved.check(&patches).unwrap_err().contains("voxel"));
        let mut big = e.clone();
        big.layout.patches[1].source_area = 3.5;
        assert!(big.check(&patches).unwrap_err().contains("area"));
    }

    #[test]
    fn triangles_sharing_a_point_are_one_surface() {
        let tri = |a: Vec3, b: Vec3, c: Vec3| Triangle {
            positions: [a, b, c],
            albedo: Vec3::splat(0.5),
            emission: Vec3::ZERO,
            double_sided: false,
            material: 0,
        };
        let v = Vec3::new;
        let scene = Scene {
            triangles: vec![
                tri(v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0), v(0.0, 0.0, 0.0)),
                tri(v(5.0, 5.0, 5.0), v(6.0, 5.0, 5.0), v(5.0, 6.0, 5.0)),
                // Shares the -0.0 corner with the first: the same point.
                tri(v(-0.0, 0.0, 0.0), v(0.0, -1.0, 0.0), v(-1.0, 0.0, 0.0)),
                tri(v(6.0, 5.0, 5.0), v(7.0, 5.0, 5.0), v(6.0, 6.0, 5.0)),
                tri(v(9.0, 9.0, 9.0), v(9.5, 9.0, 9.0), v(9.0, 9.5, 9.0)),
            ],
            ..Default::default()
        };
        assert_eq!(components(&scene), vec![0, 1, 0, 1, 2]);
    }

    #[test]
    fn sub_cells_number_x_fastest_and_clamp_into_the_voxel() {
        assert_eq!(sub_cell([3, 4, 5], [1, 1, 1], 3), 3 * (1 + 3 * 2));
        assert_eq!(sub_cell([5, 5, 5], [1, 1, 1], 3), 2 + 3 * (2 + 3 * 2));
        // A fine cell of the neighbour (rounding on the boundary) stays in the voxel.
        assert_eq!(sub_cell([2, 6, 3], [1, 1, 1], 3), 2 * 3);
    }
}
