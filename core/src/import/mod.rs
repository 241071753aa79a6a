//! glTF 2.0 import: a `.gltf` (with its external buffers and images) or `.glb` file becomes a
//! [`Scene`] of world-space triangles, each with its diffuse albedo and emission resolved, plus the
//! file's `KHR_lights_punctual` lights placed in world space.
//!
//! The importer is lenient where a bake can still be trusted and strict where it cannot: a missing
//! texture, an unsupported primitive mode or an invalid light is skipped and written to the
//! [`ImportReport`]; a file that is not glTF, a missing buffer, a non-finite vertex position or a
//! scene with no usable triangle is an [`ImportError`]. Malformed input gives an error or a report
//! line, never a panic.
//!
//! Owned here: parsing and validation, node transforms, triangle assembly, per-triangle material
//! resolution (the `texture` submodule does the texture averaging) and light placement. On request
//! ([`ImportOptions::shading`]) it also keeps what a viewer needs to draw the surfaces rather than
//! bake them: per-corner normals, texture coordinates and tints, and the decoded base-colour
//! images (the `shading` submodule); a bake leaves it off and does none of that work.
//!
//! Also here, as it reads the same files: [`pack_glb`], the scene as one self-contained GLB, which
//! a baked file keeps for viewers that draw the original meshes.

mod accessor;
mod material;
mod mesh;
mod pack;
mod packed;
mod shading;
mod source;
mod texture;

use std::borrow::Cow;
use std::collections::HashSet;
use std::path::{Path, PathBuf};

use glam::{Mat3, Mat4, Quat, Vec3};
use gltf::json::validation::{Checked, Validate};

use crate::light::Light;

pub use self::pack::{PackError, pack_bytes, pack_glb};
pub use self::packed::{MAX_SERVED_MODEL_BYTES, PackedModelError, validate_packed};
use crate::scene::{ImportReport, Scene};

use self::accessor::BufferData;
use self::material::Materials;
use self::shading::ShadingBuilder;

/// Why a file could not be imported at all.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("{}: file not found", path.display())]
    NotFound { path: PathBuf },

    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },

    #[error("{}: not a glTF 2.0 file: {reason}", path.display())]
    NotGltf { path: PathBuf, reason: String },

    /// The file lists in `extensionsRequired` an extension without which its geometry cannot be
    /// read (mesh compression, GPU instancing, ...).
    #[error("{}: requires glTF extension(s) bounce cannot read: {}", path.display(), extensions.join(", "))]
    UnsupportedExtensions {
        path: PathBuf,
        extensions: Vec<String>,
    },

    /// A buffer that geometry needs could not be loaded (missing `.bin`, bad data URI, too short).
    #[error("{}: buffer {buffer} cannot be loaded: {reason}", path.display())]
    Buffer {
        path: PathBuf,
        buffer: usize,
        reason: String,
    },

    #[error("{}: no usable triangles ({summary})", path.display())]
    NoTriangles { path: PathBuf, summary: String },

    #[error("{}: {mesh} primitive {primitive}: vertex {vertex} has a non-finite POSITION", path.display())]
    NonFinitePosition {
        path: PathBuf,
        /// The mesh's name and index, e.g. `mesh 'floor' (#3)`.
        mesh: String,
        primitive: usize,
        vertex: usize,
    },

    /// A finite position that its node transform takes past f32's range.
    #[error("{}: {mesh} primitive {primitive}: vertex {vertex} is not finite in world space (its node transform overflows f32)", path.display())]
    NonFiniteWorldPosition {
        path: PathBuf,
        mesh: String,
        primitive: usize,
        vertex: usize,
    },
}

/// What an import produces beyond the bake's triangles.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ImportOptions {
    /// Fill [`Scene::shading`] with per-corner normals, texture coordinates and tints and the
    /// decoded base-colour images, for drawing the surfaces at full resolution.
    pub shading: bool,
}

/// Imports a `.gltf` or `.glb` file; external buffers and images are resolved relative to it.
pub fn import_path(path: &Path) -> Result<Scene, ImportError> {
    import_path_with(path, &ImportOptions::default())
}

