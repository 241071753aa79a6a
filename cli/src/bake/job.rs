//! One bake, scene to file: packed model, budget, progress, the atomic write and the summary.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use bounce_core::bake::{BakeOptions, bake_file};
use bounce_core::format::Baked;
use bounce_core::import::pack_glb;
use bounce_core::meta::{BakeStats, StageTiming};
use serde::{Deserialize, Serialize};

use super::budget::Budget;
use super::summary::print_summary;
use crate::progress::TermProgress;

/// What `--report-json` writes, and `bounce bench bake` reads back.
#[derive(Debug, Serialize, Deserialize)]
pub struct BakeReport {
    /// Bake and write, as the process saw it.
    pub wall_seconds: f64,
    pub peak_rss_bytes: Option<u64>,
    pub file_bytes: u64,
    pub stats: BakeStats,
    pub timings: Vec<StageTiming>,
}

/// The scene at `path` packed into one GLB, for the baked file to keep.
pub fn pack_model(path: &Path) -> Result<Vec<u8>> {
    pack_glb(path).with_context(|| {
        format!(
            "packing the model of {} into the baked file (fix the file, or bake with --no-model \
             to leave the model out)",
            path.display()
        )
    })
}

/// Bake `scene` into `out` and print the summary. With `keep_model` the file keeps the scene,
/// packed into one GLB.
pub fn bake(
    scene: &Path,
    out: &Path,
    options: &BakeOptions,
    keep_model: bool,
    quiet: bool,
) -> Result<Baked> {
    bake_within(scene, out, options, keep_model, quiet, Budget::default())
}

/// [`bake`] within `budget` (`--max-seconds`, `--max-memory`): over it, the process ends with
/// an error naming the budget and the stage, and nothing is written (see [`super::budget`]).
pub fn bake_within(
    scene: &Path,
    out: &Path,
    options: &BakeOptions,
    keep_model: bool,
    quiet: bool,
    budget: Budget,
) -> Result<Baked> {
    let start = Instant::now();
    let progress = TermProgress::new(quiet);
    let watched = budget.watch(&progress);
    let mut baked = bake_file(scene, options, &watched)
        .with_context(|| format!("baking {}", scene.display()))?;
    // After the bake, so that a file that is not a scene gets the importer's error; by now the
    // files it names have been read once, so packing rarely fails.
    watched.step("pack model");
    baked.model = keep_model.then(|| pack_model(scene)).transpose()?;
    watched.disarm();
    let write_start = Instant::now();
    baked
        .write_atomic(out)
        .with_context(|| format!("writing {}", out.display()))?;
    let write_s = write_start.elapsed().as_secs_f64();
    baked.meta.timings.push(StageTiming {
        stage: "write".to_string(),
        seconds: write_s,
    });
    if !quiet {
        eprintln!("{:>14}  {write_s:8.2} s", "write");
    }
    let file_bytes = std::fs::metadata(out).map(|m| m.len()).unwrap_or(0);
    print_summary(&baked, out, file_bytes, start.elapsed().as_secs_f64());
    Ok(baked)
}
