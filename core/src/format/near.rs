//! The `NEAR` section (version 4, surface geometry only, optional there): the near-field matrix
//! ([`crate::nearfield::NearField`]) over the transport's rows and the `SURF` sample points.
//!
//! Samples per row u32, row count u32, entry count u32, flags u32 (16 bytes), then `rows + 1`
//! row offsets u32, `entries` sample indices u32 and `entries` shares f32; with flag bit 0 (format
//! version 9), then the samples' sky view: `rows · per_row` times 9 SH coefficients f32, in row
//! order; with flag bit 1 (format version 12), then each entry's albedo, f16×3 (6 bytes an
//! entry, each within `[0, 1]`). A version 4-8 file has no flags (0) and so no view; a file
//! before version 12 may not set bit 1. A shard's `NROW` section is laid out the same over its
//! own rows, with columns over the whole transport.

use crate::nearfield::NearField;
use crate::sky::SkyVisibility;

use super::FormatError;
use super::container::{FieldReader, SectionKind};

/// Bytes before the offsets.
pub const NEAR_HEADER_LEN: u64 = 16;
/// Flag: the samples' sky view follows the shares.
const FLAG_SKY: u32 = 1;
/// Flag: each entry's albedo follows (format version 12).
const FLAG_ALBEDO: u32 = 2;
/// Bytes of one entry's albedo.
const ALBEDO_BYTES: usize = 6;
/// f32s a sample's sky view takes.
const SKY_WORDS: u64 = bounce_types::sh::SH_COEFFICIENTS as u64;

/// The section's bytes for `rows` rows of a transport of `total_rows` rows with `per_row` sample
/// points each, which the matrix is checked against as a reader will check it.
pub(crate) fn encode_near(
    kind: SectionKind,
    near: &NearField,
    rows: usize,
    total_rows: usize,
    per_row: u32,
) -> Result<Vec<u8>, FormatError> {
    near.check(rows, total_rows, per_row)
        .map_err(|m| FormatError::NearField(format!("section '{kind}': {m}")))?;
    let too_large = |what, value: usize| FormatError::TooLarge {
        what,
        value: value as u64,
        max: u64::from(u32::MAX),
    };
    let rows = u32::try_from(near.rows()).map_err(|_| too_large("near-field rows", near.rows()))?;
    let nnz = u32::try_from(near.nnz()).map_err(|_| too_large("near-field entries", near.nnz()))?;
    let sky = near.sky.as_ref().map_or(&[][..], |s| &s.rows[..]);
    let albedo = near.albedo.as_deref().unwrap_or(&[]);
    let mut out = Vec::with_capacity(
        NEAR_HEADER_LEN as usize
            + 4 * (near.row_ptr.len() + 2 * near.nnz() + 9 * sky.len())
            + ALBEDO_BYTES * albedo.len(),
    );
    let flags = if near.sky.is_some() { FLAG_SKY } else { 0 }
        | if near.albedo.is_some() {
            FLAG_ALBEDO
        } else {
            0
        };
    for v in [near.per_row, rows, nnz, flags] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in near.row_ptr.iter().chain(&near.cols) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in near.values.iter().chain(sky.iter().flatten()) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    // The bake rounds each entry's albedo to f16 itself, so what it measured is what is read.
    for &c in albedo.iter().flatten() {
        out.extend_from_slice(&half::f16::from_f32(c).to_le_bytes());
    }
    Ok(out)
}

