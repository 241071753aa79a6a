//! The sharded bake's command line: `bounce bake SCENE --shard I/N` (phase 1),
//! `bounce bake transport` (phase 2) and `bounce bake merge`. The steps themselves are
//! `bounce_core::shard`; this module resolves the shard index, names output files, shows
//! progress and prints what each step did.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use bounce_core::bake::BakeOptions;
use bounce_core::bake::shard::{self, Phase, ShardSpec};
use bounce_core::format::ShardFile;
use bounce_core::meta::StageTiming;
use clap::Args;

use super::budget::{Budget, BudgetArgs};
use super::summary::{human_bytes, print_summary, stage_list};
use crate::memory::peak_rss_bytes;
use crate::progress::TermProgress;

/// The environment variable a Kubernetes Indexed Job sets to each pod's index.
pub const COMPLETION_INDEX_ENV: &str = "JOB_COMPLETION_INDEX";

/// Help shared by the sharded steps.
pub const SHARDING_HELP: &str = "\
Sharded bake (for a cluster; the result is bit for bit the one-process bake's, timings aside):
  1. bounce bake SCENE --shard I/N -o ff/ [bake options]    rows of the form factors, per shard
  2. bounce bake transport --shard I/M -o t/ ff/             rows of the transport, per shard
  3. bounce bake merge t/ -o SCENE.bounce                     assemble and encode the transport
--shard N alone takes the index from JOB_COMPLETION_INDEX (a Kubernetes Indexed Job sets it).
Shards count from 0. An -o that does not end in .bshard is a directory: the shard is named
there by phase and index. Phase 2 needs every phase-1 shard, M need not equal N, and `merge` of phase-1 shards
computes the transport itself (fine for one bounce or few patches). Every step checks that its
shards are one bake's, each exactly once.";

/// `--shard`'s value resolved against the job's index.
pub fn spec(arg: &str) -> Result<ShardSpec> {
    let env = std::env::var(COMPLETION_INDEX_ENV).ok();
    Ok(ShardSpec::parse(arg, env.as_deref())?)
}

