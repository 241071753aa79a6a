//! The `EMIT` section (version 6, optional): the scene's emissive materials and each transport
//! row's weights of them ([`crate::emitter::Emitters`]); a shard's `SEMT` section lays out the
//! same over the whole bake (every shard computes all rows' weights from the same layout).
//!
//! Group count u32, row count u32, entry count u32, reserved u32 (0) (16 bytes); per group its
//! colour f32×3, strength f32, name length u32 and the name's UTF-8 bytes, zero-padded to a
//! multiple of 4; then `rows + 1` row offsets u32; then per entry its group u32 and weight f32×3.
//! Checked on reading as [`Emitters::check`] checks: counts against the section's length before
//! any allocation, offsets, groups, weights and names.

use crate::emitter::{EmitterEntry, EmitterGroup, Emitters};

use super::FormatError;
use super::container::{FieldReader, SectionKind};

fn bad(kind: SectionKind, m: impl std::fmt::Display) -> FormatError {
    FormatError::Emitters(format!("section '{kind}': {m}"))
}

/// The section's bytes for a transport of `rows` rows, checked as a reader will check them.
pub(crate) fn encode_emitters(
    kind: SectionKind,
    e: &Emitters,
    rows: usize,
) -> Result<Vec<u8>, FormatError> {
    e.check(rows).map_err(|m| bad(kind, m))?;
    let count = |what, n: usize| {
        u32::try_from(n).map_err(|_| FormatError::TooLarge {
            what,
            value: n as u64,
            max: u64::from(u32::MAX),
        })
    };
    let mut out = Vec::new();
    for v in [
        count("emissive materials", e.groups.len())?,
        count("emitter rows", rows)?,
        count("emitter entries", e.entries.len())?,
        0,
    ] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for g in &e.groups {
        for v in g.color.iter().chain([&g.strength]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&(g.name.len() as u32).to_le_bytes());
        out.extend_from_slice(g.name.as_bytes());
        out.resize(out.len().next_multiple_of(4), 0);
    }
    for p in &e.row_ptr {
        out.extend_from_slice(&p.to_le_bytes());
    }
    for entry in &e.entries {
        out.extend_from_slice(&entry.group.to_le_bytes());
        for w in entry.weight {
            out.extend_from_slice(&w.to_le_bytes());
        }
    }
    Ok(out)
}

