//! The baked file format: exact round trips, the documented layout, and refusal (never a panic or
//! an outsized allocation) of truncated, corrupted and hostile files.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;
use std::time::{Duration, Instant};

use bounce_core::format::{
    Baked, ENTRY_LEN, FORMAT_VERSION, FileSummary, FormatError, HEADER_LEN, MAGIC,
    OCCUPANCY_HEADER_LEN, PATCH_RECORD_LEN, SECTION_ALIGN, SECTION_OPTIONAL, SectionKind,
    read_summary,
};
use bounce_core::light::Light;
use bounce_core::matrix::{DenseMatrix, EncodedMatrix};
use bounce_core::meta::{BakeMeta, BakeSettings, BakeStats, Bounces, StageTiming};
use bounce_core::patch::{Face, Patch, PatchLayout};
use bounce_core::scene::ImportReport;
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------------
// Largest single allocation per thread, so tests can show that a file's claims never size an
// allocation beyond what its length justifies.

struct Tracking;

thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note(size: usize) {
    let _ = LARGEST.try_with(|c| c.set(c.get().max(size)));
}

// SAFETY: forwards every call to the system allocator unchanged; only records sizes.
unsafe impl GlobalAlloc for Tracking {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Tracking = Tracking;

/// Parses `bytes`, returning the result, the largest allocation made and the time taken.
fn parse_tracked(bytes: &[u8]) -> (Result<Baked, FormatError>, usize, Duration) {
    LARGEST.with(|c| c.set(0));
    let start = Instant::now();
    let result = Baked::from_bytes(bytes);
    let elapsed = start.elapsed();
    (result, LARGEST.with(|c| c.get()), elapsed)
}

/// A hostile file must be refused quickly and without allocating more than its own size.
fn refuse(bytes: &[u8]) -> FormatError {
    let (result, largest, elapsed) = parse_tracked(bytes);
    let err = match result {
        Ok(_) => panic!("hostile file of {} bytes was accepted", bytes.len()),
        Err(e) => e,
    };
    assert!(
        largest <= bytes.len() + 4096,
        "refusing a {}-byte file allocated {largest} bytes at once ({err})",
        bytes.len()
    );
    assert!(
        elapsed < Duration::from_secs(2),
        "took {elapsed:?} to refuse ({err})"
    );
    err
}

// ---------------------------------------------------------------------------------------------
// Sample values.

fn sample_meta() -> BakeMeta {
    BakeMeta {
        tool_version: "0.1.0".into(),
        source_name: "cornell.glb".into(),
        source_bytes: 123_456,
        settings: BakeSettings {
            target_patches: Some(500),
            requested_voxel_size: None,
            rays_per_patch: 256,
            seed: 7,
            bounces: Bounces::All,
            all_bounces: Some(bounce_core::meta::AllBounces::Clustered),
            tracer: bounce_core::rays::Tracer::Grid,
            codec: "bc1".to_string(),
            sparse_share: Some(0.04),
            max_error: Some(0.02),
            patch_order: bounce_core::voxel::PatchOrder::Morton,
            geometry: bounce_core::voxel::Geometry::VoxelFaces,
            direct_samples: 0,
            landing_samples: 0,
            max_grey_error: 0.02,
            near_radius: 0.0,
            probes: None,
        },
        stats: BakeStats {
            patches: 5,
            elements: 5,
            voxel_size: 0.25,
            occupied_voxels: 3,
            dropped_patches: 1,
            rays_total: 1280,
            rays: bounce_core::rays::RayTally {
                patch: 1000,
                escaped: 200,
                occluder: 50,
                back_face: 30,
            },
            row_sum_min: 0.1,
            row_sum_max: 0.9,
            row_sum_mean: 0.5,
            reciprocity_error: 0.012,
            isolated_patches: 0,
            channels: 3,
            grey_rel_l2: 0.05,
            grey_tail_rel_l2: Some(0.01),
            matrix_bytes: 300,
            codec_eind_rel_l2: 1.5e-3,
            surface_area: 12.5,
            unassigned_area: 0.25,
        },
        timings: vec![StageTiming {
            stage: "form factors".into(),
            seconds: 1.25,
        }],
        import_report: ImportReport {
            meshes: 2,
            primitives: 3,
            triangles: 40,
            warnings: vec!["a ünïcode warning".into()],
            ..Default::default()
        },
        lights: vec![Light::Point {
            position: [0.0, 1.5, 0.0],
            color: [1.0, 0.9, 0.8],
            intensity: 10.0,
            range: None,
            name: Some("key".into()),
        }],
    }
}

fn sample_layout(n: usize) -> PatchLayout {
    let patches = (0..n)
        .map(|i| Patch {
            voxel: [i as u32 % 4, (i as u32 / 4) % 3, 1],
            face: Face::ALL[i % 6],
            albedo: [0.5, 0.25 + i as f32 * 0.01, 0.75],
            centroid: [i as f32 * 0.3, -1.5, 2.0e-7],
            normal: Face::ALL[i % 6].normal().to_array(),
            source_area: 0.0625 * (i + 1) as f32,
            emission: if i == 0 { [3.0, 2.0, 1.0] } else { [0.0; 3] },
        })
        .collect();
    PatchLayout {
        origin: [-1.0, 0.0, -0.5],
        voxel_size: 0.25,
        dims: [4, 3, 2],
        patches,
    }
}

fn dense(n: usize, channels: usize, seed: f32) -> DenseMatrix {
    let mut m = DenseMatrix::zeros(n, channels);
    for (k, v) in m.data.iter_mut().enumerate() {
        *v = ((k as f32 + seed) * 0.37).sin().abs() / n as f32;
    }
    m
}

/// Occupied voxels of the sample's 4×3×2 grid: the patches' voxels (12..=16) and a few more.
const SAMPLE_OCCUPANCY: [u64; 8] = [0, 5, 12, 13, 14, 15, 16, 23];

fn sample(channels: usize, with_form_factors: bool) -> Baked {
    let n = 5;
    Baked {
        meta: sample_meta(),
        layout: sample_layout(n),
        transport: EncodedMatrix::encode_dense_f32(&dense(n, channels, 1.0)),
        form_factors: with_form_factors.then(|| EncodedMatrix::encode_dense_f32(&dense(n, 1, 2.0))),
        occupancy: Some(SAMPLE_OCCUPANCY.to_vec()),
        surface: None,
        elements: None,
        near_field: None,
        sky: None,
        emitters: None,
        probes: None,
        model: None,
    }
}

fn sample_bytes() -> Vec<u8> {
    sample(3, true).to_bytes().expect("sample encodes")
}

// ---------------------------------------------------------------------------------------------
// Raw access to the container, written from the layout's description rather than the library's
// code, so that hand-made files test the documented format.

fn get_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn get_u64(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

fn put_u32(b: &mut [u8], at: usize, v: u32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

fn put_u64(b: &mut [u8], at: usize, v: u64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

fn entry_at(i: usize) -> usize {
    HEADER_LEN as usize + i * ENTRY_LEN as usize
}

/// Index of the table entry of `kind`.
fn entry_of(b: &[u8], kind: &[u8; 4]) -> usize {
    let count = get_u32(b, 12) as usize;
    (0..count)
        .find(|&i| &b[entry_at(i)..entry_at(i) + 4] == kind)
        .unwrap_or_else(|| panic!("no section {}", kind.escape_ascii()))
}

/// `(offset, len)` of the section of `kind`.
fn section_of(b: &[u8], kind: &[u8; 4]) -> (usize, usize) {
    let e = entry_at(entry_of(b, kind));
    (get_u64(b, e + 8) as usize, get_u64(b, e + 16) as usize)
}

/// A file made of these sections, laid out as documented, with correct checksums.
fn raw_file(sections: &[(&[u8; 4], u32, &[u8])]) -> Vec<u8> {
    let table_end = HEADER_LEN as usize + sections.len() * ENTRY_LEN as usize;
    let mut b = vec![0u8; table_end];
    b[..8].copy_from_slice(&MAGIC);
    put_u32(&mut b, 8, FORMAT_VERSION);
    put_u32(&mut b, 12, sections.len() as u32);
    for (i, (kind, flags, bytes)) in sections.iter().enumerate() {
        let offset = b.len().next_multiple_of(SECTION_ALIGN as usize);
        b.resize(offset, 0);
        b.extend_from_slice(bytes);
        let e = entry_at(i);
        b[e..e + 4].copy_from_slice(*kind);
        put_u32(&mut b, e + 4, *flags);
        put_u64(&mut b, e + 8, offset as u64);
        put_u64(&mut b, e + 16, bytes.len() as u64);
    }
    let len = b.len() as u64;
    put_u64(&mut b, 16, len);
    reseal(&mut b);
    b
}

/// Recomputes every checksum that the (possibly edited) table lets one compute, so an edit is
/// seen by the check it targets rather than by a checksum.
fn reseal(b: &mut [u8]) {
    if b.len() < HEADER_LEN as usize {
        return;
    }
    let count = get_u32(b, 12) as usize;
    let table_end = count
        .checked_mul(ENTRY_LEN as usize)
        .and_then(|t| t.checked_add(HEADER_LEN as usize))
        .filter(|&t| t <= b.len());
    let Some(table_end) = table_end else { return };
    for i in 0..count {
        let e = entry_at(i);
        let (offset, len) = (get_u64(b, e + 8), get_u64(b, e + 16));
        let end = offset.checked_add(len).filter(|&end| end <= b.len() as u64);
        if let Some(end) = end {
            let crc = crc32fast::hash(&b[offset as usize..end as usize]);
            put_u32(b, e + 24, crc);
        }
    }
    let mut h = crc32fast::Hasher::new();
    h.update(&b[..28]);
    h.update(&b[HEADER_LEN as usize..table_end]);
    let crc = h.finalize();
    put_u32(b, 28, crc);
}

/// The sample's sections, for building variants of it.
fn sample_sections() -> Vec<([u8; 4], Vec<u8>)> {
    let b = sample_bytes();
    [b"META", b"LAYT", b"MTRX", b"FFAC", b"OCCU"]
        .into_iter()
        .map(|k| {
            let (o, l) = section_of(&b, k);
            (*k, b[o..o + l].to_vec())
        })
        .collect()
}

fn file_with(replace: &[u8; 4], with: Vec<u8>) -> Vec<u8> {
    let sections: Vec<_> = sample_sections()
        .into_iter()
        .map(|(k, v)| {
            if &k == replace {
                (k, with.clone())
            } else {
                (k, v)
            }
        })
        .collect();
    let refs: Vec<(&[u8; 4], u32, &[u8])> = sections
        .iter()
        .map(|(k, v)| (k, u32::from(k == b"OCCU"), v.as_slice()))
        .collect();
    raw_file(&refs)
}

// ---------------------------------------------------------------------------------------------
// Round trips and the layout on disk.

#[test]
fn round_trip_through_a_file_is_exact() {
    let dir = tempfile::tempdir().unwrap();
    for (channels, with_ff, with_occ) in [
        (1, false, false),
        (1, true, true),
        (3, false, true),
        (3, true, false),
        (3, true, true),
    ] {
        let mut baked = sample(channels, with_ff);
        if !with_occ {
            baked.occupancy = None;
        }
        let bytes = baked.to_bytes().unwrap();
        assert_eq!(bytes, baked.to_bytes().unwrap(), "writing is deterministic");

        let path = dir
            .path()
            .join(format!("scene-{channels}-{with_ff}-{with_occ}.bounce"));
        baked.write_atomic(&path).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), bytes);

        let back = Baked::read(&path).unwrap();
        assert_eq!(back.meta, baked.meta);
        assert_eq!(back.layout, baked.layout);
        assert_eq!(back.transport, baked.transport);
        assert_eq!(back.form_factors, baked.form_factors);
        assert_eq!(back.occupancy, baked.occupancy);
        assert_eq!(back, baked);
        assert_eq!(back.to_bytes().unwrap(), bytes, "re-encoding is bit-exact");
        assert_eq!(
            back.transport.decode().unwrap(),
            dense(5, channels, 1.0),
            "the payload still decodes to the matrix"
        );
    }
}

#[test]
fn round_trip_keeps_float_bits() {
    let mut baked = sample(1, false);
    let centroid = [-0.0, f32::MIN_POSITIVE / 8.0, f32::MAX];
    let albedo = [f32::MIN, 1.0e-45, 0.1];
    baked.layout.patches[1].centroid = centroid;
    baked.layout.patches[1].albedo = albedo;
    let back = Baked::from_bytes(&baked.to_bytes().unwrap()).unwrap();
    let bits = |v: [f32; 3]| v.map(f32::to_bits);
    assert_eq!(bits(back.layout.patches[1].centroid), bits(centroid));
    assert_eq!(bits(back.layout.patches[1].albedo), bits(albedo));
}

/// `BakeMeta` holds f64 timings; the format promises they come back bit for bit.
#[test]
fn meta_floats_round_trip_exactly() {
    let mut baked = sample(1, false);
    baked.meta.timings[0].seconds = 26.341909587323226;
    baked.meta.stats.row_sum_mean = 6.033644e-37;
    let back = Baked::from_bytes(&baked.to_bytes().unwrap()).unwrap();
    assert_eq!(
        back.meta.timings[0].seconds.to_bits(),
        baked.meta.timings[0].seconds.to_bits(),
        "serde_json parsed an f64 inexactly: bounce-core needs serde_json's `float_roundtrip` feature"
    );
    assert_eq!(back, baked);
}

#[test]
fn layout_on_disk_matches_the_documentation() {
    let baked = sample(3, true);
    let b = baked.to_bytes().unwrap();
    assert_eq!(&b[..8], b"BOUNCE\0B");
    assert_eq!(get_u32(&b, 8), 13);
    assert_eq!(get_u32(&b, 12), 5);
    assert_eq!(get_u64(&b, 16), b.len() as u64);
    let kinds: Vec<&[u8]> = (0..5).map(|i| &b[entry_at(i)..entry_at(i) + 4]).collect();
    assert_eq!(kinds, [b"META", b"LAYT", b"MTRX", b"FFAC", b"OCCU"]);
    let flags: Vec<u32> = (0..5).map(|i| get_u32(&b, entry_at(i) + 4)).collect();
    assert_eq!(
        flags,
        [0, 0, 0, 0, SECTION_OPTIONAL],
        "only OCCU is optional"
    );
    for i in 0..5 {
        assert_eq!(
            get_u64(&b, entry_at(i) + 8) % 64,
            0,
            "section {i} is 64-byte aligned"
        );
    }

    let (meta_at, meta_len) = section_of(&b, b"META");
    let meta: BakeMeta = serde_json::from_slice(&b[meta_at..meta_at + meta_len]).unwrap();
    assert_eq!(meta, baked.meta);

    let (layt_at, layt_len) = section_of(&b, b"LAYT");
    assert_eq!(layt_len as u64, 32 + 5 * PATCH_RECORD_LEN);
    assert_eq!(get_u32(&b, layt_at + 28), 5, "patch count");
    let second = layt_at + 32 + PATCH_RECORD_LEN as usize;
    assert_eq!(get_u32(&b, second), 1, "patch 1 voxel x");
    assert_eq!(b[second + 12], Face::NegX.code(), "patch 1 face code");

    // The payload sits 64-byte aligned in the file, byte for byte: usable in place from a map.
    let (mtrx_at, mtrx_len) = section_of(&b, b"MTRX");
    assert_eq!(&b[mtrx_at..mtrx_at + 9], b"dense-f32");
    let payload = &baked.transport.payload;
    let payload_at = mtrx_at + mtrx_len - payload.len();
    assert_eq!(payload_at % 64, 0);
    assert_eq!(&b[payload_at..mtrx_at + mtrx_len], payload.as_slice());
    assert_eq!(get_u64(&b, mtrx_at + 48), payload.len() as u64);

    // A 24-cell grid stores its occupied voxels as u32.
    let (occu_at, occu_len) = section_of(&b, b"OCCU");
    assert_eq!(
        occu_len as u64,
        OCCUPANCY_HEADER_LEN + 4 * SAMPLE_OCCUPANCY.len() as u64
    );
    assert_eq!(get_u64(&b, occu_at), SAMPLE_OCCUPANCY.len() as u64, "count");
    assert_eq!(get_u32(&b, occu_at + 8), 4, "index width");
    assert_eq!(get_u32(&b, occu_at + 12), 0, "reserved");
    let indices: Vec<u64> = (0..SAMPLE_OCCUPANCY.len())
        .map(|i| u64::from(get_u32(&b, occu_at + 16 + 4 * i)))
        .collect();
    assert_eq!(indices, SAMPLE_OCCUPANCY);
}

#[test]
fn summary_lists_sections_and_flags_a_damaged_one() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.bounce");
    sample(3, true).write_atomic(&path).unwrap();
    let s = read_summary(&path).unwrap();
    assert_eq!(s.header.format_version, FORMAT_VERSION);
    assert_eq!(s.header.file_len, std::fs::metadata(&path).unwrap().len());
    let kinds: Vec<String> = s
        .sections
        .iter()
        .map(|s| s.entry.kind.to_string())
        .collect();
    assert_eq!(kinds, ["META", "LAYT", "MTRX", "FFAC", "OCCU"]);
    assert!(s.sections.iter().all(|s| s.crc_ok));

    let mut b = std::fs::read(&path).unwrap();
    let (mtrx_at, mtrx_len) = section_of(&b, b"MTRX");
    b[mtrx_at + mtrx_len - 1] ^= 0x40;
    let s = FileSummary::from_bytes(&b).unwrap();
    let ok: Vec<bool> = s.sections.iter().map(|s| s.crc_ok).collect();
    assert_eq!(ok, [true, true, false, true, true]);
    let err = refuse(&b);
    assert!(
        matches!(err, FormatError::SectionChecksum { kind } if kind == SectionKind::MTRX),
        "{err:?}"
    );
    assert_eq!(err.to_string(), "checksum mismatch in section 'MTRX'");
}

// ---------------------------------------------------------------------------------------------
// Truncation, corruption, garbage.

#[test]
fn every_truncation_is_refused() {
    let b = sample_bytes();
    for len in 0..b.len() {
        let err = refuse(&b[..len]);
        if len >= HEADER_LEN as usize {
            assert!(
                matches!(err, FormatError::ShortFile { declared, actual }
                    if declared == b.len() as u64 && actual == len as u64),
                "{len}: {err:?}"
            );
        }
    }
    assert!(matches!(refuse(&b[..0]), FormatError::Truncated { .. }));
    assert_eq!(
        refuse(&b[..b.len() - 1]).to_string(),
        format!(
            "file truncated: its header says it has {} bytes but it has {}",
            b.len(),
            b.len() - 1
        )
    );
}

#[test]
fn truncated_and_empty_files_on_disk_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let b = sample_bytes();
    for len in [0, 7, 31, 100, b.len() - 1] {
        let path = dir.path().join(format!("t{len}.bounce"));
        std::fs::write(&path, &b[..len]).unwrap();
        assert!(Baked::read(&path).is_err(), "length {len}");
        assert!(read_summary(&path).is_err(), "length {len}");
    }
}

