//! The container: header, section table, checksums and alignment, knowing nothing about what the
//! sections hold. Also the little-endian field reader the section decoders share, and the atomic,
//! memory-mapped file access.
//!
//! Parsing validates every offset and length against the file before touching the bytes they name,
//! with checked arithmetic, so a hostile table can neither panic the reader nor make it allocate
//! more than the file's own size justifies.

use std::borrow::Cow;
use std::fmt;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::ops::Deref;
use std::path::Path;

use super::{FORMAT_VERSION, FormatError, SHARD_FORMAT_VERSION};

/// First 8 bytes of every baked file.
pub const MAGIC: [u8; 8] = *b"BOUNCE\0B";
/// First 8 bytes of every bake shard (a sharded bake's partial result, see [`crate::bake::shard`]).
pub const SHARD_MAGIC: [u8; 8] = *b"BOUNCE\0S";

/// Which kind of file a container holds: the same header, table and checksums serve baked files
/// and bake shards, told apart by their magic and versioned separately.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Flavour {
    Baked,
    Shard,
}

impl Flavour {
    fn magic(self) -> [u8; 8] {
        match self {
            Flavour::Baked => MAGIC,
            Flavour::Shard => SHARD_MAGIC,
        }
    }

    fn version(self) -> u32 {
        match self {
            Flavour::Baked => FORMAT_VERSION,
            Flavour::Shard => SHARD_FORMAT_VERSION,
        }
    }

    /// The oldest version this build reads: baked files of version 1 (voxel faces, before
    /// surface patches) still serve; shards are read only by the release that wrote them.
    fn oldest(self) -> u32 {
        match self {
            Flavour::Baked => super::OLDEST_FORMAT_VERSION,
            Flavour::Shard => SHARD_FORMAT_VERSION,
        }
    }

    /// The error for bytes that do not start with this flavour's magic: naming the other
    /// flavour when it is that, since handing a shard to `serve` (or a baked file to `merge`) is
    /// an easy mistake.
    fn wrong_magic(self, prefix: &[u8]) -> FormatError {
        match self {
            Flavour::Baked if SHARD_MAGIC.starts_with(prefix) && !prefix.is_empty() => {
                FormatError::ShardNotBaked
            }
            Flavour::Shard if MAGIC.starts_with(prefix) && !prefix.is_empty() => {
                FormatError::BakedNotShard
            }
            Flavour::Baked => FormatError::BadMagic,
            Flavour::Shard => FormatError::ShardBadMagic,
        }
    }
}
/// Bytes of the fixed header.
pub const HEADER_LEN: u64 = 32;
/// Bytes of one section-table entry.
pub const ENTRY_LEN: u64 = 32;
/// Every section starts at a multiple of this, so payloads can be used in place (f32 views, GPU
/// uploads) from a memory map.
pub const SECTION_ALIGN: u64 = 64;
/// Section flag: a reader that does not know the section's kind may skip it.
pub const SECTION_OPTIONAL: u32 = 1;

/// Where the header holds the file length, which is known only once the sections are placed.
const FILE_LEN_AT: usize = 16;
/// Header bytes the header checksum covers: all but the checksum itself.
const HEADER_CRC_AT: usize = 28;

/// A section's four-character kind, e.g. `MTRX`.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SectionKind(pub [u8; 4]);

impl SectionKind {
    pub const META: SectionKind = SectionKind(*b"META");
    pub const LAYT: SectionKind = SectionKind(*b"LAYT");
    pub const MTRX: SectionKind = SectionKind(*b"MTRX");
    pub const FFAC: SectionKind = SectionKind(*b"FFAC");
    pub const OCCU: SectionKind = SectionKind(*b"OCCU");
    pub const MODL: SectionKind = SectionKind(*b"MODL");
    pub const SURF: SectionKind = SectionKind(*b"SURF");
    pub const ELEM: SectionKind = SectionKind(*b"ELEM");
    pub const NEAR: SectionKind = SectionKind(*b"NEAR");
    pub const SKYV: SectionKind = SectionKind(*b"SKYV");
    pub const EMIT: SectionKind = SectionKind(*b"EMIT");
    pub const PROB: SectionKind = SectionKind(*b"PROB");
    pub const PSKY: SectionKind = SectionKind(*b"PSKY");
}

