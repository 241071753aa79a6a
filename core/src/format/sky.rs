//! The `SKYV` section (version 5, optional): each transport row's view of the sky
//! ([`crate::sky::SkyVisibility`]), and a shard's `SROW` section, laid out the same over the
//! shard's rows.
//!
//! Row count u32, coefficients per row u32 (9), reserved u32 (0) ×2 (16 bytes), then per row its
//! 9 coefficients `c_lm` f32. Checked on reading: the row count is the transport's (or the
//! shard's), and every value is finite and within what the rays could sum to.

use bounce_types::sh::SH_COEFFICIENTS;

use crate::sky::SkyVisibility;

use super::FormatError;
use super::container::{FieldReader, SectionKind};

/// Bytes before the coefficients.
pub const SKY_HEADER_LEN: u64 = 16;

fn bad(kind: SectionKind, m: impl std::fmt::Display) -> FormatError {
    FormatError::Sky(format!("section '{kind}': {m}"))
}

/// The section's bytes for `rows` rows, checked as a reader will check them.
pub(crate) fn encode_sky(
    kind: SectionKind,
    sky: &SkyVisibility,
    rows: usize,
) -> Result<Vec<u8>, FormatError> {
    sky.check(rows).map_err(|m| bad(kind, m))?;
    let count = u32::try_from(rows).map_err(|_| FormatError::TooLarge {
        what: "sky-visibility rows",
        value: rows as u64,
        max: u64::from(u32::MAX),
    })?;
    let mut out = Vec::with_capacity(SKY_HEADER_LEN as usize + rows * SH_COEFFICIENTS * 4);
    for v in [count, SH_COEFFICIENTS as u32, 0, 0] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in sky.rows.iter().flatten() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    Ok(out)
}

/// The sky view of a `SKYV` (or `SROW`) section holding `rows` rows.
pub(crate) fn decode_sky(
    kind: SectionKind,
    bytes: &[u8],
    rows: usize,
) -> Result<SkyVisibility, FormatError> {
    let mut r = FieldReader::new(bytes, Some(kind));
    let stored_rows = r.u32("row count")?;
    let per_row = r.u32("coefficients per row")?;
    if r.u32("reserved")? != 0 || r.u32("reserved")? != 0 {
        return Err(FormatError::Reserved {
            what: format!("section '{kind}'"),
        });
    }
    if per_row as usize != SH_COEFFICIENTS {
        return Err(bad(
            kind,
            format!("{per_row} coefficients a row, this build reads {SH_COEFFICIENTS} (order 2)"),
        ));
    }
    if stored_rows as usize != rows {
        return Err(bad(kind, format!("{stored_rows} rows, expected {rows}")));
    }
    let rest = r.remaining();
    // Only a count the section's length accounts for may size an allocation.
    let want = u64::from(stored_rows) * SH_COEFFICIENTS as u64 * 4;
    if want != rest.len() as u64 {
        return Err(bad(
            kind,
            format!(
                "{stored_rows} rows need {want} bytes of coefficients, the section holds {}",
                rest.len()
            ),
        ));
    }
    let sky = SkyVisibility {
        rows: rest
            .chunks_exact(SH_COEFFICIENTS * 4)
            .map(|row| {
                std::array::from_fn(|k| {
                    f32::from_le_bytes([row[4 * k], row[4 * k + 1], row[4 * k + 2], row[4 * k + 3]])
                })
            })
            .collect(),
    };
    sky.check(rows).map_err(|m| bad(kind, m))?;
    Ok(sky)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sky::SkySum;

    fn sample() -> SkyVisibility {
        let mut a = SkySum::default();
        a.add(glam::Vec3::Y);
        a.add(glam::Vec3::new(0.6, 0.0, 0.8));
        SkyVisibility {
            rows: vec![a.finish(4), SkySum::default().finish(4)],
        }
    }

    #[test]
    fn a_sky_view_reads_back() {
        let kind = SectionKind(*b"SKYV");
        let bytes = encode_sky(kind, &sample(), 2).unwrap();
        assert_eq!(bytes.len(), 16 + 2 * 9 * 4);
        assert_eq!(decode_sky(kind, &bytes, 2).unwrap(), sample());
    }

    #[test]
    fn damaged_sections_are_refused_with_a_reason() {
        let kind = SectionKind(*b"SKYV");
        let bytes = encode_sky(kind, &sample(), 2).unwrap();
        for len in 0..bytes.len() {
            assert!(decode_sky(kind, &bytes[..len], 2).is_err(), "{len}");
        }
        for at in [0, 4, 8, 12] {
            let mut b = bytes.clone();
            b[at] ^= 0x40;
            assert!(decode_sky(kind, &b, 2).is_err(), "byte {at}");
        }
        assert!(decode_sky(kind, &bytes, 3).is_err());
        // A NaN and a coefficient beyond what any rays sum to.
        for value in [f32::NAN, 2.0] {
            let mut b = bytes.clone();
            let at = SKY_HEADER_LEN as usize + 4 * 3;
            b[at..at + 4].copy_from_slice(&value.to_le_bytes());
            let e = decode_sky(kind, &b, 2).unwrap_err().to_string();
            assert!(e.contains("row 0, coefficient 3"), "{e}");
        }
        // A writer refuses what the reader would.
        let mut worse = sample();
        worse.rows[1][0] = -1.0;
        assert!(encode_sky(kind, &worse, 2).is_err());
    }
}