#[test]
fn trailing_bytes_are_refused() {
    let mut b = sample_bytes();
    b.push(0);
    assert!(matches!(refuse(&b), FormatError::LongFile { .. }));
}

#[test]
fn a_flipped_byte_between_sections_is_refused() {
    let mut b = sample_bytes();
    let (meta_at, meta_len) = section_of(&b, b"META");
    let gap = meta_at + meta_len;
    assert_ne!(gap % 64, 0, "the sample has padding after META");
    b[gap] = 1;
    assert!(
        matches!(refuse(&b), FormatError::StrayByte { offset } if offset == gap as u64),
        "padding is checked though no checksum covers it"
    );
}

#[test]
fn a_flipped_byte_in_the_table_fails_the_header_checksum() {
    let mut b = sample_bytes();
    b[entry_at(1) + 28] ^= 1; // reserved field of LAYT's entry
    assert!(matches!(refuse(&b), FormatError::HeaderChecksum));
    reseal(&mut b);
    assert!(matches!(refuse(&b), FormatError::Reserved { .. }));
}

/// `PROPTEST_CASES` raises (or lowers) every property's case count for a deeper run.
fn cases(default: u32) -> ProptestConfig {
    let cases = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default);
    ProptestConfig {
        cases,
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(cases(512))]

    #[test]
    fn any_flipped_bytes_are_refused(
        flips in prop::collection::vec((any::<prop::sample::Index>(), 1u8..=255), 1..4)
    ) {
        let mut b = sample_bytes();
        let mut positions = Vec::new();
        for (at, mask) in flips {
            let at = at.index(b.len());
            b[at] ^= mask;
            positions.push(at);
        }
        positions.sort_unstable();
        positions.dedup();
        if b != sample_bytes() {
            let (result, _, _) = parse_tracked(&b);
            prop_assert!(result.is_err(), "flips at {positions:?} went unnoticed");
        }
    }

    #[test]
    fn garbage_is_refused(mut b in prop::collection::vec(any::<u8>(), 0..2048), magic: bool) {
        if magic && b.len() >= 8 {
            b[..8].copy_from_slice(&MAGIC);
        }
        let err = refuse(&b);
        prop_assert!(!err.to_string().is_empty());
    }

    /// Garbage that passes every checksum reaches the section decoders: they must not panic or
    /// over-allocate either (the decision itself may go either way).
    #[test]
    fn resealed_corruption_never_panics(
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        table_edit in proptest::option::of((0usize..5, 0usize..4, any::<u64>())),
    ) {
        let mut b = sample_bytes();
        let body = HEADER_LEN as usize + 5 * ENTRY_LEN as usize;
        for (at, v) in edits {
            let at = body + at.index(b.len() - body);
            b[at] = v;
        }
        if let Some((entry, field, v)) = table_edit {
            // flags, offset or length of one entry
            let e = entry_at(entry);
            match field {
                0 => put_u32(&mut b, e + 4, v as u32),
                1 => put_u64(&mut b, e + 8, v),
                2 => put_u64(&mut b, e + 16, v),
                _ => put_u64(&mut b, e + 16, v % 4096),
            }
        }
        reseal(&mut b);
        let (result, largest, _) = parse_tracked(&b);
        // JSON trees may take a small multiple of their text; nothing may take more.
        prop_assert!(largest <= 64 * b.len() + 65536, "allocated {largest} for {} bytes", b.len());
        if let Ok(baked) = result {
            prop_assert!(baked.to_bytes().is_ok(), "an accepted file re-encodes");
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Hand-made hostile files: each refused by the check aimed at, fast and without a big allocation.

#[test]
fn bad_magic() {
    let mut b = sample_bytes();
    b[0] = b'b';
    assert!(matches!(refuse(&b), FormatError::BadMagic));
    assert_eq!(
        refuse(&b).to_string(),
        "not a bounce baked file (bad magic)"
    );
    assert!(matches!(refuse(b"{\"lights\": []}"), FormatError::BadMagic));
    assert!(matches!(refuse(b"PK\x03\x04"), FormatError::BadMagic));
}

#[test]
fn future_version() {
    let mut b = sample_bytes();
    put_u32(&mut b, 8, 14);
    reseal(&mut b);
    let err = refuse(&b);
    assert!(
        matches!(
            err,
            FormatError::UnsupportedVersion {
                found: 14,
                oldest: 1,
                supported: 13
            }
        ),
        "{err:?}"
    );
    assert_eq!(
        err.to_string(),
        "unsupported format version 14 (this build reads versions 1 to 13); bake the scene again \
         with this bounce"
    );
}

/// The sample as a surface bake: its `SURF` section with two triangles and two sample points a
/// patch.
fn surface_sample() -> Baked {
    let mut b = sample(3, false);
    b.meta.settings.geometry = bounce_core::voxel::Geometry::Surface;
    b.meta.settings.direct_samples = 2;
    b.occupancy = None;
    b.surface = Some(bounce_core::surface::SurfaceData {
        triangles: vec![
            [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]],
        ],
        per_patch: 2,
        area_samples: 2,
        points: (0..10)
            .map(|k| bounce_core::surface::SamplePoint {
                position: [k as f32 * 0.1, 0.5, 0.25],
                normal: [0.0, 0.0, 1.0],
            })
            .collect(),
        // Without the samples' albedo (version 11): most tests relabel this file with older
        // versions; `the_samples_albedo_round_trips_and_is_checked` adds it.
        albedo: None,
    });
    b
}

/// The surface sample with patches 0 and 3 split into two elements each (seven transport rows):
/// the transport and the sample points are then per element.
fn element_sample() -> Baked {
    let mut b = surface_sample();
    let (mut records, mut owner) = (Vec::new(), Vec::new());
    for (i, p) in b.layout.patches.iter().enumerate() {
        let parts = if i == 0 || i == 3 { 2 } else { 1 };
        for _ in 0..parts {
            records.push(Patch {
                source_area: p.source_area / parts as f32,
                ..*p
            });
            owner.push(i as u32);
        }
    }
    let m = records.len();
    b.elements = Some(bounce_core::element::Elements {
        layout: PatchLayout {
            patches: records,
            ..b.layout.clone()
        },
        patch: owner,
    });
    b.transport = EncodedMatrix::encode_dense_f32(&dense(m, 3, 1.0));
    if let Some(s) = &mut b.surface {
        s.points = (0..m * 2)
            .map(|k| bounce_core::surface::SamplePoint {
                position: [k as f32 * 0.1, 0.5, 0.25],
                normal: [0.0, 0.0, 1.0],
            })
            .collect();
        if s.albedo.is_some() {
            s.albedo = Some((0..m * 2).map(|k| [0.05 * k as f32, 0.5, 0.25]).collect());
        }
    }
    b
}

#[test]
fn transport_elements_round_trip_and_are_checked() {
    let b = element_sample();
    let bytes = b.to_bytes().expect("an element sample encodes");
    let back = Baked::from_bytes(&bytes).unwrap();
    assert_eq!(back, b);
    assert_eq!(back.transport_layout().len(), 7);
    assert_eq!(back.layout.len(), 5);
    // A version-2 file cannot hold elements.
    let mut old = bytes.clone();
    put_u32(&mut old, 8, 2);
    reseal(&mut old);
    assert!(matches!(refuse(&old), FormatError::Elements(_)));
    // Every way the elements can disagree with the patches or the rest of the file is refused
    // by the writer (which runs the reader's checks).
    let refuse = |edit: &dyn Fn(&mut Baked)| {
        let mut bad = b.clone();
        edit(&mut bad);
        assert!(bad.to_bytes().is_err());
    };
    refuse(&|b| b.elements.as_mut().unwrap().patch.swap(0, 2));
    refuse(&|b| b.elements.as_mut().unwrap().layout.patches[1].voxel = [9, 9, 9]);
    refuse(&|b| b.elements.as_mut().unwrap().layout.patches[0].source_area = 1e9);
    refuse(&|b| b.elements.as_mut().unwrap().layout.patches[0].albedo = [f32::NAN; 3]);
    // A matrix or sample points sized for the patches, not the elements.
    refuse(&|b| b.transport = EncodedMatrix::encode_dense_f32(&dense(5, 3, 1.0)));
    refuse(&|b| b.surface.as_mut().unwrap().points.truncate(10));
    // Elements belong to surface bakes only.
    let mut voxel = element_sample();
    voxel.meta.settings.geometry = bounce_core::voxel::Geometry::VoxelFaces;
    voxel.surface = None;
    assert!(voxel.to_bytes().is_err());
}

#[test]
fn surface_geometry_round_trips_and_is_checked() {
    let b = surface_sample();
    let bytes = b.to_bytes().expect("a surface sample encodes");
    assert_eq!(
        get_u32(&bytes, 8),
        FORMAT_VERSION,
        "written as this version"
    );
    assert_eq!(Baked::from_bytes(&bytes).unwrap(), b);
    // A surface bake without its section, or a voxel-face bake with one, is refused both ways.
    let mut missing = b.clone();
    missing.surface = None;
    assert!(matches!(
        missing.to_bytes(),
        Err(FormatError::MissingSection { .. })
    ));
    let mut extra = sample(3, false);
    extra.surface = b.surface.clone();
    assert!(matches!(extra.to_bytes(), Err(FormatError::Surface(_))));
    // Counts that do not fit the layout, and non-unit normals, are refused.
    let mut short = b.clone();
    if let Some(s) = &mut short.surface {
        s.points.pop();
    }
    assert!(matches!(short.to_bytes(), Err(FormatError::Surface(_))));
    let mut tilted = b.clone();
    if let Some(s) = &mut tilted.surface {
        s.points[3].normal = [0.0, 0.0, 2.0];
    }
    assert!(matches!(tilted.to_bytes(), Err(FormatError::Surface(_))));
    // Every truncation of the file is refused without a panic.
    for cut in (0..bytes.len()).step_by(97) {
        assert!(Baked::from_bytes(&bytes[..cut]).is_err());
    }
}

#[test]
fn a_near_field_round_trips_and_is_checked() {
    let mut b = element_sample();
    b.meta.settings.near_radius = 0.5;
    // Seven rows of two samples: row 0 met samples of rows 2 and 6, row 4 one of row 0's.
    let mut row_ptr = vec![0u32, 2, 2, 2, 2, 3, 3, 3];
    let near = bounce_core::nearfield::NearField {
        per_row: 2,
        row_ptr: row_ptr.clone(),
        cols: vec![4, 13, 1],
        values: vec![0.25, 0.125, 0.5],
        // Version 9: each of the 14 samples' view of the sky.
        sky: Some(bounce_core::sky::SkyVisibility {
            rows: (0..14)
                .map(|i| std::array::from_fn(|k| 0.01 * (i + k) as f32))
                .collect(),
        }),
        // Version 12: the albedo where each entry's rays landed (exact in f16).
        albedo: Some(vec![[0.25, 0.5, 0.75], [1.0, 0.0, 0.125], [0.5; 3]]),
    };
    b.near_field = Some(near.clone());
    let bytes = b.to_bytes().expect("a near-field sample encodes");
    assert_eq!(Baked::from_bytes(&bytes).unwrap(), b);
    // A version-3 file cannot hold a near field.
    let mut old = bytes.clone();
    put_u32(&mut old, 8, 3);
    reseal(&mut old);
    assert!(matches!(refuse(&old), FormatError::NearField(_)));
    // A version-11 file may not set the entries' albedo flag; without it, it reads, and the
    // landings then reflect with their samples' albedo.
    let mut v11 = bytes.clone();
    put_u32(&mut v11, 8, 11);
    reseal(&mut v11);
    assert!(
        matches!(refuse(&v11), FormatError::Reserved { .. }),
        "{:?}",
        refuse(&v11)
    );
    let mut plain = b.clone();
    plain.near_field.as_mut().unwrap().albedo = None;
    let mut v11 = plain
        .to_bytes()
        .expect("a near field without the entries' albedo encodes");
    put_u32(&mut v11, 8, 11);
    reseal(&mut v11);
    assert_eq!(
        Baked::from_bytes(&v11).unwrap().near_field,
        plain.near_field
    );
    // A near field sized for other rows, naming a sample past the stored ones, or in a file
    // without sample points is refused by the writer, as the reader would.
    let refuse = |edit: &dyn Fn(&mut Baked)| {
        let mut bad = b.clone();
        edit(&mut bad);
        assert!(bad.to_bytes().is_err());
    };
    row_ptr.push(3);
    refuse(&|b| b.near_field.as_mut().unwrap().row_ptr = row_ptr.clone());
    refuse(&|b| b.near_field.as_mut().unwrap().cols[1] = 14);
    refuse(&|b| b.near_field.as_mut().unwrap().per_row = 1);
    // A sky view for other samples, or one no rays could give.
    refuse(&|b| {
        let near = b.near_field.as_mut().unwrap();
        near.sky.as_mut().unwrap().rows.pop();
    });
    refuse(&|b| {
        let near = b.near_field.as_mut().unwrap();
        near.sky.as_mut().unwrap().rows[3][0] = -1.0;
    });
    // Entries' albedo for other entries, or outside 0 to 1.
    refuse(&|b| {
        b.near_field
            .as_mut()
            .unwrap()
            .albedo
            .as_mut()
            .unwrap()
            .pop();
    });
    refuse(&|b| b.near_field.as_mut().unwrap().albedo.as_mut().unwrap()[2][1] = 1.5);
    // A near field without the samples' view (as versions 4-8 wrote it) still reads.
    let mut without = b.clone();
    without.near_field.as_mut().unwrap().sky = None;
    let bytes_without = without
        .to_bytes()
        .expect("a near field without a sky view encodes");
    assert_eq!(Baked::from_bytes(&bytes_without).unwrap(), without);
    refuse(&|b| {
        b.meta.settings.geometry = bounce_core::voxel::Geometry::VoxelFaces;
        b.surface = None;
        b.elements = None;
    });
    // Every truncation is refused without a panic.
    for cut in (0..bytes.len()).step_by(61) {
        assert!(Baked::from_bytes(&bytes[..cut]).is_err());
    }
}

/// A sky view of `rows` rows, each a different share of its rays escaped upwards and sideways.
fn sample_sky(rows: usize) -> bounce_core::sky::SkyVisibility {
    bounce_core::sky::SkyVisibility {
        rows: (0..rows)
            .map(|i| {
                let mut s = bounce_core::sky::SkySum::default();
                for k in 0..i {
                    s.add(if k % 2 == 0 {
                        glam::Vec3::Y
                    } else {
                        glam::Vec3::X
                    });
                }
                s.finish(rows as u32)
            })
            .collect(),
    }
}

#[test]
fn a_sky_view_round_trips_and_is_checked() {
    // Over the transport's rows: the elements where there are some.
    for mut b in [sample(3, true), element_sample()] {
        let rows = b.transport_layout().len();
        b.sky = Some(sample_sky(rows));
        let bytes = b.to_bytes().expect("a sky sample encodes");
        assert_eq!(Baked::from_bytes(&bytes).unwrap(), b);
        // Laid out as documented: 16 bytes of counts, then 9 f32 a row; flagged optional.
        let (o, l) = section_of(&bytes, b"SKYV");
        assert_eq!(l, 16 + rows * 9 * 4);
        assert_eq!(get_u32(&bytes, o), rows as u32);
        assert_eq!(get_u32(&bytes, o + 4), 9);
        assert_eq!(get_u32(&bytes, entry_at(entry_of(&bytes, b"SKYV")) + 4), 1);
        let last = rows - 1;
        let c00 = f32::from_le_bytes(bytes[o + 16 + last * 36..][..4].try_into().unwrap());
        assert_eq!(c00, b.sky.as_ref().unwrap().rows[last][0]);
        // A corrupted value (resealed, so the check and not the checksum refuses it), a count
        // that does not match the rows, and a version-4 file claiming one are refused.
        for (at, value) in [
            (o + 16 + 4 * 2, f32::NAN.to_bits()),
            (o + 16, 3.0f32.to_bits()),
        ] {
            let mut bad = bytes.clone();
            put_u32(&mut bad, at, value);
            reseal(&mut bad);
            let e = refuse(&bad);
            assert!(matches!(e, FormatError::Sky(_)), "{e:?}");
            assert!(e.to_string().starts_with("section 'SKYV': row 0"), "{e}");
        }
        let mut bad = bytes.clone();
        put_u32(&mut bad, o, rows as u32 + 1);
        reseal(&mut bad);
        assert!(refuse(&bad).to_string().contains("rows, expected"));
        // Unsealed, a flipped bit is the checksum's to find.
        let mut flipped = bytes.clone();
        flipped[o + 20] ^= 1;
        assert!(matches!(
            refuse(&flipped),
            FormatError::SectionChecksum { .. }
        ));
        let mut old = bytes.clone();
        put_u32(&mut old, 8, 4);
        reseal(&mut old);
        assert!(
            refuse(&old)
                .to_string()
                .contains("a version-4 file cannot hold a sky view")
        );
        // The writer refuses a view of other rows, as the reader would.
        let mut wrong = b.clone();
        wrong.sky = Some(sample_sky(rows + 1));
        assert!(wrong.to_bytes().is_err());
        for cut in (0..bytes.len()).step_by(29) {
            assert!(Baked::from_bytes(&bytes[..cut]).is_err());
        }
    }
}

#[test]
fn emitters_round_trip_and_are_checked() {
    use bounce_core::emitter::{EmitterEntry, EmitterGroup, Emitters};
    let mut b = element_sample();
    let rows = b.transport_layout().len();
    let mut row_ptr = vec![0u32; rows + 1];
    for p in row_ptr.iter_mut().skip(1) {
        *p = 1;
    }
    b.emitters = Some(Emitters {
        groups: vec![EmitterGroup {
            name: "Lamp".into(),
            node: Some("Desk".into()),
            color: [1.0, 0.5, 0.25],
            strength: 8.0,
        }],
        row_ptr,
        entries: vec![EmitterEntry {
            group: 0,
            weight: [0.5; 3],
        }],
    });
    let bytes = b.to_bytes().expect("emitters encode");
    assert_eq!(Baked::from_bytes(&bytes).unwrap(), b);
    // Flagged optional: an older reader skips it and keeps the baked emission.
    assert_eq!(get_u32(&bytes, entry_at(entry_of(&bytes, b"EMIT")) + 4), 1);
    let (o, _) = section_of(&bytes, b"EMIT");
    assert_eq!(get_u32(&bytes, o), 1);
    assert_eq!(get_u32(&bytes, o + 4), rows as u32);
    // A count that does not match the rows, and a version-5 file claiming the section.
    let mut bad = bytes.clone();
    put_u32(&mut bad, o + 4, rows as u32 + 1);
    reseal(&mut bad);
    let e = refuse(&bad);
    assert!(matches!(e, FormatError::Emitters(_)), "{e:?}");
    assert!(e.to_string().starts_with("section 'EMIT'"), "{e}");
    let mut old = bytes.clone();
    put_u32(&mut old, 8, 5);
    reseal(&mut old);
    assert!(
        refuse(&old)
            .to_string()
            .contains("a version-5 file cannot hold emitters")
    );
    // Node names (flag bit 0) in a version-9 file, which cannot hold them.
    assert_eq!(get_u32(&bytes, o + 12), 1, "the groups carry their nodes");
    let mut nine = bytes.clone();
    put_u32(&mut nine, 8, 9);
    reseal(&mut nine);
    assert!(matches!(refuse(&nine), FormatError::Reserved { .. }));
    // The writer refuses weights over other rows, as the reader would.
    let mut wrong = b.clone();
    wrong.emitters.as_mut().unwrap().row_ptr.push(1);
    assert!(wrong.to_bytes().is_err());
    for cut in (0..bytes.len()).step_by(31) {
        assert!(Baked::from_bytes(&bytes[..cut]).is_err());
    }
}

#[test]
fn probes_round_trip_and_are_checked() {
    use bounce_core::probe::Probes;
    let mut b = element_sample();
    let rows = b.transport_layout().len() as u32;
    // Two probes: the first's +X direction meets rows 0 and the last, the rest meet nothing.
    let mut row_ptr = vec![0u32, 2];
    row_ptr.extend([2u32; 11]);
    b.probes = Some(Probes {
        spacing: 0.5,
        rays: 64,
        positions: vec![[0.25, 0.5, 0.75], [1.0, 1.0, 1.0]],
        row_ptr,
        cols: vec![0, rows - 1],
        values: vec![0.25, 0.5],
        sky: None,
    });
    let bytes = b.to_bytes().expect("probes encode");
    assert_eq!(Baked::from_bytes(&bytes).unwrap(), b);
    // Flagged optional: an older reader skips it.
    assert_eq!(get_u32(&bytes, entry_at(entry_of(&bytes, b"PROB")) + 4), 1);
    let (o, _) = section_of(&bytes, b"PROB");
    assert_eq!(get_u32(&bytes, o), 2);
    assert_eq!(get_u32(&bytes, o + 4), rows);
    // Another transport's rows, and a version-6 file claiming the section.
    let mut bad = bytes.clone();
    put_u32(&mut bad, o + 4, rows + 1);
    reseal(&mut bad);
    let e = refuse(&bad);
    assert!(matches!(e, FormatError::Probes(_)), "{e:?}");
    assert!(e.to_string().starts_with("section 'PROB'"), "{e}");
    // A probe count the section cannot hold is refused before anything is allocated.
    let mut huge = bytes.clone();
    put_u32(&mut huge, o, u32::MAX / 8);
    reseal(&mut huge);
    assert!(matches!(refuse(&huge), FormatError::Probes(_)));
    let mut old = bytes.clone();
    put_u32(&mut old, 8, 6);
    reseal(&mut old);
    assert!(
        refuse(&old)
            .to_string()
            .contains("a version-6 file cannot hold probes")
    );
    // The writer refuses a gather over rows the file does not have, as the reader would.
    let mut wrong = b.clone();
    wrong.probes.as_mut().unwrap().cols[1] = rows;
    assert!(wrong.to_bytes().is_err());
    for cut in (0..bytes.len()).step_by(31) {
        assert!(Baked::from_bytes(&bytes[..cut]).is_err());
    }
}

/// The probes' view of the sky (`PSKY`, version 8) rides beside `PROB`: it round-trips, is
/// flagged optional (a version-7 reader reads the probes without it), and is refused in a
/// version-7 file, without probes, or over another count of probe directions.
#[test]
fn the_probes_sky_view_round_trips_and_is_checked() {
    use bounce_core::probe::Probes;
    use bounce_core::sky::SkyVisibility;
    let mut b = element_sample();
    let rows = b.transport_layout().len() as u32;
    let mut row_ptr = vec![0u32, 1];
    row_ptr.extend([1u32; 5]);
    let mut sky = SkyVisibility {
        rows: vec![[0.0; 9]; 6],
    };
    // The +Y direction sees the open sky over a third of its rays.
    sky.rows[2][0] = std::f32::consts::PI * 0.282_094_8 / 3.0;
    sky.rows[2][2] = 0.2;
    b.probes = Some(Probes {
        spacing: 0.5,
        rays: 64,
        positions: vec![[0.25, 0.5, 0.75]],
        row_ptr,
        cols: vec![rows - 1],
        values: vec![0.5],
        sky: Some(sky),
    });
    let bytes = b.to_bytes().expect("probes with a sky view encode");
    assert_eq!(Baked::from_bytes(&bytes).unwrap(), b);
    assert_eq!(get_u32(&bytes, entry_at(entry_of(&bytes, b"PSKY")) + 4), 1);
    let (o, _) = section_of(&bytes, b"PSKY");
    assert_eq!(get_u32(&bytes, o), 6, "six probe directions");
    // As a version-7 file, the section is refused by its version, not skipped.
    let mut old = bytes.clone();
    put_u32(&mut old, 8, 7);
    reseal(&mut old);
    let e = refuse(&old);
    assert!(
        e.to_string()
            .contains("a version-7 file cannot hold the probes' sky view"),
        "{e}"
    );
    // Another count of directions.
    let mut bad = bytes.clone();
    put_u32(&mut bad, o, 12);
    reseal(&mut bad);
    assert!(
        refuse(&bad).to_string().contains("PSKY"),
        "{}",
        refuse(&bad)
    );
    // A value no rays could sum to, refused by the writer as by the reader.
    let mut wrong = b.clone();
    wrong.probes.as_mut().unwrap().sky.as_mut().unwrap().rows[0][0] = -1.0;
    assert!(wrong.to_bytes().is_err());
    // With `PROB` renamed to a kind no reader knows (optional, so skipped), the sky view is
    // left without probes, and refused.
    let mut no_probes = bytes.clone();
    let at = entry_at(entry_of(&no_probes, b"PROB"));
    no_probes[at..at + 4].copy_from_slice(b"XXXX");
    reseal(&mut no_probes);
    let e = refuse(&no_probes);
    assert!(e.to_string().contains("without probes"), "{e}");
    for cut in (0..bytes.len()).step_by(31) {
        assert!(Baked::from_bytes(&bytes[..cut]).is_err());
    }
}

/// Files from before the sky view read, without one: a sky then adds nothing to them.
#[test]
fn older_files_read_without_a_sky_view() {
    // As version 4 (the near field's), written without the section.
    let mut b = element_sample().to_bytes().unwrap();
    put_u32(&mut b, 8, 4);
    reseal(&mut b);
    let read = Baked::from_bytes(&b).expect("version 4 is read");
    assert_eq!(read.sky, None);
    // And a real version-3 file an older bounce wrote (the fuzz corpus' seed).
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus/baked_file/cornell-30.bounce");
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(get_u32(&bytes, 8), 3, "the seed is a version-3 file");
    let old = Baked::from_bytes(&bytes).expect("the version-3 seed reads");
    assert!(old.sky.is_none());
    assert!(old.surface.is_some());
}

#[test]
fn a_version_1_file_is_still_read_as_voxel_faces() {
    // A voxel-face bake written as version 1 (what bounce wrote before surface patches), its
    // META without the geometry fields.
    let mut b = sample_bytes();
    put_u32(&mut b, 8, 1);
    reseal(&mut b);
    let read = Baked::from_bytes(&b).expect("version 1 is read");
    assert_eq!(
        read.meta.settings.geometry,
        bounce_core::voxel::Geometry::VoxelFaces
    );
    let json = r#"{"target_patches":500,"requested_voxel_size":null,"rays_per_patch":256,"seed":7,"bounces":"all","tracer":"grid"}"#;
    let old: BakeSettings = serde_json::from_str(json).expect("old settings parse");
    assert_eq!(old.geometry, bounce_core::voxel::Geometry::VoxelFaces);
    assert_eq!(old.direct_samples, 0);
    // A version-1 file cannot hold surface geometry.
    let mut s = surface_sample().to_bytes().unwrap();
    put_u32(&mut s, 8, 1);
    reseal(&mut s);
    assert!(matches!(
        Baked::from_bytes(&s),
        Err(FormatError::Surface(_))
    ));
}

#[test]
fn section_count_u32_max() {
    let mut b = sample_bytes();
    put_u32(&mut b, 12, u32::MAX);
    reseal(&mut b);
    let err = refuse(&b);
    assert!(
        matches!(
            err,
            FormatError::TooManySections {
                count: u32::MAX,
                ..
            }
        ),
        "{err:?}"
    );
}

#[test]
fn section_offset_plus_len_overflows() {
    let mut b = sample_bytes();
    let e = entry_at(entry_of(&b, b"MTRX"));
    let offset = get_u64(&b, e + 8);
    put_u64(&mut b, e + 16, u64::MAX - offset + 1);
    reseal(&mut b);
    let err = refuse(&b);
    assert!(
        matches!(err, FormatError::SectionOverflow { kind, .. } if kind == SectionKind::MTRX),
        "{err:?}"
    );
}

#[test]
fn section_past_the_end_of_the_file() {
    let mut b = sample_bytes();
    let e = entry_at(entry_of(&b, b"MTRX"));
    let offset = get_u64(&b, e + 8);
    put_u64(&mut b, e + 16, 1 << 40);
    reseal(&mut b);
    let err = refuse(&b);
    assert_eq!(
        err.to_string(),
        format!(
            "file truncated: section 'MTRX' ends at byte {} but the file has {} bytes",
            offset + (1 << 40),
            b.len()
        )
    );
}

#[test]
fn overlapping_sections() {
    let mut b = sample_bytes();
    let (layt_at, _) = section_of(&b, b"LAYT");
    let e = entry_at(entry_of(&b, b"META"));
    let meta_at = get_u64(&b, e + 8);
    put_u64(&mut b, e + 16, layt_at as u64 - meta_at + 1);
    reseal(&mut b);
    let err = refuse(&b);
    assert!(
        matches!(err, FormatError::Overlap { first, second }
            if first == SectionKind::META && second == SectionKind::LAYT),
        "{err:?}"
    );
}

#[test]
fn section_inside_the_header_and_misaligned_section() {
    let mut b = sample_bytes();
    let e = entry_at(entry_of(&b, b"META"));
    put_u64(&mut b, e + 8, 0);
    reseal(&mut b);
    assert!(matches!(refuse(&b), FormatError::SectionInHeader { .. }));

    let mut b = sample_bytes();
    let e = entry_at(entry_of(&b, b"FFAC"));
    let (offset, len) = (get_u64(&b, e + 8), get_u64(&b, e + 16));
    put_u64(&mut b, e + 8, offset + 4);
    put_u64(&mut b, e + 16, len - 4);
    reseal(&mut b);
    assert!(matches!(refuse(&b), FormatError::Misaligned { .. }));
}

#[test]
fn duplicate_and_missing_sections() {
    let sections = sample_sections();
    let (k, v) = &sections[0];
    let b = raw_file(&[(k, 0, v), (k, 0, v)]);
    assert!(
        matches!(refuse(&b), FormatError::DuplicateSection { kind } if kind == SectionKind::META)
    );

    let refs: Vec<(&[u8; 4], u32, &[u8])> = sections[..2]
        .iter()
        .map(|(k, v)| (k, 0, v.as_slice()))
        .collect();
    let err = refuse(&raw_file(&refs));
    assert!(matches!(err, FormatError::MissingSection { kind } if kind == SectionKind::MTRX));
    assert_eq!(err.to_string(), "required section 'MTRX' is missing");
}

#[test]
fn unknown_sections_are_skipped_only_when_optional() {
    let sections = sample_sections();
    let extra = b"written by bounce 2".to_vec();
    for (flags, accept) in [(1, true), (0, false), (2, false)] {
        let mut refs: Vec<(&[u8; 4], u32, &[u8])> =
            sections.iter().map(|(k, v)| (k, 0, v.as_slice())).collect();
        refs.insert(2, (b"XTRA", flags, &extra));
        let b = raw_file(&refs);
        match Baked::from_bytes(&b) {
            Ok(baked) => {
                assert!(accept, "flags {flags}");
                assert_eq!(baked, sample(3, true));
            }
            Err(e) => {
                assert!(!accept, "flags {flags}: {e}");
                assert!(matches!(e, FormatError::UnknownSection { .. }), "{e:?}");
            }
        }
    }

    // A known section with a flag this version does not define is refused.
    let refs: Vec<(&[u8; 4], u32, &[u8])> = sections
        .iter()
        .map(|(k, v)| (k, if k == b"LAYT" { 4 } else { 0 }, v.as_slice()))
        .collect();
    assert!(matches!(
        refuse(&raw_file(&refs)),
        FormatError::UnknownFlags { flags: 4, .. }
    ));
}

#[test]
fn layout_claiming_2_pow_31_patches_in_100_bytes() {
    let (_, layt) = sample_sections().swap_remove(1);
    let mut section = layt[..100].to_vec();
    put_u32(&mut section, 28, 1 << 31);
    let err = refuse(&file_with(b"LAYT", section));
    assert!(
        matches!(err, FormatError::PatchCount { count, have: 68, .. } if count == 1 << 31),
        "{err:?}"
    );
}

#[test]
fn layout_shorter_than_its_header() {
    let err = refuse(&file_with(b"LAYT", vec![0; 20]));
    assert!(
        matches!(err, FormatError::SectionTooShort { kind, .. } if kind == SectionKind::LAYT),
        "{err:?}"
    );
}

/// The sample's LAYT with one byte of patch `patch`'s record (at `field`) rewritten.
fn layout_with(patch: usize, field: usize, bytes: &[u8]) -> Vec<u8> {
    let (_, mut layt) = sample_sections().swap_remove(1);
    let at = 32 + patch * PATCH_RECORD_LEN as usize + field;
    layt[at..at + bytes.len()].copy_from_slice(bytes);
    file_with(b"LAYT", layt)
}

#[test]
fn bad_face_code() {
    let err = refuse(&layout_with(3, 12, &[9]));
    assert!(
        matches!(err, FormatError::BadFace { patch: 3, code: 9 }),
        "{err:?}"
    );
    assert_eq!(err.to_string(), "patch 3 has face code 9");
    assert!(matches!(
        refuse(&layout_with(3, 13, &[1])),
        FormatError::NonZeroPadding { .. }
    ));
}

#[test]
fn voxel_outside_the_grid() {
    let err = refuse(&layout_with(2, 8, &3u32.to_le_bytes())); // z = 3 in a grid 2 deep
    assert!(
        matches!(err, FormatError::VoxelOutsideGrid { patch: 2, .. }),
        "{err:?}"
    );
}

#[test]
fn non_finite_floats_and_bad_voxel_size() {
    let err = refuse(&layout_with(4, 20, &f32::NAN.to_le_bytes())); // albedo g
    assert!(
        matches!(&err, FormatError::NotFinite { what } if what == "patch 4 albedo"),
        "{err:?}"
    );
    let err = refuse(&layout_with(0, 52, &f32::INFINITY.to_le_bytes())); // source area
    assert!(matches!(err, FormatError::NotFinite { .. }), "{err:?}");

    let (_, mut layt) = sample_sections().swap_remove(1);
    layt[12..16].copy_from_slice(&(-0.25f32).to_le_bytes());
    assert!(matches!(
        refuse(&file_with(b"LAYT", layt)),
        FormatError::BadVoxelSize(_)
    ));
}

fn sample_mtrx() -> Vec<u8> {
    sample_sections().swap_remove(2).1
}

#[test]
fn matrix_params_length_huge() {
    let mut m = sample_mtrx();
    put_u32(&mut m, 44, u32::MAX);
    let err = refuse(&file_with(b"MTRX", m));
    assert!(
        matches!(err, FormatError::SectionTooShort { kind, what: "matrix params", .. }
            if kind == SectionKind::MTRX),
        "{err:?}"
    );
}

#[test]
fn matrix_payload_length_huge_or_short() {
    let mut m = sample_mtrx();
    put_u64(&mut m, 48, u64::MAX);
    let err = refuse(&file_with(b"MTRX", m));
    assert!(
        matches!(
            err,
            FormatError::SectionTooShort {
                what: "matrix payload",
                ..
            }
        ),
        "{err:?}"
    );

    let mut m = sample_mtrx();
    let len = get_u64(&m, 48);
    put_u64(&mut m, 48, len - 4);
    assert!(matches!(
        refuse(&file_with(b"MTRX", m)),
        FormatError::SectionTooLong { .. }
    ));
}

#[test]
fn matrix_not_matching_the_layout() {
    let mut m = sample_mtrx();
    put_u32(&mut m, 32, 6); // rows
    let err = refuse(&file_with(b"MTRX", m));
    assert!(
        matches!(
            err,
            FormatError::MatrixShape {
                rows: 6,
                patches: 5,
                ..
            }
        ),
        "{err:?}"
    );

    let mut m = sample_sections().swap_remove(3).1;
    put_u32(&mut m, 40, 2); // channels
    let err = refuse(&file_with(b"FFAC", m));
    assert!(
        matches!(err, FormatError::MatrixShape { kind, channels: 2, .. } if kind == SectionKind::FFAC),
        "{err:?}"
    );
}

#[test]
fn matrix_codec_name_and_params_are_checked() {
    for name in [&b"dense\x01f32"[..], b"", b"dense f32"] {
        let mut m = sample_mtrx();
        m[..32].fill(0);
        m[..name.len()].copy_from_slice(name);
        let err = refuse(&file_with(b"MTRX", m));
        assert!(
            matches!(err, FormatError::BadCodecName { .. }),
            "{name:?}: {err:?}"
        );
    }
    let mut m = sample_mtrx();
    m[20] = b'x'; // after the name's terminating zero
    assert!(matches!(
        refuse(&file_with(b"MTRX", m)),
        FormatError::BadCodecName { .. }
    ));

    let mut m = sample_mtrx();
    m[56] = b'['; // params "{}" becomes "[}"
    assert!(matches!(
        refuse(&file_with(b"MTRX", m)),
        FormatError::Json { .. }
    ));
}

#[test]
fn meta_that_is_not_bake_metadata() {
    let err = refuse(&file_with(b"META", b"{\"tool_version\": 3}".to_vec()));
    assert!(
        matches!(err, FormatError::Json { kind, .. } if kind == SectionKind::META),
        "{err:?}"
    );
}

// ---------------------------------------------------------------------------------------------
// The writer refuses what the reader would refuse.

#[test]
fn writer_refuses_invalid_values() {
    let check = |b: Baked, ok: fn(&FormatError) -> bool| {
        let err = b.to_bytes().expect_err("invalid value was written");
        assert!(ok(&err), "{err:?}");
    };
    let mut b = sample(3, false);
    b.layout.patches[2].normal[1] = f32::NAN;
    check(b, |e| matches!(e, FormatError::NotFinite { .. }));

    let mut b = sample(3, false);
    b.layout.patches[0].voxel = [4, 0, 0];
    check(b, |e| {
        matches!(e, FormatError::VoxelOutsideGrid { patch: 0, .. })
    });

    let mut b = sample(3, false);
    b.layout.voxel_size = 0.0;
    check(b, |e| matches!(e, FormatError::BadVoxelSize(_)));

    let mut b = sample(3, false);
    b.layout.patches.pop();
    check(b, |e| matches!(e, FormatError::MatrixShape { .. }));

    let mut b = sample(3, true);
    b.form_factors.as_mut().unwrap().channels = 4;
    check(b, |e| matches!(e, FormatError::MatrixShape { .. }));

    for name in [
        "x".repeat(33),
        String::new(),
        "dense f32".into(),
        "bc1\0".into(),
    ] {
        let mut b = sample(3, false);
        b.transport.codec = name;
        check(b, |e| matches!(e, FormatError::BadCodecName { .. }));
    }

    let mut b = sample(3, false);
    b.meta.stats.row_sum_max = f32::INFINITY;
    check(b, |e| matches!(e, FormatError::Json { .. }));
}

// ---------------------------------------------------------------------------------------------
// Atomic writes.

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn write_atomic_replaces_and_leaves_no_temp_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scene.bounce");
    sample(1, false).write_atomic(&path).unwrap();
    sample(3, true).write_atomic(&path).unwrap();
    assert_eq!(names(dir.path()), ["scene.bounce"]);
    assert_eq!(Baked::read(&path).unwrap(), sample(3, true));
}

