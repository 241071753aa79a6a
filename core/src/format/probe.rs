//! The `PROB` section (version 7, optional): the bake's irradiance probes and their gather
//! matrix ([`crate::probe::Probes`]).
//!
//! Probe count u32, row count u32 (the transport's), entry count u32, rays a direction u32,
//! spacing f32, reserved u32 (0) (24 bytes); then per probe its position f32×3; then
//! `6 · probes + 1` row offsets u32; then per entry its transport row u32; then per entry its
//! value f32. Checked on reading as [`Probes::check`] checks, counts against the section's
//! length before any allocation.
//!
//! A shard's `PROW` section (a sharded bake with probes) holds its range of gather rows
//! ([`ProbeRows`]): probe count u32, row count u32 (the transport's), entry count u32, rays a
//! direction u32, spacing f32, first gather row u32, end gather row u32, reserved u32 (0) (32
//! bytes); then every probe's position f32×3; then `end − first + 1` row offsets u32; the
//! entries' rows u32 and values f32; then per gather row held its sky view, 9 f32.

use bounce_types::sh::SH_COEFFICIENTS;

use crate::probe::{DIRECTIONS, ProbeRows, Probes};
use crate::sky::SkyVisibility;

use super::FormatError;
use super::container::{FieldReader, SectionKind};

/// The section's fixed header, bytes.
pub const PROBE_HEADER_LEN: usize = 24;

fn bad(m: impl std::fmt::Display) -> FormatError {
    FormatError::Probes(format!("section 'PROB': {m}"))
}

/// The section's bytes for a transport of `rows` rows, checked as a reader will check them.
pub(crate) fn encode_probes(p: &Probes, rows: usize) -> Result<Vec<u8>, FormatError> {
    p.check(rows).map_err(bad)?;
    let mut out =
        Vec::with_capacity(PROBE_HEADER_LEN + p.len() * 12 + p.row_ptr.len() * 4 + p.nnz() * 8);
    for v in [
        count("probes", p.len())?,
        count("probe rows", rows)?,
        count("probe entries", p.nnz())?,
        p.rays,
    ] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&p.spacing.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    write_gathers(&mut out, &p.positions, &p.row_ptr, &p.cols, &p.values);
    Ok(out)
}

