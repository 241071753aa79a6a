//! The `EMIT` section (version 6, optional): the scene's emissive materials and each transport
//! row's weights of them ([`crate::emitter::Emitters`]); a shard's `SEMT` section lays out the
//! same over the whole bake (every shard computes all rows' weights from the same layout).
//!
//! Group count u32, row count u32, entry count u32, flags u32 (16 bytes); per group its
//! colour f32×3, strength f32, name length u32 and the name's UTF-8 bytes, zero-padded to a
//! multiple of 4, and with flag bit 0 (version 10) its node's name the same way; then `rows + 1`
//! row offsets u32; then per entry its group u32 and weight f32×3. Before version 10 the flags
//! were a reserved 0, and such a file's groups have no node.
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
    let nodes = e.groups.iter().any(|g| g.node.is_some());
    let mut out = Vec::new();
    for v in [
        count("emissive materials", e.groups.len())?,
        count("emitter rows", rows)?,
        count("emitter entries", e.entries.len())?,
        if nodes { NODE_NAMES } else { 0 },
    ] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let name = |out: &mut Vec<u8>, name: &str| {
        out.extend_from_slice(&(name.len() as u32).to_le_bytes());
        out.extend_from_slice(name.as_bytes());
        out.resize(out.len().next_multiple_of(4), 0);
    };
    for g in &e.groups {
        for v in g.color.iter().chain([&g.strength]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        name(&mut out, &g.name);
        if let Some(node) = &g.node {
            name(&mut out, node);
        }
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

/// The flag saying that each group carries its node's name.
const NODE_NAMES: u32 = 1;

/// The emitters of an `EMIT` (or `SEMT`) section over a transport of `rows` rows; `nodes` when
/// the file's version may carry the groups' nodes (10 on).
pub(crate) fn decode_emitters(
    kind: SectionKind,
    bytes: &[u8],
    rows: usize,
    nodes: bool,
) -> Result<Emitters, FormatError> {
    let mut r = FieldReader::new(bytes, Some(kind));
    let groups = r.u32("emissive material count")?;
    let stored_rows = r.u32("row count")?;
    let entries = r.u32("entry count")?;
    let flags = r.u32("flags")?;
    let allowed = if nodes { NODE_NAMES } else { 0 };
    if flags & !allowed != 0 {
        return Err(FormatError::Reserved {
            what: format!("section '{kind}' (flags {flags:#x})"),
        });
    }
    let has_nodes = flags & NODE_NAMES != 0;
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
        let mut name = |what: &str| -> Result<String, FormatError> {
            let len = r.u32("emitter name length")?;
            let padded = (len as usize).next_multiple_of(4);
            let name = r.take(padded as u64, "emitter name")?;
            std::str::from_utf8(&name[..len as usize])
                .map(str::to_string)
                .map_err(|_| bad(kind, format!("group {i}'s {what} name is not UTF-8")))
        };
        let material = name("material")?;
        let node = if has_nodes { Some(name("node")?) } else { None };
        out.groups.push(EmitterGroup {
            name: material,
            node,
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
                    node: Some("Desk".into()),
                    color: [1.0, 0.9, 0.8],
                    strength: 40.0,
                },
                EmitterGroup {
                    name: "écran".into(),
                    node: Some("node #3".into()),
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
        assert_eq!(decode_emitters(kind, &bytes, 3, true).unwrap(), sample());
        let none = Emitters {
            row_ptr: vec![0; 4],
            ..Emitters::default()
        };
        let bytes = encode_emitters(kind, &none, 3).unwrap();
        assert_eq!(decode_emitters(kind, &bytes, 3, true).unwrap(), none);
    }

    #[test]
    fn groups_without_nodes_read_as_older_files_wrote_them() {
        let kind = SectionKind(*b"EMIT");
        let mut old = sample();
        for g in &mut old.groups {
            g.node = None;
        }
        let bytes = encode_emitters(kind, &old, 3).unwrap();
        assert_eq!(&bytes[12..16], &[0; 4], "no flag");
        assert_eq!(decode_emitters(kind, &bytes, 3, false).unwrap(), old);
        assert_eq!(decode_emitters(kind, &bytes, 3, true).unwrap(), old);
        // Some groups with a node and some without is no file.
        let mut mixed = sample();
        mixed.groups[1].node = None;
        assert!(encode_emitters(kind, &mixed, 3).is_err());
    }

    #[test]
    fn damaged_sections_are_refused_with_a_reason() {
        let kind = SectionKind(*b"EMIT");
        let bytes = encode_emitters(kind, &sample(), 3).unwrap();
        for len in 0..bytes.len() {
            assert!(
                decode_emitters(kind, &bytes[..len], 3, true).is_err(),
                "{len}"
            );
        }
        assert!(decode_emitters(kind, &bytes, 2, true).is_err());
        // Counts far beyond the section, a group past the list, a weight over 1, a NaN colour.
        for (at, value) in [(0usize, u32::MAX), (8, 1 << 30)] {
            let mut b = bytes.clone();
            b[at..at + 4].copy_from_slice(&value.to_le_bytes());
            assert!(decode_emitters(kind, &b, 3, true).is_err(), "byte {at}");
        }
        // The last entry (row 2's only one) names a group past the list.
        let last = bytes.len() - 16;
        let mut b = bytes.clone();
        b[last..last + 4].copy_from_slice(&7u32.to_le_bytes());
        let e = decode_emitters(kind, &b, 3, true).unwrap_err().to_string();
        assert!(e.contains("names group 7"), "{e}");
        let entries_at = bytes.len() - 3 * 16;
        let mut b = bytes.clone();
        b[entries_at + 4..entries_at + 8].copy_from_slice(&2.0f32.to_le_bytes());
        let e = decode_emitters(kind, &b, 3, true).unwrap_err().to_string();
        assert!(e.contains("not a share of its area"), "{e}");
        let mut b = bytes.clone();
        b[16..20].copy_from_slice(&f32::NAN.to_le_bytes());
        let e = decode_emitters(kind, &b, 3, true).unwrap_err().to_string();
        assert!(e.contains("emits nothing usable"), "{e}");
        // Node names in a file whose version cannot hold them.
        let e = decode_emitters(kind, &bytes, 3, false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("flags 0x1"), "{e}");
        // A writer refuses what the reader would.
        let mut worse = sample();
        worse.entries[0].weight[0] = -0.5;
        assert!(encode_emitters(kind, &worse, 3).is_err());
    }
}
