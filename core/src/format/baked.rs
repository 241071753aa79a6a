//! bounce's own sections: the bake metadata, the patch layout and the encoded matrices, and the
//! [`Baked`] value they make together.
//!
//! Section contents, offsets relative to the section's start:
//!
//! `META`: the [`BakeMeta`] as compact JSON.
//!
//! `LAYT`: grid origin f32×3, voxel size f32, dims u32×3, patch count u32 (32 bytes), then per
//! patch a 68-byte record: voxel u32×3, face code u8 and 3 zero bytes, albedo f32×3, centroid
//! f32×3, normal f32×3, source area f32, emission f32×3. Every field is 4-byte aligned, so the
//! records can be viewed in place as a `#[repr(C)]` struct.
//!
//! `MTRX` / `FFAC`: codec name (32 bytes, ASCII, zero-padded), rows u32, cols u32, channels u32,
//! params length u32, payload length u64 (56 bytes), the codec params as JSON, zeros up to the next
//! multiple of 64, then the payload, which therefore starts 64-byte aligned in the file.
//!
//! `OCCU` (flagged [`SECTION_OPTIONAL`]): the occupied voxels, which shadow rays are traced
//! against. Count u64, index width u32 (4 or 8), reserved u32 (0) (16 bytes), then `count` linear
//! voxel indices `x + dims.x · (y + dims.y · z)`, strictly ascending, each inside the `LAYT` grid,
//! as u32 when the grid has at most 2^32 cells and as u64 otherwise (the width is fixed by the
//! grid, so a file has one encoding). Every patch's voxel is among them. Files without the
//! section are valid; their readers get no occupancy and trace shadows against the patches alone.
//!
//! `SURF` (version 2, surface geometry only, required there): what direct light needs at run
//! time. Triangle count u32, samples per row u32, row count u32, flags u32 (16 bytes),
//! then per triangle its three corners f32×9 (36 bytes; every triangle blocks shadow rays from
//! both sides), then `rows × samples per row` sample points, position f32×3 and unit normal
//! f32×3 (24 bytes), row by row; with flag bit 0 (version 11), then each sample's albedo f32×3
//! (12 bytes), in the same order; with flag bit 1 (version 13), a u32 between the header and
//! the triangles: how many of each row's samples, its first, are spread over it by area (1 to
//! samples per row; the row's direct light is their mean), the rest lying where near-field rays
//! land (`crate::surface::SurfaceScene::landing_samples`); without it, all are spread by area.
//! Positions are already pushed off their surface
//! ([`crate::trimesh::offset_origin`]). Every value is finite, an albedo within `[0, 1]`; the
//! rows are the transport's (the elements, or the patches in a file without `ELEM`). Before
//! version 11 the flags word was reserved (0).
//!
//! `ELEM` (version 3, surface geometry only, optional there): the transport elements
//! ([`crate::element`]) when they are not the patches themselves. Element count u32, reserved
//! u32 (0) (8 bytes), then per element its patch index u32 followed by a 68-byte record laid out
//! as a `LAYT` patch record (72 bytes). Patch `p` owns a contiguous, non-empty run of elements on
//! its own voxel and face. With the section, the transport, the form factors and the `SURF`
//! sample points are per element; without it, per patch.
//!
//! `NEAR` (version 4, surface geometry only, optional there): the near-field first bounce's
//! matrix over the transport's rows and the `SURF` sample points; `super::near` has its layout.
//!
//! `SKYV` (version 5, flagged [`SECTION_OPTIONAL`]): each transport row's view of the sky, 9
//! spherical-harmonic coefficients a row; `super::sky` has its layout. Files without it (every
//! older one) read, with no sky view: a sky lights nothing in them.
//!
//! `EMIT` (version 6, flagged [`SECTION_OPTIONAL`], surface geometry): the scene's emissive
//! materials and each transport row's weights of them ([`crate::emitter`]); `super::emit` has its
//! layout. Files without it keep their baked emission, which no light set can change.
//!
//! `PROB` (version 7, flagged [`SECTION_OPTIONAL`], surface geometry baked with probes): the
//! irradiance probes and their gather matrix over the transport's rows ([`crate::probe`]);
//! `super::probe` has its layout. Files without it have no probes.
//!
//! `PSKY` (version 8, flagged [`SECTION_OPTIONAL`], only beside `PROB`): each probe direction's
//! view of the sky (row `6 · probe + direction`), laid out as `SKYV` over those rows. Probes
//! without it see no sky directly.
//!
//! `MODL` (flagged [`SECTION_OPTIONAL`]): the scene the file was baked from, packed into one
//! self-contained GLB 2.0 file ([`crate::import::pack_glb`]): every buffer and image inside its
//! BIN chunk, the glTF JSON otherwise as the source had it. The section is exactly the GLB's
//! bytes (its header's length is the section's length). Viewers that draw the original meshes
//! (the browser page) take it from here; files without it are valid.

use std::borrow::Cow;
use std::path::Path;

use crate::element::Elements;
use crate::matrix::EncodedMatrix;
use crate::meta::BakeMeta;
use crate::nearfield::NearField;
use crate::patch::{Face, Patch, PatchLayout};
use crate::surface::{MAX_SURFACE_SAMPLES, SamplePoint, SurfaceData};
use crate::voxel::Geometry;

use super::FormatError;
use super::container::{
    self, Assembled, Container, FieldReader, FileBytes, FileSummary, SECTION_ALIGN,
    SECTION_OPTIONAL, Section, SectionKind,
};
use super::emit::{decode_emitters, encode_emitters};
use super::near::{decode_near, encode_near};
use super::probe::{decode_probes, encode_probes};
use super::sky::{decode_sky, encode_sky};
use crate::emitter::Emitters;
use crate::probe::Probes;
use crate::sky::SkyVisibility;