/// [`import_path`] with options.
pub fn import_path_with(path: &Path, options: &ImportOptions) -> Result<Scene, ImportError> {
    let bytes = std::fs::read(path).map_err(|source| match source.kind() {
        std::io::ErrorKind::NotFound => ImportError::NotFound {
            path: path.to_path_buf(),
        },
        _ => ImportError::Io {
            path: path.to_path_buf(),
            source,
        },
    })?;
    import(&bytes, Some(base_dir(path)), path.to_path_buf(), options)
}

/// The directory a scene file's relative URIs resolve against. A bare file name's parent is the
/// empty path, which names no directory (canonicalising it fails): it means the current one.
pub(crate) fn base_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Imports glTF or GLB bytes. External (non-`data:`) URIs are resolved relative to `base_dir`;
/// without one, a buffer they name is an error and an image they name is reported missing.
pub fn import_slice(bytes: &[u8], base_dir: Option<&Path>) -> Result<Scene, ImportError> {
    import_slice_with(bytes, base_dir, &ImportOptions::default())
}

/// [`import_slice`] with options.
pub fn import_slice_with(
    bytes: &[u8],
    base_dir: Option<&Path>,
    options: &ImportOptions,
) -> Result<Scene, ImportError> {
    import(bytes, base_dir, PathBuf::from("<in-memory glTF>"), options)
}

/// Required extensions that can be honoured, or safely ignored for diffuse lighting.
fn required_extension_ok(name: &str) -> bool {
    matches!(
        name,
        "KHR_lights_punctual" | "KHR_texture_transform" | "KHR_mesh_quantization"
    ) || name.starts_with("KHR_materials_")
}

/// Used extensions that need no warning: read here, or only about non-diffuse shading.
fn used_extension_silent(name: &str) -> bool {
    required_extension_ok(name) && name != "KHR_materials_pbrSpecularGlossiness"
}

fn import(
    bytes: &[u8],
    base_dir: Option<&Path>,
    path: PathBuf,
    options: &ImportOptions,
) -> Result<Scene, ImportError> {
    let (container, root) = parse(bytes, &path)?;

    let mut report = ImportReport::default();
    for ext in &root.extensions_used {
        if ext == "KHR_materials_pbrSpecularGlossiness" {
            report.warnings.push(
                "KHR_materials_pbrSpecularGlossiness is not read: such materials use their \
                 metallic-roughness base colour (white if absent)"
                    .into(),
            );
        } else if !used_extension_silent(ext) {
            report.warnings.push(format!(
                "glTF extension {ext} is not supported and was ignored"
            ));
        }
    }
    // Only this extension's data is needed from the raw JSON (the `gltf` crate is built without
    // it); parse the JSON a second time only when it is used.
    let raw = root
        .extensions_used
        .iter()
        .any(|e| e == "KHR_texture_transform")
        .then(|| serde_json::from_slice::<serde_json::Value>(container.json).ok())
        .flatten();

    let document = gltf::Document::from_json_without_validation(root);
    let buffers = load_buffers(&document, container.bin, base_dir);
    let mut importer = Importer {
        path: &path,
        base_dir,
        document: &document,
        buffers: &buffers,
        materials: Materials::new(&document, raw.as_ref(), &mut report),
        scene: Scene {
            report,
            ..Scene::default()
        },
        seen_meshes: HashSet::new(),
        placed_lights: HashSet::new(),
        shading: options.shading.then(ShadingBuilder::default),
    };
    importer.walk()?;
    importer.finish()
}

