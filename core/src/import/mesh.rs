//! Mesh primitives to world-space triangles with their albedo and emission resolved.

use glam::{Mat4, Vec2, Vec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::{Mode, Semantic};

use super::accessor::{self, ReadError};
use super::material::TexRef;
use super::shading::{PrimitiveShading, normal_matrix};
use super::{ImportError, Importer, mirrors};
use crate::scene::Triangle;

/// Why a primitive produced no triangles.
enum Problem {
    /// The whole import must fail.
    Fatal(ImportError),
    /// Skip this primitive; the reason goes to the report.
    Skip(String),
}

impl From<String> for Problem {
    fn from(reason: String) -> Self {
        Problem::Skip(reason)
    }
}

impl From<&str> for Problem {
    fn from(reason: &str) -> Self {
        Problem::Skip(reason.to_owned())
    }
}

impl Importer<'_> {
    /// Adds the triangles of one instance of `mesh` placed by `world`, by the node named `node`.
    pub(super) fn mesh_instance(
        &mut self,
        mesh: &gltf::Mesh<'_>,
        node: &str,
        world: Mat4,
    ) -> Result<(), ImportError> {
        // Report lines and counts once per mesh, however often it is instanced.
        let first = self.seen_meshes.insert(mesh.index());
        if first {
            self.scene.report.meshes += 1;
        }
        let label = mesh_label(mesh);
        for primitive in mesh.primitives() {
            if first {
                self.scene.report.primitives += 1;
            }
            let mut warnings = Vec::new();
            let result = self.primitive(&label, &primitive, node, world, &mut warnings);
            if first {
                let prefix = format!("{label} primitive {}", primitive.index());
                self.scene
                    .report
                    .warnings
                    .extend(warnings.into_iter().map(|w| format!("{prefix}: {w}")));
                if let Err(Problem::Skip(reason)) = &result {
                    self.scene
                        .report
                        .skipped_primitives
                        .push(format!("{prefix}: {reason}"));
                }
            }
            if let Err(Problem::Fatal(e)) = result {
                return Err(e);
            }
        }
        Ok(())
    }

    fn primitive(
        &mut self,
        mesh_label: &str,
        primitive: &gltf::Primitive<'_>,
        node: &str,
        world: Mat4,
        warnings: &mut Vec<String>,
    ) -> Result<(), Problem> {
        let mode = primitive.mode();
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            return Err(format!("mode {mode:?}").into());
        }
        let positions = primitive
            .get(&Semantic::Positions)
            .ok_or("no POSITION attribute")?;
        if positions.dimensions() != Dimensions::Vec3 {
            return Err(format!("POSITION is {:?}, not Vec3", positions.dimensions()).into());
        }
        let positions: Vec<Vec3> = self
            .read(&positions, "POSITION", |v| v as f32)?
            .chunks_exact(3)
            .map(Vec3::from_slice)
            .collect();
        if let Some(vertex) = positions.iter().position(|p| !p.is_finite()) {
            return Err(Problem::Fatal(ImportError::NonFinitePosition {
                path: self.path.to_path_buf(),
                mesh: mesh_label.to_owned(),
                primitive: primitive.index(),
                vertex,
            }));
        }
        let n = positions.len();

        let indices: Vec<u32> = match primitive.indices() {
            Some(acc) => {
                if acc.dimensions() != Dimensions::Scalar
                    || !matches!(
                        acc.data_type(),
                        DataType::U8 | DataType::U16 | DataType::U32
                    )
                {
                    return Err(format!(
                        "indices are {:?} {:?}, not unsigned scalars",
                        acc.data_type(),
                        acc.dimensions()
                    )
                    .into());
                }
                self.read(&acc, "indices", |v| v as u32)?
            }
            None => (0..n as u32).collect(),
        };
        if let Some(&bad) = indices.iter().find(|&&i| i as usize >= n) {
            return Err(format!("index {bad} out of range ({n} vertices)").into());
        }
        let (mut corners, leftover) = assemble(mode, &indices);
        if leftover > 0 {
            warnings.push(format!(
                "{leftover} trailing index(es) do not form a triangle and were ignored"
            ));
        }

        let material = self.materials.index_for(primitive);
        let material = self.materials.for_node(material, node);
        let entry = self.materials.entry(material);
        let colors = self.colors(primitive, n, warnings);
        let base = self.texture_input(primitive, entry.base, n, "base-colour", warnings);
        let emissive = self.texture_input(primitive, entry.emissive, n, "emissive", warnings);

        let world_positions: Vec<Vec3> = positions
            .iter()
            .map(|&p| world.transform_point3(p))
            .collect();
        // Otherwise its triangles would be counted as degenerate, hiding the cause.
        if let Some(vertex) = world_positions.iter().position(|p| !p.is_finite()) {
            return Err(Problem::Fatal(ImportError::NonFiniteWorldPosition {
                path: self.path.to_path_buf(),
                mesh: mesh_label.to_owned(),
                primitive: primitive.index(),
                vertex,
            }));
        }
        let flip = mirrors(&world);
        // Under a mirroring transform the same index order winds the other way; swapping two
        // corners keeps `cross()` pointing where the author's normal pointed.
        if flip {
            for t in &mut corners {
                t.swap(1, 2);
            }
        }
        let shading = self.shading.is_some().then(|| {
            self.primitive_shading(
                primitive,
                world,
                world_positions.len(),
                (entry.albedo, colors.as_deref(), &base),
                warnings,
            )
        });
        for &t in &corners {
            let [a, b, c] = t.map(|i| i as usize);
            let tri = [world_positions[a], world_positions[b], world_positions[c]];
            let cross = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
            let len2 = cross.length_squared();
            if !(len2 > 0.0 && len2.is_finite()) {
                self.scene.report.degenerate_triangles += 1;
                continue;
            }
            // Pushed only beside a kept triangle, so the two lists stay parallel.
            if let (Some(shading), Some(out)) = (&shading, &mut self.shading) {
                out.triangles
                    .push(shading.triangle([a, b, c], cross / len2.sqrt()));
            }
            let mut albedo = entry.albedo;
            if let Some(colors) = &colors {
                albedo *= (colors[a] + colors[b] + colors[c]) / 3.0;
            }
            albedo *= self.texture_average(&base, [a, b, c]);
            let emission = entry.emission * self.texture_average(&emissive, [a, b, c]);
            self.scene.triangles.push(Triangle {
                positions: tri,
                albedo: unit_clamp(albedo),
                emission: if emission.is_finite() {
                    emission.max(Vec3::ZERO)
                } else {
                    Vec3::ZERO
                },
                double_sided: entry.double_sided,
                material: material as u32,
            });
        }
        Ok(())
    }

    /// Per-vertex shading inputs of one primitive instance: normals (the file's, else none:
    /// flat), transformed texture coordinates and tints.
    fn primitive_shading(
        &mut self,
        primitive: &gltf::Primitive<'_>,
        world: Mat4,
        n: usize,
        (factor, colors, base): (Vec3, Option<&[Vec3]>, &TextureInput),
        warnings: &mut Vec<String>,
    ) -> PrimitiveShading {
        let normals = match self.normals(primitive, n, warnings) {
            Some(normals) => {
                let m = normal_matrix(&world);
                normals
                    .into_iter()
                    .map(|v| (m * v).normalize_or_zero())
                    .collect()
            }
            // glTF: "When normals are not specified, client implementations MUST calculate flat
            // normals" (§3.7.2.1); zero makes each triangle take its face normal. three.js
            // does the same, so the browser and native viewers shade such a mesh alike.
            None => vec![Vec3::ZERO; n],
        };
        let mean = match base {
            TextureInput::Mean(image) => {
                self.materials.image(*image).map_or(Vec3::ONE, |i| i.mean())
            }
            _ => Vec3::ONE,
        };
        let tints = (0..n)
            .map(|i| {
                unit_clamp(
                    factor * mean * colors.and_then(|c| c.get(i).copied()).unwrap_or(Vec3::ONE),
                )
            })
            .collect();
        let texture = match (base, &mut self.shading) {
            (TextureInput::Mapped { slot, uv }, Some(shading)) => {
                let uv = uv
                    .iter()
                    .map(|&p| {
                        let p = slot.lookup.transform.transform_point2(p);
                        // As the averaging does: a texture lookup at NaN would poison a pixel.
                        if p.is_finite() { p } else { Vec2::ZERO }
                    })
                    .collect();
                Some((uv, shading.texture_index(slot)))
            }
            _ => None,
        };
        PrimitiveShading {
            normals,
            texture,
            tints,
        }
    }

    /// `NORMAL` per vertex in the primitive's space, or `None` (with a warning if it is present
    /// but unusable) so that flat normals stand in.
    fn normals(
        &self,
        primitive: &gltf::Primitive<'_>,
        n: usize,
        warnings: &mut Vec<String>,
    ) -> Option<Vec<Vec3>> {
        let acc = primitive.get(&Semantic::Normals)?;
        if acc.dimensions() != Dimensions::Vec3 {
            warnings.push(format!(
                "NORMAL is {:?}, not Vec3; used flat normals",
                acc.dimensions()
            ));
            return None;
        }
        match self.read(&acc, "NORMAL", |v| v as f32) {
            Ok(values) if values.len() == n * 3 => {
                Some(values.chunks_exact(3).map(Vec3::from_slice).collect())
            }
            Ok(values) => {
                warnings.push(format!(
                    "NORMAL has {} values for {n} vertices; used flat normals",
                    values.len() / 3
                ));
                None
            }
            Err(Problem::Skip(reason) | Problem::Fatal(ImportError::Buffer { reason, .. })) => {
                warnings.push(format!("{reason}; used flat normals"));
                None
            }
            Err(Problem::Fatal(e)) => {
                warnings.push(format!("{e}; used flat normals"));
                None
            }
        }
    }

    fn read<T: Copy>(
        &self,
        acc: &gltf::Accessor<'_>,
        what: &str,
        conv: impl Fn(f64) -> T,
    ) -> Result<Vec<T>, Problem> {
        accessor::read(acc, self.buffers, conv).map_err(|e| match e {
            ReadError::Buffer { buffer, reason } => Problem::Fatal(ImportError::Buffer {
                path: self.path.to_path_buf(),
                buffer,
                reason,
            }),
            ReadError::Invalid(reason) => Problem::Skip(format!("{what}: {reason}")),
        })
    }

    /// `COLOR_0` as linear rgb per vertex, or `None` (with a warning if it is present but unusable).
    fn colors(
        &self,
        primitive: &gltf::Primitive<'_>,
        n: usize,
        warnings: &mut Vec<String>,
    ) -> Option<Vec<Vec3>> {
        let acc = primitive.get(&Semantic::Colors(0))?;
        let dims = match acc.dimensions() {
            Dimensions::Vec3 => 3,
            Dimensions::Vec4 => 4,
            other => {
                warnings.push(format!("COLOR_0 is {other:?}; ignored"));
                return None;
            }
        };
        match self.read(&acc, "COLOR_0", |v| v as f32) {
            Ok(values) if values.len() == n * dims => Some(
                values
                    .chunks_exact(dims)
                    .map(|c| unit_clamp(Vec3::new(c[0], c[1], c[2])))
                    .collect(),
            ),
            Ok(values) => {
                warnings.push(format!(
                    "COLOR_0 has {} values for {n} vertices; ignored",
                    values.len() / dims
                ));
                None
            }
            Err(Problem::Skip(reason) | Problem::Fatal(ImportError::Buffer { reason, .. })) => {
                warnings.push(format!("{reason}; COLOR_0 ignored"));
                None
            }
            Err(Problem::Fatal(e)) => {
                warnings.push(format!("{e}; COLOR_0 ignored"));
                None
            }
        }
    }

    /// What a texture slot needs per primitive: the loaded image and its texture coordinates.
    fn texture_input(
        &mut self,
        primitive: &gltf::Primitive<'_>,
        slot: Option<TexRef>,
        n: usize,
        what: &str,
        warnings: &mut Vec<String>,
    ) -> TextureInput {
        let Some(slot) = slot else {
            return TextureInput::None;
        };
        self.ensure_image(slot.image);
        if self.materials.image(slot.image).is_none() {
            // Already in `missing_textures`: the factor alone is used.
            return TextureInput::None;
        }
        let set = slot.tex_coord;
        let uv = primitive.get(&Semantic::TexCoords(set)).and_then(|acc| {
            if acc.dimensions() != Dimensions::Vec2 {
                return None;
            }
            self.read(&acc, "TEXCOORD", |v| v as f32)
                .ok()
                .filter(|v| v.len() == 2 * n)
        });
        match uv {
            Some(uv) => TextureInput::Mapped {
                slot,
                uv: uv.chunks_exact(2).map(Vec2::from_slice).collect(),
            },
            None => {
                warnings.push(format!(
                    "the {what} texture needs TEXCOORD_{set}, which is missing or unreadable; \
                     used the texture's mean colour"
                ));
                TextureInput::Mean(slot.image)
            }
        }
    }

    /// Mean texture colour over a triangle (corner vertex indices), or white if there is none.
    fn texture_average(&self, input: &TextureInput, corners: [usize; 3]) -> Vec3 {
        match input {
            TextureInput::None => Vec3::ONE,
            TextureInput::Mean(image) => {
                self.materials.image(*image).map_or(Vec3::ONE, |i| i.mean())
            }
            TextureInput::Mapped { slot, uv } => match self.materials.image(slot.image) {
                Some(image) => slot.lookup.footprint_average(image, corners.map(|i| uv[i])),
                None => Vec3::ONE,
            },
        }
    }
}

