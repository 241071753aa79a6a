//! The scene's triangles as the GPU draws them: one vertex buffer, and the base-colour maps in
//! one texture array (layer 0 is white, for untextured surfaces).

use bounce_core::scene::{Scene, Shading, ShadingTexture};
use image::{RgbaImage, imageops};

use crate::gpu_types::{Vertex, WRAP_REPEAT_U, WRAP_REPEAT_V};

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
    pub fn mip_count(&self) -> u32 {
        self.side.ilog2() + 1
    }
}

/// The array's side is the largest image's, rounded up to a power of two (so every level halves
/// exactly) and capped here: the images of a scene share one side, and 1024² is what a
/// base-colour map needs at viewing distance while 8 of them stay under 45 MB with mips.
const MAX_SIDE: u32 = 1024;

/// The scene's triangles with their shading: the file's normals, texture coordinates, tints and
/// images when the import kept [`Scene::shading`]; without it (or if it does not match the
/// triangles), the bake's averaged albedo on flat faces.
pub(crate) fn mesh(scene: &Scene) -> Mesh {
    match &scene.shading {
        Some(shading) if shading.triangles.len() == scene.triangles.len() => shaded(scene, shading),
        _ => flat(scene),
    }
}

/// glTF's rule for a primitive without normals is flat shading, and the averaged albedo is
/// what the bake saw.
fn flat(scene: &Scene) -> Mesh {
    let vertices = scene
        .triangles
        .iter()
        .flat_map(|t| {
            let n = t.cross().normalize_or_zero();
            [0, 1, 2].map(|k| Vertex {
                position: t.positions[k].to_array(),
                normal: n.to_array(),
                albedo: t.albedo.to_array(),
                emission: t.emission.to_array(),
                uv: [0.0; 2],
                layer: 0,
                wrap: 0,
            })
        })
        .collect();
    Mesh {
        vertices,
        maps: albedo_maps(&[]),
    }
}

fn shaded(scene: &Scene, shading: &Shading) -> Mesh {
    let vertices = scene
        .triangles
        .iter()
        .zip(&shading.triangles)
        .flat_map(|(t, s)| {
            let texture = s
                .texture
                .and_then(|i| Some((i, shading.textures.get(i as usize)?)));
            let (layer, wrap) = match texture {
                Some((i, tex)) => (
                    i + 1,
                    if tex.repeat_u { WRAP_REPEAT_U } else { 0 }
                        | if tex.repeat_v { WRAP_REPEAT_V } else { 0 },
                ),
                None => (0, 0),
            };
            [0, 1, 2].map(|k| Vertex {
                position: t.positions[k].to_array(),
                normal: s.normals[k].to_array(),
                albedo: s.tint[k].to_array(),
                emission: t.emission.to_array(),
                uv: s.uvs[k].to_array(),
                layer,
                wrap,
            })
        })
        .collect();
    Mesh {
        vertices,
        maps: albedo_maps(&shading.textures),
    }
}

/// Layer 0 white, then every texture resized to the common side with its mip chain.
pub(crate) fn albedo_maps(textures: &[ShadingTexture]) -> AlbedoMaps {
    let largest = textures
        .iter()
        .map(|t| t.width.max(t.height))
        .max()
        .unwrap_or(1);
    let side = largest.clamp(1, MAX_SIDE).next_power_of_two();
    let white = RgbaImage::from_pixel(side, side, image::Rgba([255; 4]));
    let mut levels = vec![mip_chain(white)];
    for t in textures {
        // The importer builds these from decoded images; a size that does not match its pixels
        // would be a bug there, and a white layer is a safer answer than a panic in a viewer.
        let image = RgbaImage::from_raw(t.width, t.height, t.rgba.clone())
            .filter(|i| i.width() > 0 && i.height() > 0)
            .map(|i| {
                if i.dimensions() == (side, side) {
                    i
                } else {
                    imageops::resize(&i, side, side, imageops::FilterType::Triangle)
                }
            })
            .unwrap_or_else(|| RgbaImage::from_pixel(side, side, image::Rgba([255; 4])));
        levels.push(mip_chain(image));
    }
    AlbedoMaps { side, levels }
}

/// Level 0 and every 2×2 box-filtered level below it down to 1×1. The colour is averaged in
/// linear light (the texels are sRGB-encoded): averaging the encoded values darkens fine
/// contrast, the classic too-dark distant brick.
fn mip_chain(base: RgbaImage) -> Vec<Vec<u8>> {
    let to_linear: Vec<f32> = (0..=255u8)
        .map(|v| srgb_to_linear(v as f32 / 255.0))
        .collect();
    let mut side = base.width();
    let mut current = base.into_raw();
    let mut levels = Vec::new();
    while side > 1 {
        let half = side / 2;
        let mut next = vec![0u8; (half * half * 4) as usize];
        for y in 0..half {
            for x in 0..half {
                let mut sum = [0.0f32; 4];
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let at = (((2 * y + dy) * side + 2 * x + dx) * 4) as usize;
                    for c in 0..3 {
                        sum[c] += to_linear[current[at + c] as usize];
                    }
                    sum[3] += current[at + 3] as f32 / 255.0;
                }
                let out = ((y * half + x) * 4) as usize;
                for c in 0..3 {
                    next[out + c] = encode(linear_to_srgb(sum[c] / 4.0));
                }
                next[out + 3] = encode(sum[3] / 4.0);
            }
        }
        levels.push(std::mem::replace(&mut current, next));
        side = half;
    }
    levels.push(current);
    levels
}

