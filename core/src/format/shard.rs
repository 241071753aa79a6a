//! The bake-shard file: one process's share of a sharded bake (see [`crate::bake::shard`]), in the same
//! container as a baked file (header, section table, CRC-32 per section, 64-byte alignment) under
//! its own magic `BOUNCE\0S` and its own version ([`super::SHARD_FORMAT_VERSION`]).
//!
//! Sections:
//!
//! - `SHRD`: the [`ShardMeta`] as JSON: phase, shard index and count, its rows, the bake's
//!   settings, the source scene, ray tallies, timings.
//! - `LAYT`, `OCCU`: the patch layout and occupied voxels, encoded as in a baked file. Every shard
//!   carries them, so later steps need no scene file and can refuse shards of another layout.
//! - `SURF` (surface geometry only): the triangles and direct-light sample points, as in a baked
//!   file, carried to the merge.
//! - `ELEM` (surface geometry, when the transport runs on elements): as in a baked file. The rows
//!   are then the elements'.
//! - `ROWS`: the shard's rows: transport rows (patches or elements) u32, first row u32, end row u32, channels u32 (16 bytes),
//!   zeros up to byte 64, then `channels × rows × patches` f32, channel-major then row-major.
//!   Form-factor rows in phase 1, transport rows in phase 2.
//! - `FROW` (phase 2, only when the bake keeps its form factors): the same rows of `F`, same
//!   encoding, one channel.
//! - `NROW` (surface geometry baked with a near-field radius): the shard's rows of the
//!   near-field matrix, laid out as a baked file's `NEAR` over the shard's rows (columns over
//!   the whole transport). Phase 1 traces them, phase 2 carries its own rows, the merge joins
//!   them.
//! - `SROW`: the shard's rows of the sky view, laid out as a baked file's `SKYV` over the
//!   shard's rows. Phase 1 traces them with its rows of `F`, phase 2 carries its own rows, the
//!   merge joins them.
//! - `PROW` (a bake with probes): every probe's position and the shard's range of the probes'
//!   gather rows with their sky view ([`crate::probe::ProbeRows`], laid out in `super::probe`).
//!   Phase 1 places every probe and gathers its range (the gather rows split as the transport's
//!   rows are), phase 2 carries its own range of the same split, the merge joins them.
//! - `SEMT` (surface geometry): the bake's emitters, laid out as a baked file's `EMIT` over all
//!   rows: every shard computes them from the same layout, and the merge takes the first's.
//! - `MODL` (flagged optional, when the bake keeps the model): the scene as one GLB, as in a
//!   baked file. Phase 1 packs it, phase 2 passes it on, the merge puts it in the baked file.
//!
//! Reading checks, beyond the container, that the metadata, layout and rows agree with each other
//! (row range of the shard index, channel count of the phase, lengths) and that every entry is
//! finite and non-negative; whether shards belong together is [`crate::bake::shard`]'s check.

use std::borrow::Cow;
use std::path::Path;

use crate::element::Elements;
use crate::emitter::Emitters;
use crate::patch::PatchLayout;

use super::FormatError;
use super::baked::{
    decode_elements, decode_layout, decode_occupancy, decode_surface, encode_elements,
    encode_layout, encode_occupancy, encode_surface, model_section, validate_model,
};
use super::container::{
    self, Assembled, Container, FieldReader, FileBytes, Flavour, SECTION_ALIGN, SECTION_OPTIONAL,
    Section, SectionKind,
};
use super::emit::{decode_emitters, encode_emitters};
use super::near::{decode_near, encode_near};
use super::probe::{PROW, decode_probe_rows, encode_probe_rows};
use super::shard_meta::{Phase, ShardMeta, shard_rows};
use super::sky::{decode_sky, encode_sky};
use crate::nearfield::NearField;
use crate::probe::ProbeRows;
use crate::sky::SkyVisibility;
use crate::surface::SurfaceData;
use crate::voxel::Geometry;

/// Bytes of the `ROWS`/`FROW` fields before the (64-byte aligned) values.
pub const ROWS_HEADER_LEN: u64 = 16;