#[cfg(unix)]
#[test]
fn write_atomic_gives_the_permissions_of_a_created_file() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let reference = dir.path().join("reference");
    std::fs::File::create(&reference).unwrap();
    let path = dir.path().join("scene.bounce");
    sample(1, false).write_atomic(&path).unwrap();
    let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode();
    assert_eq!(mode(&path), mode(&reference));
}

#[test]
fn write_atomic_failure_keeps_the_old_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scene.bounce");
    sample(3, true).write_atomic(&path).unwrap();
    let good = std::fs::read(&path).unwrap();

    let mut bad = sample(3, true);
    bad.layout.patches[0].albedo[0] = f32::NAN;
    assert!(bad.write_atomic(&path).is_err());
    assert_eq!(std::fs::read(&path).unwrap(), good);
    assert_eq!(names(dir.path()), ["scene.bounce"]);
}

#[test]
fn write_atomic_onto_a_directory_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("scene.bounce");
    std::fs::create_dir(&target).unwrap();
    std::fs::write(target.join("keep"), b"kept").unwrap();
    let err = sample(1, false).write_atomic(&target).unwrap_err();
    assert!(matches!(err, FormatError::Io { .. }), "{err:?}");
    assert!(
        err.to_string().contains(&*target.to_string_lossy()),
        "{err}"
    );
    assert_eq!(
        names(dir.path()),
        ["scene.bounce"],
        "no temporary file left"
    );
    assert_eq!(std::fs::read(target.join("keep")).unwrap(), b"kept");
}

