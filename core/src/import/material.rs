//! glTF materials reduced to what radiosity needs (base colour, emission, sidedness, and the two
//! textures that modulate them), and the images those textures use, loaded once on first use.

use glam::{Affine2, Vec2, Vec3};

use super::texture::{self, Image, Lookup};
use super::{Importer, accessor, source};
use crate::scene::{ImportReport, MaterialInfo};

/// A texture slot of a material: which image, which `TEXCOORD_n`, how it is looked up.
#[derive(Debug, Clone, Copy)]
pub(super) struct TexRef {
    pub image: usize,
    pub tex_coord: u32,
    pub lookup: Lookup,
}

/// A material as triangles use it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Entry {
    /// Base-colour factor (rgb).
    pub albedo: Vec3,
    /// Emissive factor × `KHR_materials_emissive_strength`.
    pub emission: Vec3,
    pub double_sided: bool,
    pub base: Option<TexRef>,
    pub emissive: Option<TexRef>,
}

enum ImageSlot {
    NotLoaded,
    Loaded(Image),
    Failed,
}

pub(super) struct Materials {
    infos: Vec<MaterialInfo>,
    entries: Vec<Entry>,
    /// Index of the glTF default material, appended on first use.
    default: Option<usize>,
    /// The entry of each (emissive material, node) pair after the material's first node, which
    /// takes the material's own entry.
    by_node: std::collections::HashMap<(usize, String), usize>,
    images: Vec<ImageSlot>,
}

impl Materials {
    pub(super) fn new(
        document: &gltf::Document,
        raw: Option<&serde_json::Value>,
        report: &mut ImportReport,
    ) -> Self {
        let mut infos = Vec::new();
        let mut entries = Vec::new();
        for (i, m) in document.materials().enumerate() {
            let name = m
                .name()
                .map_or_else(|| format!("material #{i}"), str::to_owned);
            let pbr = m.pbr_metallic_roughness();
            let [r, g, b, _] = pbr.base_color_factor();
            let strength = m.emissive_strength().unwrap_or(1.0);
            let mut emission = Vec3::from(m.emissive_factor()) * strength;
            if !(emission.is_finite() && emission.min_element() >= 0.0) {
                report.warnings.push(format!(
                    "material '{name}': emission {emission} (factor {:?} × strength {strength}) is \
                     invalid; used none",
                    m.emissive_factor()
                ));
                emission = Vec3::ZERO;
            }
            let mut slot = |info: Option<gltf::texture::Info<'_>>, path: &[&str]| {
                info.map(|info| tex_ref(&info, raw, i, path, &name, report))
            };
            let base = slot(
                pbr.base_color_texture(),
                &["pbrMetallicRoughness", "baseColorTexture"],
            );
            let emissive = slot(m.emissive_texture(), &["emissiveTexture"]);
            infos.push(MaterialInfo {
                name,
                base_color_factor: [r, g, b],
                has_base_color_texture: base.is_some(),
                emission: emission.into(),
                emissive_strength: strength,
                double_sided: m.double_sided(),
                node: None,
            });
            entries.push(Entry {
                albedo: Vec3::new(r, g, b),
                emission,
                double_sided: m.double_sided(),
                base,
                emissive,
            });
        }
        Materials {
            infos,
            entries,
            default: None,
            by_node: std::collections::HashMap::new(),
            images: (0..document.images().len())
                .map(|_| ImageSlot::NotLoaded)
                .collect(),
        }
    }

    /// The index a primitive's material has in [`crate::scene::Scene::materials`].
    pub(super) fn index_for(&mut self, primitive: &gltf::Primitive<'_>) -> usize {
        if let Some(i) = primitive.material().index()
            && i < self.entries.len()
        {
            return i;
        }
        *self.default.get_or_insert_with(|| {
            // glTF's default material: white, not emissive, one-sided.
            self.infos.push(MaterialInfo {
                name: "default".into(),
                base_color_factor: [1.0; 3],
                has_base_color_texture: false,
                emission: [0.0; 3],
                emissive_strength: 1.0,
                double_sided: false,
                node: None,
            });
            self.entries.push(Entry {
                albedo: Vec3::ONE,
                emission: Vec3::ZERO,
                double_sided: false,
                base: None,
                emissive: None,
            });
            self.entries.len() - 1
        })
    }

    /// The entry of material `index` as placed by node `node`: the material's own for a
    /// material that emits nothing; for an emissive one, an entry of this node's own (the
    /// material's first node takes the material's entry, later nodes a copy each), so emitters
    /// can be told apart by node ([`crate::emitter`]).
    pub(super) fn for_node(&mut self, index: usize, node: &str) -> usize {
        let info = &self.infos[index];
        if info.emission.iter().all(|&c| c <= 0.0) {
            return index;
        }
        match &info.node {
            None => {
                self.infos[index].node = Some(node.to_string());
                index
            }
            Some(first) if first == node => index,
            Some(_) => {
                if let Some(&i) = self.by_node.get(&(index, node.to_string())) {
                    return i;
                }
                let mut copy = self.infos[index].clone();
                copy.node = Some(node.to_string());
                self.infos.push(copy);
                self.entries.push(self.entries[index]);
                let i = self.entries.len() - 1;
                self.by_node.insert((index, node.to_string()), i);
                i
            }
        }
    }

    pub(super) fn entry(&self, index: usize) -> Entry {
        self.entries[index]
    }

    /// The decoded image, if it has been loaded successfully.
    pub(super) fn image(&self, index: usize) -> Option<&Image> {
        match self.images.get(index) {
            Some(ImageSlot::Loaded(image)) => Some(image),
            _ => None,
        }
    }

    /// Moves a loaded image out; later lookups see it as absent.
    pub(super) fn take_image(&mut self, index: usize) -> Option<Image> {
        let slot = self.images.get_mut(index)?;
        match std::mem::replace(slot, ImageSlot::Failed) {
            ImageSlot::Loaded(image) => Some(image),
            other => {
                *slot = other;
                None
            }
        }
    }

    pub(super) fn into_infos(self) -> Vec<MaterialInfo> {
        self.infos
    }
}

