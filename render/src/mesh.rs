//! The scene's triangles as the GPU draws them: one vertex buffer, and the base-colour maps in
//! one texture array (layer 0 is white, for untextured surfaces).

use std::collections::HashMap;

use bounce_core::scene::Scene;
use glam::Vec3;

use crate::gpu_types::Vertex;

/// Vertices (three a triangle, no index buffer: materials are resolved per triangle) and the
/// albedo maps they sample.
pub(crate) struct Mesh {
    pub vertices: Vec<Vertex>,
    pub maps: AlbedoMaps,
}

/// Square RGBA8 (sRGB) layers of one side with their mip chains; layer `i` level `l` is
/// `levels[i][l]`.
pub(crate) struct AlbedoMaps {
    pub side: u32,
    pub levels: Vec<Vec<Vec<u8>>>,
}

impl AlbedoMaps {
    fn white() -> AlbedoMaps {
        AlbedoMaps {
            side: 1,
            levels: vec![vec![vec![255; 4]]],
        }
    }

    pub fn mip_count(&self) -> u32 {
        self.side.ilog2() + 1
    }
}

/// Triangles with the bake's averaged albedo (the importer resolves materials per triangle) and
/// smoothed corner normals ([`corner_normals`]).
pub(crate) fn mesh(scene: &Scene) -> Mesh {
    let normals = corner_normals(scene);
    let vertices = scene
        .triangles
        .iter()
        .zip(normals)
        .flat_map(|(t, n)| {
            [0, 1, 2].map(|k| Vertex {
                position: t.positions[k].to_array(),
                normal: n[k].to_array(),
                albedo: t.albedo.to_array(),
                emission: t.emission.to_array(),
                uv: [0.0; 2],
                layer: 0,
                pad: 0,
            })
        })
        .collect();
    Mesh {
        vertices,
        maps: AlbedoMaps::white(),
    }
}

/// Faces meeting at more than this keep a hard edge.
const CREASE_DEGREES: f32 = 40.0;

/// Per corner, the area-weighted mean of the face normals of the triangles that share the
/// corner's position and bend from this triangle's face by less than [`CREASE_DEGREES`]: curved
/// surfaces shade smoothly, walls and box edges stay hard. The importer keeps no glTF normals,
/// so they are rebuilt from the positions; corners match by exact position, as vertices a glTF
/// shares come out of one node transform bit-identical. Faces wound the other way (the other
/// side of a double-sided surface) bend by more than the crease and are left out.
pub(crate) fn corner_normals(scene: &Scene) -> Vec<[Vec3; 3]> {
    let key = |p: Vec3| p.to_array().map(f32::to_bits);
    let mut at: HashMap<[u32; 3], Vec<u32>> = HashMap::new();
    for (i, t) in scene.triangles.iter().enumerate() {
        for p in t.positions {
            at.entry(key(p)).or_default().push(i as u32);
        }
    }
    let faces: Vec<Vec3> = scene.triangles.iter().map(|t| t.cross()).collect();
    let cos_crease = CREASE_DEGREES.to_radians().cos();
    scene
        .triangles
        .iter()
        .zip(&faces)
        .map(|(t, &face)| {
            let unit = face.normalize_or_zero();
            t.positions.map(|p| {
                let sum: Vec3 = at
                    .get(&key(p))
                    .into_iter()
                    .flatten()
                    .map(|&j| faces[j as usize])
                    .filter(|other| other.normalize_or_zero().dot(unit) >= cos_crease)
                    .sum();
                sum.try_normalize().unwrap_or(unit)
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounce_core::scene::Triangle;

    fn tri(positions: [Vec3; 3]) -> Triangle {
        Triangle {
            positions,
            albedo: Vec3::splat(0.5),
            emission: Vec3::ZERO,
            double_sided: false,
            material: 0,
        }
    }

    #[test]
    fn gentle_bends_are_smoothed_and_creases_kept() {
        // Two triangles sharing the edge x = 0, each tilted 10° away: a shallow roof.
        let (s, c) = 10f32.to_radians().sin_cos();
        let a = Vec3::new(0.0, 0.0, 0.0);
        let b = Vec3::new(0.0, 0.0, 1.0);
        let left = Vec3::new(-c, -s, 0.5);
        let right = Vec3::new(c, -s, 0.5);
        // Both wound so their normals point up.
        let roof = Scene {
            triangles: vec![tri([a, b, right]), tri([b, a, left])],
            ..Scene::default()
        };
        let n = corner_normals(&roof);
        for t in &roof.triangles {
            assert!(t.cross().y > 0.0);
        }
        // On the shared edge both triangles get the bisector, straight up.
        for corner in [n[0][0], n[0][1], n[1][0], n[1][1]] {
            assert!((corner - Vec3::Y).length() < 1e-5, "{corner}");
        }
        // The outer corners touch one triangle only: its face normal.
        let face = roof.triangles[0].cross().normalize();
        assert!((n[0][2] - face).length() < 1e-6);

        // A cube's corner: three faces at 90° stay flat.
        let o = Vec3::ZERO;
        let corner = Scene {
            triangles: vec![
                tri([o, Vec3::X, Vec3::Y]),
                tri([o, Vec3::Y, Vec3::Z]),
                tri([o, Vec3::Z, Vec3::X]),
            ],
            ..Scene::default()
        };
        let n = corner_normals(&corner);
        for (t, normals) in corner.triangles.iter().zip(&n) {
            let face = t.cross().normalize();
            for v in normals {
                assert!((*v - face).length() < 1e-6, "{v} vs {face}");
            }
        }
    }
}