#[test]
fn write_atomic_into_a_missing_directory_names_it() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope");
    let err = sample(1, false)
        .write_atomic(&missing.join("scene.bounce"))
        .unwrap_err();
    assert!(
        err.to_string().contains(&*missing.to_string_lossy()),
        "{err}"
    );
}

#[cfg(unix)]
#[test]
fn write_atomic_into_a_read_only_directory_keeps_the_old_file() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scene.bounce");
    sample(3, true).write_atomic(&path).unwrap();
    let good = std::fs::read(&path).unwrap();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o555)).unwrap();
    let restore = || std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755));

    // Root (as in many containers) ignores directory permissions; nothing to test then.
    let probe = dir.path().join("probe");
    if std::fs::write(&probe, b"").is_ok() {
        std::fs::remove_file(&probe).unwrap();
        restore().unwrap();
        eprintln!("skipped: directory permissions are not enforced for this user");
        return;
    }
    let result = sample(1, false).write_atomic(&path);
    restore().unwrap();
    let err = result.unwrap_err();
    assert!(matches!(err, FormatError::Io { .. }), "{err:?}");
    assert_eq!(std::fs::read(&path).unwrap(), good);
    assert_eq!(names(dir.path()), ["scene.bounce"]);
}

/// A matrix of `n` patches whose payload has `len` bytes of a pattern; the format treats payloads
/// as opaque, so its length need not be what the codec would produce.
fn opaque_matrix(n: usize, channels: u32, params: serde_json::Value, len: usize) -> EncodedMatrix {
    EncodedMatrix {
        codec: "bc1-sparse".into(),
        rows: n as u32,
        cols: n as u32,
        channels,
        params,
        payload: (0..len).map(|i| (i * 31 + len) as u8).collect(),
    }
}