/// Bytes of the `LAYT` fields before the patch records.
pub const LAYOUT_HEADER_LEN: u64 = 32;
/// Bytes of one patch record in `LAYT`.
pub const PATCH_RECORD_LEN: u64 = 68;
/// Bytes of the fixed `MTRX`/`FFAC` fields before the codec params.
pub const MATRIX_HEADER_LEN: u64 = 56;
const CODEC_NAME_LEN: usize = 32;
/// Bytes of the `OCCU` fields before the indices.
pub const OCCUPANCY_HEADER_LEN: u64 = 16;
/// Bytes of the `SURF` fields before the triangles.
pub const SURFACE_HEADER_LEN: u64 = 16;
const TRIANGLE_RECORD_LEN: u64 = 36;
const SAMPLE_RECORD_LEN: u64 = 24;
/// Bytes of the `ELEM` fields before the element records.
pub const ELEMENTS_HEADER_LEN: u64 = 8;
/// Bytes of one element record in `ELEM`: the patch index, then a `LAYT` record.
pub const ELEMENT_RECORD_LEN: u64 = 4 + PATCH_RECORD_LEN;

/// Everything a baked file holds.
#[derive(Debug, Clone, PartialEq)]
pub struct Baked {
    pub meta: BakeMeta,
    pub layout: PatchLayout,
    /// The transport `T`, `rows × rows` ([`Baked::transport_layout`]).
    pub transport: EncodedMatrix,
    /// The single-bounce form factors `F`, kept when the bake was asked to.
    pub form_factors: Option<EncodedMatrix>,
    /// Linear indices of the occupied voxels of the layout's grid, ascending (see
    /// [`crate::voxel::Voxelization::occupied`]): what shadow rays are traced against. Absent in
    /// files from bakes that did not store it.
    pub occupancy: Option<Vec<u64>>,
    /// Surface geometry: the triangles shadow rays are traced against and each patch's
    /// direct-light sample points (the `SURF` section). `None` for voxel faces.
    pub surface: Option<SurfaceData>,
    /// The transport elements (the `ELEM` section), when they are not the patches themselves:
    /// the transport, form factors and sample points are then per element, and what a patch
    /// streams is its elements' irradiance restricted to it ([`Elements::restrict`]).
    pub elements: Option<Elements>,
    /// The near-field first bounce (the `NEAR` section; surface geometry baked with a radius).
    pub near_field: Option<NearField>,
    /// Each transport row's view of the sky (the `SKYV` section), from the form-factor rays
    /// that escaped; absent in files from before it, where a sky adds nothing.
    pub sky: Option<SkyVisibility>,
    /// The emissive materials and the rows they cover (the `EMIT` section; surface geometry),
    /// so a light set can change them; absent in older files and voxel-face bakes.
    pub emitters: Option<Emitters>,
    /// Irradiance probes for moving objects and their gather matrix (the `PROB` section; surface
    /// geometry baked with probes).
    pub probes: Option<Probes>,
    /// The scene baked, as one self-contained GLB (the `MODL` section): what a viewer draws.
    /// Absent in files baked without it (`bounce bake --no-model`, or an older bounce).
    pub model: Option<Vec<u8>>,
}

impl Baked {
    /// What the transport's rows and columns are: the elements, or the patches.
    pub fn transport_layout(&self) -> &PatchLayout {
        self.elements.as_ref().map_or(&self.layout, |e| &e.layout)
    }

    /// The file's bytes. Fails, without writing anything, on a value the reader would refuse
    /// (non-finite numbers, patches outside the grid, a matrix that does not fit the layout), so
    /// every file written can be read back.
    pub fn to_bytes(&self) -> Result<Vec<u8>, FormatError> {
        self.assemble()?.to_vec()
    }

