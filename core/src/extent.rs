//! A scene's extent against the size of its triangles, checked before voxelisation.
//!
//! A scene whose bounds are many orders of magnitude larger than its typical triangle (one stray
//! vertex at 1e9 in a room of one-unit triangles) cannot be baked to anything useful: every
//! voxel size either lumps the real geometry into a handful of voxels or cuts the stray
//! triangles, which span the whole extent, into millions of pieces and patches, each probed and
//! clipped. Before this check such a scene ran voxelisation for minutes and a gigabyte (issue
//! 19); now it is refused at once, naming the stray vertex.

use glam::Vec3;
use thiserror::Error;

use crate::scene::Scene;

/// The most a scene's largest extent may be, as a multiple of its median triangle's longest
/// edge. A bake has at most [`crate::voxel::MAX_PATCHES`] patches, so its voxels are at least
/// about extent / 150 across in a cube-shaped scene; a triangle a million times smaller than the
/// extent is far below any voxel a bake can make, so a real scene is nowhere near this.
pub const MAX_EXTENT_RATIO: f64 = 1e6;

/// A scene whose extent is absurd against its triangles.
#[derive(Debug, Clone, Error, PartialEq)]
#[error(
    "the scene spans {extent:.3e} units, but half its triangles are under {median_edge:.3e} \
     units across (a ratio over {MAX_EXTENT_RATIO:.0e}): a stray vertex, probably the one at \
     {farthest:?} in triangle {triangle}; fix the model (or its units) and bake again"
)]
pub struct AbsurdExtent {
    pub extent: f64,
    pub median_edge: f64,
    /// The vertex farthest from the median of the triangles' centres, and its triangle.
    pub farthest: [f32; 3],
    pub triangle: usize,
}

/// Refuses a scene whose largest extent passes [`MAX_EXTENT_RATIO`] × its median triangle's
/// longest edge. Linear in the triangles (one selection, no sort).
pub fn check(scene: &Scene) -> Result<(), AbsurdExtent> {
    let Some((lo, hi)) = scene.bounds() else {
        return Ok(());
    };
    let extent = f64::from((hi - lo).max_element());
    let mut edges: Vec<f64> = scene
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.positions.map(|p| p.as_dvec3());
            (a - b).length().max((b - c).length()).max((c - a).length())
        })
        .filter(|e| e.is_finite() && *e > 0.0)
        .collect();
    if edges.is_empty() {
        return Ok(());
    }
    let mid = edges.len() / 2;
    let (_, &mut median_edge, _) = edges.select_nth_unstable_by(mid, f64::total_cmp);
    if extent.is_nan() || extent <= MAX_EXTENT_RATIO * median_edge {
        return Ok(());
    }
    // Name the vertex farthest from where most of the scene is: the per-axis median of the
    // triangles' first vertices.
    let median_axis = |axis: usize| {
        let mut v: Vec<f32> = scene
            .triangles
            .iter()
            .map(|t| t.positions[0][axis])
            .collect();
        let m = v.len() / 2;
        *v.select_nth_unstable_by(m, f32::total_cmp).1
    };
    let centre = Vec3::new(median_axis(0), median_axis(1), median_axis(2)).as_dvec3();
    let (triangle, farthest) = scene
        .triangles
        .iter()
        .enumerate()
        .flat_map(|(i, t)| t.positions.map(|p| (i, p)))
        .max_by(|a, b| {
            let d = |p: Vec3| (p.as_dvec3() - centre).length();
            d(a.1).total_cmp(&d(b.1))
        })
        .unwrap_or((0, lo));
    Err(AbsurdExtent {
        extent,
        median_edge,
        farthest: farthest.to_array(),
        triangle,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Triangle;

    fn tri(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> Triangle {
        Triangle {
            positions: [Vec3::from(a), Vec3::from(b), Vec3::from(c)],
            albedo: Vec3::splat(0.5),
            emission: Vec3::ZERO,
            double_sided: false,
            material: 0,
        }
    }

    /// A unit floor of `n`×`n` unit squares, and optionally one more triangle reaching `far`.
    fn floor(n: usize, far: Option<f32>) -> Scene {
        let mut triangles = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let (x, z) = (i as f32, j as f32);
                triangles.push(tri([x, 0.0, z], [x + 1.0, 0.0, z], [x, 0.0, z + 1.0]));
                triangles.push(tri(
                    [x + 1.0, 0.0, z],
                    [x + 1.0, 0.0, z + 1.0],
                    [x, 0.0, z + 1.0],
                ));
            }
        }
        if let Some(far) = far {
            triangles.push(tri([0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [far, 0.0, 0.0]));
        }
        Scene {
            triangles,
            ..Scene::default()
        }
    }

    #[test]
    fn a_stray_vertex_far_from_a_small_scene_is_named() {
        assert_eq!(check(&floor(4, None)), Ok(()));
        // Large, but a bake of it still means something.
        assert_eq!(check(&floor(4, Some(1e5))), Ok(()));
        for far in [1e9f32, 1e20, 1e30] {
            let e = check(&floor(4, Some(far))).unwrap_err();
            assert_eq!(e.triangle, 32, "{e}");
            assert_eq!(e.farthest, [far, 0.0, 0.0]);
            let message = e.to_string();
            assert!(message.contains("a stray vertex"), "{message}");
        }
    }
}
