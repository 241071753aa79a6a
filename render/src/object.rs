//! The probe-lit test object (issue 22): a sphere that is none of the baked surfaces, lit the
//! way a moving object is, from the scene's irradiance probes (docs/design.md §2, "Probes").
//!
//! The probes nearest the sphere's centre are blended on the CPU into one **ambient cube**, six
//! irradiance values in the face order (+X, −X, +Y, −Y, +Z, −Z), uploaded as a small uniform;
//! the shader lights each fragment of normal `n` with
//! `E(n) = n.x² E[±X] + n.y² E[±Y] + n.z² E[±Z]` (the sign of each component picking the side),
//! plus the lights' direct irradiance and shadows as any surface. The blend is inverse-distance
//! weighting (`1 / d²`) over the [`BLEND_PROBES`] nearest probes: simple and continuous as the
//! object moves, but blind to walls (a probe behind a thin wall counts as much as one beside
//! the object), and the sphere casts no shadow and is not in the baked light.

use glam::Vec3;

use crate::camera::Camera;
use crate::gpu_types::Object;

/// How many of the nearest probes one ambient cube blends.
pub const BLEND_PROBES: usize = 8;

/// The test sphere: where it is, how big, its colour and the irradiance it gets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeSphere {
    pub centre: Vec3,
    pub radius: f32,
    /// Linear RGB.
    pub albedo: Vec3,
    /// The ambient cube at the centre ([`ambient_cube`]): irradiance facing +X, −X, +Y, −Y,
    /// +Z, −Z.
    pub cube: [[f32; 3]; 6],
}

impl ProbeSphere {
    /// A light grey sphere ahead of `camera`, sized by the scene's `bounds`: radius 3% of the
    /// diagonal, its centre six radii along the view direction.
    pub fn ahead_of(camera: &Camera, bounds: (Vec3, Vec3), cube: [[f32; 3]; 6]) -> ProbeSphere {
        let (lo, hi) = bounds;
        let radius = ((hi - lo).length() * 0.03).max(1e-3);
        let dir = (camera.target - camera.eye).normalize_or(Vec3::NEG_Z);
        ProbeSphere {
            centre: camera.eye + dir * radius * 6.0,
            radius,
            albedo: Vec3::splat(0.8),
            cube,
        }
    }

    /// `Object` in `shade.wgsl`.
    pub(crate) fn gpu(&self) -> Object {
        let mut cube = [[0.0; 4]; 6];
        for (c, e) in cube.iter_mut().zip(self.cube) {
            *c = [e[0], e[1], e[2], 0.0];
        }
        Object {
            centre: self.centre.to_array(),
            radius: self.radius,
            albedo: self.albedo.to_array(),
            pad: 0,
            cube,
        }
    }
}

/// The ambient cube at `at` from the probes at `positions` with `irradiance` (six values a
/// probe, `6 · k + direction`, as a relight or a probe frame gives them): inverse-distance
/// weights (`1 / d²`) over the [`BLEND_PROBES`] nearest, a probe's own values where `at` is on
/// it. `None` without probes or when the counts disagree.
pub fn ambient_cube(
    positions: &[Vec3],
    irradiance: &[[f32; 3]],
    at: Vec3,
) -> Option<[[f32; 3]; 6]> {
    if positions.is_empty() || irradiance.len() != 6 * positions.len() {
        return None;
    }
    let mut near: Vec<(f32, usize)> = positions
        .iter()
        .enumerate()
        .map(|(k, p)| (p.distance_squared(at), k))
        .filter(|(d2, _)| d2.is_finite())
        .collect();
    let keep = BLEND_PROBES.min(near.len());
    if keep == 0 {
        return None;
    }
    near.select_nth_unstable_by(keep - 1, |a, b| a.0.total_cmp(&b.0));
    near.truncate(keep);
    let own = |k: usize| -> [[f32; 3]; 6] { std::array::from_fn(|d| irradiance[6 * k + d]) };
    if let Some(&(_, k)) = near.iter().find(|(d2, _)| *d2 <= 1e-12) {
        return Some(own(k));
    }
    let mut sum = [Vec3::ZERO; 6];
    let mut total = 0.0;
    for &(d2, k) in &near {
        let w = 1.0 / d2;
        total += w;
        for (s, e) in sum.iter_mut().zip(own(k)) {
            *s += Vec3::from_array(e) * w;
        }
    }
    Some(sum.map(|s| (s / total).to_array()))
}

/// The cube's irradiance for a surface of unit normal `n`: the shader's `cube_irradiance`.
pub fn cube_irradiance(cube: &[[f32; 3]; 6], n: Vec3) -> Vec3 {
    let side = |axis: usize, c: f32| Vec3::from_array(cube[2 * axis + usize::from(c < 0.0)]);
    side(0, n.x) * n.x * n.x + side(1, n.y) * n.y * n.y + side(2, n.z) * n.z * n.z
}