/// Resolves a texture slot, applying `KHR_texture_transform` found at `materials[i].<path>`.
fn tex_ref(
    info: &gltf::texture::Info<'_>,
    raw: Option<&serde_json::Value>,
    material: usize,
    path: &[&str],
    name: &str,
    report: &mut ImportReport,
) -> TexRef {
    let texture = info.texture();
    let mut tex_coord = info.tex_coord();
    let mut transform = Affine2::IDENTITY;
    let ext = raw.and_then(|raw| {
        let mut v = raw.get("materials")?.get(material)?;
        for key in path {
            v = v.get(key)?;
        }
        v.get("extensions")?.get("KHR_texture_transform")
    });
    if let Some(ext) = ext {
        match parse_transform(ext) {
            Ok((t, set)) => {
                transform = t;
                tex_coord = set.unwrap_or(tex_coord);
            }
            Err(reason) => report.warnings.push(format!(
                "material '{name}' {}: KHR_texture_transform ignored: {reason}",
                path.last().copied().unwrap_or_default()
            )),
        }
    }
    TexRef {
        image: texture.source().index(),
        tex_coord,
        lookup: Lookup::new(&texture.sampler(), transform),
    }
}

fn parse_transform(v: &serde_json::Value) -> Result<(Affine2, Option<u32>), String> {
    let pair = |key: &str, default: Vec2| -> Result<Vec2, String> {
        match v.get(key) {
            None => Ok(default),
            Some(a) => match a.as_array().map(Vec::as_slice) {
                Some([x, y]) => match (x.as_f64(), y.as_f64()) {
                    (Some(x), Some(y)) => Ok(Vec2::new(x as f32, y as f32)),
                    _ => Err(format!("{key} is not two numbers")),
                },
                _ => Err(format!("{key} is not two numbers")),
            },
        }
    };
    let offset = pair("offset", Vec2::ZERO)?;
    let scale = pair("scale", Vec2::ONE)?;
    let rotation = match v.get("rotation") {
        None => 0.0,
        Some(r) => r.as_f64().ok_or("rotation is not a number")? as f32,
    };
    let tex_coord = match v.get("texCoord") {
        None => None,
        Some(t) => Some(
            t.as_u64()
                .and_then(|t| u32::try_from(t).ok())
                .ok_or("texCoord is not a small non-negative integer")?,
        ),
    };
    if !(offset.is_finite() && scale.is_finite() && rotation.is_finite()) {
        return Err("non-finite values".into());
    }
    Ok((texture::uv_transform(offset, rotation, scale), tex_coord))
}

impl Importer<'_> {
    /// Loads and decodes an image on first use; a failure is reported once and the image is
    /// treated as absent from then on.
    pub(super) fn ensure_image(&mut self, index: usize) {
        if !matches!(self.materials.images.get(index), Some(ImageSlot::NotLoaded)) {
            return;
        }
        let Some(image) = self.document.images().nth(index) else {
            return;
        };
        // `gltf::Image::source` unwraps both: an image with neither a URI nor a buffer view, or
        // a buffer view without a mimeType, passes glTF validation and panicked there (found by
        // the `gltf_import` fuzz target).
        let json = &self.document.as_json().images[index];
        let malformed = match (&json.buffer_view, &json.uri, &json.mime_type) {
            (None, None, _) => Some("it has neither a uri nor a bufferView"),
            (Some(_), _, None) => Some("it has a bufferView but no mimeType"),
            _ => None,
        };
        if let Some(reason) = malformed {
            let name = image.name().map(|n| format!(" '{n}'")).unwrap_or_default();
            self.scene
                .report
                .missing_textures
                .push(format!("image {index}{name}: {reason}"));
            self.materials.images[index] = ImageSlot::Failed;
            return;
        }
        let (what, bytes, mime) = match image.source() {
            gltf::image::Source::View { view, mime_type } => (
                format!("buffer view {}", view.index()),
                accessor::view_bytes(&view, self.buffers)
                    .map(<[u8]>::to_vec)
                    .map_err(|e| match e {
                        accessor::ReadError::Buffer { buffer, reason } => {
                            format!("buffer {buffer}: {reason}")
                        }
                        accessor::ReadError::Invalid(reason) => reason,
                    }),
                Some(mime_type),
            ),
            gltf::image::Source::Uri { uri, mime_type } => (
                if uri.starts_with("data:") {
                    "data URI".to_string()
                } else {
                    uri.to_string()
                },
                source::read_uri(uri, self.base_dir),
                mime_type,
            ),
        };
        // Shading hands the pixels on with their alpha; decoding them that way now saves
        // decoding the image twice.
        let keep_alpha = self.shading.is_some();
        let decoded = bytes.and_then(|b| Image::decode(&b, mime, keep_alpha));
        self.materials.images[index] = match decoded {
            Ok(decoded) => ImageSlot::Loaded(decoded),
            Err(reason) => {
                let name = image.name().map(|n| format!(" '{n}'")).unwrap_or_default();
                self.scene
                    .report
                    .missing_textures
                    .push(format!("image {index}{name} ({what}): {reason}"));
                ImageSlot::Failed
            }
        };
    }
}