#[test]
fn write_atomic_writes_exactly_to_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scene.bounce");
    let mut values = Vec::new();
    for channels in [1, 3] {
        for with_ff in [false, true] {
            values.push(sample(channels, with_ff));
        }
    }
    // Params of every padding before the payload: none (`"abcdef"` ends the header at byte 64),
    // one byte, and JSON values with no content.
    let params = [
        serde_json::json!({}),
        serde_json::json!(null),
        serde_json::json!(""),
        serde_json::json!("abcdef"),
        serde_json::json!("abcdefg"),
        serde_json::json!({"seed": 7, "perms": [1, 2, 3]}),
    ];
    for (i, params) in params.into_iter().enumerate() {
        for len in [0, 1, 63, 65, 1000 + i] {
            let mut b = sample(3, false);
            b.transport = opaque_matrix(5, 3, params.clone(), len);
            b.form_factors = (len % 2 == 1).then(|| opaque_matrix(5, 1, params.clone(), len + 7));
            values.push(b);
        }
    }
    let mut empty = sample(1, true);
    empty.layout.patches.clear();
    empty.transport = opaque_matrix(0, 1, serde_json::json!({}), 0);
    empty.form_factors = Some(opaque_matrix(0, 3, serde_json::json!(null), 3));
    values.push(empty);

    for (i, baked) in values.iter().enumerate() {
        let bytes = baked.to_bytes().unwrap();
        baked.write_atomic(&path).unwrap();
        assert!(std::fs::read(&path).unwrap() == bytes, "value {i}");
        assert_eq!(&Baked::read(&path).unwrap(), baked, "value {i}");
    }
    assert_eq!(names(dir.path()), ["scene.bounce"]);
}