/// A unit sphere as a triangle list (no index buffer, as the scene's): positions, which are
/// also the normals, wound counter-clockwise seen from outside.
pub(crate) fn unit_sphere(rings: u32, segments: u32) -> Vec<[f32; 3]> {
    let point = |ring: u32, seg: u32| -> [f32; 3] {
        let theta = std::f32::consts::PI * ring as f32 / rings as f32;
        let phi = std::f32::consts::TAU * seg as f32 / segments as f32;
        [
            theta.sin() * phi.cos(),
            theta.cos(),
            -theta.sin() * phi.sin(),
        ]
    };
    let mut out = Vec::with_capacity((rings * segments * 6) as usize);
    for r in 0..rings {
        for s in 0..segments {
            let (a, b) = (point(r, s), point(r + 1, s));
            let (c, d) = (point(r + 1, s + 1), point(r, s + 1));
            out.extend_from_slice(&[a, b, c, a, c, d]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube_of(k: f32) -> [[f32; 3]; 6] {
        std::array::from_fn(|d| [k + d as f32, 2.0 * k, 0.0])
    }

    #[test]
    fn a_cube_gives_each_axis_its_own_side_and_blends_between() {
        let cube = cube_of(10.0);
        for (d, n) in [
            Vec3::X,
            Vec3::NEG_X,
            Vec3::Y,
            Vec3::NEG_Y,
            Vec3::Z,
            Vec3::NEG_Z,
        ]
        .into_iter()
        .enumerate()
        {
            assert_eq!(cube_irradiance(&cube, n), Vec3::from_array(cube[d]));
        }
        // Halfway between −X and +Y: half of each.
        let n = Vec3::new(-1.0, 1.0, 0.0).normalize();
        let e = cube_irradiance(&cube, n);
        let want = (Vec3::from_array(cube[1]) + Vec3::from_array(cube[2])) / 2.0;
        assert!((e - want).length() < 1e-5, "{e} {want}");
        // Six equal sides: the same for every normal.
        let flat = [[3.0, 2.0, 1.0]; 6];
        let e = cube_irradiance(&flat, Vec3::new(0.3, -0.5, 0.7).normalize());
        assert!((e - Vec3::new(3.0, 2.0, 1.0)).length() < 1e-5, "{e}");
    }

    #[test]
    fn the_blend_weighs_the_nearest_probes_by_inverse_square_distance() {
        let positions = [Vec3::ZERO, Vec3::X * 2.0, Vec3::X * 100.0];
        let irradiance: Vec<[f32; 3]> = [cube_of(1.0), cube_of(4.0), cube_of(1000.0)].concat();
        // On a probe: that probe.
        assert_eq!(
            ambient_cube(&positions, &irradiance, Vec3::X * 2.0),
            Some(cube_of(4.0))
        );
        // At x = 0.5: weights 1/0.25 and 1/2.25 (the far probe counts for almost nothing).
        let c = ambient_cube(&positions, &irradiance, Vec3::X * 0.5).unwrap();
        let (w0, w1, w2) = (4.0f32, 1.0 / 2.25, 1.0 / 99.5f32.powi(2));
        let want = (1.0 * w0 + 4.0 * w1 + 1000.0 * w2) / (w0 + w1 + w2);
        assert!((c[0][0] - want).abs() < 1e-4, "{} {want}", c[0][0]);
        assert!((c[0][1] - 2.0 * want).abs() < 1e-4);
        // Only the nearest BLEND_PROBES count.
        let many: Vec<Vec3> = (0..20).map(|i| Vec3::X * i as f32).collect();
        let values: Vec<[f32; 3]> = (0..20)
            .flat_map(|i| [[if i < BLEND_PROBES { 1.0 } else { 1e6 }, 0.0, 0.0]; 6])
            .collect();
        let c = ambient_cube(&many, &values, Vec3::new(-0.5, 0.0, 0.0)).unwrap();
        assert!((c[3][0] - 1.0).abs() < 1e-5, "{c:?}");
        // No probes, or values that do not fit them: nothing.
        assert_eq!(ambient_cube(&[], &[], Vec3::ZERO), None);
        assert_eq!(ambient_cube(&positions, &irradiance[..6], Vec3::ZERO), None);
    }

    #[test]
    fn the_sphere_faces_outward() {
        let tris = unit_sphere(8, 16);
        assert_eq!(tris.len(), 8 * 16 * 6);
        for t in tris.chunks_exact(3) {
            let [a, b, c] = [t[0], t[1], t[2]].map(Vec3::from_array);
            assert!((a.length() - 1.0).abs() < 1e-5);
            let n = (b - a).cross(c - a);
            // Degenerate at the poles; otherwise outward.
            if n.length() > 1e-6 {
                assert!(n.dot(a + b + c) > 0.0, "{a} {b} {c}");
            }
        }
    }
}