impl fmt::Display for SectionKind {
    // Kinds come from files, so anything that is not printable ASCII is escaped.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0.escape_ascii())
    }
}

impl fmt::Debug for SectionKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "SectionKind({self})")
    }
}

/// The fixed header, as read from a file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    pub format_version: u32,
    pub section_count: u32,
    pub file_len: u64,
    /// CRC-32 of the header's first 28 bytes and the section table.
    pub crc: u32,
}

/// One section-table entry. Offset and length are validated against the file once parsed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SectionEntry {
    pub kind: SectionKind,
    pub flags: u32,
    pub offset: u64,
    pub len: u64,
    /// CRC-32 of the section's bytes.
    pub crc: u32,
}

impl SectionEntry {
    pub fn is_optional(&self) -> bool {
        self.flags & SECTION_OPTIONAL != 0
    }

    /// End offset; cannot overflow once the entry has been parsed.
    pub fn end(&self) -> u64 {
        self.offset.saturating_add(self.len)
    }
}

/// What `bounce inspect` shows without decoding the sections.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FileSummary {
    pub header: Header,
    /// In table order.
    pub sections: Vec<SectionSummary>,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SectionSummary {
    pub entry: SectionEntry,
    /// Whether the section's bytes match its checksum.
    pub crc_ok: bool,
}

/// A structurally valid container over borrowed bytes: header and table checked, every section
/// inside the file, aligned, not overlapping, and nothing but zeros between them. Section
/// checksums are not yet checked (see [`Container::verify_checksums`]).
pub(crate) struct Container<'a> {
    pub header: Header,
    pub entries: Vec<SectionEntry>,
    bytes: &'a [u8],
}

impl<'a> Container<'a> {
    pub fn parse(bytes: &'a [u8]) -> Result<Self, FormatError> {
        Container::parse_as(bytes, Flavour::Baked)
    }