/// The emitters of an `EMIT` (or `SEMT`) section over a transport of `rows` rows.
pub(crate) fn decode_emitters(
    kind: SectionKind,
    bytes: &[u8],
    rows: usize,
) -> Result<Emitters, FormatError> {
    let mut r = FieldReader::new(bytes, Some(kind));
    let groups = r.u32("emissive material count")?;
    let stored_rows = r.u32("row count")?;
    let entries = r.u32("entry count")?;
    if r.u32("reserved")? != 0 {
        return Err(FormatError::Reserved {
            what: format!("section '{kind}'"),
        });
    }
    if stored_rows as usize != rows {
        return Err(bad(kind, format!("{stored_rows} rows, expected {rows}")));
    }
    // Each group takes at least 20 bytes, each row 4 and each entry 16: only counts the
    // section's length accounts for may size an allocation.
    let least = u64::from(groups) * 20 + (u64::from(stored_rows) + 1) * 4 + u64::from(entries) * 16;
    if least > bytes.len() as u64 {
        return Err(bad(
            kind,
            format!(
                "{groups} materials, {stored_rows} rows and {entries} entries need at least \
                 {least} bytes, the section holds {}",
                bytes.len()
            ),
        ));
    }
    let mut out = Emitters {
        groups: Vec::with_capacity(groups as usize),
        row_ptr: Vec::with_capacity(stored_rows as usize + 1),
        entries: Vec::with_capacity(entries as usize),
    };
    for i in 0..groups {
        let color = r.f32x3("emitter colour")?;
        let strength = r.f32("emitter strength")?;
        let len = r.u32("emitter name length")?;
        let padded = (len as usize).next_multiple_of(4);
        let name = r.take(padded as u64, "emitter name")?;
        let name = std::str::from_utf8(&name[..len as usize])
            .map_err(|_| bad(kind, format!("material {i}'s name is not UTF-8")))?;
        out.groups.push(EmitterGroup {
            name: name.to_string(),
            color,
            strength,
        });
    }
    for _ in 0..=stored_rows {
        out.row_ptr.push(r.u32("row offset")?);
    }
    for _ in 0..entries {
        let group = r.u32("entry material")?;
        let weight = r.f32x3("entry weight")?;
        out.entries.push(EmitterEntry { group, weight });
    }
    if !r.remaining().is_empty() {
        return Err(bad(
            kind,
            format!("{} bytes after the last entry", r.remaining().len()),
        ));
    }
    out.check(rows).map_err(|m| bad(kind, m))?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Emitters {
        Emitters {
            groups: vec![
                EmitterGroup {
                    name: "Lamp".into(),
                    color: [1.0, 0.9, 0.8],
                    strength: 40.0,
                },
                EmitterGroup {
                    name: "écran".into(),
                    color: [0.0, 0.0, 1.0],
                    strength: 1.0,
                },
            ],
            row_ptr: vec![0, 0, 2, 3],
            entries: vec![
                EmitterEntry {
                    group: 0,
                    weight: [0.5; 3],
                },
                EmitterEntry {
                    group: 1,
                    weight: [0.25, 0.25, 0.2],
                },
                EmitterEntry {
                    group: 1,
                    weight: [1.0; 3],
                },
            ],
        }
    }

    #[test]
    fn emitters_read_back() {
        let kind = SectionKind(*b"EMIT");
        let bytes = encode_emitters(kind, &sample(), 3).unwrap();
        assert_eq!(bytes.len() % 4, 0);
        assert_eq!(decode_emitters(kind, &bytes, 3).unwrap(), sample());
        let none = Emitters {
            row_ptr: vec![0; 4],
            ..Emitters::default()
        };
        let bytes = encode_emitters(kind, &none, 3).unwrap();
        assert_eq!(decode_emitters(kind, &bytes, 3).unwrap(), none);
    }

    #[test]
    fn damaged_sections_are_refused_with_a_reason() {
        let kind = SectionKind(*b"EMIT");
        let bytes = encode_emitters(kind, &sample(), 3).unwrap();
        for len in 0..bytes.len() {
            assert!(decode_emitters(kind, &bytes[..len], 3).is_err(), "{len}");
        }
        assert!(decode_emitters(kind, &bytes, 2).is_err());
        // Counts far beyond the section, a group past the list, a weight over 1, a NaN colour.
        for (at, value) in [(0usize, u32::MAX), (8, 1 << 30)] {
            let mut b = bytes.clone();
            b[at..at + 4].copy_from_slice(&value.to_le_bytes());
            assert!(decode_emitters(kind, &b, 3).is_err(), "byte {at}");
        }
        // The last entry (row 2's only one) names a group past the list.
        let last = bytes.len() - 16;
        let mut b = bytes.clone();
        b[last..last + 4].copy_from_slice(&7u32.to_le_bytes());
        let e = decode_emitters(kind, &b, 3).unwrap_err().to_string();
        assert!(e.contains("names group 7"), "{e}");
        let entries_at = bytes.len() - 3 * 16;
        let mut b = bytes.clone();
        b[entries_at + 4..entries_at + 8].copy_from_slice(&2.0f32.to_le_bytes());
        let e = decode_emitters(kind, &b, 3).unwrap_err().to_string();
        assert!(e.contains("not a share of its area"), "{e}");
        let mut b = bytes.clone();
        b[16..20].copy_from_slice(&f32::NAN.to_le_bytes());
        let e = decode_emitters(kind, &b, 3).unwrap_err().to_string();
        assert!(e.contains("emits nothing usable"), "{e}");
        // A writer refuses what the reader would.
        let mut worse = sample();
        worse.entries[0].weight[0] = -0.5;
        assert!(encode_emitters(kind, &worse, 3).is_err());
    }
}
