//! Direct-light sample points: what one is, and which of an element's samples stands for a point
//! of its surface.
//!
//! A surface bake stores a few sample points per transport row ([`crate::surface`]); the server
//! evaluates each light at each of them. The bake also gives rays to them: a form-factor ray that
//! lands near its origin is credited to the sample standing for where it landed (the near field,
//! [`crate::nearfield`]), and every ray to the sample standing for where it started (that
//! sample's view of the sky, [`crate::sky`]). Both use [`nearest_sample`], so they credit the
//! same sample. This module owns only that vocabulary, so the modules that trace rays
//! ([`crate::formfactor`], [`crate::surface`]) and the sky's sums can all use it without using
//! each other.

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// A point on a patch's surface where direct light is evaluated, with the unit normal of the
/// side the patch stands for. The position is already pushed off the surface along the normal
/// ([`crate::trimesh::offset_origin`]), so shadow rays start from it as is, on the CPU and the
/// GPU alike.
#[repr(C)]
#[derive(
    Debug, Clone, Copy, PartialEq, Serialize, Deserialize, bytemuck::Pod, bytemuck::Zeroable,
)]
pub struct SamplePoint {
    pub position: [f32; 3],
    pub normal: [f32; 3],
}

/// Checks albedos read from a file, one for each of `expected` things named `what` ("sample",
/// "entry"): the count, and every channel within `[0, 1]`, as a reflectance must be. The
/// message says which one failed.
pub fn check_albedo(albedo: &[[f32; 3]], expected: usize, what: &str) -> Result<(), String> {
    if albedo.len() != expected {
        return Err(format!(
            "{} {what} albedos, {expected} expected",
            albedo.len()
        ));
    }
    match albedo
        .iter()
        .position(|a| !a.iter().all(|c| (0.0..=1.0).contains(c)))
    {
        Some(i) => Err(format!(
            "{what} {i}'s albedo {:?} is not within [0, 1]",
            albedo[i]
        )),
        None => Ok(()),
    }
}

/// How much more an offset across a surface counts than one along it, in squared distance, when
/// a sample is chosen for a point ([`nearest_sample`]).
const ACROSS_WEIGHT: f32 = 64.0;

/// Which of `samples` stands for the surface point `to` of unit normal `normal`: the one nearest
/// in a distance that counts offsets across the surfaces heavily,
///
/// ```text
/// |q − x|² + w · ((n_x · (q − x))² + (n_q · (q − x))²),    w = 64,
/// ```
///
/// the first on a tie; 0 when there are none. An element groups pieces by the direction they
/// face most, so it may hold a wall and the slanted trim beside it, or a floor and a step: a
/// point on the trim is lit and shadowed as the trim is, not as the wall sample that happens to
/// lie nearer, and the wall sample lies off the trim's plane. On a smoothly curved surface a
/// nearby sample lies almost on the point's tangent plane (off it by about `κ d² / 2`), so it
/// stays the nearest. `w` was chosen on `pandora` and the sheen chair, against the plain nearest
/// sample and the nearest "facing within 8°" (README, "A near landing goes to a sample on its own
/// surface"): larger took `pandora` closer to its reference and the chair, past 16, slightly
/// away.
pub(crate) fn nearest_sample(samples: &[SamplePoint], to: Vec3, normal: Vec3) -> usize {
    samples
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let d = Vec3::from(s.position) - to;
            let (a, b) = (normal.dot(d), Vec3::from(s.normal).dot(d));
            (i, d.length_squared() + ACROSS_WEIGHT * (a * a + b * b))
        })
        .fold(
            (0, f32::INFINITY),
            |best, c| if c.1 < best.1 { c } else { best },
        )
        .0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(position: [f32; 3], normal: [f32; 3]) -> SamplePoint {
        SamplePoint { position, normal }
    }

    #[test]
    fn a_point_goes_to_the_nearest_sample_on_its_own_surface() {
        // A floor (y = 0, facing up) meeting a trim that rises at 30° from x = 0.
        let tilt = Vec3::new(-0.5, 3f32.sqrt() / 2.0, 0.0);
        let on_trim = |s: f32| Vec3::new(s * tilt.y, -s * tilt.x, 0.0);
        let floor = |x: f32| sample([x, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let trim = |s: f32| sample(on_trim(s).to_array(), tilt.to_array());
        let distance = |s: &SamplePoint, p: Vec3| Vec3::from(s.position).distance(p);
        // A floor point beside the crease: a trim sample lies nearer, off the floor's plane.
        let samples = [floor(-0.3), trim(0.15), trim(0.9)];
        let x = Vec3::new(-0.05, 0.0, 0.0);
        assert!(distance(&samples[1], x) < distance(&samples[0], x));
        assert_eq!(nearest_sample(&samples, x, Vec3::Y), 0);
        // Far up the trim, its upper sample.
        assert_eq!(nearest_sample(&samples, on_trim(0.8), tilt), 2);
        // A trim point beside the crease: a floor sample lies nearer, off the trim's plane.
        let samples = [floor(-0.15), trim(0.4)];
        let t = on_trim(0.1);
        assert!(distance(&samples[0], t) < distance(&samples[1], t));
        assert_eq!(nearest_sample(&samples, t, tilt), 1);
    }

    #[test]
    fn on_a_curved_surface_the_nearest_sample_stays_nearest() {
        // A cylinder of radius 1 about z, samples every 10°; a point between the 0° and 10°
        // samples, nearer the 10° one, goes to it although the 0° one faces more nearly as it.
        let at = |deg: f32| {
            let r = deg.to_radians();
            sample([r.cos(), r.sin(), 0.0], [r.cos(), r.sin(), 0.0])
        };
        let samples = [at(0.0), at(10.0), at(20.0), at(40.0)];
        let r = 6f32.to_radians();
        let p = Vec3::new(r.cos(), r.sin(), 0.0);
        assert_eq!(nearest_sample(&samples, p, p), 1);
        let r = 4f32.to_radians();
        let p = Vec3::new(r.cos(), r.sin(), 0.0);
        assert_eq!(nearest_sample(&samples, p, p), 0);
    }

    #[test]
    fn a_parallel_surface_a_step_away_loses_to_one_farther_along() {
        // A floor sample 1 away, and a step top 0.3 above, 0.2 across: the floor's own sample.
        let samples = [
            sample([0.2, 0.3, 0.0], [0.0, 1.0, 0.0]),
            sample([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        ];
        assert_eq!(nearest_sample(&samples, Vec3::ZERO, Vec3::Y), 1);
        // Without the step the nearer floor sample wins; on a tie the first; none gives 0.
        let flat = [sample([0.2, 0.0, 0.0], [0.0, 1.0, 0.0]), samples[1]];
        assert_eq!(nearest_sample(&flat, Vec3::ZERO, Vec3::Y), 0);
        let twins = [flat[0], flat[0]];
        assert_eq!(nearest_sample(&twins, Vec3::ZERO, Vec3::Y), 0);
        assert_eq!(nearest_sample(&[], Vec3::ZERO, Vec3::Y), 0);
    }
}