    pub fn parse_as(bytes: &'a [u8], flavour: Flavour) -> Result<Self, FormatError> {
        let actual = bytes.len() as u64;
        let truncated = |what: &str, end: u64| FormatError::Truncated {
            what: what.to_string(),
            end,
            len: actual,
        };

        // An empty or cut-short file that starts like ours is truncated; anything else is foreign.
        let magic = flavour.magic();
        let prefix_len = bytes.len().min(magic.len());
        let prefix = bytes.get(..prefix_len).unwrap_or_default();
        if magic.get(..prefix_len) != Some(prefix) {
            // An 8-byte prefix that is the other flavour's whole magic names it; a shorter one
            // is only foreign.
            let whole = if prefix_len == magic.len() {
                prefix
            } else {
                &[]
            };
            return Err(flavour.wrong_magic(whole));
        }
        let mut r = FieldReader::new(bytes, None);
        let header_bytes = r
            .take(HEADER_LEN, "header")
            .map_err(|_| truncated("the header", HEADER_LEN))?;
        let mut h = FieldReader::new(header_bytes, None);
        let _magic: [u8; 8] = h.array("magic")?;
        let format_version = h.u32("format version")?;
        let section_count = h.u32("section count")?;
        let file_len = h.u64("file length")?;
        let reserved = h.u32("reserved")?;
        let crc = h.u32("header checksum")?;

        if !(flavour.oldest()..=flavour.version()).contains(&format_version) {
            return Err(FormatError::UnsupportedVersion {
                found: format_version,
                oldest: flavour.oldest(),
                supported: flavour.version(),
            });
        }
        if file_len > actual {
            return Err(FormatError::ShortFile {
                declared: file_len,
                actual,
            });
        }
        if file_len < actual {
            return Err(FormatError::LongFile {
                declared: file_len,
                actual,
            });
        }
        // Bound the count by what the file can hold before anything is sized by it.
        let max = (actual - HEADER_LEN) / ENTRY_LEN;
        if u64::from(section_count) > max {
            return Err(FormatError::TooManySections {
                count: section_count,
                max,
                file_len: actual,
            });
        }
        let table_len = u64::from(section_count) * ENTRY_LEN;
        let table = r
            .take(table_len, "section table")
            .map_err(|_| truncated("the section table", HEADER_LEN + table_len))?;
        let table_end = HEADER_LEN + table_len;

        let mut hasher = crc32fast::Hasher::new();
        hasher.update(header_bytes.get(..HEADER_CRC_AT).unwrap_or_default());
        hasher.update(table);
        if hasher.finalize() != crc {
            return Err(FormatError::HeaderChecksum);
        }
        if reserved != 0 {
            return Err(FormatError::Reserved {
                what: "the header".to_string(),
            });
        }
        let header = Header {
            format_version,
            section_count,
            file_len,
            crc,
        };

        // Bounded by `max` above: at most one entry per 32 bytes of file.
        let mut entries = Vec::with_capacity(table.len() / ENTRY_LEN as usize);
        let mut t = FieldReader::new(table, None);
        for index in 0..section_count {
            let kind = SectionKind(t.array("section kind")?);
            let flags = t.u32("section flags")?;
            let offset = t.u64("section offset")?;
            let len = t.u64("section length")?;
            let crc = t.u32("section checksum")?;
            if t.u32("reserved")? != 0 {
                return Err(FormatError::Reserved {
                    what: format!("section table entry {index} ('{kind}')"),
                });
            }
            let end = offset
                .checked_add(len)
                .ok_or(FormatError::SectionOverflow { kind, offset, len })?;
            if offset < table_end {
                return Err(FormatError::SectionInHeader {
                    kind,
                    offset,
                    table_end,
                });
            }
            if !offset.is_multiple_of(SECTION_ALIGN) {
                return Err(FormatError::Misaligned { kind, offset });
            }
            if end > actual {
                return Err(truncated(&format!("section '{kind}'"), end));
            }
            if entries.iter().any(|e: &SectionEntry| e.kind == kind) {
                return Err(FormatError::DuplicateSection { kind });
            }
            entries.push(SectionEntry {
                kind,
                flags,
                offset,
                len,
                crc,
            });
        }

        // Walk the sections in file order: each must start at or after the furthest end so far,
        // and every byte not inside one must be zero (no checksum covers those bytes).
        let mut by_offset: Vec<&SectionEntry> = entries.iter().collect();
        by_offset.sort_by_key(|e| (e.offset, e.end()));
        let mut covered = table_end;
        let mut last: Option<SectionKind> = None;
        for e in by_offset {
            // `last` is set whenever `covered` has moved past the table, where sections start.
            if e.offset < covered
                && let Some(first) = last
            {
                return Err(FormatError::Overlap {
                    first,
                    second: e.kind,
                });
            }
            check_zero(bytes, covered, e.offset)?;
            if e.end() >= covered {
                covered = e.end();
                last = Some(e.kind);
            }
        }
        check_zero(bytes, covered, actual)?;

        Ok(Container {
            header,
            entries,
            bytes,
        })
    }

    pub fn entry(&self, kind: SectionKind) -> Option<&SectionEntry> {
        self.entries.iter().find(|e| e.kind == kind)
    }

