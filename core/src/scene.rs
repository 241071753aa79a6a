//! The imported scene: world-space triangles with their diffuse material, and the scene's lights.
//!
//! This is the boundary between file formats and the lighting pipeline: everything downstream
//! (voxelisation, the reference path tracer) sees only these flat triangles. A viewer that draws
//! the surfaces themselves can ask the importer for [`Shading`] data alongside them.

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::light::Light;

/// One world-space triangle with its diffuse material already resolved.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Triangle {
    pub positions: [Vec3; 3],
    /// Linear RGB albedo: base-colour factor × vertex colour × the texture averaged over this
    /// triangle's UV footprint. Each channel in `[0, 1]`.
    pub albedo: Vec3,
    /// Linear RGB emitted exitance scale: emissive factor × emissive texture average ×
    /// `KHR_materials_emissive_strength`.
    pub emission: Vec3,
    /// glTF `doubleSided`: the surface reflects light on both sides.
    pub double_sided: bool,
    /// Index into [`Scene::materials`] (the glTF material, or the default material).
    pub material: u32,
}

impl Triangle {
    /// Unnormalised normal: its length is twice the area.
    pub fn cross(&self) -> Vec3 {
        let [a, b, c] = self.positions;
        (b - a).cross(c - a)
    }

    pub fn area(&self) -> f32 {
        0.5 * self.cross().length()
    }

    pub fn centroid(&self) -> Vec3 {
        let [a, b, c] = self.positions;
        (a + b + c) / 3.0
    }
}

/// A material as the scene file names it, kept for reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MaterialInfo {
    pub name: String,
    pub base_color_factor: [f32; 3],
    pub has_base_color_texture: bool,
    /// Emissive factor × strength.
    pub emission: [f32; 3],
    /// `KHR_materials_emissive_strength` (1 without it): `emission` over it is glTF's
    /// `emissiveFactor`, which a session's emissive change keeps when it gives no colour.
    #[serde(default = "unit_strength")]
    pub emissive_strength: f32,
    pub double_sided: bool,
    /// For an emissive material: the glTF node whose mesh uses this entry (`node #i` when the
    /// node has no name). The importer gives each (emissive material, node) pair an entry of
    /// its own, so a session can change one lamp of many sharing a material; `None` for every
    /// other material, which is one entry however many nodes use it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub node: Option<String>,
}

fn unit_strength() -> f32 {
    1.0
}

/// What the importer read, dropped or could not use. Printed after an import and kept in the
/// baked file, so a surprising bake can be explained later.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ImportReport {
    pub meshes: usize,
    pub primitives: usize,
    pub triangles: usize,
    pub lights: usize,
    /// Primitives skipped, with the reason (e.g. "mesh 'x' primitive 2: mode Lines").
    pub skipped_primitives: Vec<String>,
    /// Triangles dropped because their area was zero or not finite.
    pub degenerate_triangles: usize,
    /// Textures that could not be used (missing file, undecodable), by name or index.
    pub missing_textures: Vec<String>,
    /// Lights skipped (unsupported type or invalid values), with the reason.
    pub skipped_lights: Vec<String>,
    /// Anything else worth telling the user.
    pub warnings: Vec<String>,
}

/// An imported scene.
#[derive(Debug, Clone, Default)]
pub struct Scene {
    pub triangles: Vec<Triangle>,
    pub materials: Vec<MaterialInfo>,
    /// The scene's own `KHR_lights_punctual` lights, placed by their nodes, in world space.
    pub lights: Vec<Light>,
    pub report: ImportReport,
    /// What a viewer needs to draw the original surfaces at full resolution. Only filled when the
    /// import asked for it ([`crate::import::ImportOptions::shading`]): a bake does not pay for it.
    pub shading: Option<Shading>,
}

/// Per-corner shading attributes of [`Scene::triangles`], and the base-colour images they use.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Shading {
    /// Parallel to [`Scene::triangles`]: one entry per triangle, same order.
    pub triangles: Vec<TriangleShading>,
    /// Base-colour images, decoded, in the order [`TriangleShading::texture`] indexes them.
    pub textures: Vec<ShadingTexture>,
}

/// How one triangle is drawn: a fragment's albedo is `tint × texture(uv)` (or `tint` alone),
/// interpolated across the corners as they are ordered in [`Triangle::positions`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriangleShading {
    /// World-space unit normals at the corners: the file's `NORMAL` through the node's normal
    /// matrix, mirroring transforms included. Where a primitive has none (or one that cannot be
    /// used), the face normal, as glTF asks (flat shading, §3.7.2.1).
    pub normals: [Vec3; 3],
    /// Base-colour texture coordinates at the corners, `KHR_texture_transform` applied; zero
    /// when there is no texture.
    pub uvs: [Vec2; 3],
    /// Linear RGB base-colour factor × vertex colour at the corners, not multiplied by the
    /// texture. Where the texture is absent this is what the bake averaged (times the image's
    /// mean when the texture could only be used as its mean, for want of texture coordinates).
    pub tint: [Vec3; 3],
    /// Index into [`Shading::textures`], or `None`.
    pub texture: Option<u32>,
}

/// A decoded base-colour image and how its texture wraps.
#[derive(Clone, PartialEq)]
pub struct ShadingTexture {
    pub width: u32,
    pub height: u32,
    /// RGBA8 as stored in the image (sRGB-encoded colour, per glTF), rows top to bottom.
    pub rgba: Vec<u8>,
    /// The sampler's wrap modes: true = repeat (glTF's mirrored repeat is also `true`: it tiles,
    /// and drawing it as a plain repeat is closer than clamping), false = clamp to edge.
    pub repeat_u: bool,
    pub repeat_v: bool,
}

/// Without the texels: a derived `Debug` would print megabytes of them.
impl std::fmt::Debug for ShadingTexture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ShadingTexture")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("rgba", &format_args!("[{} bytes]", self.rgba.len()))
            .field("repeat_u", &self.repeat_u)
            .field("repeat_v", &self.repeat_v)
            .finish()
    }
}

impl Scene {
    /// Axis-aligned bounds of all triangles, or `None` for an empty scene.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut it = self.triangles.iter().flat_map(|t| t.positions);
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
    }

    pub fn total_area(&self) -> f64 {
        self.triangles.iter().map(|t| t.area() as f64).sum()
    }
}