    /// The file laid out, every value validated and every checksum computed, with the matrix
    /// payloads borrowed rather than copied.
    fn assemble(&self) -> Result<Assembled<'_>, FormatError> {
        let rows = self.transport_layout();
        let n = rows.len();
        let owned = |kind, bytes| Section {
            kind,
            flags: 0,
            pieces: vec![Cow::Owned(bytes)],
        };
        let mut sections = vec![
            owned(SectionKind::META, encode_meta(&self.meta)?),
            owned(SectionKind::LAYT, encode_layout(&self.layout)?),
            encode_matrix(SectionKind::MTRX, &self.transport, n)?,
        ];
        if let Some(m) = &self.form_factors {
            sections.push(encode_matrix(SectionKind::FFAC, m, n)?);
        }
        if let Some(occ) = &self.occupancy {
            sections.push(Section {
                kind: SectionKind::OCCU,
                flags: SECTION_OPTIONAL,
                pieces: vec![Cow::Owned(encode_occupancy(occ, &self.layout)?)],
            });
        }
        check_geometry(&self.meta, self.surface.is_some(), self.elements.is_some())?;
        if let Some(elements) = &self.elements {
            sections.push(owned(
                SectionKind::ELEM,
                encode_elements(elements, &self.layout)?,
            ));
        }
        if let Some(surface) = &self.surface {
            sections.push(owned(SectionKind::SURF, encode_surface(surface, rows)?));
        }
        if let Some(near) = &self.near_field {
            let Some(surface) = &self.surface else {
                return Err(FormatError::NearField(
                    "a near field needs the surface's sample points".to_string(),
                ));
            };
            sections.push(owned(
                SectionKind::NEAR,
                encode_near(SectionKind::NEAR, near, n, n, surface.per_patch)?,
            ));
        }
        if let Some(sky) = &self.sky {
            sections.push(Section {
                kind: SectionKind::SKYV,
                flags: SECTION_OPTIONAL,
                pieces: vec![Cow::Owned(encode_sky(SectionKind::SKYV, sky, n)?)],
            });
        }
        if let Some(emitters) = &self.emitters {
            sections.push(Section {
                kind: SectionKind::EMIT,
                flags: SECTION_OPTIONAL,
                pieces: vec![Cow::Owned(encode_emitters(SectionKind::EMIT, emitters, n)?)],
            });
        }
        if let Some(probes) = &self.probes {
            sections.push(Section {
                kind: SectionKind::PROB,
                flags: SECTION_OPTIONAL,
                pieces: vec![Cow::Owned(encode_probes(probes, n)?)],
            });
            if let Some(sky) = &probes.sky {
                sections.push(Section {
                    kind: SectionKind::PSKY,
                    flags: SECTION_OPTIONAL,
                    pieces: vec![Cow::Owned(encode_sky(
                        SectionKind::PSKY,
                        sky,
                        probes.len() * crate::probe::DIRECTIONS,
                    )?)],
                });
            }
        }
        if let Some(model) = &self.model {
            sections.push(model_section(model)?);
        }
        Assembled::new(sections)
    }

    /// Parses and validates a whole file. Matrix payloads are located and copied, not decoded.
    pub fn from_bytes(bytes: &[u8]) -> Result<Baked, FormatError> {
        let c = Container::parse(bytes)?;
        c.verify_checksums()?;
        for e in &c.entries {
            let known = [
                SectionKind::META,
                SectionKind::LAYT,
                SectionKind::MTRX,
                SectionKind::FFAC,
                SectionKind::OCCU,
                SectionKind::MODL,
                SectionKind::SURF,
                SectionKind::ELEM,
                SectionKind::NEAR,
                SectionKind::SKYV,
                SectionKind::EMIT,
                SectionKind::PROB,
                SectionKind::PSKY,
            ]
            .contains(&e.kind);
            if !known && !e.is_optional() {
                return Err(FormatError::UnknownSection { kind: e.kind });
            }
            if known && e.flags & !SECTION_OPTIONAL != 0 {
                return Err(FormatError::UnknownFlags {
                    kind: e.kind,
                    flags: e.flags,
                });
            }
        }
        let required = |kind| {
            c.entry(kind)
                .ok_or(FormatError::MissingSection { kind })
                .and_then(|e| c.section(e))
        };
        let meta = decode_meta(required(SectionKind::META)?)?;
        let layout = decode_layout(required(SectionKind::LAYT)?)?;
        let elements = match c.entry(SectionKind::ELEM) {
            Some(_) if c.header.format_version < 3 => {
                return Err(FormatError::Elements(format!(
                    "a version-{} file cannot hold transport elements",
                    c.header.format_version
                )));
            }
            Some(e) => Some(decode_elements(c.section(e)?, &layout)?),
            None => None,
        };
        let rows = elements.as_ref().map_or(&layout, |e| &e.layout);
        let n = rows.len();
        let transport = decode_matrix(SectionKind::MTRX, required(SectionKind::MTRX)?, n)?;
        let form_factors = match c.entry(SectionKind::FFAC) {
            Some(e) => Some(decode_matrix(SectionKind::FFAC, c.section(e)?, n)?),
            None => None,
        };
        let occupancy = match c.entry(SectionKind::OCCU) {
            Some(e) => Some(decode_occupancy(c.section(e)?, &layout)?),
            None => None,
        };
        let surface = match c.entry(SectionKind::SURF) {
            Some(_) if c.header.format_version < 2 => {
                return Err(FormatError::Surface(
                    "a version-1 file cannot hold surface geometry".to_string(),
                ));
            }
            Some(e) => Some(decode_surface(
                c.section(e)?,
                rows,
                c.header.format_version,
            )?),
            None => None,
        };
        check_geometry(&meta, surface.is_some(), elements.is_some())?;
        let near_field = match (c.entry(SectionKind::NEAR), &surface) {
            (None, _) => None,
            (Some(_), _) if c.header.format_version < 4 => {
                return Err(FormatError::NearField(format!(
                    "a version-{} file cannot hold a near field",
                    c.header.format_version
                )));
            }
            (Some(_), None) => {
                return Err(FormatError::NearField(
                    "a near field needs the surface's sample points (SURF)".to_string(),
                ));
            }
            (Some(e), Some(s)) => Some(decode_near(
                SectionKind::NEAR,
                c.section(e)?,
                n,
                n,
                s.per_patch,
                c.header.format_version >= 12,
            )?),
        };
        let sky = match c.entry(SectionKind::SKYV) {
            None => None,
            Some(_) if c.header.format_version < 5 => {
                return Err(FormatError::Sky(format!(
                    "a version-{} file cannot hold a sky view",
                    c.header.format_version
                )));
            }
            Some(e) => Some(decode_sky(SectionKind::SKYV, c.section(e)?, n)?),
        };
        let emitters = match c.entry(SectionKind::EMIT) {
            None => None,
            Some(_) if c.header.format_version < 6 => {
                return Err(FormatError::Emitters(format!(
                    "a version-{} file cannot hold emitters",
                    c.header.format_version
                )));
            }
            Some(e) => Some(decode_emitters(
                SectionKind::EMIT,
                c.section(e)?,
                n,
                c.header.format_version >= 10,
            )?),
        };
        let probes = match c.entry(SectionKind::PROB) {
            None => None,
            Some(_) if c.header.format_version < 7 => {
                return Err(FormatError::Probes(format!(
                    "a version-{} file cannot hold probes",
                    c.header.format_version
                )));
            }
            Some(e) => Some(decode_probes(c.section(e)?, n)?),
        };
        let probes = match (probes, c.entry(SectionKind::PSKY)) {
            (probes, None) => probes,
            (_, Some(_)) if c.header.format_version < 8 => {
                return Err(FormatError::Probes(format!(
                    "a version-{} file cannot hold the probes' sky view",
                    c.header.format_version
                )));
            }
            (None, Some(_)) => {
                return Err(FormatError::Probes(
                    "a probes' sky view (PSKY) without probes (PROB)".to_string(),
                ));
            }
            (Some(mut p), Some(e)) => {
                let rows = p.len() * crate::probe::DIRECTIONS;
                p.sky = Some(decode_sky(SectionKind::PSKY, c.section(e)?, rows)?);
                Some(p)
            }
        };
        let model = match c.entry(SectionKind::MODL) {
            Some(e) => {
                let bytes = c.section(e)?;
                validate_model(bytes)?;
                Some(bytes.to_vec())
            }
            None => None,
        };
        Ok(Baked {
            meta,
            layout,
            transport,
            form_factors,
            occupancy,
            surface,
            elements,
            near_field,
            sky,
            emitters,
            probes,
            model,
        })
    }

    /// Writes the file atomically: a temporary file in the same directory, synced, then renamed
    /// over `path`. On any failure an existing file at `path` is left as it was.
    /// The file is streamed: however large the matrices, no copy of one (or of the file) is made.
    pub fn write_atomic(&self, path: &Path) -> Result<(), FormatError> {
        // Everything that can refuse the value runs before the temporary file exists.
        let file = self.assemble()?;
        container::write_atomic(path, &file)
    }

    /// Memory-maps `path` and parses it.
    pub fn read(path: &Path) -> Result<Baked, FormatError> {
        let bytes = FileBytes::open(path)?;
        Baked::from_bytes(&bytes)
    }
}