const SHRD: SectionKind = SectionKind(*b"SHRD");
const ROWS: SectionKind = SectionKind(*b"ROWS");
const FROW: SectionKind = SectionKind(*b"FROW");
const NROW: SectionKind = SectionKind(*b"NROW");
const SROW: SectionKind = SectionKind(*b"SROW");
const SEMT: SectionKind = SectionKind(*b"SEMT");

/// What a shard says about itself, without its rows: enough to check a set of shards before
/// any row is read.
#[derive(Debug, Clone, PartialEq)]
pub struct ShardHeader {
    pub meta: ShardMeta,
    pub layout: PatchLayout,
    pub occupancy: Vec<u64>,
    /// Surface geometry's triangles and sample points, for the baked file.
    pub surface: Option<SurfaceData>,
    /// The transport elements, when they are not the patches.
    pub elements: Option<Elements>,
    /// The emissive materials and every transport row's weights of them (surface geometry).
    pub emitters: Option<Emitters>,
}

impl ShardHeader {
    /// What the rows are rows of: the elements, or the patches.
    pub fn transport_layout(&self) -> &PatchLayout {
        self.elements.as_ref().map_or(&self.layout, |e| &e.layout)
    }
}

/// A whole shard.
#[derive(Debug, Clone, PartialEq)]
pub struct ShardFile {
    pub header: ShardHeader,
    /// `channels × rows × patches`, channel-major then row-major.
    pub rows: Vec<f32>,
    /// Phase 2 of a bake that keeps its form factors: the same rows of `F`.
    pub form_factor_rows: Option<Vec<f32>>,
    /// The same rows of the near-field matrix, when the bake has one.
    pub near_rows: Option<NearField>,
    /// The same rows of the sky view.
    pub sky_rows: SkyVisibility,
    /// The shard's range of the probes' gather rows, when the bake places probes.
    pub probe_rows: Option<ProbeRows>,
    /// The scene as one self-contained GLB, for the baked file's `MODL` section.
    pub model: Option<Vec<u8>>,
}