/// Splits the container, parses and validates the JSON. Validation problems that only cost a
/// primitive or a light are let through, to be skipped and reported later.
fn parse<'b>(
    bytes: &'b [u8],
    path: &Path,
) -> Result<(source::Container<'b>, gltf::json::Root), ImportError> {
    let not_gltf = |reason: String| ImportError::NotGltf {
        path: path.to_path_buf(),
        reason,
    };
    let container = source::split(bytes).map_err(&not_gltf)?;
    let root: gltf::json::Root =
        gltf::json::deserialize::from_slice(container.json).map_err(|e| not_gltf(e.to_string()))?;
    if !root.asset.version.starts_with("2.") {
        return Err(not_gltf(format!(
            "asset.version is \"{}\"; only glTF 2.x is supported",
            root.asset.version
        )));
    }

    let unsupported: Vec<String> = root
        .extensions_required
        .iter()
        .filter(|e| !required_extension_ok(e))
        .cloned()
        .collect();
    if !unsupported.is_empty() {
        return Err(ImportError::UnsupportedExtensions {
            path: path.to_path_buf(),
            extensions: unsupported,
        });
    }

    // gltf-json's own validation indexes `accessors` with the POSITION index unchecked.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for (semantic, index) in &prim.attributes {
                if index.value() >= root.accessors.len() {
                    return Err(not_gltf(format!(
                        "meshes[{m}].primitives[{p}].attributes.{}: accessor {} does not \
                         exist ({} accessors)",
                        semantic.to_string(),
                        index.value(),
                        root.accessors.len()
                    )));
                }
            }
        }
    }

    let mut problems = Vec::new();
    root.validate(&root, gltf::json::Path::new, &mut |p, e| {
        let p = p().to_string();
        // Required extensions were judged above. Light errors (unknown type, missing `spot`, bad
        // index) only skip that light, which `place_light` reports. A missing POSITION only skips
        // its primitive. POSITION's min and max are required by the spec but unused here, and
        // often missing or malformed.
        let harmless = p.starts_with("extensionsRequired")
            || p.contains("khrLightsPunctual")
            || p.contains("KHR_lights_punctual")
            || p.ends_with("[\"POSITION\"]")
            || p.ends_with("[\"POSITION\"].min")
            || p.ends_with("[\"POSITION\"].max");
        if !harmless {
            problems.push(format!("{p}: {e}"));
        }
    });
    if !problems.is_empty() {
        let more = problems.len().saturating_sub(5);
        let mut reason = problems[..problems.len().min(5)].join("; ");
        if more > 0 {
            reason.push_str(&format!("; and {more} more"));
        }
        return Err(not_gltf(format!("invalid glTF: {reason}")));
    }

    Ok((container, root))
}

/// Every buffer's bytes, or why they could not be had; only a buffer that geometry needs makes
/// the import fail.
fn load_buffers<'b>(
    document: &gltf::Document,
    mut bin: Option<&'b [u8]>,
    base_dir: Option<&Path>,
) -> Vec<BufferData<'b>> {
    document
        .buffers()
        .map(|buffer| {
            let data: Cow<'_, [u8]> = match buffer.source() {
                gltf::buffer::Source::Bin => Cow::Borrowed(
                    bin.take()
                        .ok_or_else(|| "the file has no GLB binary chunk".to_string())?,
                ),
                gltf::buffer::Source::Uri(uri) => Cow::Owned(source::read_uri(uri, base_dir)?),
            };
            if data.len() < buffer.length() {
                return Err(format!(
                    "{} bytes, but byteLength says {}",
                    data.len(),
                    buffer.length()
                ));
            }
            Ok(data)
        })
        .collect()
}

/// State of one import.
struct Importer<'a> {
    path: &'a Path,
    base_dir: Option<&'a Path>,
    document: &'a gltf::Document,
    buffers: &'a [BufferData<'a>],
    materials: Materials,
    scene: Scene,
    /// Meshes already instanced once: report lines and counts are per mesh, not per instance.
    seen_meshes: HashSet<usize>,
    placed_lights: HashSet<usize>,
    /// Present only when the import was asked for shading data.
    shading: Option<ShadingBuilder>,
}

