//! The scene's triangles as the GPU draws them: one vertex buffer, and the base-colour maps in
//! one texture array (layer 0 is white, for untextured surfaces).

use bounce_core::scene::Scene;

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

/// Flat-shaded triangles with the bake's averaged albedo: the importer resolves materials per
/// triangle.
pub(crate) fn mesh(scene: &Scene) -> Mesh {
    let vertices = scene
        .triangles
        .iter()
        .flat_map(|t| {
            let normal = t.cross().normalize_or_zero().to_array();
            t.positions.map(|p| Vertex {
                position: p.to_array(),
                normal,
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
