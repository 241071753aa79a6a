//! What a shard of a sharded bake says about itself (the `SHRD` section): which phase and rows it
//! holds, the settings and source of the bake it belongs to, its ray tallies and timings. The
//! pipeline that computes and merges shards is [`crate::bake::shard`]; this is only what the file
//! records, so the format reads it without the pipeline.

use std::ops::Range;

use serde::{Deserialize, Serialize};

use crate::formfactor::FormFactorStats;
use crate::meta::{BakeSettings, SourceInfo, StageTiming};
use crate::rays::RayTally;
use crate::transport::ROW_BLOCK;

/// File extension of shards; a directory given to a step stands for its `*.bshard` files.
pub const SHARD_EXTENSION: &str = "bshard";

/// Which rows a shard holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Phase {
    /// Phase 1: rows of the form factors `F`.
    FormFactors,
    /// Phase 2: rows of the transport `T`.
    Transport,
}

impl Phase {
    pub fn name(self) -> &'static str {
        match self {
            Phase::FormFactors => "form-factor (phase 1)",
            Phase::Transport => "transport (phase 2)",
        }
    }

    /// The file name a shard of this phase gets inside an output directory.
    pub fn file_name(self, spec: ShardSpec) -> String {
        let stem = match self {
            Phase::FormFactors => "ff",
            Phase::Transport => "t",
        };
        format!(
            "{stem}-{:05}-of-{:05}.{SHARD_EXTENSION}",
            spec.index, spec.count
        )
    }
}

/// The form factors a phase-2 shard computed from: its statistics (which the baked file records)
/// and a checksum of all of `F`, so the merge can tell shards computed from different `F`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FormFactorSummary {
    pub stats: FormFactorStats,
    /// CRC-32 of `F` as little-endian f32, row-major.
    pub crc32: u32,
}

/// A shard's metadata (the `SHRD` section).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardMeta {
    pub phase: Phase,
    pub index: u32,
    pub count: u32,
    pub first_row: usize,
    pub end_row: usize,
    /// Rows (and columns) of the transport: the elements, or the patches of a voxel-face bake.
    pub patches: usize,
    /// Channels of the rows: 1 for form factors; the transport's 1 or 3.
    pub channels: usize,
    /// Phase 2: how much one grey channel changes `E_ind` (`BakeStats::grey_rel_l2`).
    #[serde(default)]
    pub grey_rel_l2: f64,
    /// Phase 2: `BakeStats::grey_tail_rel_l2`.
    #[serde(default)]
    pub grey_tail_rel_l2: Option<f64>,
    /// The `bounce-core` version that wrote it: shards of one bake must come from one build.
    pub tool_version: String,
    pub settings: BakeSettings,
    pub keep_form_factors: bool,
    pub source: SourceInfo,
    pub occupied_voxels: usize,
    pub dropped_patches: usize,
    /// The scene's surface area and the part that belongs to no patch (see `BakeStats`).
    #[serde(default)]
    pub surface_area: f64,
    #[serde(default)]
    pub unassigned_area: f64,
    /// Where the rays ended: this shard's rows in phase 1, the whole bake's in phase 2.
    pub rays: RayTally,
    /// Phase 2: the form factors it was computed from.
    pub form_factors: Option<FormFactorSummary>,
    /// Phase 2: the stage times of phase 1, summed over its shards.
    pub inherited_timings: Vec<StageTiming>,
    /// This shard's own stage times.
    pub timings: Vec<StageTiming>,
}

/// Shard `index` of `count`: which part of a sharded bake a process computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShardSpec {
    pub index: u32,
    pub count: u32,
}

/// The rows shard `index` of `count` owns among `n`. Shards own whole blocks of the transport
/// ([`ROW_BLOCK`] rows, its unit of work: a shard starting inside a block would compute all of
/// it) when there are at least as many blocks as shards; with fewer, rows are split evenly.
/// Either way the ranges of `0..count` cover `0..n` in order without overlap.
pub fn shard_rows(n: usize, index: u32, count: u32) -> Range<usize> {
    if count == 0 {
        return 0..0;
    }
    let (i, c) = (u64::from(index), u64::from(count));
    // index, count < 2^32 and n, blocks < 2^32 (the format's patch count), so no overflow.
    let split = |units: u64, k: u64| (k.min(c) * units / c) as usize;
    let blocks = n.div_ceil(ROW_BLOCK) as u64;
    if blocks >= c {
        let at = |k| (split(blocks, k) * ROW_BLOCK).min(n);
        at(i)..at(i + 1)
    } else {
        split(n as u64, i)..split(n as u64, i + 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_rows_cover_every_row_once_in_order() {
        for n in [0usize, 1, 5, 255, 256, 257, 400, 767, 768, 1000, 5000] {
            for count in 1..=9u32 {
                let ranges: Vec<_> = (0..count).map(|i| shard_rows(n, i, count)).collect();
                assert_eq!(ranges[0].start, 0, "n {n}, count {count}");
                assert_eq!(ranges.last().unwrap().end, n, "n {n}, count {count}");
                for w in ranges.windows(2) {
                    assert_eq!(w[0].end, w[1].start, "n {n}, count {count}: {ranges:?}");
                }
                let blocks = n.div_ceil(ROW_BLOCK);
                if blocks >= count as usize {
                    // Whole blocks, and every shard gets at least one.
                    for r in &ranges {
                        assert_eq!(r.start % ROW_BLOCK, 0, "n {n}, count {count}: {ranges:?}");
                        assert!(!r.is_empty(), "n {n}, count {count}: {ranges:?}");
                    }
                } else {
                    // Even split: sizes differ by at most one row.
                    let sizes: Vec<_> = ranges.iter().map(|r| r.len()).collect();
                    let (lo, hi) = (sizes.iter().min().unwrap(), sizes.iter().max().unwrap());
                    assert!(hi - lo <= 1, "n {n}, count {count}: {sizes:?}");
                }
            }
        }
    }
}