/// Writing streams the matrices from where they are: neither a matrix payload nor the whole file
/// is ever copied into one buffer.
#[test]
fn write_atomic_makes_no_copy_of_a_large_matrix() {
    let n = 2048;
    let mut baked = sample(3, true);
    baked.layout = sample_layout(n);
    baked.occupancy = None;
    // 48 MiB and 16 MiB, the sizes of dense f32 matrices of 2048 patches.
    baked.transport = opaque_matrix(n, 3, serde_json::json!({"scale": 0.5}), n * n * 12);
    baked.form_factors = Some(opaque_matrix(n, 1, serde_json::json!({}), n * n * 4));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("big.bounce");

    LARGEST.with(|c| c.set(0));
    baked.write_atomic(&path).unwrap();
    let largest = LARGEST.with(|c| c.get());
    eprintln!("largest allocation while writing a 64 MiB file: {largest} bytes");
    assert!(
        largest < 8 << 20,
        "writing allocated {largest} bytes at once for a {}-byte payload",
        baked.transport.payload.len()
    );

    assert!(std::fs::read(&path).unwrap() == baked.to_bytes().unwrap());
}

#[test]
fn reading_what_is_not_a_file_names_the_path() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.bounce");
    let err = Baked::read(&missing).unwrap_err();
    assert!(matches!(err, FormatError::Io { .. }), "{err:?}");
    assert!(
        err.to_string().contains(&*missing.to_string_lossy()),
        "{err}"
    );
    let err = Baked::read(dir.path()).unwrap_err();
    assert!(err.to_string().contains("not a regular file"), "{err}");
    assert!(read_summary(dir.path()).is_err());
}