impl ShardFile {
    /// The file laid out and checked (everything the reader checks), rows borrowed.
    fn assemble(&self) -> Result<Assembled<'_>, FormatError> {
        let h = &self.header;
        check_meta(&h.meta, h.transport_layout())?;
        check_rows_len(ROWS, &h.meta, h.meta.channels, self.rows.len())?;
        check_values(ROWS, &self.rows)?;
        let wants_frow = wants_form_factor_rows(&h.meta);
        match (&self.form_factor_rows, wants_frow) {
            (Some(f), true) => {
                check_rows_len(FROW, &h.meta, 1, f.len())?;
                check_values(FROW, f)?;
            }
            (None, false) => {}
            (Some(_), false) => return Err(bad("form-factor rows in a shard that has none")),
            (None, true) => return Err(bad("a phase-2 shard that keeps F lacks its rows of F")),
        }
        let meta =
            serde_json::to_vec(&h.meta).map_err(|error| FormatError::Json { kind: SHRD, error })?;
        // A non-finite float becomes `null`, which the reader refuses: find that now.
        decode_meta(&meta)?;
        let owned = |kind, bytes| Section {
            kind,
            flags: 0,
            pieces: vec![Cow::Owned(bytes)],
        };
        let mut sections = vec![
            owned(SHRD, meta),
            owned(SectionKind::LAYT, encode_layout(&h.layout)?),
            owned(
                SectionKind::OCCU,
                encode_occupancy(&h.occupancy, &h.layout)?,
            ),
        ];
        if h.meta.settings.geometry == Geometry::Surface && h.surface.is_none() {
            return Err(bad("a surface bake's shard lacks its surface geometry"));
        }
        if let Some(elements) = &h.elements {
            if h.meta.settings.geometry != Geometry::Surface {
                return Err(bad("a voxel-face bake's shard holds transport elements"));
            }
            sections.push(owned(
                SectionKind::ELEM,
                encode_elements(elements, &h.layout)?,
            ));
        }
        if let Some(surface) = &h.surface {
            sections.push(owned(
                SectionKind::SURF,
                encode_surface(surface, h.transport_layout())?,
            ));
        }
        if let Some(emitters) = &h.emitters {
            if h.meta.settings.geometry != Geometry::Surface {
                return Err(bad("a voxel-face bake's shard holds emitters"));
            }
            sections.push(owned(
                SEMT,
                encode_emitters(SEMT, emitters, h.meta.patches)?,
            ));
        }
        match (&self.near_rows, &h.surface, wants_near_rows(&h.meta)) {
            (Some(near), Some(surface), true) => sections.push(owned(
                NROW,
                encode_near(
                    NROW,
                    near,
                    h.meta.end_row - h.meta.first_row,
                    h.meta.patches,
                    surface.per_patch,
                )?,
            )),
            (None, _, false) => {}
            (Some(_), _, _) => return Err(bad("near-field rows in a shard that has none")),
            (None, _, true) => return Err(bad("a shard of a near-field bake lacks its rows")),
        }
        sections.push(owned(
            SROW,
            encode_sky(SROW, &self.sky_rows, h.meta.end_row - h.meta.first_row)?,
        ));
        match (&self.probe_rows, wants_probe_rows(&h.meta)) {
            (Some(p), true) => {
                check_probe_range(p, &h.meta)?;
                sections.push(owned(PROW, encode_probe_rows(p, h.meta.patches)?));
            }
            (None, false) => {}
            (Some(_), false) => return Err(bad("probe rows in a shard of a bake without probes")),
            (None, true) => return Err(bad("a shard of a bake with probes lacks its probe rows")),
        }
        // Before the rows, which stay last as they are the bulk of the file.
        if let Some(model) = &self.model {
            sections.push(model_section(model)?);
        }
        sections.push(rows_section(ROWS, &h.meta, h.meta.channels, &self.rows));
        if let Some(f) = &self.form_factor_rows {
            sections.push(rows_section(FROW, &h.meta, 1, f));
        }
        Assembled::new_as(sections, Flavour::Shard)
    }

    pub fn to_bytes(&self) -> Result<Vec<u8>, FormatError> {
        self.assemble()?.to_vec()
    }

    /// Written to a temporary file beside `path`, synced and renamed over it: a failed or killed
    /// shard job leaves no partial shard for a later step to trip on.
    pub fn write_atomic(&self, path: &Path) -> Result<(), FormatError> {
        let file = self.assemble()?;
        container::write_atomic(path, &file)
    }

    pub fn from_bytes(bytes: &[u8]) -> Result<ShardFile, FormatError> {
        let c = Container::parse_as(bytes, Flavour::Shard)?;
        c.verify_checksums()?;
        let header = header_from(&c)?;
        let m = &header.meta;
        let rows = decode_rows(ROWS, section(&c, ROWS)?, m, m.channels)?;
        let form_factor_rows = match (c.entry(FROW), wants_form_factor_rows(m)) {
            (Some(e), true) => Some(decode_rows(FROW, c.section(e)?, m, 1)?),
            (None, false) => None,
            (Some(_), false) => return Err(bad("form-factor rows in a shard that has none")),
            (None, true) => return Err(FormatError::MissingSection { kind: FROW }),
        };
        let near_rows = match (c.entry(NROW), &header.surface, wants_near_rows(m)) {
            (Some(e), Some(surface), true) => Some(decode_near(
                NROW,
                c.section(e)?,
                m.end_row - m.first_row,
                m.patches,
                surface.per_patch,
                true,
            )?),
            (None, _, false) => None,
            (Some(_), _, _) => return Err(bad("near-field rows in a shard that has none")),
            (None, _, true) => return Err(FormatError::MissingSection { kind: NROW }),
        };
        let sky_rows = decode_sky(SROW, section(&c, SROW)?, m.end_row - m.first_row)?;
        let probe_rows = match (c.entry(PROW), wants_probe_rows(m)) {
            (Some(e), true) => {
                let p = decode_probe_rows(c.section(e)?, m.patches)?;
                check_probe_range(&p, m)?;
                Some(p)
            }
            (None, false) => None,
            (Some(_), false) => return Err(bad("probe rows in a shard of a bake without probes")),
            (None, true) => return Err(FormatError::MissingSection { kind: PROW }),
        };
        let model = model_of(&c)?;
        Ok(ShardFile {
            header,
            rows,
            form_factor_rows,
            near_rows,
            sky_rows,
            probe_rows,
            model,
        })
    }

    /// Only the model of the shard at `path`, its checksum verified: what the later steps pass
    /// on without reading a shard's rows twice.
    pub fn read_model(path: &Path) -> Result<Option<Vec<u8>>, FormatError> {
        let bytes = FileBytes::open(path)?;
        let c = Container::parse_as(&bytes, Flavour::Shard)?;
        if let Some(e) = c.entry(SectionKind::MODL)
            && !c.section_crc_ok(e)?
        {
            return Err(FormatError::SectionChecksum {
                kind: SectionKind::MODL,
            });
        }
        model_of(&c)
    }

    /// Memory-maps `path` and parses all of it, every checksum verified.
    pub fn read(path: &Path) -> Result<ShardFile, FormatError> {
        ShardFile::from_bytes(&FileBytes::open(path)?)
    }
}

