//! The baked file: what a bake writes and what the server and `bounce inspect` read.
//!
//! This module owns the on-disk bytes and nothing else: the container (header, section table,
//! checksums, alignment) in [`container`], the encoding of bounce's own sections in [`baked`], the
//! errors a reader can meet, and atomic writing. Decoding a matrix payload is the codec's job
//! ([`crate::matrix::EncodedMatrix::decode`]); this module only checks that the payload is where the
//! file says it is.
//!
//! Layout, little-endian throughout:
//!
//! | bytes                  | content                                                              |
//! |------------------------|----------------------------------------------------------------------|
//! | 0..32                  | header: magic `BOUNCE\0B`, version u32, section count u32, file length u64, reserved u32 (0), CRC-32 u32 of bytes 0..28 and the table |
//! | 32..32+32·count        | section table, per entry: kind `[u8; 4]`, flags u32, offset u64, length u64, CRC-32 u32, reserved u32 (0) |
//! | each section's offset  | the section, starting at a multiple of 64; bytes between sections are zero |
//!
//! Sections of version 1: `META` (the [`crate::meta::BakeMeta`] as JSON), `LAYT` (the patch layout,
//! binary), `MTRX` (the transport matrix) and optionally `FFAC` (the single-bounce form factors, same
//! encoding as `MTRX`), `OCCU` (the occupied voxels, flagged optional so that a reader
//! predating it skips it) and `MODL` (the scene the file was baked from as one self-contained
//! GLB, for viewers that draw it; optional too). Bake shards (partial results of a sharded bake, [`crate::bake::shard`]) use the
//! same container under the magic `BOUNCE\0S` with sections of their own ([`ShardFile`]). A reader skips sections of unknown kind whose [`SECTION_OPTIONAL`] flag is set
//! and refuses the file otherwise, so later versions can add sections that old readers may ignore.

mod baked;
mod container;
mod emit;
mod near;
mod probe;
mod shard;
mod shard_meta;
mod sky;

use std::path::PathBuf;

use thiserror::Error;

pub use baked::{
    Baked, LAYOUT_HEADER_LEN, MATRIX_HEADER_LEN, OCCUPANCY_HEADER_LEN, PATCH_RECORD_LEN,
    SURFACE_HEADER_LEN, read_summary,
};
pub use container::{
    ENTRY_LEN, FileSummary, HEADER_LEN, Header, MAGIC, SECTION_ALIGN, SECTION_OPTIONAL,
    SHARD_MAGIC, SectionEntry, SectionKind, SectionSummary,
};
pub use probe::PROBE_HEADER_LEN;
pub(crate) use shard::le_bytes as f32_le_bytes;
pub use shard::{ROWS_HEADER_LEN, ShardFile, ShardHeader};
pub use shard_meta::{FormFactorSummary, Phase, SHARD_EXTENSION, ShardMeta, ShardSpec, shard_rows};
pub use sky::SKY_HEADER_LEN;