/// The header and section table of `path`, with each section's checksum verdict, without decoding
/// the sections: enough for `bounce inspect` to describe even a damaged file.
pub fn read_summary(path: &Path) -> Result<FileSummary, FormatError> {
    let bytes = FileBytes::open(path)?;
    Container::parse(&bytes)?.summary()
}

impl FileSummary {
    /// As [`read_summary`], from bytes already in memory.
    pub fn from_bytes(bytes: &[u8]) -> Result<FileSummary, FormatError> {
        Container::parse(bytes)?.summary()
    }
}

fn encode_meta(meta: &BakeMeta) -> Result<Vec<u8>, FormatError> {
    let json_err = |error| FormatError::Json {
        kind: SectionKind::META,
        error,
    };
    let json = serde_json::to_vec(meta).map_err(json_err)?;
    // serde_json writes a non-finite float as `null`, which the reader then refuses; find that
    // now rather than in a file nobody can open.
    decode_meta(&json)?;
    Ok(json)
}

fn decode_meta(bytes: &[u8]) -> Result<BakeMeta, FormatError> {
    serde_json::from_slice(bytes).map_err(|error| FormatError::Json {
        kind: SectionKind::META,
        error,
    })
}

/// The checks shared by writer and reader, so the writer never produces a file the reader refuses.
fn validate_layout(layout: &PatchLayout) -> Result<(), FormatError> {
    let finite = |v: &[f32], what: &dyn Fn() -> String| {
        if v.iter().all(|x| x.is_finite()) {
            Ok(())
        } else {
            Err(FormatError::NotFinite { what: what() })
        }
    };
    finite(&layout.origin, &|| "grid origin".to_string())?;
    if !(layout.voxel_size.is_finite() && layout.voxel_size > 0.0) {
        return Err(FormatError::BadVoxelSize(layout.voxel_size));
    }
    for (i, p) in layout.patches.iter().enumerate() {
        if p.voxel.iter().zip(&layout.dims).any(|(v, d)| v >= d) {
            return Err(FormatError::VoxelOutsideGrid {
                patch: i,
                voxel: p.voxel,
                dims: layout.dims,
            });
        }
        finite(&p.albedo, &|| format!("patch {i} albedo"))?;
        finite(&p.centroid, &|| format!("patch {i} centroid"))?;
        finite(&p.normal, &|| format!("patch {i} normal"))?;
        finite(&[p.source_area], &|| format!("patch {i} source area"))?;
        finite(&p.emission, &|| format!("patch {i} emission"))?;
    }
    Ok(())
}

pub(super) fn encode_layout(layout: &PatchLayout) -> Result<Vec<u8>, FormatError> {
    validate_layout(layout)?;
    let count = u32::try_from(layout.len()).map_err(|_| FormatError::TooLarge {
        what: "patch count",
        value: layout.len() as u64,
        max: u64::from(u32::MAX),
    })?;
    let mut out =
        Vec::with_capacity(LAYOUT_HEADER_LEN as usize + layout.len() * PATCH_RECORD_LEN as usize);
    let f32s = |out: &mut Vec<u8>, v: &[f32]| {
        for x in v {
            out.extend_from_slice(&x.to_le_bytes());
        }
    };
    let u32s = |out: &mut Vec<u8>, v: &[u32]| {
        for x in v {
            out.extend_from_slice(&x.to_le_bytes());
        }
    };
    f32s(&mut out, &layout.origin);
    f32s(&mut out, &[layout.voxel_size]);
    u32s(&mut out, &layout.dims);
    u32s(&mut out, &[count]);
    for p in &layout.patches {
        encode_record(&mut out, p);
    }
    debug_assert_eq!(
        out.len() as u64,
        LAYOUT_HEADER_LEN + u64::from(count) * PATCH_RECORD_LEN
    );
    Ok(out)
}