impl Importer<'_> {
    /// Walks the default scene (else scene 0, else every root node), composing node transforms.
    fn walk(&mut self) -> Result<(), ImportError> {
        let nodes: Vec<gltf::Node<'_>> = self.document.nodes().collect();
        let scene_count = self.document.scenes().len();
        let roots: Vec<usize> = match self
            .document
            .default_scene()
            .or_else(|| self.document.scenes().next())
        {
            Some(scene) => {
                if scene_count > 1 {
                    self.scene.report.warnings.push(format!(
                        "the file has {scene_count} scenes; imported scene {} only",
                        scene_label(&scene)
                    ));
                }
                scene.nodes().map(|n| n.index()).collect()
            }
            None => {
                let mut is_child = vec![false; nodes.len()];
                for node in &nodes {
                    for child in node.children() {
                        if let Some(c) = is_child.get_mut(child.index()) {
                            *c = true;
                        }
                    }
                }
                (0..nodes.len()).filter(|&i| !is_child[i]).collect()
            }
        };

        // Depth-first with an explicit stack: a deep hierarchy cannot overflow the call stack.
        let mut stack: Vec<(usize, Mat4)> =
            roots.iter().rev().map(|&i| (i, Mat4::IDENTITY)).collect();
        let mut visited = vec![false; nodes.len()];
        let mut skin_warned = false;
        while let Some((index, parent)) = stack.pop() {
            let Some(node) = nodes.get(index) else {
                continue;
            };
            if std::mem::replace(&mut visited[index], true) {
                self.scene.report.warnings.push(format!(
                    "{} is reached twice in the node hierarchy (a cycle or a shared child); \
                     only its first occurrence was imported",
                    node_label(node)
                ));
                continue;
            }
            let world = parent * self.local_transform(node);
            if !world.is_finite() {
                self.scene.report.warnings.push(format!(
                    "{} has a non-finite world transform",
                    node_label(node)
                ));
            }
            if let Some(mesh) = node.mesh() {
                if node.skin().is_some() && !skin_warned {
                    skin_warned = true;
                    self.scene
                        .report
                        .warnings
                        .push("skinned meshes were imported in their bind pose".into());
                }
                let name = node
                    .name()
                    .map_or_else(|| format!("node #{}", node.index()), str::to_owned);
                self.mesh_instance(&mesh, &name, world)?;
            }
            self.place_light(node, world);
            for child in node.children().collect::<Vec<_>>().into_iter().rev() {
                stack.push((child.index(), world));
            }
        }
        Ok(())
    }

    fn local_transform(&mut self, node: &gltf::Node<'_>) -> Mat4 {
        match node.transform() {
            gltf::scene::Transform::Matrix { matrix } => Mat4::from_cols_array_2d(&matrix),
            gltf::scene::Transform::Decomposed {
                translation,
                rotation,
                scale,
            } => {
                let q = Quat::from_array(rotation);
                // The spec requires unit quaternions; exporters round, so renormalise rather than
                // let a slightly long quaternion scale the geometry.
                let q = if q.is_finite() && q.length_squared() > 0.0 {
                    q.normalize()
                } else {
                    self.scene.report.warnings.push(format!(
                        "{} has an invalid rotation {rotation:?}; used none",
                        node_label(node)
                    ));
                    Quat::IDENTITY
                };
                Mat4::from_scale_rotation_translation(scale.into(), q, translation.into())
            }
        }
    }

    /// The `KHR_lights_punctual` light on `node`, if any, placed by its world transform.
    fn place_light(&mut self, node: &gltf::Node<'_>, world: Mat4) {
        let json = self.document.as_json();
        let Some(light_ref) = json
            .nodes
            .get(node.index())
            .and_then(|n| n.extensions.as_ref())
            .and_then(|e| e.khr_lights_punctual.as_ref())
        else {
            return;
        };
        let index = light_ref.light.value();
        let lights = document_lights(json);
        let Some(light) = lights.get(index) else {
            self.scene.report.skipped_lights.push(format!(
                "{}: light {index} does not exist ({} defined)",
                node_label(node),
                lights.len()
            ));
            return;
        };
        self.placed_lights.insert(index);
        let name = light
            .name
            .clone()
            .or_else(|| node.name().map(str::to_owned));
        let label = match &name {
            Some(n) => format!("light {index} '{n}' at {}", node_label(node)),
            None => format!("light {index} at {}", node_label(node)),
        };
        match make_light(light, world, name) {
            Ok(l) => self.scene.lights.push(l),
            Err(reason) => self
                .scene
                .report
                .skipped_lights
                .push(format!("{label}: {reason}")),
        }
    }

    fn finish(mut self) -> Result<Scene, ImportError> {
        let json = self.document.as_json();
        let lights = document_lights(json);
        for (i, light) in lights.iter().enumerate() {
            if !self.placed_lights.contains(&i) {
                let name = light.name.as_deref().unwrap_or("unnamed");
                self.scene.report.skipped_lights.push(format!(
                    "light {i} '{name}': not placed by any node of the imported scene"
                ));
            }
        }
        if let Some(shading) = self.shading.take() {
            self.scene.shading = Some(shading.finish(&mut self.materials));
        }
        self.scene.materials = self.materials.into_infos();
        let report = &mut self.scene.report;
        report.triangles = self.scene.triangles.len();
        report.lights = self.scene.lights.len();
        if self.scene.triangles.is_empty() {
            return Err(ImportError::NoTriangles {
                path: self.path.to_path_buf(),
                summary: summary(report),
            });
        }
        Ok(self.scene)
    }
}

