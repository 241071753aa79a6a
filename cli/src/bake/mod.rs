//! `bounce bake`: import, voxelise, trace, transport, write; then a summary. A whole bake, or a
//! step of a sharded one.
//!
//! The folder, bottom up: [`summary`] (what a bake prints), [`budget`] (`--max-seconds`,
//! `--max-memory`), [`args`] (the options and the codec request), [`job`] (one bake, scene to
//! file), [`shard`] (the sharded steps); this file parses the command and runs one of them.

pub mod args;
pub mod budget;
pub mod job;
pub mod shard;
pub mod summary;

use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};

pub use args::{BakeArgs, DEFAULT_CODEC, DEFAULT_MAX_ERROR, codec_request, codec_request_label};
pub use job::{BakeReport, bake, bake_within};

use crate::memory::peak_rss_bytes;

/// `bounce bake`: a whole bake, or a step of a sharded one.
#[derive(Args, Debug)]
#[command(
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true,
    after_help = shard::SHARDING_HELP
)]
pub struct BakeCommand {
    #[command(subcommand)]
    pub step: Option<BakeStep>,
    #[command(flatten)]
    pub args: BakeArgs,
}

/// The steps of a sharded bake after the first (which is `bounce bake SCENE --shard I/N`).
#[derive(Subcommand, Debug)]
pub enum BakeStep {
    /// Phase 2 of a sharded bake: this shard's rows of the transport, from every phase-1 shard.
    Transport(shard::TransportArgs),
    /// The last step of a sharded bake: assemble the shards, encode the transport, write the
    /// baked file.
    Merge(shard::MergeArgs),
}

pub fn run(command: &BakeCommand) -> Result<()> {
    match &command.step {
        Some(BakeStep::Transport(args)) => shard::transport(args),
        Some(BakeStep::Merge(args)) => shard::merge(args),
        None => run_bake(&command.args),
    }
}

fn run_bake(args: &BakeArgs) -> Result<()> {
    // clap requires both; a missing one here is a bug in the parser's setup.
    let (Some(scene), Some(out)) = (&args.scene, &args.out) else {
        bail!("bake needs a SCENE and -o OUT");
    };
    if let Some(shard) = &args.shard {
        if args.report_json.is_some() {
            bail!("--report-json describes a whole bake; a shard prints its own summary");
        }
        let spec = shard::spec(shard)?;
        return shard::form_factors(
            scene,
            out,
            &args.options()?,
            spec,
            !args.no_model,
            args.quiet,
            args.budget.budget()?,
        );
    }
    let start = Instant::now();
    let baked = bake_within(
        scene,
        out,
        &args.options()?,
        !args.no_model,
        args.quiet,
        args.budget.budget()?,
    )?;
    if let Some(path) = &args.report_json {
        let report = BakeReport {
            wall_seconds: start.elapsed().as_secs_f64(),
            peak_rss_bytes: peak_rss_bytes(),
            file_bytes: std::fs::metadata(out).map(|m| m.len()).unwrap_or(0),
            stats: baked.meta.stats.clone(),
            timings: baked.meta.timings.clone(),
        };
        std::fs::write(path, serde_json::to_vec_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