    /// The bytes of a parsed entry.
    pub fn section(&self, e: &SectionEntry) -> Result<&'a [u8], FormatError> {
        let range = to_usize(e.offset)..to_usize(e.end());
        self.bytes.get(range).ok_or_else(|| FormatError::Truncated {
            what: format!("section '{}'", e.kind),
            end: e.end(),
            len: self.bytes.len() as u64,
        })
    }

    pub fn section_crc_ok(&self, e: &SectionEntry) -> Result<bool, FormatError> {
        Ok(crc32fast::hash(self.section(e)?) == e.crc)
    }

    pub fn verify_checksums(&self) -> Result<(), FormatError> {
        for e in &self.entries {
            if !self.section_crc_ok(e)? {
                return Err(FormatError::SectionChecksum { kind: e.kind });
            }
        }
        Ok(())
    }

    pub fn summary(&self) -> Result<FileSummary, FormatError> {
        let sections = self
            .entries
            .iter()
            .map(|e| {
                Ok(SectionSummary {
                    entry: *e,
                    crc_ok: self.section_crc_ok(e)?,
                })
            })
            .collect::<Result<_, FormatError>>()?;
        Ok(FileSummary {
            header: self.header,
            sections,
        })
    }
}

/// `usize::MAX` for values a 32-bit target cannot address, so a later `get` fails cleanly.
fn to_usize(v: u64) -> usize {
    usize::try_from(v).unwrap_or(usize::MAX)
}

fn check_zero(bytes: &[u8], from: u64, to: u64) -> Result<(), FormatError> {
    if from >= to {
        return Ok(());
    }
    let gap = bytes.get(to_usize(from)..to_usize(to)).unwrap_or_default();
    match gap.iter().position(|&b| b != 0) {
        Some(i) => Err(FormatError::StrayByte {
            offset: from + i as u64,
        }),
        None => Ok(()),
    }
}

/// One section to write, as pieces whose concatenation is its bytes: a matrix payload is one
/// borrowed piece, so writing never copies it.
pub(crate) struct Section<'a> {
    pub kind: SectionKind,
    pub flags: u32,
    pub pieces: Vec<Cow<'a, [u8]>>,
}

impl Section<'_> {
    fn len(&self) -> u64 {
        self.pieces.iter().map(|p| p.len() as u64).sum()
    }

    fn crc(&self) -> u32 {
        let mut hasher = crc32fast::Hasher::new();
        for p in &self.pieces {
            hasher.update(p);
        }
        hasher.finalize()
    }
}

/// A whole file, laid out but not written: the header and table in memory, sections as pieces.
/// [`Assembled::write_to`] is the only code that emits a file's bytes, whether into memory or
/// onto disk, so the two cannot differ.
pub(crate) struct Assembled<'a> {
    /// Header and section table, checksums filled in.
    head: Vec<u8>,
    /// In table order, each with its offset.
    sections: Vec<(u64, Section<'a>)>,
    file_len: u64,
}

/// Enough zeros for any gap [`Assembled::write_to`] has to fill.
static ZEROS: [u8; SECTION_ALIGN as usize] = [0; SECTION_ALIGN as usize];

/// Zero bytes that bring `at` up to the next multiple of [`SECTION_ALIGN`].
pub(crate) fn padding_to_align(at: u64) -> &'static [u8] {
    &ZEROS[..(at.next_multiple_of(SECTION_ALIGN) - at) as usize]
}

impl<'a> Assembled<'a> {
    /// Lays sections out after the header and table, each at the next multiple of
    /// [`SECTION_ALIGN`], in the order given. The same input always gives the same bytes.
    /// Checksums every section here, so nothing is left to fail once writing starts but I/O.
    pub fn new(sections: Vec<Section<'a>>) -> Result<Self, FormatError> {
        Assembled::new_as(sections, Flavour::Baked)
    }