/// The version this build writes. Version 2 added surface patches: the `SURF` section and the
/// `geometry` setting in `META`. Version 3 added transport elements (the `ELEM` section), so a
/// version-2 reader refuses such a file by its version rather than by a section it does not know.
/// Version 4 added the near-field first bounce (the `NEAR` section), which changes what a relight
/// computes, so an older reader must refuse the file rather than skip the section. Version 5
/// added each row's view of the sky (the `SKYV` section, flagged optional): a file without it
/// (any older one) reads, and a sky then adds nothing to it. Version 6 added the emissive
/// materials and the rows they cover (the `EMIT` section, flagged optional): a file without it
/// keeps its baked emission, and a light set cannot change it. Version 7 added irradiance
/// probes (the `PROB` section, flagged optional): a file without them has none. Version 8 added
/// the probes' view of the sky (the `PSKY` section, flagged optional, beside `PROB`): a file
/// without it (any older one) reads, and its probes see the sky only off the surfaces. Version 9
/// added the samples' sky view to the near field (`NEAR`'s flag bit 0): an older file reads, and
/// its sky then gets no near-field correction. Version 10 added each emitter's node (`EMIT`'s
/// flag bit 0): an older file reads, and its emitters are changed by material only. Version 11
/// added each sample point's albedo (`SURF`'s flag bit 0, once reserved): an older file reads,
/// and its near field reflects a landing's light with its row's albedo. Version 12 added each
/// near-field entry's albedo, where its rays landed (`NEAR`'s flag bit 1): an older file reads,
/// and its landings reflect with their sample's albedo. Version 13 added landing samples, sample
/// points placed where near-field rays land (`SURF`'s flag bit 1 and the count of samples spread
/// by area): an older file reads, and all its samples are spread by area.
pub const FORMAT_VERSION: u32 = 13;
/// The oldest version this build reads: a version-1 file is a voxel-face bake and is relit as
/// one.
pub const OLDEST_FORMAT_VERSION: u32 = 1;
/// The bake-shard version this build writes, and the only one it reads. Shards are
/// intermediate files of one bake, written and read by the same release, so there is no reason
/// to read older ones. Version 5 added each shard's rows of the sky view (`SROW`), version 6 the
/// emitters (`SEMT`), version 7 the samples' sky view in `NROW`, version 8 the probes' gather
/// rows (`PROW`) and the emitters' nodes in `SEMT`, version 9 the samples' albedo in `SURF`,
/// version 10 the near-field entries' albedo in `NROW`, version 11 the landing samples in `SURF`.
pub const SHARD_FORMAT_VERSION: u32 = 11;

