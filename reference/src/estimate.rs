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
//!
//! Light that surfaces emit is sampled both ways and the two combined by multiple importance
//! sampling (Veach's balance heuristic): at `x` and at every vertex whose next bounce the mode
//! still counts, one point drawn on the emitting triangles (in proportion to their power,
//! [`EmitterSampler`]) with a shadow ray; and where the path's own next ray meets an emitter,
//! its emission. Each is weighted by its density over the sum of both, so emission is counted
//! once. A small emitter (a lamp's shade) is then found by every vertex, not only by the few
//! paths that hit it, and a point beside a large emitter keeps the cosine sampling that suits it.
//! Emission is exitance `M` (Lambertian, radiance `M/π`), emitted on a one-sided triangle's
//! front only.

use bounce_core::meta::Bounces;
use glam::Vec3;

use crate::lights::{EmitterSampler, Illumination, Sky, Source};
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
    // Emitted light straight to `x` is its first bounce.
    let mut total = emitted(mesh, lights, x, n, rng);
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
        // Emission met by the path, weighted against the vertex's own sample of the emitters.
        if let Some(sampler) = &lights.emitters {
            let m = lights.emission(hit.tri, tri.emission);
            if m.max_element() > 0.0 {
                let cos_p = dir.dot(tri.normal).abs();
                let cos_x = dir.dot(n).max(0.0);
                let light = sampler.chance(hit.tri) / f64::from(tri.area())
                    * f64::from(hit.t * hit.t)
                    / f64::from(cos_p).max(1e-12);
                let bsdf = f64::from(cos_x) * std::f64::consts::FRAC_1_PI;
                total += throughput * m * (bsdf / (bsdf + light)) as f32;
            }
        } else {
            total += throughput * lights.emission(hit.tri, tri.emission);
        }
        let mut e_direct = direct(mesh, &lights.sources, y, facing);
        if let Some(sky) = &lights.sky {
            e_direct += sky_direct(mesh, sky, y, facing, rng);
        }
        // Emitted light reflected at `y` reaches `x` in one bounce more than `y`'s direct light.
        if bounce + 1 < max {
            e_direct += emitted(mesh, lights, y, facing, rng);
        }
        total += throughput * tri.albedo * e_direct;
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

/// One estimate of the irradiance at `y` (normal `n`) from the emitting triangles: a point `p`
/// on them, `M(p)/π · cos θ_y · cos θ_p / r²` over its density, if nothing lies between.
pub(crate) fn emitted(
    mesh: &Mesh,
    lights: &Illumination,
    y: Vec3,
    n: Vec3,
    rng: &mut Pcg32,
) -> Vec3 {
    let Some(sampler) = &lights.emitters else {
        return Vec3::ZERO;
    };
    sample_emitter(mesh, lights, sampler, y, n, rng)
}

fn sample_emitter(
    mesh: &Mesh,
    lights: &Illumination,
    sampler: &EmitterSampler,
    y: Vec3,
    n: Vec3,
    rng: &mut Pcg32,
) -> Vec3 {
    let (index, chance) = sampler.pick(rng.next_f32());
    let tri = &mesh.tris[index as usize];
    // A uniform point on the triangle.
    let (u1, u2) = (rng.next_f32().sqrt(), rng.next_f32());
    let p = tri.p0 + tri.e1 * (u1 * (1.0 - u2)) + tri.e2 * (u1 * u2);
    let d = p - y;
    let r2 = d.length_squared();
    if r2 <= 0.0 || !r2.is_finite() {
        return Vec3::ZERO;
    }
    let dist = r2.sqrt();
    let w = d / dist;
    let cos_y = n.dot(w);
    // The side of the emitter `y` sees: its front, or its back where it is double-sided.
    let cos_p = match -tri.normal.dot(w) {
        c if c > 0.0 => c,
        c if tri.double_sided => -c,
        _ => 0.0,
    };
    if cos_y <= 0.0 || cos_p <= 0.0 {
        return Vec3::ZERO;
    }
    let origin = y + n * mesh.epsilon;
    // Stop short of the emitter itself.
    let reach = (p - origin).length() - 2.0 * mesh.epsilon;
    if reach > 0.0 && mesh.occluded(origin, (p - origin) / (p - origin).length(), reach) {
        return Vec3::ZERO;
    }
    // Densities over the solid angle at `y`: the point's, and cosine sampling's.
    let light = chance / f64::from(tri.area()) * f64::from(r2) / f64::from(cos_p);
    let bsdf = f64::from(cos_y) * std::f64::consts::FRAC_1_PI;
    let m = lights.emission(index, tri.emission);
    // Radiance M/π times cos θ_y over the density, weighted by light / (light + bsdf).
    m * (std::f64::consts::FRAC_1_PI * f64::from(cos_y) / (light + bsdf)) as f32
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
pub(crate) fn cosine_direction(n: Vec3, rng: &mut Pcg32) -> Vec3 {
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