    pub fn new_as(sections: Vec<Section<'a>>, flavour: Flavour) -> Result<Self, FormatError> {
        let count = u32::try_from(sections.len()).map_err(|_| FormatError::TooLarge {
            what: "section count",
            value: sections.len() as u64,
            max: u64::from(u32::MAX),
        })?;
        let table_end = HEADER_LEN + u64::from(count) * ENTRY_LEN;
        let mut head = Vec::with_capacity(table_end as usize);
        head.extend_from_slice(&flavour.magic());
        head.extend_from_slice(&flavour.version().to_le_bytes());
        head.extend_from_slice(&count.to_le_bytes());
        head.extend_from_slice(&0u64.to_le_bytes()); // file length, filled in below
        head.extend_from_slice(&0u32.to_le_bytes());
        head.extend_from_slice(&0u32.to_le_bytes()); // checksum, filled in below
        let mut file_len = table_end;
        let mut placed = Vec::with_capacity(sections.len());
        for s in sections {
            let offset = file_len.next_multiple_of(SECTION_ALIGN);
            let len = s.len();
            // Cannot overflow: every piece is in memory at once.
            file_len = offset + len;
            head.extend_from_slice(&s.kind.0);
            head.extend_from_slice(&s.flags.to_le_bytes());
            head.extend_from_slice(&offset.to_le_bytes());
            head.extend_from_slice(&len.to_le_bytes());
            head.extend_from_slice(&s.crc().to_le_bytes());
            head.extend_from_slice(&0u32.to_le_bytes());
            placed.push((offset, s));
        }
        head[FILE_LEN_AT..FILE_LEN_AT + 8].copy_from_slice(&file_len.to_le_bytes());
        let mut hasher = crc32fast::Hasher::new();
        hasher.update(&head[..HEADER_CRC_AT]);
        hasher.update(&head[HEADER_LEN as usize..]);
        let crc = hasher.finalize();
        head[HEADER_CRC_AT..HEADER_LEN as usize].copy_from_slice(&crc.to_le_bytes());
        Ok(Assembled {
            head,
            sections: placed,
            file_len,
        })
    }

    /// Writes the file from its start. Large pieces go to `w` as they are, so a `BufWriter`
    /// passes them straight through rather than copying them into its buffer.
    pub fn write_to(&self, w: &mut impl Write) -> std::io::Result<()> {
        w.write_all(&self.head)?;
        let mut at = self.head.len() as u64;
        for (offset, s) in &self.sections {
            w.write_all(padding_to_align(at))?;
            debug_assert_eq!(at.next_multiple_of(SECTION_ALIGN), *offset);
            for p in &s.pieces {
                w.write_all(p)?;
            }
            at = offset + s.len();
        }
        debug_assert_eq!(at, self.file_len);
        Ok(())
    }

    pub fn to_vec(&self) -> Result<Vec<u8>, FormatError> {
        let capacity = usize::try_from(self.file_len).map_err(|_| FormatError::TooLarge {
            what: "file length",
            value: self.file_len,
            max: usize::MAX as u64,
        })?;
        let mut out = Vec::with_capacity(capacity);
        // Writing into a Vec only fails by running out of memory, which aborts instead.
        if let Err(e) = self.write_to(&mut out) {
            unreachable!("writing into memory failed: {e}");
        }
        debug_assert_eq!(out.len() as u64, self.file_len);
        Ok(out)
    }
}

/// Sequential little-endian reads from a slice, each failing with a [`FormatError`] instead of
/// panicking when the slice is too short.
pub(crate) struct FieldReader<'a> {
    bytes: &'a [u8],
    pos: usize,
    /// The section being read, for error messages; `None` for the header and table, whose
    /// lengths are checked before a reader is made.
    kind: Option<SectionKind>,
}

impl<'a> FieldReader<'a> {
    pub fn new(bytes: &'a [u8], kind: Option<SectionKind>) -> Self {
        FieldReader {
            bytes,
            pos: 0,
            kind,
        }
    }

    pub fn pos(&self) -> usize {
        self.pos
    }

