//! What a viewer needs to draw the imported surfaces rather than bake them: per-corner normals,
//! texture coordinates and tints, and the base-colour images they index. Built only when
//! [`super::ImportOptions::shading`] asks for it.

use std::collections::HashMap;

use glam::{Mat3, Mat4, Vec2, Vec3};
use gltf::texture::WrappingMode;

use super::material::{Materials, TexRef};
use super::mirrors;
use crate::scene::{Shading, ShadingTexture, TriangleShading};

/// Shading data gathered over the walk; the images are only collected at the end, when the
/// triangle averaging no longer needs them.
#[derive(Default)]
pub(super) struct ShadingBuilder {
    pub triangles: Vec<TriangleShading>,
    /// Textures in index order.
    textures: Vec<TextureKey>,
    index: HashMap<TextureKey, u32>,
}

/// A shading texture is an image under a pair of wrap modes: the same image sampled two ways
/// needs two entries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct TextureKey {
    image: usize,
    repeat_u: bool,
    repeat_v: bool,
}

impl ShadingBuilder {
    /// The index in [`Shading::textures`] of a base-colour slot whose image has loaded.
    pub(super) fn texture_index(&mut self, slot: &TexRef) -> u32 {
        let key = TextureKey {
            image: slot.image,
            repeat_u: repeats(slot.lookup.wrap_s),
            repeat_v: repeats(slot.lookup.wrap_t),
        };
        *self.index.entry(key).or_insert_with(|| {
            self.textures.push(key);
            (self.textures.len() - 1) as u32
        })
    }

    /// Moves the used images out of `materials` (cloning only an image used with two wrap-mode
    /// pairs) and returns the finished shading data.
    pub(super) fn finish(mut self, materials: &mut Materials) -> Shading {
        let mut textures: Vec<ShadingTexture> = Vec::with_capacity(self.textures.len());
        // Old texture index to new: an image that cannot be handed on leaves its triangles
        // untextured rather than pointing past the list.
        let mut remap: Vec<Option<u32>> = Vec::with_capacity(self.textures.len());
        let mut first_use: HashMap<usize, usize> = HashMap::new();
        for key in &self.textures {
            let pixels = match first_use.get(&key.image) {
                Some(&at) => Some((
                    textures[at].width,
                    textures[at].height,
                    textures[at].rgba.clone(),
                )),
                None => materials.take_image(key.image).and_then(|image| {
                    let (w, h) = image.size();
                    let rgba = image.into_rgba()?;
                    Some((u32::try_from(w).ok()?, u32::try_from(h).ok()?, rgba))
                }),
            };
            remap.push(pixels.map(|(width, height, rgba)| {
                first_use.entry(key.image).or_insert(textures.len());
                textures.push(ShadingTexture {
                    width,
                    height,
                    rgba,
                    repeat_u: key.repeat_u,
                    repeat_v: key.repeat_v,
                });
                (textures.len() - 1) as u32
            }));
        }
        for t in &mut self.triangles {
            t.texture = t
                .texture
                .and_then(|i| remap.get(i as usize).copied().flatten());
        }
        Shading {
            triangles: self.triangles,
            textures,
        }
    }
}

/// Mirrored repeat counts as repeat: it tiles, and a plain repeat draws it closer than a clamp.
fn repeats(mode: WrappingMode) -> bool {
    mode != WrappingMode::ClampToEdge
}

/// One primitive instance's shading inputs, per vertex.
pub(super) struct PrimitiveShading {
    /// World-space unit normals, or zero where none could be had.
    pub normals: Vec<Vec3>,
    /// Base-colour texture coordinates with `KHR_texture_transform` applied, and the texture's
    /// index, when the primitive is textured.
    pub texture: Option<(Vec<Vec2>, u32)>,
    /// Linear base-colour factor × vertex colour (× the image mean where the texture could only
    /// be used as its mean).
    pub tints: Vec<Vec3>,
}