impl ShardHeader {
    /// The metadata, layout and occupancy of a shard, their checksums verified, without reading
    /// its rows (whose checksum [`ShardFile::read`] verifies).
    pub fn from_bytes(bytes: &[u8]) -> Result<ShardHeader, FormatError> {
        let c = Container::parse_as(bytes, Flavour::Shard)?;
        for kind in [
            SHRD,
            SectionKind::LAYT,
            SectionKind::OCCU,
            SectionKind::SURF,
            SectionKind::ELEM,
            SEMT,
        ] {
            if let Some(e) = c.entry(kind)
                && !c.section_crc_ok(e)?
            {
                return Err(FormatError::SectionChecksum { kind });
            }
        }
        header_from(&c)
    }

    pub fn read(path: &Path) -> Result<ShardHeader, FormatError> {
        ShardHeader::from_bytes(&FileBytes::open(path)?)
    }
}

fn bad(message: impl Into<String>) -> FormatError {
    FormatError::BadShard(message.into())
}

fn section<'a>(c: &Container<'a>, kind: SectionKind) -> Result<&'a [u8], FormatError> {
    c.entry(kind)
        .ok_or(FormatError::MissingSection { kind })
        .and_then(|e| c.section(e))
}

fn model_of(c: &Container<'_>) -> Result<Option<Vec<u8>>, FormatError> {
    match c.entry(SectionKind::MODL) {
        Some(e) => {
            let bytes = c.section(e)?;
            validate_model(bytes)?;
            Ok(Some(bytes.to_vec()))
        }
        None => Ok(None),
    }
}