enum TextureInput {
    None,
    /// No usable texture coordinates: the whole image's mean stands in.
    Mean(usize),
    Mapped {
        slot: TexRef,
        uv: Vec<Vec2>,
    },
}

/// Triangles as corner indices, and how many trailing indices formed no triangle.
fn assemble(mode: Mode, indices: &[u32]) -> (Vec<[u32; 3]>, usize) {
    let n = indices.len();
    match mode {
        Mode::TriangleStrip if n >= 3 => (
            // Odd triangles swap their last two corners to keep one winding (glTF spec 3.7.2.1).
            (0..n - 2)
                .map(|i| {
                    let (a, b, c) = (indices[i], indices[i + 1], indices[i + 2]);
                    if i % 2 == 0 { [a, b, c] } else { [a, c, b] }
                })
                .collect(),
            0,
        ),
        Mode::TriangleFan if n >= 3 => (
            (1..n - 1)
                .map(|i| [indices[i], indices[i + 1], indices[0]])
                .collect(),
            0,
        ),
        Mode::TriangleStrip | Mode::TriangleFan => (Vec::new(), n),
        _ => (
            indices
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]])
                .collect(),
            n % 3,
        ),
    }
}

/// Clamps each channel to `[0, 1]`, NaN to 0.
fn unit_clamp(v: Vec3) -> Vec3 {
    Vec3::from_array(
        v.to_array()
            .map(|c| if c.is_nan() { 0.0 } else { c.clamp(0.0, 1.0) }),
    )
}

fn mesh_label(mesh: &gltf::Mesh<'_>) -> String {
    match mesh.name() {
        Some(name) => format!("mesh '{name}' (#{})", mesh.index()),
        None => format!("mesh #{}", mesh.index()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_alternate_winding_and_fans_pivot_on_the_first_index() {
        let (strip, left) = assemble(Mode::TriangleStrip, &[0, 1, 2, 3]);
        assert_eq!((strip, left), (vec![[0, 1, 2], [1, 3, 2]], 0));
        let (fan, _) = assemble(Mode::TriangleFan, &[0, 1, 2, 3]);
        assert_eq!(fan, vec![[1, 2, 0], [2, 3, 0]]);
        let (list, left) = assemble(Mode::Triangles, &[0, 1, 2, 3]);
        assert_eq!((list, left), (vec![[0, 1, 2]], 1));
    }
}