/// Positions, row offsets, entries' rows and values, as both sections lay them out.
fn write_gathers(
    out: &mut Vec<u8>,
    positions: &[[f32; 3]],
    row_ptr: &[u32],
    cols: &[u32],
    values: &[f32],
) {
    for v in positions.iter().flatten() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in row_ptr.iter().chain(cols) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// What [`write_gathers`] wrote, for `probes` probes, `rows` gather rows and `entries` entries;
/// the caller has checked the counts against the section's length.
struct Gathers {
    positions: Vec<[f32; 3]>,
    row_ptr: Vec<u32>,
    cols: Vec<u32>,
    values: Vec<f32>,
}

fn read_gathers(
    r: &mut FieldReader<'_>,
    probes: u32,
    rows: u64,
    entries: u32,
) -> Result<Gathers, FormatError> {
    let mut g = Gathers {
        positions: Vec::with_capacity(probes as usize),
        row_ptr: Vec::with_capacity(rows as usize + 1),
        cols: Vec::with_capacity(entries as usize),
        values: Vec::with_capacity(entries as usize),
    };
    for _ in 0..probes {
        g.positions.push(r.f32x3("probe position")?);
    }
    for _ in 0..=rows {
        g.row_ptr.push(r.u32("probe row offset")?);
    }
    for _ in 0..entries {
        g.cols.push(r.u32("probe entry row")?);
    }
    for _ in 0..entries {
        g.values.push(r.f32("probe entry value")?);
    }
    Ok(g)
}

/// The probes of a `PROB` section over a transport of `rows` rows.
pub(crate) fn decode_probes(bytes: &[u8], rows: usize) -> Result<Probes, FormatError> {
    let kind = SectionKind::PROB;
    let mut r = FieldReader::new(bytes, Some(kind));
    let probes = r.u32("probe count")?;
    let stored_rows = r.u32("row count")?;
    let entries = r.u32("entry count")?;
    let rays = r.u32("rays a direction")?;
    let spacing = r.f32("probe spacing")?;
    if r.u32("reserved")? != 0 {
        return Err(FormatError::Reserved {
            what: format!("section '{kind}'"),
        });
    }
    if stored_rows as usize != rows {
        return Err(bad(format!("{stored_rows} rows, expected {rows}")));
    }
    let gathers = u64::from(probes) * DIRECTIONS as u64;
    // Only counts the section's length accounts for may size an allocation.
    let need = u64::from(probes) * 12 + (gathers + 1) * 4 + u64::from(entries) * 8;
    if need != r.remaining().len() as u64 {
        return Err(bad(format!(
            "{probes} probes and {entries} entries take {need} bytes after the header, the \
             section holds {}",
            r.remaining().len()
        )));
    }
    let g = read_gathers(&mut r, probes, gathers, entries)?;
    let out = Probes {
        spacing,
        rays,
        positions: g.positions,
        row_ptr: g.row_ptr,
        cols: g.cols,
        values: g.values,
        // In its own section (`PSKY`), read beside this one.
        sky: None,
    };
    out.check(rows).map_err(bad)?;
    Ok(out)
}

/// A shard's gather rows.
pub(crate) const PROW: SectionKind = SectionKind(*b"PROW");

/// The `PROW` section's fixed header, bytes.
pub const PROBE_ROWS_HEADER_LEN: usize = 32;

fn bad_rows(m: impl std::fmt::Display) -> FormatError {
    FormatError::Probes(format!("section 'PROW': {m}"))
}

fn count(what: &'static str, n: usize) -> Result<u32, FormatError> {
    u32::try_from(n).map_err(|_| FormatError::TooLarge {
        what,
        value: n as u64,
        max: u64::from(u32::MAX),
    })
}

/// A shard's `PROW` bytes for a transport of `rows` rows, checked as a reader will check them.
pub(crate) fn encode_probe_rows(p: &ProbeRows, rows: usize) -> Result<Vec<u8>, FormatError> {
    p.check(rows).map_err(bad_rows)?;
    let mut out = Vec::with_capacity(
        PROBE_ROWS_HEADER_LEN
            + p.positions.len() * 12
            + p.row_ptr.len() * 4
            + p.cols.len() * 8
            + p.range.len() * SH_COEFFICIENTS * 4,
    );
    for v in [
        count("probes", p.positions.len())?,
        count("probe rows", rows)?,
        count("probe entries", p.cols.len())?,
        p.rays,
    ] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&p.spacing.to_le_bytes());
    for v in [
        count("gather rows", p.range.start)?,
        count("gather rows", p.range.end)?,
        0,
    ] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    write_gathers(&mut out, &p.positions, &p.row_ptr, &p.cols, &p.values);
    for v in p.sky.rows.iter().flatten() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    Ok(out)
}