/// Converts a glTF light at a node with world transform `world`, or says why it is unusable.
fn make_light(
    light: &gltf::json::extensions::scene::khr_lights_punctual::Light,
    world: Mat4,
    name: Option<String>,
) -> Result<Light, String> {
    use gltf::json::extensions::scene::khr_lights_punctual::Type;

    let Checked::Valid(kind) = light.type_ else {
        return Err("unknown light type".into());
    };
    let color = light.color;
    if !color.iter().all(|c| c.is_finite() && *c >= 0.0) {
        return Err(format!("invalid color {color:?}"));
    }
    let intensity = light.intensity;
    if !(intensity.is_finite() && intensity >= 0.0) {
        return Err(format!("invalid intensity {intensity}"));
    }
    let range = light.range;
    if let Some(r) = range
        && !(r.is_finite() && r > 0.0)
    {
        return Err(format!("invalid range {r}"));
    }
    let position = world.transform_point3(Vec3::ZERO);
    let direction = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
    let need_position = kind != Type::Directional;
    let need_direction = kind != Type::Point;
    if need_position && !position.is_finite() {
        return Err("its node's world position is not finite".into());
    }
    if need_direction && direction == Vec3::ZERO {
        return Err("its node's world transform gives no direction".into());
    }
    Ok(match kind {
        Type::Directional => Light::Directional {
            direction: direction.into(),
            color,
            intensity,
            name,
        },
        Type::Point => Light::Point {
            position: position.into(),
            color,
            intensity,
            range,
            name,
        },
        Type::Spot => {
            let Some(spot) = &light.spot else {
                return Err("spot light without `spot` cone angles".into());
            };
            let (inner, outer) = (spot.inner_cone_angle, spot.outer_cone_angle);
            // Exporters write π/2 rounded to f32 or f64; allow that rounding.
            let max = std::f32::consts::FRAC_PI_2 + 1e-6;
            if !(inner.is_finite()
                && outer.is_finite()
                && 0.0 <= inner
                && inner < outer
                && outer <= max)
            {
                return Err(format!(
                    "invalid cone angles inner {inner}, outer {outer} (need 0 <= inner < outer <= pi/2)"
                ));
            }
            Light::Spot {
                position: position.into(),
                direction: direction.into(),
                color,
                intensity,
                range,
                inner_cone_angle: inner,
                outer_cone_angle: outer,
                name,
            }
        }
    })
}

/// One line saying what was read and dropped, for `NoTriangles`.
fn summary(report: &ImportReport) -> String {
    let mut parts = vec![format!(
        "{} mesh(es) with {} primitive(s) in the scene",
        report.meshes, report.primitives
    )];
    if !report.skipped_primitives.is_empty() {
        let shown: Vec<&str> = report
            .skipped_primitives
            .iter()
            .take(3)
            .map(String::as_str)
            .collect();
        let more = report.skipped_primitives.len() - shown.len();
        parts.push(format!(
            "{} primitive(s) skipped: {}{}",
            report.skipped_primitives.len(),
            shown.join("; "),
            if more > 0 {
                format!("; and {more} more")
            } else {
                String::new()
            }
        ));
    }
    if report.degenerate_triangles > 0 {
        parts.push(format!(
            "{} degenerate triangle(s) dropped",
            report.degenerate_triangles
        ));
    }
    parts.join("; ")
}

fn node_label(node: &gltf::Node<'_>) -> String {
    match node.name() {
        Some(name) => format!("node '{name}' (#{})", node.index()),
        None => format!("node #{}", node.index()),
    }
}

fn scene_label(scene: &gltf::Scene<'_>) -> String {
    match scene.name() {
        Some(name) => format!("'{name}' (#{})", scene.index()),
        None => format!("#{}", scene.index()),
    }
}

/// Whether a world transform mirrors: then triangle winding must be reversed to keep the normals
/// the author meant.
fn mirrors(world: &Mat4) -> bool {
    Mat3::from_mat4(*world).determinant() < 0.0
}

/// The `KHR_lights_punctual` lights the document defines (placed by nodes or not).
fn document_lights(
    json: &gltf::json::Root,
) -> &[gltf::json::extensions::scene::khr_lights_punctual::Light] {
    json.extensions
        .as_ref()
        .and_then(|e| e.khr_lights_punctual.as_ref())
        .map(|l| l.lights.as_slice())
        .unwrap_or_default()
}