/// Where a shard goes: `out` itself when it names a `.bshard` file, else a file named by phase
/// and index inside the directory `out` (created), so that every pod of a job can be given the
/// same `-o`.
fn shard_path(out: &Path, phase: Phase, spec: ShardSpec) -> Result<PathBuf> {
    if out.extension().is_some_and(|e| e == shard::SHARD_EXTENSION) {
        return Ok(out.to_path_buf());
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    Ok(out.join(phase.file_name(spec)))
}

/// Phase 1: this shard's rows of the form factors of `scene`. With `keep_model` the shard
/// carries the scene packed into one GLB; phase 2 passes it on and the merge keeps it.
pub fn form_factors(
    scene: &Path,
    out: &Path,
    options: &BakeOptions,
    spec: ShardSpec,
    keep_model: bool,
    quiet: bool,
    budget: Budget,
) -> Result<()> {
    let start = Instant::now();
    let path = shard_path(out, Phase::FormFactors, spec)?;
    let progress = TermProgress::new(quiet);
    let watched = budget.watch(&progress);
    let mut file = shard::form_factor_shard(scene, options, spec, &watched).with_context(|| {
        format!(
            "baking form-factor shard {}/{} of {}",
            spec.index,
            spec.count,
            scene.display()
        )
    })?;
    // After the shard's import, as in a whole bake, so a bad scene gets the importer's error.
    watched.step("pack model");
    file.model = keep_model
        .then(|| super::job::pack_model(scene))
        .transpose()?;
    watched.disarm();
    write(&file, &path, quiet, start)
}

#[derive(Args, Debug)]
#[command(after_help = SHARDING_HELP)]
pub struct TransportArgs {
    /// Every phase-1 shard of the bake (files, or directories of *.bshard files).
    #[arg(required = true, value_name = "FF_SHARDS")]
    pub inputs: Vec<PathBuf>,
    /// This shard: I/N (shard I of N, from 0), or N with the index from JOB_COMPLETION_INDEX.
    #[arg(long, value_name = "I/N|N")]
    pub shard: String,
    /// Where to write the shard: a FILE.bshard, or else a directory (created) to write
    /// t-I-of-N.bshard in.
    #[arg(short, long, value_name = "OUT")]
    pub out: PathBuf,
    /// No progress bars or stage lines; the summary is still printed.
    #[arg(short, long)]
    pub quiet: bool,
    #[command(flatten)]
    pub budget: BudgetArgs,
}

/// Phase 2: this shard's rows of the transport, from all of the form factors.
pub fn transport(args: &TransportArgs) -> Result<()> {
    let start = Instant::now();
    let spec = spec(&args.shard)?;
    let path = shard_path(&args.out, Phase::Transport, spec)?;
    let progress = TermProgress::new(args.quiet);
    let watched = args.budget.budget()?.watch(&progress);
    let file = shard::transport_shard(&args.inputs, spec, &watched)
        .with_context(|| format!("baking transport shard {}/{}", spec.index, spec.count))?;
    watched.disarm();
    write(&file, &path, args.quiet, start)
}

#[derive(Args, Debug)]
#[command(after_help = SHARDING_HELP)]
pub struct MergeArgs {
    /// Every shard of the last phase that ran: phase 2's, or phase 1's (then the transport is
    /// computed here). Files, or directories of *.bshard files.
    #[arg(required = true, value_name = "SHARDS")]
    pub inputs: Vec<PathBuf>,
    /// Where to write the baked file (atomically).
    #[arg(short, long, value_name = "OUT.bounce")]
    pub out: PathBuf,
    /// No progress bars or stage lines; the summary is still printed.
    #[arg(short, long)]
    pub quiet: bool,
    #[command(flatten)]
    pub budget: BudgetArgs,
}

/// The last step: assemble, encode (the codec's global steps run here) and write.
pub fn merge(args: &MergeArgs) -> Result<()> {
    let start = Instant::now();
    let progress = TermProgress::new(args.quiet);
    let watched = args.budget.budget()?.watch(&progress);
    let mut baked = shard::merge(&args.inputs, &watched).context("merging the shards")?;
    watched.disarm();
    let write_start = Instant::now();
    baked
        .write_atomic(&args.out)
        .with_context(|| format!("writing {}", args.out.display()))?;
    let write_s = write_start.elapsed().as_secs_f64();
    baked.meta.timings.push(StageTiming {
        stage: "write".to_string(),
        seconds: write_s,
    });
    if !args.quiet {
        eprintln!("{:>14}  {write_s:8.2} s", "write");
    }
    let file_bytes = std::fs::metadata(&args.out).map(|m| m.len()).unwrap_or(0);
    print_summary(&baked, &args.out, file_bytes, start.elapsed().as_secs_f64());
    println!("  (stage times of a merged bake are sums over its shards)");
    Ok(())
}

fn write(file: &ShardFile, path: &Path, quiet: bool, start: Instant) -> Result<()> {
    let write_start = Instant::now();
    file.write_atomic(path)
        .with_context(|| format!("writing {}", path.display()))?;
    if !quiet {
        eprintln!(
            "{:>14}  {:8.2} s",
            "write",
            write_start.elapsed().as_secs_f64()
        );
    }
    let m = &file.header.meta;
    let bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    println!(
        "shard {}/{} ({} rows) {} ({})",
        m.index,
        m.count,
        m.phase.name(),
        path.display(),
        human_bytes(bytes)
    );
    println!(
        "  rows          {}..{} of {} patches, {} channel(s)",
        m.first_row, m.end_row, m.patches, m.channels
    );
    println!(
        "  time          {:.2} s: {}",
        start.elapsed().as_secs_f64(),
        stage_list(&m.timings)
    );
    if let Some(peak) = peak_rss_bytes() {
        println!("  peak memory   {}", human_bytes(peak));
    }
    Ok(())
}