    pub fn remaining(&self) -> &'a [u8] {
        self.bytes.get(self.pos..).unwrap_or_default()
    }

    pub fn take(&mut self, n: u64, what: &'static str) -> Result<&'a [u8], FormatError> {
        let short = || FormatError::SectionTooShort {
            kind: self.kind.unwrap_or(SectionKind(*b"????")),
            what,
            need: (self.pos as u64).saturating_add(n),
            have: self.bytes.len() as u64,
        };
        let n = usize::try_from(n).map_err(|_| short())?;
        let end = self.pos.checked_add(n).ok_or_else(short)?;
        let s = self.bytes.get(self.pos..end).ok_or_else(short)?;
        self.pos = end;
        Ok(s)
    }

    pub fn array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], FormatError> {
        let s = self.take(N as u64, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub fn u32(&mut self, what: &'static str) -> Result<u32, FormatError> {
        self.array(what).map(u32::from_le_bytes)
    }

    pub fn u64(&mut self, what: &'static str) -> Result<u64, FormatError> {
        self.array(what).map(u64::from_le_bytes)
    }

    pub fn f32(&mut self, what: &'static str) -> Result<f32, FormatError> {
        self.array(what).map(f32::from_le_bytes)
    }

    pub fn f32x3(&mut self, what: &'static str) -> Result<[f32; 3], FormatError> {
        Ok([self.f32(what)?, self.f32(what)?, self.f32(what)?])
    }

    pub fn u32x3(&mut self, what: &'static str) -> Result<[u32; 3], FormatError> {
        Ok([self.u32(what)?, self.u32(what)?, self.u32(what)?])
    }
}

/// A read-only view of a whole file: memory-mapped, so large matrices are not copied twice.
pub(crate) struct FileBytes {
    map: memmap2::Mmap,
}

impl FileBytes {
    pub fn open(path: &Path) -> Result<Self, FormatError> {
        let file = File::open(path).map_err(|e| FormatError::io("open", path, e))?;
        let meta = file
            .metadata()
            .map_err(|e| FormatError::io("read", path, e))?;
        if !meta.is_file() {
            let e = std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a regular file");
            return Err(FormatError::io("read", path, e));
        }
        // SAFETY: the map is only read, and only through the bounds-checked parser. Mapping is
        // undefined behaviour if another process changes the file meanwhile; bounce never writes a
        // baked file in place (`write_atomic` renames a new inode over the old path), so a mapped
        // file keeps its contents even while a new bake replaces it.
        let map = unsafe { memmap2::Mmap::map(&file) }
            .map_err(|e| FormatError::io("memory-map", path, e))?;
        Ok(FileBytes { map })
    }
}

impl Deref for FileBytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        &self.map
    }
}

/// Size of the buffer the small pieces of a file are gathered in before they reach the disk.
const WRITE_BUFFER: usize = 1 << 20;

/// Writes `file` to a temporary file beside `path`, syncs it and renames it over `path`, so
/// readers see the old file or the new one, never a partial one. On failure the temporary file is
/// removed and `path` is untouched.
pub(crate) fn write_atomic(path: &Path, file: &Assembled<'_>) -> Result<(), FormatError> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let mut prefix = std::ffi::OsString::from(".");
    prefix.push(path.file_name().unwrap_or_default());
    prefix.push(".");
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(".tmp");
    // tempfile's default is owner-only; ask for what `File::create` gives (0o666 less the umask)
    // so a server running as another user can read the bake.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let tmp = builder
        .tempfile_in(dir)
        .map_err(|e| FormatError::io("create a temporary file in", dir, e))?;
    let mut w = BufWriter::with_capacity(WRITE_BUFFER, tmp.as_file());
    // Flushed explicitly: dropping a BufWriter would swallow the last write's error.
    file.write_to(&mut w)
        .and_then(|()| w.flush())
        .map_err(|e| FormatError::io("write", tmp.path(), e))?;
    drop(w);
    tmp.as_file()
        .sync_all()
        .map_err(|e| FormatError::io("sync", tmp.path(), e))?;
    tmp.persist(path)
        .map_err(|e| FormatError::io("replace", path, e.error))?;
    // The rename is only durable once the directory entry is on disk.
    #[cfg(unix)]
    File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|e| FormatError::io("sync directory", dir, e))?;
    Ok(())
}