// ---------------------------------------------------------------------------------------------
// Random values round-trip.

fn finite_f32() -> impl Strategy<Value = f32> {
    any::<f32>().prop_filter("finite", |x| x.is_finite())
}

fn f32x3() -> impl Strategy<Value = [f32; 3]> {
    [finite_f32(), finite_f32(), finite_f32()]
}

fn arb_layout() -> impl Strategy<Value = PatchLayout> {
    ([1u32..6, 1u32..6, 1u32..6], f32x3(), 1.0e-6f32..1.0e3).prop_flat_map(
        |(dims, origin, voxel_size)| {
            let patch = (
                [0..dims[0], 0..dims[1], 0..dims[2]],
                0usize..6,
                (f32x3(), f32x3(), f32x3(), finite_f32(), f32x3()),
            )
                .prop_map(
                    |(voxel, face, (albedo, centroid, normal, source_area, emission))| Patch {
                        voxel,
                        face: Face::ALL[face],
                        albedo,
                        centroid,
                        normal,
                        source_area,
                        emission,
                    },
                );
            prop::collection::vec(patch, 0..7).prop_map(move |patches| PatchLayout {
                origin,
                voxel_size,
                dims,
                patches,
            })
        },
    )
}

fn arb_params() -> impl Strategy<Value = serde_json::Value> {
    (
        any::<i64>(),
        "[a-z0-9 ]{0,12}",
        any::<bool>(),
        prop::collection::vec(any::<u32>(), 0..4),
        any::<f64>().prop_filter("finite", |x| x.is_finite()),
    )
        .prop_map(|(seed, name, sparse, perms, scale)| {
            serde_json::json!({
                "seed": seed, "name": name, "sparse": sparse, "perms": perms, "scale": scale
            })
        })
}

fn arb_matrix(n: usize) -> impl Strategy<Value = EncodedMatrix> {
    (
        prop::sample::select(vec![
            "dense-f32",
            "bc1-sparse",
            "f16",
            "abcdefghijklmnopqrstuvwxyz012345",
        ]),
        prop::sample::select(vec![1u32, 3]),
        arb_params(),
    )
        .prop_flat_map(move |(codec, channels, params)| {
            // Codec payloads are opaque here: any bytes, any length the codec might choose.
            prop::collection::vec(any::<u8>(), 0..(n * n * channels as usize * 4 + 9)).prop_map(
                move |payload| EncodedMatrix {
                    codec: codec.to_string(),
                    rows: n as u32,
                    cols: n as u32,
                    channels,
                    params: params.clone(),
                    payload,
                },
            )
        })
}

fn arb_meta() -> impl Strategy<Value = BakeMeta> {
    (
        "\\PC{0,16}",
        any::<u64>(),
        (finite_f32(), finite_f32(), finite_f32(), finite_f32()),
        prop::option::of(finite_f32()),
        any::<u32>(),
        prop::collection::vec(("[a-z ]{1,10}", 0.0f64..1.0e4), 0..3),
    )
        .prop_map(|(source_name, seed, (a, b, c, d), voxel, k, timings)| {
            let mut meta = sample_meta();
            meta.source_name = source_name;
            meta.settings.seed = seed;
            meta.settings.requested_voxel_size = voxel;
            meta.settings.bounces = if k == 0 { Bounces::All } else { Bounces::K(k) };
            meta.stats.row_sum_min = a;
            meta.stats.row_sum_max = b;
            meta.stats.reciprocity_error = c;
            meta.stats.voxel_size = d;
            meta.timings = timings
                .into_iter()
                .map(|(stage, seconds)| StageTiming { stage, seconds })
                .collect();
            meta.lights = vec![Light::Spot {
                position: [a, b, c],
                direction: [0.0, -1.0, 0.0],
                color: [1.0, 1.0, 1.0],
                intensity: d,
                range: voxel,
                inner_cone_angle: 0.3,
                outer_cone_angle: 0.6,
                name: None,
            }];
            meta
        })
}

/// The patches' voxels plus any others of the grid, ascending.
fn arb_occupancy(layout: &PatchLayout) -> impl Strategy<Value = Vec<u64>> + use<> {
    let [dx, dy, _] = layout.dims.map(u64::from);
    let cells = layout.dims.iter().map(|&d| u64::from(d)).product::<u64>();
    let own: Vec<u64> = layout
        .patches
        .iter()
        .map(|p| {
            let [x, y, z] = p.voxel.map(u64::from);
            x + dx * (y + dy * z)
        })
        .collect();
    prop::collection::vec(0..cells, 0..12).prop_map(move |mut extra| {
        extra.extend_from_slice(&own);
        extra.sort_unstable();
        extra.dedup();
        extra
    })
}

fn arb_baked() -> impl Strategy<Value = Baked> {
    (arb_layout(), arb_meta()).prop_flat_map(|(layout, meta)| {
        let n = layout.len();
        (
            arb_matrix(n),
            prop::option::of(arb_matrix(n)),
            prop::option::of(arb_occupancy(&layout)),
        )
            .prop_map(move |(transport, form_factors, occupancy)| Baked {
                meta: meta.clone(),
                layout: layout.clone(),
                transport,
                form_factors,
                occupancy,
                surface: None,
                elements: None,
                near_field: None,
                sky: None,
                emitters: None,
                probes: None,
                model: None,
            })
    })
}

proptest! {
    #![proptest_config(cases(256))]

    #[test]
    fn random_values_round_trip(baked in arb_baked()) {
        let bytes = baked.to_bytes().unwrap();
        let (back, largest, _) = parse_tracked(&bytes);
        let back = back.unwrap();
        prop_assert_eq!(&back, &baked);
        prop_assert_eq!(back.to_bytes().unwrap(), bytes.clone());
        prop_assert!(largest <= bytes.len(), "allocated {} for a {}-byte file", largest, bytes.len());
    }
}

// ---------------------------------------------------------------------------------------------
// The occupancy section.

/// An `OCCU` section for the sample's grid, written from the documentation.
fn occu_section(count: u64, width: u32, reserved: u32, indices: &[u64]) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend_from_slice(&count.to_le_bytes());
    v.extend_from_slice(&width.to_le_bytes());
    v.extend_from_slice(&reserved.to_le_bytes());
    for &k in indices {
        if width == 8 {
            v.extend_from_slice(&k.to_le_bytes());
        } else {
            v.extend_from_slice(&(k as u32).to_le_bytes());
        }
    }
    v
}

fn occupancy_error(section: Vec<u8>) -> String {
    let err = refuse(&file_with(b"OCCU", section));
    assert!(
        matches!(
            err,
            FormatError::Occupancy(_) | FormatError::Reserved { .. }
        ),
        "{err:?}"
    );
    err.to_string()
}

#[test]
fn a_file_without_occupancy_reads_as_none() {
    let mut baked = sample(3, true);
    baked.occupancy = None;
    let b = baked.to_bytes().unwrap();
    assert_eq!(get_u32(&b, 12), 4, "no OCCU section");
    assert_eq!(Baked::from_bytes(&b).unwrap().occupancy, None);
    // The hand-made equivalent of the sample parses to the sample.
    let occ = occu_section(8, 4, 0, &SAMPLE_OCCUPANCY);
    assert_eq!(
        Baked::from_bytes(&file_with(b"OCCU", occ)).unwrap(),
        sample(3, true)
    );
}

#[test]
fn occupancy_count_not_matching_the_length_is_refused() {
    // A huge count in a small section must not size an allocation.
    let msg = occupancy_error(occu_section(1 << 40, 4, 0, &SAMPLE_OCCUPANCY));
    assert!(msg.contains("claims 1099511627776 voxels"), "{msg}");
    let msg = occupancy_error(occu_section(u64::MAX, 4, 0, &SAMPLE_OCCUPANCY));
    assert!(msg.contains("claims"), "{msg}");
    occupancy_error(occu_section(7, 4, 0, &SAMPLE_OCCUPANCY));
    let mut short = occu_section(8, 4, 0, &SAMPLE_OCCUPANCY);
    short.pop();
    occupancy_error(short);
    let err = refuse(&file_with(b"OCCU", vec![0; 10]));
    assert!(
        matches!(err, FormatError::SectionTooShort { .. }),
        "{err:?}"
    );
}