fn header_from(c: &Container<'_>) -> Result<ShardHeader, FormatError> {
    for e in &c.entries {
        let known = [
            SHRD,
            SectionKind::LAYT,
            SectionKind::OCCU,
            SectionKind::SURF,
            SectionKind::ELEM,
            ROWS,
            FROW,
            NROW,
            SROW,
            SEMT,
            PROW,
        ]
        .contains(&e.kind);
        if e.kind == SectionKind::MODL {
            if e.flags != SECTION_OPTIONAL {
                return Err(FormatError::UnknownFlags {
                    kind: e.kind,
                    flags: e.flags,
                });
            }
            continue;
        }
        if !known && !e.is_optional() {
            return Err(FormatError::UnknownSection { kind: e.kind });
        }
        if known && e.flags != 0 {
            return Err(FormatError::UnknownFlags {
                kind: e.kind,
                flags: e.flags,
            });
        }
    }
    let meta = decode_meta(section(c, SHRD)?)?;
    let layout = decode_layout(section(c, SectionKind::LAYT)?)?;
    let elements = match (c.entry(SectionKind::ELEM), meta.settings.geometry) {
        (Some(e), Geometry::Surface) => Some(decode_elements(c.section(e)?, &layout)?),
        (Some(_), Geometry::VoxelFaces) => {
            return Err(bad("a voxel-face bake's shard holds transport elements"));
        }
        (None, _) => None,
    };
    let rows = elements.as_ref().map_or(&layout, |e| &e.layout);
    check_meta(&meta, rows)?;
    let occupancy = decode_occupancy(section(c, SectionKind::OCCU)?, &layout)?;
    let surface = match (c.entry(SectionKind::SURF), meta.settings.geometry) {
        (Some(e), Geometry::Surface) => {
            Some(decode_surface(c.section(e)?, rows, super::FORMAT_VERSION)?)
        }
        (None, Geometry::VoxelFaces) => None,
        (None, Geometry::Surface) => {
            return Err(FormatError::MissingSection {
                kind: SectionKind::SURF,
            });
        }
        (Some(_), Geometry::VoxelFaces) => {
            return Err(bad("a voxel-face bake's shard holds surface geometry"));
        }
    };
    let emitters = match (c.entry(SEMT), meta.settings.geometry) {
        (Some(e), Geometry::Surface) => {
            Some(decode_emitters(SEMT, c.section(e)?, rows.len(), true)?)
        }
        (Some(_), Geometry::VoxelFaces) => {
            return Err(bad("a voxel-face bake's shard holds emitters"));
        }
        (None, _) => None,
    };
    Ok(ShardHeader {
        meta,
        layout,
        occupancy,
        surface,
        elements,
        emitters,
    })
}

fn decode_meta(bytes: &[u8]) -> Result<ShardMeta, FormatError> {
    serde_json::from_slice(bytes).map_err(|error| FormatError::Json { kind: SHRD, error })
}

/// A surface bake with a near-field radius carries its rows of the matrix in every shard.
fn wants_near_rows(m: &ShardMeta) -> bool {
    m.settings.geometry == Geometry::Surface && m.settings.near_radius > 0.0
}

/// A surface bake with probes carries its range of their gather rows in every shard.
fn wants_probe_rows(m: &ShardMeta) -> bool {
    m.settings.geometry == Geometry::Surface && m.settings.probes.is_some()
}

/// The probe rows are the shard's share of the gather rows, split as the transport's rows are.
fn check_probe_range(p: &ProbeRows, m: &ShardMeta) -> Result<(), FormatError> {
    let gathers = p.positions.len() * crate::probe::DIRECTIONS;
    let want = shard_rows(gathers, m.index, m.count);
    if p.range != want {
        return Err(bad(format!(
            "holds gather rows {}..{} of the probes, but shard {}/{} of {gathers} owns rows {}..{}",
            p.range.start, p.range.end, m.index, m.count, want.start, want.end
        )));
    }
    Ok(())
}

fn wants_form_factor_rows(m: &ShardMeta) -> bool {
    m.phase == Phase::Transport && m.keep_form_factors
}

/// The metadata agrees with itself and with the transport's rows.
fn check_meta(m: &ShardMeta, layout: &PatchLayout) -> Result<(), FormatError> {
    if m.count == 0 || m.index >= m.count {
        return Err(bad(format!(
            "shard index {} of {} is out of range",
            m.index, m.count
        )));
    }
    if m.patches != layout.len() {
        return Err(bad(format!(
            "the metadata says {} patches but the layout has {}",
            m.patches,
            layout.len()
        )));
    }
    let want = shard_rows(m.patches, m.index, m.count);
    if (m.first_row, m.end_row) != (want.start, want.end) {
        return Err(bad(format!(
            "holds rows {}..{}, but shard {}/{} of {} patches owns rows {}..{}",
            m.first_row, m.end_row, m.index, m.count, m.patches, want.start, want.end
        )));
    }
    let channels_ok = match m.phase {
        Phase::FormFactors => m.channels == 1,
        Phase::Transport => m.channels == 1 || m.channels == 3,
    };
    if !channels_ok {
        return Err(bad(format!(
            "{} channel(s) in a {} shard",
            m.channels,
            m.phase.name()
        )));
    }
    match (m.phase, &m.form_factors) {
        (Phase::FormFactors, Some(_)) => Err(bad("a phase-1 shard with form-factor statistics")),
        (Phase::Transport, None) => Err(bad("a phase-2 shard without form-factor statistics")),
        _ => Ok(()),
    }
}