fn encode(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounce_core::scene::{Triangle, TriangleShading};
    use glam::{Vec2, Vec3};

    fn texture(width: u32, height: u32, texel: [u8; 4]) -> ShadingTexture {
        ShadingTexture {
            width,
            height,
            rgba: texel.repeat((width * height) as usize),
            repeat_u: true,
            repeat_v: false,
        }
    }

    #[test]
    fn maps_share_a_power_of_two_side_with_full_mip_chains() {
        let maps = albedo_maps(&[texture(300, 100, [10, 20, 30, 255]), texture(7, 7, [0; 4])]);
        assert_eq!(maps.side, 512);
        assert_eq!(maps.mip_count(), 10);
        assert_eq!(maps.levels.len(), 3, "white, then one layer a texture");
        for layer in &maps.levels {
            assert_eq!(layer.len(), 10);
            for (l, level) in layer.iter().enumerate() {
                let side = 512usize >> l;
                assert_eq!(level.len(), side * side * 4);
            }
        }
        assert!(maps.levels[0].iter().flatten().all(|&v| v == 255));
        // A uniform image stays itself at every level, resizing included.
        for level in &maps.levels[1] {
            assert_eq!(&level[..4], &[10, 20, 30, 255]);
            assert_eq!(&level[level.len() - 4..], &[10, 20, 30, 255]);
        }
        // Without textures the array is one white texel.
        let none = albedo_maps(&[]);
        assert_eq!((none.side, none.levels.len()), (1, 1));
        // An oversized image is capped.
        assert_eq!(albedo_maps(&[texture(3000, 10, [0; 4])]).side, MAX_SIDE);
    }

    #[test]
    fn mips_average_in_linear_light() {
        // Black and white checks: the encoded mean would be 128, the linear mean is 50% → 188.
        let mut image = RgbaImage::new(2, 2);
        for (x, y, p) in image.enumerate_pixels_mut() {
            let v = if (x + y) % 2 == 0 { 255 } else { 0 };
            *p = image::Rgba([v, v, v, 255]);
        }
        let chain = mip_chain(image);
        assert_eq!(chain.len(), 2);
        assert_eq!(chain[1], vec![188, 188, 188, 255]);
    }

    #[test]
    fn shaded_vertices_carry_the_files_attributes_and_a_bad_texture_index_is_white() {
        let t = Triangle {
            positions: [Vec3::ZERO, Vec3::X, Vec3::Y],
            albedo: Vec3::splat(0.5),
            emission: Vec3::ZERO,
            double_sided: false,
            material: 0,
        };
        let n = Vec3::new(0.0, 0.6, 0.8);
        let s = TriangleShading {
            normals: [Vec3::Z, n, Vec3::Z],
            uvs: [Vec2::ZERO, Vec2::new(2.0, 0.0), Vec2::new(0.0, 1.0)],
            tint: [Vec3::ONE, Vec3::splat(0.25), Vec3::ONE],
            texture: Some(0),
        };
        let scene = Scene {
            triangles: vec![t, t],
            shading: Some(Shading {
                triangles: vec![
                    s,
                    TriangleShading {
                        texture: Some(9),
                        ..s
                    },
                ],
                textures: vec![texture(4, 4, [255, 0, 0, 255])],
            }),
            ..Scene::default()
        };
        let mesh = mesh(&scene);
        let v = &mesh.vertices;
        assert_eq!(v.len(), 6);
        assert_eq!(v[1].normal, n.to_array());
        assert_eq!(v[1].albedo, [0.25; 3]);
        assert_eq!(v[1].uv, [2.0, 0.0]);
        assert_eq!((v[1].layer, v[1].wrap), (1, WRAP_REPEAT_U));
        assert_eq!((v[4].layer, v[4].wrap), (0, 0));
        assert_eq!(mesh.maps.levels.len(), 2);

        // Shading that does not match the triangles falls back to flat faces.
        let mismatched = Scene {
            triangles: vec![t],
            ..scene
        };
        let flat = super::mesh(&mismatched);
        assert_eq!(flat.vertices[1].normal, [0.0, 0.0, 1.0]);
        assert_eq!(flat.vertices[1].albedo, [0.5; 3]);
    }
}
