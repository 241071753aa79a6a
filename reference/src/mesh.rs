//! The original triangles, in a BVH, with the reference's own ray–triangle test.

use bounce_core::scene::Scene;
use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::ray::{Ray, RayHit};
use obvhs::{Boundable, BvhBuildParams};

/// One triangle as the tracer needs it: a corner, two edges, and what it reflects and emits.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Tri {
    pub p0: Vec3,
    pub e1: Vec3,
    pub e2: Vec3,
    /// Unit geometric normal (the winding's side).
    pub normal: Vec3,
    pub albedo: Vec3,
    pub emission: Vec3,
    pub double_sided: bool,
    /// Index into the scene's materials: which emissive changes apply to it.
    pub material: u32,
}

impl Boundable for Tri {
    fn aabb(&self) -> Aabb {
        let (a, b, c) = (self.p0, self.p0 + self.e1, self.p0 + self.e2);
        Aabb::new(Vec3A::from(a.min(b).min(c)), Vec3A::from(a.max(b).max(c)))
    }
}

impl Tri {
    pub fn area(&self) -> f32 {
        0.5 * self.e1.cross(self.e2).length()
    }

    /// Möller–Trumbore: the distance along the ray if it crosses the triangle (either side) at
    /// `t` in `(t_min, t_max)`.
    #[inline]
    pub(crate) fn intersect(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Option<f32> {
        let p = dir.cross(self.e2);
        let det = self.e1.dot(p);
        if det.abs() < 1e-20 {
            return None;
        }
        let inv = 1.0 / det;
        let s = origin - self.p0;
        let u = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(self.e1);
        let v = dir.dot(q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let t = self.e2.dot(q) * inv;
        (t > t_min && t < t_max).then_some(t)
    }
}

/// A ray's first crossing.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hit {
    pub t: f32,
    pub tri: u32,
}

/// The scene's triangles and their BVH.
pub(crate) struct Mesh {
    pub tris: Vec<Tri>,
    bvh: Bvh2,
    /// Rays start this far along their normal and ignore crossings nearer than it: a fraction
    /// of the scene's size, so a scene in millimetres and one in kilometres behave alike.
    pub epsilon: f32,
}

impl Mesh {
    /// `None` when the scene has no triangle with an area.
    pub fn new(scene: &Scene) -> Option<Mesh> {
        let tris: Vec<Tri> = scene
            .triangles
            .iter()
            .filter_map(|t| {
                let [a, b, c] = t.positions;
                let normal = (b - a).cross(c - a).try_normalize()?;
                Some(Tri {
                    p0: a,
                    e1: b - a,
                    e2: c - a,
                    normal,
                    albedo: t.albedo,
                    emission: t.emission,
                    double_sided: t.double_sided,
                    material: t.material,
                })
            })
            .collect();
        if tris.is_empty() {
            return None;
        }
        let (lo, hi) = tris.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), t| {
                let b = t.aabb();
                (lo.min(b.min.into()), hi.max(b.max.into()))
            },
        );
        let bvh = obvhs::bvh2::builder::build_bvh2(
            &tris,
            BvhBuildParams::medium_build(),
            &mut std::time::Duration::default(),
        );
        Some(Mesh {
            tris,
            bvh,
            epsilon: (hi - lo).length() * 1e-5,
        })
    }

    /// The first triangle the ray meets beyond `epsilon`.
    pub fn closest(&self, origin: Vec3, dir: Vec3) -> Option<Hit> {
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), 0.0, f32::INFINITY);
        let mut hit = RayHit::none();
        let eps = self.epsilon;
        let found = self.bvh.ray_traverse(ray, &mut hit, |ray, prim| {
            let tri = &self.tris[self.bvh.primitive_indices[prim] as usize];
            tri.intersect(origin, dir, eps, ray.tmax)
                .unwrap_or(f32::INFINITY)
        });
        found.then(|| Hit {
            t: hit.t,
            tri: self.bvh.primitive_indices[hit.primitive_id as usize],
        })
    }

    /// Whether anything lies on the ray between `epsilon` and `max_t`.
    pub fn occluded(&self, origin: Vec3, dir: Vec3, max_t: f32) -> bool {
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), 0.0, max_t);
        let eps = self.epsilon;
        !self.bvh.ray_traverse_miss(ray, |ray, prim| {
            let tri = &self.tris[self.bvh.primitive_indices[prim] as usize];
            tri.intersect(origin, dir, eps, ray.tmax)
                .unwrap_or(f32::INFINITY)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounce_core::scene::Triangle;

    fn scene(triangles: &[[Vec3; 3]]) -> Scene {
        Scene {
            triangles: triangles
                .iter()
                .map(|&positions| Triangle {
                    positions,
                    albedo: Vec3::splat(0.5),
                    emission: Vec3::ZERO,
                    double_sided: false,
                    material: 0,
                })
                .collect(),
            ..Scene::default()
        }
    }

    #[test]
    fn rays_find_the_nearest_triangle_from_either_side() {
        let quad = |z: f32| {
            [
                [
                    Vec3::new(-1., -1., z),
                    Vec3::new(1., -1., z),
                    Vec3::new(1., 1., z),
                ],
                [
                    Vec3::new(-1., -1., z),
                    Vec3::new(1., 1., z),
                    Vec3::new(-1., 1., z),
                ],
            ]
        };
        let mut tris = quad(1.0).to_vec();
        tris.extend(quad(3.0));
        // A zero-area sliver is dropped, not intersected.
        tris.push([Vec3::ZERO, Vec3::X, Vec3::X * 2.0]);
        let mesh = Mesh::new(&scene(&tris)).unwrap();
        assert_eq!(mesh.tris.len(), 4);
        let hit = mesh.closest(Vec3::new(0.2, 0.3, 0.0), Vec3::Z).unwrap();
        assert!((hit.t - 1.0).abs() < 1e-6);
        assert!(hit.tri < 2);
        let back = mesh.closest(Vec3::new(0.2, 0.3, 4.0), -Vec3::Z).unwrap();
        assert!((back.t - 1.0).abs() < 1e-6);
        assert!(back.tri >= 2);
        assert!(mesh.closest(Vec3::new(5.0, 0.0, 0.0), Vec3::Z).is_none());
        assert!(mesh.occluded(Vec3::new(0.2, 0.3, 0.0), Vec3::Z, 1.5));
        assert!(!mesh.occluded(Vec3::new(0.2, 0.3, 0.0), Vec3::Z, 0.9));
        // Starting on a surface does not hit that surface again.
        let from_surface = mesh.closest(Vec3::new(0.2, 0.3, 1.0), Vec3::Z).unwrap();
        assert!((from_surface.t - 2.0).abs() < 1e-5);
        assert!(Mesh::new(&scene(&[[Vec3::ZERO; 3]])).is_none());
    }
}