/// The gather rows of a shard's `PROW` section over a transport of `rows` rows.
pub(crate) fn decode_probe_rows(bytes: &[u8], rows: usize) -> Result<ProbeRows, FormatError> {
    let mut r = FieldReader::new(bytes, Some(PROW));
    let probes = r.u32("probe count")?;
    let stored_rows = r.u32("row count")?;
    let entries = r.u32("entry count")?;
    let rays = r.u32("rays a direction")?;
    let spacing = r.f32("probe spacing")?;
    let first = r.u32("first gather row")?;
    let end = r.u32("end gather row")?;
    if r.u32("reserved")? != 0 {
        return Err(FormatError::Reserved {
            what: "section 'PROW'".to_string(),
        });
    }
    if stored_rows as usize != rows {
        return Err(bad_rows(format!("{stored_rows} rows, expected {rows}")));
    }
    let gathers = u64::from(probes) * DIRECTIONS as u64;
    if first > end || u64::from(end) > gathers {
        return Err(bad_rows(format!(
            "gather rows {first}..{end} of {probes} probes' {gathers}"
        )));
    }
    let held = u64::from(end - first);
    // Only counts the section's length accounts for may size an allocation.
    let need = u64::from(probes) * 12
        + (held + 1) * 4
        + u64::from(entries) * 8
        + held * SH_COEFFICIENTS as u64 * 4;
    if need != r.remaining().len() as u64 {
        return Err(bad_rows(format!(
            "{probes} probes, {held} gather rows and {entries} entries take {need} bytes after \
             the header, the section holds {}",
            r.remaining().len()
        )));
    }
    let g = read_gathers(&mut r, probes, held, entries)?;
    let mut out = ProbeRows {
        spacing,
        rays,
        positions: g.positions,
        range: first as usize..end as usize,
        row_ptr: g.row_ptr,
        cols: g.cols,
        values: g.values,
        sky: SkyVisibility {
            rows: Vec::with_capacity(held as usize),
        },
    };
    for _ in 0..held {
        let mut c = [0.0f32; SH_COEFFICIENTS];
        for v in &mut c {
            *v = r.f32("probe sky coefficient")?;
        }
        out.sky.rows.push(c);
    }
    out.check(rows).map_err(bad_rows)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Probes {
        let mut row_ptr = vec![0, 2];
        row_ptr.extend([3; 11]);
        Probes {
            spacing: 0.5,
            rays: 8,
            positions: vec![[1.0, 2.0, 3.0], [-1.0, 0.5, 0.0]],
            row_ptr,
            cols: vec![0, 3, 1],
            values: vec![0.125, 0.5, 0.875],
            sky: None,
        }
    }

    #[test]
    fn probes_round_trip() {
        let p = sample();
        let bytes = encode_probes(&p, 4).unwrap();
        assert_eq!(bytes.len(), PROBE_HEADER_LEN + 2 * 12 + 13 * 4 + 3 * 8);
        assert_eq!(decode_probes(&bytes, 4).unwrap(), p);
    }

    #[test]
    fn a_shards_rows_round_trip_and_join() {
        let mut p = sample();
        p.sky = Some(SkyVisibility {
            rows: (0..12)
                .map(|i| [0.01 * i as f32; SH_COEFFICIENTS])
                .collect(),
        });
        let parts: Vec<ProbeRows> = [0..1, 1..7, 7..12]
            .into_iter()
            .map(|range| {
                let part = p.rows(range).unwrap();
                let bytes = encode_probe_rows(&part, 4).unwrap();
                let back = decode_probe_rows(&bytes, 4).unwrap();
                assert_eq!(back, part);
                back
            })
            .collect();
        assert_eq!(ProbeRows::join(parts.clone()).unwrap(), p);
        // Parts out of order, short of the end, or of another placement do not join.
        let e = ProbeRows::join([parts[1].clone(), parts[0].clone()]).unwrap_err();
        assert!(e.contains("follow"), "{e}");
        let e = ProbeRows::join(parts[..2].to_vec()).unwrap_err();
        assert!(e.contains("end at"), "{e}");
        let mut moved = parts.clone();
        moved[2].positions[0][0] += 1.0;
        let e = ProbeRows::join(moved).unwrap_err();
        assert!(e.contains("different probes"), "{e}");
        // A damaged section is refused before anything is allocated.
        let bytes = encode_probe_rows(&parts[1], 4).unwrap();
        assert!(decode_probe_rows(&bytes, 5).is_err(), "another transport");
        assert!(decode_probe_rows(&bytes[..bytes.len() - 4], 4).is_err());
        let mut past = bytes.clone();
        past[24..28].copy_from_slice(&13u32.to_le_bytes());
        let e = decode_probe_rows(&past, 4).unwrap_err().to_string();
        assert!(e.contains("gather rows"), "{e}");
    }

    #[test]
    fn a_damaged_section_is_refused() {
        let bytes = encode_probes(&sample(), 4).unwrap();
        assert!(decode_probes(&bytes, 5).is_err(), "another transport");
        assert!(
            decode_probes(&bytes[..bytes.len() - 4], 4).is_err(),
            "short"
        );
        // A probe count the bytes cannot hold is refused before anything is allocated.
        let mut huge = bytes.clone();
        huge[0..4].copy_from_slice(&u32::MAX.to_le_bytes());
        let e = decode_probes(&huge, 4).unwrap_err().to_string();
        assert!(e.contains("take"), "{e}");
        // A row past the transport's.
        let mut past = bytes.clone();
        let at = PROBE_HEADER_LEN + 2 * 12 + 13 * 4 + 4;
        past[at..at + 4].copy_from_slice(&9u32.to_le_bytes());
        let e = decode_probes(&past, 4).unwrap_err().to_string();
        assert!(e.contains("past the last"), "{e}");
        let mut reserved = bytes;
        reserved[20] = 1;
        assert!(decode_probes(&reserved, 4).is_err());
    }
}