pub(super) fn decode_layout(bytes: &[u8]) -> Result<PatchLayout, FormatError> {
    let mut r = FieldReader::new(bytes, Some(SectionKind::LAYT));
    let origin = r.f32x3("grid origin")?;
    let voxel_size = r.f32("voxel size")?;
    let dims = r.u32x3("grid dims")?;
    let count = r.u32("patch count")?;
    let records = r.remaining();
    // Only a count the section's length accounts for may size an allocation.
    let have = records.len() as u64;
    if u64::from(count).checked_mul(PATCH_RECORD_LEN) != Some(have) {
        return Err(FormatError::PatchCount {
            count,
            record: PATCH_RECORD_LEN,
            have,
        });
    }
    let mut patches = Vec::with_capacity(count as usize);
    for (i, record) in records.chunks_exact(PATCH_RECORD_LEN as usize).enumerate() {
        let mut r = FieldReader::new(record, Some(SectionKind::LAYT));
        patches.push(decode_record(&mut r, i)?);
    }
    let layout = PatchLayout {
        origin,
        voxel_size,
        dims,
        patches,
    };
    validate_layout(&layout)?;
    Ok(layout)
}

/// One patch record (`LAYT`, and after its patch index in `ELEM`).
fn encode_record(out: &mut Vec<u8>, p: &Patch) {
    for v in p.voxel {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&[p.face.code(), 0, 0, 0]);
    let f = p
        .albedo
        .iter()
        .chain(&p.centroid)
        .chain(&p.normal)
        .chain(std::slice::from_ref(&p.source_area))
        .chain(&p.emission);
    for x in f {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

fn decode_record(r: &mut FieldReader<'_>, i: usize) -> Result<Patch, FormatError> {
    let voxel = r.u32x3("patch voxel")?;
    let [code, pad @ ..] = r.array::<4>("patch face")?;
    let face = Face::from_code(code).ok_or(FormatError::BadFace { patch: i, code })?;
    if pad != [0; 3] {
        return Err(FormatError::NonZeroPadding {
            what: format!("patch {i}"),
        });
    }
    Ok(Patch {
        voxel,
        face,
        albedo: r.f32x3("patch albedo")?,
        centroid: r.f32x3("patch centroid")?,
        normal: r.f32x3("patch normal")?,
        source_area: r.f32("patch source area")?,
        emission: r.f32x3("patch emission")?,
    })
}

/// The checks shared by writer and reader: finite records on the patches' grid, each patch
/// owning a contiguous run ([`Elements::check`]).
fn validate_elements(e: &Elements, layout: &PatchLayout) -> Result<(), FormatError> {
    validate_layout(&e.layout).map_err(|err| FormatError::Elements(err.to_string()))?;
    e.check(layout).map_err(FormatError::Elements)
}

pub(super) fn encode_elements(e: &Elements, layout: &PatchLayout) -> Result<Vec<u8>, FormatError> {
    validate_elements(e, layout)?;
    let count = u32::try_from(e.len()).map_err(|_| FormatError::TooLarge {
        what: "element count",
        value: e.len() as u64,
        max: u64::from(u32::MAX),
    })?;
    let mut out =
        Vec::with_capacity(ELEMENTS_HEADER_LEN as usize + e.len() * ELEMENT_RECORD_LEN as usize);
    out.extend_from_slice(&count.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    for (&p, rec) in e.patch.iter().zip(&e.layout.patches) {
        out.extend_from_slice(&p.to_le_bytes());
        encode_record(&mut out, rec);
    }
    Ok(out)
}

pub(super) fn decode_elements(bytes: &[u8], layout: &PatchLayout) -> Result<Elements, FormatError> {
    let kind = SectionKind::ELEM;
    let mut r = FieldReader::new(bytes, Some(kind));
    let count = r.u32("element count")?;
    if r.u32("reserved")? != 0 {
        return Err(FormatError::Reserved {
            what: format!("section '{kind}'"),
        });
    }
    let records = r.remaining();
    // Only a count the section's length accounts for may size an allocation.
    if u64::from(count) * ELEMENT_RECORD_LEN != records.len() as u64 {
        return Err(FormatError::Elements(format!(
            "{count} elements need {} bytes, the section holds {}",
            u64::from(count) * ELEMENT_RECORD_LEN,
            records.len()
        )));
    }
    let mut patch = Vec::with_capacity(count as usize);
    let mut patches = Vec::with_capacity(count as usize);
    for (i, record) in records
        .chunks_exact(ELEMENT_RECORD_LEN as usize)
        .enumerate()
    {
        let mut r = FieldReader::new(record, Some(kind));
        patch.push(r.u32("element patch")?);
        patches.push(decode_record(&mut r, i)?);
    }
    let e = Elements {
        layout: PatchLayout {
            origin: layout.origin,
            voxel_size: layout.voxel_size,
            dims: layout.dims,
            patches,
        },
        patch,
    };
    validate_elements(&e, layout)?;
    Ok(e)
}

/// Cells of the layout's grid; cannot overflow (three u32 factors fit in 96 bits, and u128 holds
/// them).
fn grid_cells(layout: &PatchLayout) -> u128 {
    layout.dims.iter().map(|&d| u128::from(d)).product()
}

/// Bytes per index in `OCCU` for this grid.
fn occupancy_width(layout: &PatchLayout) -> u32 {
    if grid_cells(layout) <= 1u128 << 32 {
        4
    } else {
        8
    }
}

/// The checks shared by writer and reader: ascending, inside the grid, and covering every
/// patch's voxel.
fn validate_occupancy(occ: &[u64], layout: &PatchLayout) -> Result<(), FormatError> {
    let cells = grid_cells(layout);
    let mut last: Option<u64> = None;
    for (i, &k) in occ.iter().enumerate() {
        if u128::from(k) >= cells {
            return Err(FormatError::Occupancy(format!(
                "voxel index {k} (entry {i}) is outside the {:?} grid",
                layout.dims
            )));
        }
        if let Some(l) = last
            && l >= k
        {
            return Err(FormatError::Occupancy(format!(
                "voxel indices are not strictly ascending at entry {i} ({k} after {l})"
            )));
        }
        last = Some(k);
    }
    let dims = layout.dims.map(u64::from);
    for (i, p) in layout.patches.iter().enumerate() {
        // Inside the grid (checked with the layout), so the index fits in u64.
        let [x, y, z] = p.voxel.map(u64::from);
        let k = x + dims[0] * (y + dims[1] * z);
        if occ.binary_search(&k).is_err() {
            return Err(FormatError::Occupancy(format!(
                "patch {i}'s voxel {:?} is not occupied",
                p.voxel
            )));
        }
    }
    Ok(())
}

pub(super) fn encode_occupancy(occ: &[u64], layout: &PatchLayout) -> Result<Vec<u8>, FormatError> {
    validate_occupancy(occ, layout)?;
    let width = occupancy_width(layout);
    let mut out = Vec::with_capacity(OCCUPANCY_HEADER_LEN as usize + occ.len() * width as usize);
    out.extend_from_slice(&(occ.len() as u64).to_le_bytes());
    out.extend_from_slice(&width.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    for &k in occ {
        if width == 4 {
            // Below the grid's cell count, checked above, hence below 2^32.
            out.extend_from_slice(&(k as u32).to_le_bytes());
        } else {
            out.extend_from_slice(&k.to_le_bytes());
        }
    }
    Ok(out)
}

pub(super) fn decode_occupancy(
    bytes: &[u8],
    layout: &PatchLayout,
) -> Result<Vec<u64>, FormatError> {
    let kind = SectionKind::OCCU;
    let mut r = FieldReader::new(bytes, Some(kind));
    let count = r.u64("occupied voxel count")?;
    let width = r.u32("voxel index width")?;
    if r.u32("reserved")? != 0 {
        return Err(FormatError::Reserved {
            what: format!("section '{kind}'"),
        });
    }
    let want = occupancy_width(layout);
    if width != want {
        return Err(FormatError::Occupancy(format!(
            "voxel indices are {width} bytes wide, but a {:?} grid has {want}-byte indices",
            layout.dims
        )));
    }
    let indices = r.remaining();
    // Only a count the section's length accounts for may size an allocation.
    let have = indices.len() as u64;
    if count.checked_mul(u64::from(width)) != Some(have) {
        return Err(FormatError::Occupancy(format!(
            "claims {count} voxels of {width} bytes but holds {have} bytes of indices"
        )));
    }
    let occ: Vec<u64> = indices
        .chunks_exact(width as usize)
        .map(|c| {
            let mut b = [0u8; 8];
            b[..c.len()].copy_from_slice(c);
            u64::from_le_bytes(b)
        })
        .collect();
    validate_occupancy(&occ, layout)?;
    Ok(occ)
}

/// A surface bake must carry its `SURF` section (its direct light needs it) and a voxel-face
/// bake must not; only a surface bake has elements.
fn check_geometry(
    meta: &BakeMeta,
    has_surface: bool,
    has_elements: bool,
) -> Result<(), FormatError> {
    match (meta.settings.geometry, has_surface) {
        (Geometry::Surface, false) => Err(FormatError::MissingSection {
            kind: SectionKind::SURF,
        }),
        (Geometry::VoxelFaces, true) => Err(FormatError::Surface(
            "a voxel-face bake holds no surface geometry".to_string(),
        )),
        (Geometry::VoxelFaces, false) if has_elements => Err(FormatError::Elements(
            "a voxel-face bake has no transport elements".to_string(),
        )),
        _ => Ok(()),
    }
}

/// The checks shared by writer and reader.
fn validate_surface(s: &SurfaceData, layout: &PatchLayout) -> Result<(), FormatError> {
    let bad = |m: String| Err(FormatError::Surface(m));
    if !(1..=MAX_SURFACE_SAMPLES).contains(&s.per_patch) {
        return bad(format!(
            "{} samples per patch (1 to {MAX_SURFACE_SAMPLES} are valid)",
            s.per_patch
        ));
    }
    if !(1..=s.per_patch).contains(&s.area_samples) {
        return bad(format!(
            "{} of {} samples per patch spread by area (1 to {} are valid)",
            s.area_samples, s.per_patch, s.per_patch
        ));
    }
    if s.points.len() as u64 != layout.len() as u64 * u64::from(s.per_patch) {
        return bad(format!(
            "{} sample points for {} patches of {} samples",
            s.points.len(),
            layout.len(),
            s.per_patch
        ));
    }
    if let Some(i) = s
        .triangles
        .iter()
        .position(|t| !t.iter().flatten().all(|v| v.is_finite()))
    {
        return bad(format!("triangle {i} has a non-finite corner"));
    }
    if let Some(albedo) = &s.albedo
        && let Err(m) = crate::sample::check_albedo(albedo, s.points.len(), "sample")
    {
        return bad(m);
    }
    for (i, p) in s.points.iter().enumerate() {
        let n = glam::Vec3::from(p.normal);
        if !(p.position.iter().all(|v| v.is_finite()) && (n.length() - 1.0).abs() < 1e-3) {
            return bad(format!(
                "sample point {i} is not a finite point with a unit normal"
            ));
        }
    }
    Ok(())
}

pub(super) fn encode_surface(
    s: &SurfaceData,
    layout: &PatchLayout,
) -> Result<Vec<u8>, FormatError> {
    validate_surface(s, layout)?;
    let count = u32::try_from(s.triangles.len()).map_err(|_| FormatError::TooLarge {
        what: "triangle count",
        value: s.triangles.len() as u64,
        max: u64::from(u32::MAX),
    })?;
    let albedo = s.albedo.as_deref().unwrap_or(&[]);
    let mut out = Vec::with_capacity(
        SURFACE_HEADER_LEN as usize
            + s.triangles.len() * TRIANGLE_RECORD_LEN as usize
            + s.points.len() * SAMPLE_RECORD_LEN as usize
            + albedo.len() * ALBEDO_RECORD_LEN as usize,
    );
    let landing = s.area_samples < s.per_patch;
    let flags = if s.albedo.is_some() { SURF_ALBEDO } else { 0 }
        | if landing { SURF_AREA_SAMPLES } else { 0 };
    for v in [count, s.per_patch, layout.len() as u32, flags] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    if landing {
        out.extend_from_slice(&s.area_samples.to_le_bytes());
    }
    for x in s.triangles.iter().flatten().flatten() {
        out.extend_from_slice(&x.to_le_bytes());
    }
    for p in &s.points {
        for x in p.position.iter().chain(&p.normal) {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    for x in albedo.iter().flatten() {
        out.extend_from_slice(&x.to_le_bytes());
    }
    Ok(out)
}

/// `SURF`'s flag: each sample's albedo follows the sample points (version 11).
const SURF_ALBEDO: u32 = 1;
/// `SURF`'s flag: how many of a row's samples are spread by area follows the header (version
/// 13); the rest are landing samples.
const SURF_AREA_SAMPLES: u32 = 2;
/// Bytes of one sample's albedo.
const ALBEDO_RECORD_LEN: u64 = 12;

/// The `SURF` section of a file of format `version` (or a shard, which has the latest).
pub(super) fn decode_surface(
    bytes: &[u8],
    layout: &PatchLayout,
    version: u32,
) -> Result<SurfaceData, FormatError> {
    let kind = SectionKind::SURF;
    let mut r = FieldReader::new(bytes, Some(kind));
    let triangles = r.u32("triangle count")?;
    let per_patch = r.u32("samples per patch")?;
    let patches = r.u32("patch count")?;
    let flags = r.u32("flags")?;
    let known = match version {
        13.. => SURF_ALBEDO | SURF_AREA_SAMPLES,
        11 | 12 => SURF_ALBEDO,
        _ => 0,
    };
    if flags & !known != 0 {
        return Err(FormatError::Reserved {
            what: format!("section '{kind}' flags"),
        });
    }
    let with_albedo = flags & SURF_ALBEDO != 0;
    let area_samples = if flags & SURF_AREA_SAMPLES != 0 {
        r.u32("samples per patch spread by area")?
    } else {
        per_patch
    };
    if patches as usize != layout.len() {
        return Err(FormatError::Surface(format!(
            "{patches} patches, but the layout has {}",
            layout.len()
        )));
    }
    if !(1..=MAX_SURFACE_SAMPLES).contains(&per_patch) {
        return Err(FormatError::Surface(format!(
            "{per_patch} samples per patch (1 to {MAX_SURFACE_SAMPLES} are valid)"
        )));
    }
    let rest = r.remaining();
    // Only counts the section's length accounts for may size an allocation.
    let samples = u64::from(patches) * u64::from(per_patch);
    let want = u64::from(triangles) * TRIANGLE_RECORD_LEN
        + samples * SAMPLE_RECORD_LEN
        + if with_albedo {
            samples * ALBEDO_RECORD_LEN
        } else {
            0
        };
    if want != rest.len() as u64 {
        return Err(FormatError::Surface(format!(
            "{triangles} triangles and {patches} × {per_patch} samples{} need {want} bytes, the \
             section holds {}",
            if with_albedo { " with albedo" } else { "" },
            rest.len()
        )));
    }
    let floats: Vec<f32> = rest
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let (tri_floats, rest) = floats.split_at(triangles as usize * 9);
    let (sample_floats, albedo_floats) = rest.split_at(samples as usize * 6);
    let surface = SurfaceData {
        triangles: tri_floats
            .chunks_exact(9)
            .map(|c| [[c[0], c[1], c[2]], [c[3], c[4], c[5]], [c[6], c[7], c[8]]])
            .collect(),
        per_patch,
        area_samples,
        points: sample_floats
            .chunks_exact(6)
            .map(|c| SamplePoint {
                position: [c[0], c[1], c[2]],
                normal: [c[3], c[4], c[5]],
            })
            .collect(),
        albedo: with_albedo.then(|| {
            albedo_floats
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect()
        }),
    };
    validate_surface(&surface, layout)?;
    Ok(surface)
}

/// The optional `MODL` section holding `model` (a GLB), checked as the reader will check it; the
/// baked file and the shards write it alike.
pub(crate) fn model_section(model: &[u8]) -> Result<Section<'_>, FormatError> {
    validate_model(model)?;
    Ok(Section {
        kind: SectionKind::MODL,
        flags: SECTION_OPTIONAL,
        pieces: vec![Cow::Borrowed(model)],
    })
}

/// The checks shared by writer and reader: a GLB 2.0 file whose header's length is the
/// section's, with chunks that parse. (The glTF inside is the viewer's to judge.)
pub(crate) fn validate_model(bytes: &[u8]) -> Result<(), FormatError> {
    let bad = |m: String| Err(FormatError::Model(m));
    if !bytes.starts_with(b"glTF") {
        return bad(format!(
            "it does not start with the GLB magic 'glTF' ({} bytes)",
            bytes.len()
        ));
    }
    let word = |at: usize| {
        bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    match (word(4), word(8)) {
        (Some(2), Some(len)) if len as usize == bytes.len() => {}
        (Some(2), Some(len)) => {
            return bad(format!(
                "its header says {len} bytes but the section has {}",
                bytes.len()
            ));
        }
        (Some(v), Some(_)) => return bad(format!("GLB version {v}, expected 2")),
        _ => return bad("its header is truncated".to_string()),
    }
    match gltf::Glb::from_slice(bytes) {
        Ok(_) => Ok(()),
        Err(e) => bad(e.to_string()),
    }
}

fn valid_codec_name(name: &[u8]) -> bool {
    (1..=CODEC_NAME_LEN).contains(&name.len()) && name.iter().all(|b| b.is_ascii_graphic())
}

/// A transport or form-factor matrix must be `patches × patches` with 1 or 3 channels.
fn check_shape(kind: SectionKind, m: &EncodedMatrix, patches: usize) -> Result<(), FormatError> {
    let fits = |v: u32| usize::try_from(v).is_ok_and(|v| v == patches);
    if fits(m.rows) && fits(m.cols) && m.validate_shape().is_ok() {
        Ok(())
    } else {
        Err(FormatError::MatrixShape {
            kind,
            rows: m.rows,
            cols: m.cols,
            channels: m.channels,
            patches,
        })
    }
}

/// The section of a matrix: its fixed fields, params and padding built here, its payload borrowed.
fn encode_matrix<'a>(
    kind: SectionKind,
    m: &'a EncodedMatrix,
    patches: usize,
) -> Result<Section<'a>, FormatError> {
    if !valid_codec_name(m.codec.as_bytes()) {
        return Err(FormatError::BadCodecName {
            kind,
            name: m.codec.escape_default().to_string(),
        });
    }
    check_shape(kind, m, patches)?;
    let params =
        serde_json::to_vec(&m.params).map_err(|error| FormatError::Json { kind, error })?;
    let params_len = u32::try_from(params.len()).map_err(|_| FormatError::TooLarge {
        what: "matrix params",
        value: params.len() as u64,
        max: u64::from(u32::MAX),
    })?;
    let mut head = Vec::with_capacity(MATRIX_HEADER_LEN as usize + params.len() + 64);
    let mut name = [0u8; CODEC_NAME_LEN];
    name[..m.codec.len()].copy_from_slice(m.codec.as_bytes());
    head.extend_from_slice(&name);
    for v in [m.rows, m.cols, m.channels, params_len] {
        head.extend_from_slice(&v.to_le_bytes());
    }
    head.extend_from_slice(&(m.payload.len() as u64).to_le_bytes());
    head.extend_from_slice(&params);
    // Sections start aligned, so an aligned offset in the section is one in the file.
    head.extend_from_slice(container::padding_to_align(head.len() as u64));
    Ok(Section {
        kind,
        flags: 0,
        pieces: vec![Cow::Owned(head), Cow::Borrowed(&m.payload)],
    })
}

fn decode_matrix(
    kind: SectionKind,
    bytes: &[u8],
    patches: usize,
) -> Result<EncodedMatrix, FormatError> {
    let mut r = FieldReader::new(bytes, Some(kind));
    let name: [u8; CODEC_NAME_LEN] = r.array("codec name")?;
    let name_len = name.iter().position(|&b| b == 0).unwrap_or(CODEC_NAME_LEN);
    let (codec, padding) = name.split_at(name_len);
    if !valid_codec_name(codec) || padding.iter().any(|&b| b != 0) {
        return Err(FormatError::BadCodecName {
            kind,
            name: name.escape_ascii().to_string(),
        });
    }
    let rows = r.u32("rows")?;
    let cols = r.u32("cols")?;
    let channels = r.u32("channels")?;
    let params_len = r.u32("params length")?;
    let payload_len = r.u64("payload length")?;
    let params = r.take(u64::from(params_len), "matrix params")?;
    let padding = r.take(
        (r.pos() as u64).next_multiple_of(SECTION_ALIGN) - r.pos() as u64,
        "payload alignment",
    )?;
    if padding.iter().any(|&b| b != 0) {
        return Err(FormatError::NonZeroPadding {
            what: format!("section '{kind}' before the payload"),
        });
    }
    let payload = r.take(payload_len, "matrix payload")?;
    if !r.remaining().is_empty() {
        return Err(FormatError::SectionTooLong {
            kind,
            need: r.pos() as u64,
            have: bytes.len() as u64,
        });
    }
    let params =
        serde_json::from_slice(params).map_err(|error| FormatError::Json { kind, error })?;
    let mut m = EncodedMatrix {
        // Checked above to be printable ASCII, hence UTF-8.
        codec: String::from_utf8_lossy(codec).into_owned(),
        rows,
        cols,
        channels,
        params,
        payload: Vec::new(),
    };
    check_shape(kind, &m, patches)?;
    m.payload = payload.to_vec();
    Ok(m)
}