#[test]
fn occupancy_out_of_order_or_outside_the_grid_is_refused() {
    let msg = occupancy_error(occu_section(8, 4, 0, &[0, 5, 12, 13, 14, 15, 16, 24]));
    assert!(
        msg.contains("voxel index 24 (entry 7) is outside the [4, 3, 2] grid"),
        "{msg}"
    );
    let msg = occupancy_error(occu_section(8, 4, 0, &[5, 0, 12, 13, 14, 15, 16, 23]));
    assert!(
        msg.contains("not strictly ascending at entry 1 (0 after 5)"),
        "{msg}"
    );
    let msg = occupancy_error(occu_section(8, 4, 0, &[0, 12, 12, 13, 14, 15, 16, 23]));
    assert!(msg.contains("not strictly ascending"), "{msg}");
    // Every patch's voxel must be occupied: 12 is patch 0's.
    let msg = occupancy_error(occu_section(7, 4, 0, &[0, 5, 13, 14, 15, 16, 23]));
    assert!(
        msg.contains("patch 0's voxel [0, 0, 1] is not occupied"),
        "{msg}"
    );
}

#[test]
fn occupancy_width_and_reserved_field_are_checked() {
    let msg = occupancy_error(occu_section(8, 8, 0, &SAMPLE_OCCUPANCY));
    assert!(msg.contains("8 bytes wide"), "{msg}");
    occupancy_error(occu_section(8, 2, 0, &SAMPLE_OCCUPANCY));
    occupancy_error(occu_section(0, 0, 0, &[]));
    let err = refuse(&file_with(
        b"OCCU",
        occu_section(8, 4, 1, &SAMPLE_OCCUPANCY),
    ));
    assert!(matches!(err, FormatError::Reserved { .. }), "{err:?}");
}

#[test]
fn occupancy_of_a_grid_beyond_2_pow_32_cells_is_u64() {
    let mut baked = sample(1, false);
    baked.layout.dims = [70_000, 70_000, 2];
    let far = [69_999u32, 69_999, 1];
    baked.layout.patches[4].voxel = far;
    let linear = |v: [u32; 3]| {
        let [x, y, z] = v.map(u64::from);
        x + 70_000 * (y + 70_000 * z)
    };
    let mut occ: Vec<u64> = baked
        .layout
        .patches
        .iter()
        .map(|p| linear(p.voxel))
        .collect();
    occ.sort_unstable();
    occ.dedup();
    assert!(*occ.last().unwrap() > u64::from(u32::MAX));
    baked.occupancy = Some(occ.clone());
    let b = baked.to_bytes().unwrap();
    let (at, len) = section_of(&b, b"OCCU");
    assert_eq!(get_u32(&b, at + 8), 8, "index width");
    assert_eq!(len as u64, OCCUPANCY_HEADER_LEN + 8 * occ.len() as u64);
    assert_eq!(Baked::from_bytes(&b).unwrap(), baked);
}

#[test]
fn writer_refuses_invalid_occupancy() {
    for (occ, want) in [
        (vec![0, 5, 12, 13, 14, 15, 16, 99], "outside"),
        (vec![0, 12, 5, 13, 14, 15, 16], "ascending"),
        (
            vec![12, 13, 14, 15],
            "patch 4's voxel [0, 1, 1] is not occupied",
        ),
    ] {
        let mut b = sample(3, false);
        b.occupancy = Some(occ);
        let err = b.to_bytes().expect_err("invalid occupancy was written");
        assert!(err.to_string().contains(want), "{err}");
    }
}

// ---------------------------------------------------------------------------------------------
// The model (`MODL`): the scene as one GLB, kept for viewers.

/// A small valid GLB: a glTF with no meshes and a 5-byte BIN chunk.
fn tiny_glb() -> Vec<u8> {
    let json = br#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":5}]}"#;
    gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: 0,
        },
        json: json.as_slice().into(),
        bin: Some(b"abcde".as_slice().into()),
    }
    .to_vec()
    .unwrap()
}

#[test]
fn the_model_round_trips_and_is_optional() {
    let dir = tempfile::tempdir().unwrap();
    let mut with = sample(3, false);
    with.model = Some(tiny_glb());
    let path = dir.path().join("with.bounce");
    with.write_atomic(&path).unwrap();
    let back = Baked::read(&path).unwrap();
    assert_eq!(back, with);
    // Flagged optional, exactly the GLB's bytes.
    let bytes = std::fs::read(&path).unwrap();
    let e = entry_at(entry_of(&bytes, b"MODL"));
    assert_eq!(get_u32(&bytes, e + 4), SECTION_OPTIONAL);
    let (o, l) = section_of(&bytes, b"MODL");
    assert_eq!(&bytes[o..o + l], tiny_glb().as_slice());

    // Without it: no section, and the reader gives none.
    let without = sample(3, false);
    let bytes = without.to_bytes().unwrap();
    assert!(read_back_sections(&bytes).iter().all(|k| k != b"MODL"));
    assert_eq!(Baked::from_bytes(&bytes).unwrap().model, None);

    // A file with the model, made by hand from the documented layout, reads too.
    let mut sections: Vec<([u8; 4], u32, Vec<u8>)> = sample_sections()
        .into_iter()
        .map(|(k, v)| (k, u32::from(&k == b"OCCU"), v))
        .collect();
    sections.push((*b"MODL", SECTION_OPTIONAL, tiny_glb()));
    let refs: Vec<(&[u8; 4], u32, &[u8])> = sections
        .iter()
        .map(|(k, f, v)| (k, *f, v.as_slice()))
        .collect();
    let read = Baked::from_bytes(&raw_file(&refs)).unwrap();
    assert_eq!(read.model.as_deref(), Some(tiny_glb().as_slice()));
}

fn read_back_sections(bytes: &[u8]) -> Vec<[u8; 4]> {
    FileSummary::from_bytes(bytes)
        .unwrap()
        .sections
        .iter()
        .map(|s| s.entry.kind.0)
        .collect()
}

#[test]
fn a_corrupt_model_is_refused_clearly() {
    let mut sections: Vec<([u8; 4], u32, Vec<u8>)> = sample_sections()
        .into_iter()
        .map(|(k, v)| (k, u32::from(&k == b"OCCU"), v))
        .collect();
    let mut short = tiny_glb();
    short.truncate(short.len() - 4);
    let mut wrong_len = tiny_glb();
    let n = wrong_len.len() as u32 + 8;
    wrong_len[8..12].copy_from_slice(&n.to_le_bytes());
    for (model, says) in [
        (b"not a GLB at all".to_vec(), "magic"),
        (short, "header says"),
        (wrong_len, "header says"),
        (b"glTF".to_vec(), "truncated"),
    ] {
        sections.retain(|(k, _, _)| k != b"MODL");
        sections.push((*b"MODL", SECTION_OPTIONAL, model));
        let refs: Vec<(&[u8; 4], u32, &[u8])> = sections
            .iter()
            .map(|(k, f, v)| (k, *f, v.as_slice()))
            .collect();
        let e = Baked::from_bytes(&raw_file(&refs)).unwrap_err();
        assert!(matches!(e, FormatError::Model(_)), "{e:?}");
        let msg = e.to_string();
        assert!(msg.contains("'MODL'") && msg.contains(says), "{msg}");
    }
    // The writer refuses what the reader would.
    let mut bad = sample(1, false);
    bad.model = Some(b"nope".to_vec());
    assert!(matches!(bad.to_bytes(), Err(FormatError::Model(_))));
}

#[test]
fn the_samples_albedo_round_trips_and_is_checked() {
    let mut b = element_sample();
    let points = b.surface.as_ref().map_or(0, |s| s.points.len());
    if let Some(s) = &mut b.surface {
        s.albedo = Some((0..points).map(|k| [0.05 * k as f32, 0.5, 0.25]).collect());
    }
    let bytes = b.to_bytes().expect("samples with albedo encode");
    let back = Baked::from_bytes(&bytes).unwrap();
    assert_eq!(back, b);
    // Without it the file is smaller by 12 bytes a sample and reads with none.
    let mut without = b.clone();
    if let Some(s) = &mut without.surface {
        s.albedo = None;
    }
    let plain = without.to_bytes().unwrap();
    assert_eq!(bytes.len(), plain.len() + 12 * points);
    assert_eq!(Baked::from_bytes(&plain).unwrap(), without);
    // An albedo outside [0, 1], or one short, is refused by writer and reader alike.
    let mut bright = b.clone();
    if let Some(a) = bright.surface.as_mut().and_then(|s| s.albedo.as_mut()) {
        a[3] = [1.5, 0.5, 0.5];
    }
    let e = bright.to_bytes().unwrap_err();
    assert!(matches!(e, FormatError::Surface(_)), "{e:?}");
    assert!(
        e.to_string()
            .contains("sample 3's albedo [1.5, 0.5, 0.5] is not within [0, 1]"),
        "{e}"
    );
    let mut short = b.clone();
    if let Some(a) = short.surface.as_mut().and_then(|s| s.albedo.as_mut()) {
        a.pop();
    }
    assert!(matches!(short.to_bytes(), Err(FormatError::Surface(_))));
    // A version-10 file cannot hold it: the flag was reserved then.
    let mut old = bytes.clone();
    put_u32(&mut old, 8, 10);
    reseal(&mut old);
    assert!(matches!(refuse(&old), FormatError::Reserved { .. }));
}

/// Landing samples (version 13): how many of a row's samples are spread by area is written only
/// when some are not, read back, and checked; a version-12 file cannot say it.
#[test]
fn the_area_sample_count_round_trips_and_is_checked() {
    let mut b = element_sample();
    let plain = b.to_bytes().expect("samples all spread by area encode");
    if let Some(s) = &mut b.surface {
        s.area_samples = 1;
    }
    let bytes = b.to_bytes().expect("one landing sample a row encodes");
    assert_eq!(bytes.len(), plain.len() + 4, "one u32 more");
    assert_eq!(Baked::from_bytes(&bytes).unwrap(), b);
    for bad in [0, 3] {
        let mut wrong = b.clone();
        if let Some(s) = &mut wrong.surface {
            s.area_samples = bad;
        }
        let e = wrong.to_bytes().unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "section 'SURF': {bad} of 2 samples per patch spread by area (1 to 2 are \
                 valid)"
            ),
            "{e:?}"
        );
    }
    let mut old = bytes.clone();
    put_u32(&mut old, 8, 12);
    reseal(&mut old);
    assert!(matches!(refuse(&old), FormatError::Reserved { .. }));
}