/// The matrix of a `NEAR` (or `NROW`) section holding `rows` rows of a transport of
/// `total_rows` rows with `per_row` sample points each; `entry_albedo` says whether the file's
/// version may keep each entry's albedo (12 on).
pub(crate) fn decode_near(
    kind: SectionKind,
    bytes: &[u8],
    rows: usize,
    total_rows: usize,
    per_row: u32,
    entry_albedo: bool,
) -> Result<NearField, FormatError> {
    let bad = |m: String| FormatError::NearField(format!("section '{kind}': {m}"));
    let mut r = FieldReader::new(bytes, Some(kind));
    let stored_per_row = r.u32("samples per row")?;
    let stored_rows = r.u32("row count")?;
    let nnz = r.u32("entry count")?;
    let flags = r.u32("flags")?;
    let known = if entry_albedo {
        FLAG_SKY | FLAG_ALBEDO
    } else {
        FLAG_SKY
    };
    if flags & !known != 0 {
        return Err(FormatError::Reserved {
            what: format!("section '{kind}' flags"),
        });
    }
    let with_albedo = flags & FLAG_ALBEDO != 0;
    if stored_rows as usize != rows {
        return Err(bad(format!("{stored_rows} rows, expected {rows}")));
    }
    let rest = r.remaining();
    // Only counts the section's length accounts for may size an allocation.
    let sky_samples = if flags & FLAG_SKY != 0 {
        u64::from(stored_rows) * u64::from(stored_per_row)
    } else {
        0
    };
    // In u128: rows × samples a row × 9 words can pass u64 in a hostile header.
    let words_len = 4 * (u128::from(stored_rows) + 1 + 2 * u128::from(nnz))
        + 4 * u128::from(SKY_WORDS) * u128::from(sky_samples);
    let albedo_len = if with_albedo {
        ALBEDO_BYTES as u128 * u128::from(nnz)
    } else {
        0
    };
    let want = words_len + albedo_len;
    if want != rest.len() as u128 {
        return Err(bad(format!(
            "{stored_rows} rows, {nnz} entries{} and {sky_samples} samples' sky views need \
             {want} bytes, the section holds {}",
            if with_albedo { " with albedo" } else { "" },
            rest.len()
        )));
    }
    let (rest, albedo) = rest.split_at(words_len as usize);
    let words: Vec<[u8; 4]> = rest
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect();
    let (ptr, tail) = words.split_at(rows + 1);
    let (cols, tail) = tail.split_at(nnz as usize);
    let (values, sky) = tail.split_at(nnz as usize);
    let near = NearField {
        per_row: stored_per_row,
        row_ptr: ptr.iter().map(|&w| u32::from_le_bytes(w)).collect(),
        cols: cols.iter().map(|&w| u32::from_le_bytes(w)).collect(),
        values: values.iter().map(|&w| f32::from_le_bytes(w)).collect(),
        sky: (flags & FLAG_SKY != 0).then(|| SkyVisibility {
            rows: sky
                .chunks_exact(SKY_WORDS as usize)
                .map(|c| std::array::from_fn(|k| f32::from_le_bytes(c[k])))
                .collect(),
        }),
        albedo: with_albedo.then(|| {
            albedo
                .chunks_exact(ALBEDO_BYTES)
                .map(|c| {
                    std::array::from_fn(|k| {
                        half::f16::from_le_bytes([c[2 * k], c[2 * k + 1]]).to_f32()
                    })
                })
                .collect()
        }),
    };
    near.check(rows, total_rows, per_row).map_err(bad)?;
    Ok(near)
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::nearfield::test_field as field;

    #[test]
    fn a_near_field_reads_back() {
        let kind = SectionKind(*b"NEAR");
        let bytes = encode_near(kind, &field(), 2, 2, 2).unwrap();
        assert_eq!(decode_near(kind, &bytes, 2, 2, 2, true).unwrap(), field());
        assert_eq!(bytes.len() as u64, field().stored_bytes());
        // With each entry's albedo (version 12): read back as written, f16 and all.
        let mut with = field();
        with.albedo = Some(vec![[0.25, 0.5, 1.0], [0.0, 0.1, 0.2], [0.7; 3]]);
        let bytes = encode_near(kind, &with, 2, 2, 2).unwrap();
        assert_eq!(bytes.len() as u64, with.stored_bytes());
        let back = decode_near(kind, &bytes, 2, 2, 2, true).unwrap();
        let f16 = |x: f32| half::f16::from_f32(x).to_f32();
        let rounded: Vec<[f32; 3]> = with.albedo.iter().flatten().map(|a| a.map(f16)).collect();
        assert_eq!(back.albedo, Some(rounded));
        // A reader of a version before 12 refuses the flag.
        let e = decode_near(kind, &bytes, 2, 2, 2, false).unwrap_err();
        assert!(matches!(e, FormatError::Reserved { .. }), "{e}");
        // Every truncation is refused.
        for len in 0..bytes.len() {
            assert!(
                decode_near(kind, &bytes[..len], 2, 2, 2, true).is_err(),
                "{len}"
            );
        }
    }

    #[test]
    fn damaged_sections_are_refused_with_a_reason() {
        let kind = SectionKind(*b"NEAR");
        let bytes = encode_near(kind, &field(), 2, 2, 2).unwrap();
        // Every truncation, and every count changed, is refused, never a panic.
        for len in 0..bytes.len() {
            assert!(
                decode_near(kind, &bytes[..len], 2, 2, 2, true).is_err(),
                "{len}"
            );
        }
        for at in [0, 4, 8, 12] {
            let mut b = bytes.clone();
            b[at] ^= 0x40;
            assert!(decode_near(kind, &b, 2, 2, 2, true).is_err(), "byte {at}");
        }
        // A header claiming the most samples a row with a sky view: refused by its length.
        let mut b = bytes.clone();
        b[0..4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(decode_near(kind, &b, 2, 2, 2, true).is_err());
        // Row 1's column past the samples, found by the check.
        let mut b = bytes.clone();
        let col = NEAR_HEADER_LEN as usize + 3 * 4 + 2 * 4;
        b[col..col + 4].copy_from_slice(&9u32.to_le_bytes());
        let e = decode_near(kind, &b, 2, 2, 2, true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("past"), "{e}");
        // A writer refuses what the reader would.
        let mut bad = field();
        bad.values[2] = -1.0;
        assert!(encode_near(kind, &bad, 2, 2, 2).is_err());
    }
}