impl PrimitiveShading {
    /// The shading of the kept triangle with (already winding-corrected) vertex indices `corners`
    /// and face normal `face`.
    pub(super) fn triangle(&self, corners: [usize; 3], face: Vec3) -> TriangleShading {
        let normals = corners.map(|i| match self.normals.get(i) {
            Some(&n) if n != Vec3::ZERO => n,
            _ => face,
        });
        let (uvs, texture) = match &self.texture {
            Some((uv, index)) => (
                corners.map(|i| uv.get(i).copied().unwrap_or(Vec2::ZERO)),
                Some(*index),
            ),
            None => ([Vec2::ZERO; 3], None),
        };
        TriangleShading {
            normals,
            uvs,
            tint: corners.map(|i| self.tints.get(i).copied().unwrap_or(Vec3::ONE)),
            texture,
        }
    }
}

/// The matrix that carries a node's normals into world space: the inverse transpose of the upper
/// 3×3, up to a positive scale. Built as the cofactor matrix (det × inverse transpose) so that a
/// transform flattening the mesh along one axis still orients the normals it keeps, and negated
/// under a mirror to undo the determinant's sign.
pub(super) fn normal_matrix(world: &Mat4) -> Mat3 {
    let m = Mat3::from_mat4(*world);
    let cofactor = Mat3::from_cols(
        m.y_axis.cross(m.z_axis),
        m.z_axis.cross(m.x_axis),
        m.x_axis.cross(m.y_axis),
    );
    if mirrors(world) { -cofactor } else { cofactor }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use glam::{Mat3, Quat, Vec2, Vec3};
    use serde_json::{Value, json};

    use crate::import::{ImportOptions, import_path_with, import_slice, import_slice_with};
    use crate::scene::{Scene, Shading};

    /// Builds a GLB whose buffer is its BIN chunk.
    #[derive(Default)]
    struct Glb {
        bin: Vec<u8>,
        views: Vec<Value>,
        accessors: Vec<Value>,
    }

    impl Glb {
        fn view(&mut self, bytes: &[u8]) -> usize {
            while !self.bin.len().is_multiple_of(4) {
                self.bin.push(0);
            }
            self.views.push(
                json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()}),
            );
            self.bin.extend_from_slice(bytes);
            self.views.len() - 1
        }

        fn floats(&mut self, values: &[f32], dims: usize) -> usize {
            let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
            let view = self.view(&bytes);
            let ty = ["SCALAR", "VEC2", "VEC3", "VEC4"][dims - 1];
            self.accessors.push(json!({
                "bufferView": view, "componentType": 5126, "count": values.len() / dims, "type": ty
            }));
            self.accessors.len() - 1
        }

        fn vec3(&mut self, v: &[[f32; 3]]) -> usize {
            self.floats(&v.concat(), 3)
        }

        fn vec2(&mut self, v: &[[f32; 2]]) -> usize {
            self.floats(&v.concat(), 2)
        }

        fn indices(&mut self, i: &[u16]) -> usize {
            let bytes: Vec<u8> = i.iter().flat_map(|v| v.to_le_bytes()).collect();
            let view = self.view(&bytes);
            self.accessors.push(json!({
                "bufferView": view, "componentType": 5123, "count": i.len(), "type": "SCALAR"
            }));
            self.accessors.len() - 1
        }

        fn finish(mut self, mut doc: Value) -> Vec<u8> {
            while !self.bin.len().is_multiple_of(4) {
                self.bin.push(0);
            }
            let o = doc.as_object_mut().expect("an object");
            o.insert("asset".into(), json!({"version": "2.0"}));
            o.insert("buffers".into(), json!([{"byteLength": self.bin.len()}]));
            o.insert("bufferViews".into(), Value::Array(self.views));
            o.insert("accessors".into(), Value::Array(self.accessors));
            let mut json = serde_json::to_vec(&doc).expect("serialisable");
            while !json.len().is_multiple_of(4) {
                json.push(b' ');
            }
            let total = 12 + 8 + json.len() + 8 + self.bin.len();
            let mut out = b"glTF".to_vec();
            out.extend(2u32.to_le_bytes());
            out.extend((total as u32).to_le_bytes());
            out.extend((json.len() as u32).to_le_bytes());
            out.extend(b"JSON");
            out.extend(json);
            out.extend((self.bin.len() as u32).to_le_bytes());
            out.extend(b"BIN\0");
            out.extend(self.bin);
            out
        }
    }

    const SHADING: ImportOptions = ImportOptions { shading: true };

    fn import_shaded(bytes: &[u8], dir: Option<&Path>) -> (Scene, Shading) {
        let mut scene = import_slice_with(bytes, dir, &SHADING).unwrap_or_else(|e| panic!("{e}"));
        let shading = scene.shading.take().expect("shading was asked for");
        assert_eq!(shading.triangles.len(), scene.triangles.len());
        (scene, shading)
    }

    fn assert_close(a: Vec3, b: Vec3) {
        assert!((a - b).length() < 1e-5, "{a} vs {b}");
    }

    fn assert_unit(n: Vec3) {
        assert!((n.length() - 1.0).abs() < 1e-5, "{n} is not unit");
    }

    /// A unit square in z = 0, counter-clockwise from +z, as two triangles on shared corners.
    const QUAD: [[f32; 3]; 4] = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ];
    const QUAD_INDICES: [u16; 6] = [0, 1, 2, 0, 2, 3];

    #[test]
    fn file_normals_go_through_the_inverse_transpose_and_stay_unit() {
        let normals = [
            [0.0, 0.0, 1.0],
            [0.6, 0.0, 0.8],
            [0.0, -0.6, 0.8],
            [0.48, 0.36, 0.8],
        ];
        let mut g = Glb::default();
        let pos = g.vec3(&QUAD);
        let nor = g.vec3(&normals);
        let idx = g.indices(&QUAD_INDICES);
        let rotation = Quat::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
        let scale = Vec3::new(2.0, 0.5, 3.0);
        let bytes = g.finish(json!({
            "nodes": [{"mesh": 0, "rotation": rotation.to_array(), "scale": scale.to_array(),
                       "translation": [5, -1, 2]}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos, "NORMAL": nor},
                                        "indices": idx}]}]
        }));
        let (scene, shading) = import_shaded(&bytes, None);
        assert_eq!(scene.triangles.len(), 2);
        let m = Mat3::from_quat(rotation) * Mat3::from_diagonal(scale);
        let normal_matrix = m.inverse().transpose();
        for s in &shading.triangles {
            assert_eq!(s.texture, None);
            assert_eq!(s.uvs, [Vec2::ZERO; 3]);
            assert_eq!(s.tint, [Vec3::ONE; 3]);
        }
        for (k, s) in shading.triangles.iter().enumerate() {
            for (corner, n) in s.normals.iter().enumerate() {
                let vertex = usize::from(QUAD_INDICES[3 * k + corner]);
                let want = (normal_matrix * Vec3::from(normals[vertex])).normalize();
                assert_unit(*n);
                assert_close(*n, want);
            }
        }
        // Not the plain transform: the non-uniform scale tells the two apart.
        let plain = (m * Vec3::from(normals[1])).normalize();
        assert!((shading.triangles[0].normals[1] - plain).length() > 1e-2);
    }

    #[test]
    fn mirroring_nodes_keep_normals_on_the_side_the_stored_winding_faces() {
        let mut g = Glb::default();
        let pos = g.vec3(&QUAD);
        let nor = g.vec3(&[[0.0, 0.0, 1.0]; 4]);
        let idx = g.indices(&QUAD_INDICES);
        let tilt = Quat::from_rotation_y(0.4).to_array();
        let bytes = g.finish(json!({
            "nodes": [
                {"mesh": 0},
                {"mesh": 0, "scale": [-1, 1, 1]},
                {"mesh": 0, "scale": [1, 1, -1]},
                {"mesh": 0, "scale": [-2, 3, 0.5], "rotation": tilt},
                {"mesh": 1, "scale": [1, 1, -1]},
                {"mesh": 1, "scale": [-2, 3, 0.5], "rotation": tilt}
            ],
            "meshes": [
                {"primitives": [{"attributes": {"POSITION": pos, "NORMAL": nor}, "indices": idx}]},
                {"primitives": [{"attributes": {"POSITION": pos}, "indices": idx}]}
            ]
        }));
        let (scene, shading) = import_shaded(&bytes, None);
        assert_eq!(scene.triangles.len(), 12);
        for (t, s) in scene.triangles.iter().zip(&shading.triangles) {
            let face = t.cross().normalize();
            for n in s.normals {
                assert_unit(n);
                // A flat quad: every normal is the face normal, whatever the transform.
                assert_close(n, face);
            }
        }
        // The mirror across z = 0 turned the face to -z (the importer's rule), and the normals
        // with it.
        assert_close(shading.triangles[4].normals[0], -Vec3::Z);
    }

    #[test]
    fn a_flattening_node_keeps_the_normals_it_can() {
        // A triangle in the x-z plane facing +y, squashed to y = 0 along with everything else: the
        // inverse transpose does not exist, but the normal +y is still the right one.
        let mut g = Glb::default();
        let pos = g.vec3(&[[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]);
        let nor = g.vec3(&[[0.0, 1.0, 0.0], [0.6, 0.8, 0.0], [1.0, 0.0, 0.0]]);
        let bytes = g.finish(json!({
            "nodes": [{"mesh": 0, "scale": [2, 0, 1]}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos, "NORMAL": nor}}]}]
        }));
        let (scene, shading) = import_shaded(&bytes, None);
        assert_close(scene.triangles[0].cross().normalize(), Vec3::Y);
        let [a, b, c] = shading.triangles[0].normals;
        assert_close(a, Vec3::Y);
        assert_close(b, Vec3::Y);
        // +x has no direction left after the squash: the face normal stands in.
        assert_close(c, Vec3::Y);
    }

    /// A cube of side 2 around the origin on 8 shared corners, wound outwards.
    fn cube() -> (Vec<[f32; 3]>, Vec<u16>) {
        let corners: Vec<[f32; 3]> = (0..8)
            .map(|i| {
                let s = |bit: u32| if i & (1 << bit) != 0 { 1.0 } else { -1.0 };
                [s(0), s(1), s(2)]
            })
            .collect();
        // Each face as a quad a, b, c, d counter-clockwise from outside.
        let faces: [[u16; 4]; 6] = [
            [1, 3, 7, 5], // +x
            [0, 4, 6, 2], // -x
            [2, 6, 7, 3], // +y
            [0, 1, 5, 4], // -y
            [4, 5, 7, 6], // +z
            [0, 2, 3, 1], // -z
        ];
        let indices = faces
            .iter()
            .flat_map(|&[a, b, c, d]| [a, b, c, a, c, d])
            .collect();
        (corners, indices)
    }

    #[test]
    fn missing_normals_are_flat_and_face_outwards() {
        let (corners, indices) = cube();
        let mut g = Glb::default();
        let pos = g.vec3(&corners);
        let idx = g.indices(&indices);
        let bytes = g.finish(json!({
            "nodes": [{"mesh": 0}, {"mesh": 0, "scale": [-1, 2, 1], "translation": [10, 0, 0]}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos}, "indices": idx}]}]
        }));
        let (scene, shading) = import_shaded(&bytes, None);
        assert_eq!(scene.triangles.len(), 24);
        for (instance, centre) in [(0, Vec3::ZERO), (1, Vec3::new(10.0, 0.0, 0.0))] {
            for k in 0..12 {
                let (t, s) = (
                    &scene.triangles[12 * instance + k],
                    &shading.triangles[12 * instance + k],
                );
                // glTF §3.7.2.1: without NORMAL, flat. The cube shares its 8 corners between
                // faces, so smoothing would have bent every normal towards a diagonal.
                let face = t.cross().normalize();
                let middle = (t.positions[0] + t.positions[1] + t.positions[2]) / 3.0;
                assert!(face.dot(middle - centre) > 0.0, "{face} points inwards");
                for n in s.normals {
                    assert_unit(n);
                    assert_close(n, face);
                }
            }
        }
    }

    #[test]
    fn shading_stays_parallel_when_degenerate_triangles_are_dropped() {
        let mut g = Glb::default();
        let pos = g.vec3(&[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [2.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
        ]);
        let colours = g.floats(
            &[
                1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.5, 0.5, 0.5,
            ],
            3,
        );
        // Good, collinear, repeated corner, good (in the x-z plane).
        let idx = g.indices(&[0, 1, 2, 0, 1, 3, 2, 2, 1, 0, 4, 1]);
        let bytes = g.finish(json!({
            // The second instance flattens y: only the x-z triangle survives it.
            "nodes": [{"mesh": 0}, {"mesh": 0, "scale": [1, 0, 1]}],
            "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 1, 1, 1]}}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos, "COLOR_0": colours},
                                        "indices": idx, "material": 0}]}]
        }));
        let (scene, shading) = import_shaded(&bytes, None);
        assert_eq!(scene.report.degenerate_triangles, 2 + 3);
        assert_eq!(scene.triangles.len(), 3);
        // Each entry belongs to its triangle: the tints follow the corners' colours.
        let want = [
            [
                Vec3::new(0.5, 0.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.0, 0.0, 1.0),
            ],
            [
                Vec3::new(0.5, 0.0, 0.0),
                Vec3::new(0.25, 0.5, 0.5),
                Vec3::new(0.0, 1.0, 0.0),
            ],
            [
                Vec3::new(0.5, 0.0, 0.0),
                Vec3::new(0.25, 0.5, 0.5),
                Vec3::new(0.0, 1.0, 0.0),
            ],
        ];
        for ((t, s), want) in scene.triangles.iter().zip(&shading.triangles).zip(want) {
            assert_eq!(s.tint, want);
            // The bake's albedo is the corners' tints averaged.
            assert_close(t.albedo, (want[0] + want[1] + want[2]) / 3.0);
            let face = t.cross().normalize();
            for n in s.normals {
                assert_unit(n);
                assert!(n.dot(face) > 0.0, "{n} against {face}");
            }
        }
    }

    fn write_png(dir: &Path, name: &str, width: u32, rgba: &[u8]) {
        let height = rgba.len() as u32 / 4 / width;
        let img = image::RgbaImage::from_raw(width, height, rgba.to_vec()).expect("sized");
        img.save(dir.join(name)).expect("written");
    }

    #[test]
    fn textures_are_handed_on_once_with_their_alpha_wrap_modes_and_transformed_uvs() {
        let dir = tempfile::tempdir().expect("a temporary directory");
        // 2 × 2 with a translucent texel: alpha must survive.
        let texels = [
            255, 0, 0, 255, 0, 0, 255, 128, 188, 188, 188, 255, 0, 0, 0, 0,
        ];
        write_png(dir.path(), "a.png", 2, &texels);
        let mut g = Glb::default();
        let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let pos = g.vec3(&tri);
        let uv = g.vec2(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]);
        let bytes = g.finish(json!({
            "extensionsUsed": ["KHR_texture_transform"],
            "nodes": [{"mesh": 0}, {"mesh": 1}, {"mesh": 2}, {"mesh": 3}, {"mesh": 4}],
            "materials": [
                // Two materials on one texture (one image, one sampler), one shifted.
                {"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1],
                    "baseColorTexture": {"index": 0}}},
                {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0, "extensions":
                    {"KHR_texture_transform": {"offset": [0.5, 0.25], "scale": [2, 2]}}}}},
                // The same image through a clamping sampler: a second entry.
                {"pbrMetallicRoughness": {"baseColorTexture": {"index": 1}}},
                // A missing image: untextured, the factor alone.
                {"pbrMetallicRoughness": {"baseColorFactor": [0.25, 0.5, 1, 1],
                    "baseColorTexture": {"index": 2}}}
            ],
            "samplers": [{}, {"wrapS": 33071, "wrapT": 33648}],
            "textures": [{"source": 0, "sampler": 0}, {"source": 0, "sampler": 1},
                         {"source": 1}],
            "images": [{"uri": "a.png"}, {"uri": "missing.png"}],
            "meshes": [
                {"primitives": [{"attributes": {"POSITION": pos, "TEXCOORD_0": uv}, "material": 0}]},
                {"primitives": [{"attributes": {"POSITION": pos, "TEXCOORD_0": uv}, "material": 1}]},
                {"primitives": [{"attributes": {"POSITION": pos, "TEXCOORD_0": uv}, "material": 2}]},
                {"primitives": [{"attributes": {"POSITION": pos, "TEXCOORD_0": uv}, "material": 3}]},
                // Textured, but no TEXCOORD_0: drawn with the image's mean in the tint.
                {"primitives": [{"attributes": {"POSITION": pos}, "material": 0}]}
            ]
        }));
        let (scene, shading) = import_shaded(&bytes, Some(dir.path()));
        assert_eq!(scene.report.missing_textures.len(), 1);

        assert_eq!(shading.textures.len(), 2, "{:?}", shading.textures);
        for t in &shading.textures {
            assert_eq!((t.width, t.height), (2, 2));
            assert_eq!(t.rgba, texels);
        }
        assert!(shading.textures[0].repeat_u && shading.textures[0].repeat_v);
        // Clamp, and mirrored repeat counted as repeat.
        assert!(!shading.textures[1].repeat_u && shading.textures[1].repeat_v);

        let s = &shading.triangles;
        let uvs = [Vec2::ZERO, Vec2::X, Vec2::Y];
        assert_eq!((s[0].texture, s[0].uvs), (Some(0), uvs));
        assert_eq!(s[0].tint, [Vec3::splat(0.5); 3]);
        assert_eq!(s[1].texture, Some(0));
        let shifted = [
            Vec2::new(0.5, 0.25),
            Vec2::new(2.5, 0.25),
            Vec2::new(0.5, 2.25),
        ];
        for (got, want) in s[1].uvs.iter().zip(shifted) {
            assert!((*got - want).length() < 1e-6, "{got} vs {want}");
        }
        assert_eq!(s[2].texture, Some(1));
        assert_eq!(
            (s[3].texture, s[3].uvs, s[3].tint),
            (None, [Vec2::ZERO; 3], [Vec3::new(0.25, 0.5, 1.0); 3])
        );
        // The bake used the image's mean here, and so does the tint.
        assert_eq!(s[4].texture, None);
        for c in s[4].tint {
            assert_close(c, scene.triangles[4].albedo);
        }

        // Asking for shading does not change the bake's triangles.
        let plain = import_slice_with(&bytes, Some(dir.path()), &ImportOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(plain.triangles, scene.triangles);
    }

    #[test]
    fn a_default_import_has_no_shading() {
        let mut g = Glb::default();
        let pos = g.vec3(&QUAD);
        let idx = g.indices(&QUAD_INDICES);
        let bytes = g.finish(json!({
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos}, "indices": idx}]}]
        }));
        let scene = import_slice(&bytes, None).unwrap_or_else(|e| panic!("{e}"));
        assert!(scene.shading.is_none());
        let scene = import_slice_with(&bytes, None, &ImportOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(scene.shading.is_none());
    }

    #[test]
    fn sheen_chair_imports_with_textures_and_unit_normals() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../assets/sheen-chair-sun/MixedLightingExample.gltf");
        assert!(
            path.is_file(),
            "the sheen chair scene missing at {}",
            path.display()
        );
        let scene = import_path_with(&path, &SHADING).unwrap_or_else(|e| panic!("{e}"));
        let shading = scene.shading.as_ref().expect("shading was asked for");
        assert_eq!(shading.triangles.len(), scene.triangles.len());
        assert!(scene.report.missing_textures.is_empty());
        // Fabric, label, and one for both woods: they use one image through one sampler.
        assert_eq!(shading.textures.len(), 3, "{:?}", shading.textures);
        for t in &shading.textures {
            assert!(t.width > 0 && t.height > 0);
            assert_eq!(t.rgba.len(), t.width as usize * t.height as usize * 4);
            assert!(t.repeat_u && t.repeat_v);
        }
        let textured = shading
            .triangles
            .iter()
            .filter(|s| s.texture.is_some())
            .count();
        assert!(
            textured > 0 && textured < scene.triangles.len(),
            "{textured}"
        );
        let mut facing = 0;
        for (t, s) in scene.triangles.iter().zip(&shading.triangles) {
            if let Some(i) = s.texture {
                assert!((i as usize) < shading.textures.len());
            }
            for n in s.normals {
                assert!(n.is_finite());
                assert_unit(n);
            }
            facing += usize::from(s.normals.iter().sum::<Vec3>().dot(t.cross()) > 0.0);
        }
        // Authored normals may disagree with a sliver's winding, but not on the whole.
        assert!(
            facing as f64 > 0.99 * scene.triangles.len() as f64,
            "{facing}"
        );
    }
}