/// Everything that can go wrong reading or writing a baked file.
///
/// Messages are meant for people running `bounce`; I/O errors name the file. Errors keep their
/// cause in the message rather than as a `source`, so a reporter that prints the chain does not
/// repeat it.
#[derive(Debug, Error)]
pub enum FormatError {
    #[error("cannot {action} {}: {error}", path.display())]
    Io {
        action: &'static str,
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("not a bounce baked file (bad magic)")]
    BadMagic,
    #[error("not a bounce bake shard (bad magic)")]
    ShardBadMagic,
    #[error(
        "this is a bake shard, not a baked file: merge a sharded bake's shards with `bounce bake merge`"
    )]
    ShardNotBaked,
    #[error(
        "this is a baked file, not a bake shard (`bounce bake merge` reads the shards of one bake)"
    )]
    BakedNotShard,
    #[error("section '{kind}': {message}")]
    Rows { kind: SectionKind, message: String },
    #[error("inconsistent shard: {0}")]
    BadShard(String),
    #[error(
        "unsupported format version {found} (this build reads versions {oldest} to {supported}); \
         bake the scene again with this bounce"
    )]
    UnsupportedVersion {
        found: u32,
        oldest: u32,
        supported: u32,
    },
    #[error("section 'SURF': {0}")]
    Surface(String),
    #[error("section 'ELEM': {0}")]
    Elements(String),
    /// The near-field matrix (`NEAR`, or a shard's `NROW`); the message names the section.
    #[error("{0}")]
    NearField(String),
    /// The sky view (`SKYV`, or a shard's `SROW`); the message names the section.
    #[error("{0}")]
    Sky(String),
    /// The emitters (`EMIT`, or a shard's `SEMT`); the message names the section.
    #[error("{0}")]
    Emitters(String),
    /// The irradiance probes (`PROB`).
    #[error("{0}")]
    Probes(String),
    #[error("file truncated: {what} ends at byte {end} but the file has {len} bytes")]
    Truncated { what: String, end: u64, len: u64 },
    #[error("file truncated: its header says it has {declared} bytes but it has {actual}")]
    ShortFile { declared: u64, actual: u64 },
    #[error("file has {actual} bytes but its header says {declared} (trailing data)")]
    LongFile { declared: u64, actual: u64 },
    #[error("header claims {count} sections but a {file_len}-byte file holds at most {max}")]
    TooManySections { count: u32, max: u64, file_len: u64 },
    #[error("checksum mismatch in the header or section table")]
    HeaderChecksum,
    #[error("checksum mismatch in section '{kind}'")]
    SectionChecksum { kind: SectionKind },
    #[error("non-zero reserved field in {what}")]
    Reserved { what: String },
    #[error(
        "section '{kind}' at offset {offset} with length {len} runs past the end of a 64-bit file"
    )]
    SectionOverflow {
        kind: SectionKind,
        offset: u64,
        len: u64,
    },
    #[error(
        "section '{kind}' starts at byte {offset}, inside the header and section table (which end at byte {table_end})"
    )]
    SectionInHeader {
        kind: SectionKind,
        offset: u64,
        table_end: u64,
    },
    #[error("section '{kind}' starts at byte {offset}, which is not a multiple of 64")]
    Misaligned { kind: SectionKind, offset: u64 },
    #[error("sections '{first}' and '{second}' overlap")]
    Overlap {
        first: SectionKind,
        second: SectionKind,
    },
    #[error("non-zero byte at offset {offset}, outside every section")]
    StrayByte { offset: u64 },
    #[error("section '{kind}' appears more than once")]
    DuplicateSection { kind: SectionKind },
    #[error("required section '{kind}' is missing")]
    MissingSection { kind: SectionKind },
    #[error("unknown required section '{kind}' (written by a newer bounce?)")]
    UnknownSection { kind: SectionKind },
    #[error("section '{kind}' has unknown flags {flags:#x}")]
    UnknownFlags { kind: SectionKind, flags: u32 },
    #[error("section '{kind}' is too short: {what} needs {need} bytes but the section has {have}")]
    SectionTooShort {
        kind: SectionKind,
        what: &'static str,
        need: u64,
        have: u64,
    },
    #[error("section '{kind}' has {have} bytes but its contents end at byte {need}")]
    SectionTooLong {
        kind: SectionKind,
        need: u64,
        have: u64,
    },
    #[error(
        "section 'LAYT' claims {count} patches of {record} bytes but holds {have} bytes of patch records"
    )]
    PatchCount { count: u32, record: u64, have: u64 },
    #[error("patch {patch} has face code {code}")]
    BadFace { patch: usize, code: u8 },
    #[error("patch {patch} lies in voxel {voxel:?}, outside the {dims:?} grid")]
    VoxelOutsideGrid {
        patch: usize,
        voxel: [u32; 3],
        dims: [u32; 3],
    },
    #[error("{what} is not finite")]
    NotFinite { what: String },
    #[error("voxel size {0} is not a positive finite number")]
    BadVoxelSize(f32),
    #[error("{what} has non-zero padding")]
    NonZeroPadding { what: String },
    #[error("section '{kind}': codec name '{name}' is not 1 to 32 bytes of printable ASCII")]
    BadCodecName { kind: SectionKind, name: String },
    #[error(
        "section '{kind}': matrix is {rows}x{cols}x{channels} but the layout has {patches} patches (square, 1 or 3 channels)"
    )]
    MatrixShape {
        kind: SectionKind,
        rows: u32,
        cols: u32,
        channels: u32,
        patches: usize,
    },
    #[error("section '{kind}' holds invalid JSON: {error}")]
    Json {
        kind: SectionKind,
        error: serde_json::Error,
    },
    #[error("section 'OCCU': {0}")]
    Occupancy(String),
    #[error("section 'MODL' is not a valid GLB model: {0} (bake the scene again)")]
    Model(String),
    #[error("{what} is too large for the format ({value} > {max})")]
    TooLarge {
        what: &'static str,
        value: u64,
        max: u64,
    },
}

impl FormatError {
    fn io(action: &'static str, path: &std::path::Path, error: std::io::Error) -> Self {
        FormatError::Io {
            action,
            path: path.to_path_buf(),
            error,
        }
    }
}