/// Values a shard's rows must hold: `channels × rows × patches`, computed with checked
/// arithmetic so that no header can overflow it.
fn rows_values(m: &ShardMeta, channels: usize) -> Option<usize> {
    (m.end_row - m.first_row)
        .checked_mul(m.patches)?
        .checked_mul(channels)
}

fn check_rows_len(
    kind: SectionKind,
    m: &ShardMeta,
    channels: usize,
    len: usize,
) -> Result<(), FormatError> {
    if rows_values(m, channels) == Some(len) {
        Ok(())
    } else {
        Err(FormatError::Rows {
            kind,
            message: format!(
                "{len} values for {channels} channel(s) of rows {}..{} of {} patches",
                m.first_row, m.end_row, m.patches
            ),
        })
    }
}

fn check_values(kind: SectionKind, values: &[f32]) -> Result<(), FormatError> {
    match values.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        None => Ok(()),
        Some(i) => Err(FormatError::Rows {
            kind,
            message: format!("value {i} is {}, not finite and non-negative", values[i]),
        }),
    }
}

/// The rows as little-endian bytes: borrowed where the machine is little-endian already.
pub(crate) fn le_bytes(values: &[f32]) -> Cow<'_, [u8]> {
    #[cfg(target_endian = "little")]
    {
        Cow::Borrowed(bytemuck::cast_slice(values))
    }
    #[cfg(not(target_endian = "little"))]
    {
        Cow::Owned(values.iter().flat_map(|v| v.to_le_bytes()).collect())
    }
}

fn rows_section<'a>(
    kind: SectionKind,
    m: &ShardMeta,
    channels: usize,
    values: &'a [f32],
) -> Section<'a> {
    let mut head = Vec::with_capacity(SECTION_ALIGN as usize);
    // check_meta has bounded these by the layout's u32 patch count.
    for v in [m.patches, m.first_row, m.end_row, channels] {
        head.extend_from_slice(&(v as u32).to_le_bytes());
    }
    head.extend_from_slice(container::padding_to_align(head.len() as u64));
    Section {
        kind,
        flags: 0,
        pieces: vec![Cow::Owned(head), le_bytes(values)],
    }
}

fn decode_rows(
    kind: SectionKind,
    bytes: &[u8],
    m: &ShardMeta,
    channels: usize,
) -> Result<Vec<f32>, FormatError> {
    let mut r = FieldReader::new(bytes, Some(kind));
    let fields = [
        r.u32("patch count")?,
        r.u32("first row")?,
        r.u32("end row")?,
        r.u32("channels")?,
    ];
    let want = [m.patches, m.first_row, m.end_row, channels];
    if fields.iter().zip(want).any(|(&a, b)| a as usize != b) {
        return Err(FormatError::Rows {
            kind,
            message: format!(
                "header says patches, rows and channels {fields:?}, the metadata {want:?}"
            ),
        });
    }
    let padding = r.take(SECTION_ALIGN - ROWS_HEADER_LEN, "alignment")?;
    if padding.iter().any(|&b| b != 0) {
        return Err(FormatError::NonZeroPadding {
            what: format!("section '{kind}' before the rows"),
        });
    }
    let data = r.remaining();
    // Only a count the metadata and the section's length both account for sizes an allocation.
    let count = rows_values(m, channels)
        .filter(|c| c.checked_mul(4) == Some(data.len()))
        .ok_or_else(|| FormatError::Rows {
            kind,
            message: format!(
                "{} bytes of values for {channels} channel(s) of rows {}..{} of {} patches",
                data.len(),
                m.first_row,
                m.end_row,
                m.patches
            ),
        })?;
    let mut values = Vec::with_capacity(count);
    values.extend(
        data.chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
    );
    check_values(kind, &values)?;
    Ok(values)
}
