//! The Monte-Carlo estimator of indirect irradiance.
//!
//! In the convention of the design (`E_ind = T B0`, `B0 = L_e + ρ E_direct`, `T_k` carrying `k`
//! bounces), the indirect irradiance at `x` with `k` bounces is what arrives from the surfaces
//! `x` sees, each leaving `L_e + ρ (E_direct + E_ind,k−1)` (exitance, Lambertian), with
//! `E_ind,0 = 0`. Sampling the direction cosine-weighted (`pdf = cos/π`) makes one path's
//! estimate `L_e(y) + ρ(y) (E_direct(y) + Ê_ind,k−1(y))` at the surface `y` it meets, unrolled
//! below with a throughput. Direct light at `y` is next-event estimation: punctual lights are
//! deltas, so one shadow ray per light is exact. For all bounces, paths end by Russian roulette
//! after a few bounces (unbiased; the survival chance is the throughput's largest albedo).
//!
//! The sky's share of `E_direct(y)`, `∫ L_sky(ω) V(y, ω) cos θ dω`, is next-event estimation
//! too: one more cosine-weighted ray from `y`, which gives `π L_sky(ω)` where it escapes (meets
//! no triangle, front or back) and nothing otherwise. The path's own continuing ray that
//! escapes carries nothing, so the sky is counted once; and the first ray from `x` carries
//! nothing either way, since light straight from the sky to `x` is `x`'s direct light, not
//! indirect.

use bounce_core::meta::Bounces;
use glam::Vec3;

use crate::lights::{Illumination, Sky, Source};
use crate::mesh::Mesh;
use crate::rng::Pcg32;

/// Bounces with every path kept before Russian roulette starts (all-bounce mode).
const ROULETTE_AFTER: u32 = 3;
/// A path in all-bounce mode ends here whatever roulette says: albedo ≤ 1 keeps it finite
/// anyway, but a closed room of albedo 1 would otherwise never end.
const MAX_BOUNCES: u32 = 10_000;

/// One indirect-irradiance sample at `x` (unit normal `n`, on the side the light arrives at).
pub(crate) fn sample(
    mesh: &Mesh,
    lights: &Illumination,
    x: Vec3,
    n: Vec3,
    bounces: Bounces,
    rng: &mut Pcg32,
) -> Vec3 {
    let max = match bounces {
        Bounces::K(k) => k,
        Bounces::All => MAX_BOUNCES,
    };
    let mut total = Vec3::ZERO;
    let mut throughput = Vec3::ONE;
    let (mut x, mut n) = (x, n);
    for bounce in 0..max {
        let dir = cosine_direction(n, rng);
        let origin = x + n * mesh.epsilon;
        let Some(hit) = mesh.closest(origin, dir) else {
            break;
        };
        let tri = &mesh.tris[hit.tri as usize];
        // The side the ray arrives at. A one-sided surface seen from behind reflects and emits
        // nothing there (the bake's patches are one-sided too): the path ends in it.
        let facing = if dir.dot(tri.normal) < 0.0 {
            tri.normal
        } else if tri.double_sided {
            -tri.normal
        } else {
            break;
        };
        let y = origin + dir * hit.t;
        let mut e_direct = direct(mesh, &lights.sources, y, facing);
        if let Some(sky) = &lights.sky {
            e_direct += sky_direct(mesh, sky, y, facing, rng);
        }
        total += throughput * (tri.emission + tri.albedo * e_direct);
        throughput *= tri.albedo;
        if matches!(bounces, Bounces::All) && bounce + 1 >= ROULETTE_AFTER {
            let survive = throughput.max_element().min(1.0);
            if survive <= 0.0 || rng.next_f32() >= survive {
                break;
            }
            throughput /= survive;
        }
        if throughput.max_element() <= 0.0 {
            break;
        }
        (x, n) = (y, facing);
    }
    total
}

/// Irradiance from the punctual lights at `y` (normal `n`), shadowed by the full mesh.
pub(crate) fn direct(mesh: &Mesh, sources: &[Source], y: Vec3, n: Vec3) -> Vec3 {
    let origin = y + n * mesh.epsilon;
    sources
        .iter()
        .filter_map(|s| s.arrive(origin, n))
        .filter(|a| !mesh.occluded(origin, a.dir, a.distance))
        .map(|a| a.irradiance)
        .sum()
}

/// One estimate of the sky's irradiance at `y` (normal `n`): `π L(ω)` along one cosine-weighted
/// direction `ω` if it escapes the mesh, else 0.
pub(crate) fn sky_direct(mesh: &Mesh, sky: &Sky, y: Vec3, n: Vec3, rng: &mut Pcg32) -> Vec3 {
    let dir = cosine_direction(n, rng);
    let origin = y + n * mesh.epsilon;
    if mesh.closest(origin, dir).is_some() {
        return Vec3::ZERO;
    }
    std::f32::consts::PI * sky.radiance(dir)
}

/// A cosine-distributed unit direction about `n` (Malley's method: a uniform disc point lifted
/// onto the hemisphere).
fn cosine_direction(n: Vec3, rng: &mut Pcg32) -> Vec3 {
    let (u1, u2) = (rng.next_f32(), rng.next_f32());
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (t, b) = n.any_orthonormal_pair();
    let z = (1.0 - u1).max(0.0).sqrt();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_directions_have_mean_cosine_two_thirds() {
        let mut rng = Pcg32::new(3, 9);
        let n = Vec3::new(0.3, -0.5, 0.8).normalize();
        let count = 200_000;
        let mut sum = 0.0f64;
        for _ in 0..count {
            let d = cosine_direction(n, &mut rng);
            let c = d.dot(n);
            assert!(c >= -1e-6 && (d.length() - 1.0).abs() < 1e-5);
            sum += f64::from(c);
        }
        // E[cos θ] under pdf cos θ/π is 2/3.
        assert!((sum / count as f64 - 2.0 / 3.0).abs() < 0.003);
    }
}
