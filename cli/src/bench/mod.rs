//! `bounce bench`: benchmark commands that print a table and write CSV, comparing variants
//! measured in one run. Each bake runs in a child process so its peak memory is its own.
//!
//! One file a benchmark, all on the tables of [`table`]: [`bake`] (stages, memory, size per patch
//! count), [`rays`] (the form-factor tracers), [`codecs`], [`engines`], [`direct`] (direct light under
//! moving lights), [`serve`] (the service under load) and [`tradeoff`] (run time against error, with [`plot`]).

mod bake;
mod codecs;
mod direct;
mod engines;
mod plot;
mod rays;
mod serve;
pub mod table;
mod tradeoff;

use anyhow::Result;
use clap::{Args, Subcommand};

#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchWhat,
}

#[derive(Subcommand, Debug)]
pub enum BenchWhat {
    /// Bake one scene at several patch counts: time per stage, peak memory, file size, checks.
    Bake(bake::BenchBakeArgs),
    /// Form-factor ray tracing: the voxel-grid tracer against the obvhs BVH on the same patches.
    Rays(rays::BenchRaysArgs),
    /// Every codec on one baked (dense-f32) transport: bytes, encode and product time, entry and
    /// indirect-irradiance error, side by side; the thesis' reordering table (0, 1, 2 passes, from
    /// the bake's patch order and from a shuffled one); optionally a sparse-share sweep; a plot.
    Codecs(codecs::BenchCodecsArgs),
    /// Relight engines (CPU, GPU) × codecs × batch sizes against the exact solve, with the
    /// thesis' baselines (classic radiosity with F, dense T, compressed T): latency, light sets
    /// per second, effective bandwidth, E_ind error.
    Engines(engines::BenchEnginesArgs),
    /// The lighting service under load on loopback: mixed gRPC and WebSocket viewers, light
    /// changes at a fixed rate on one or more sessions; change-to-frame latency per viewer,
    /// frames per second, order checked on every frame.
    Serve(serve::BenchServeArgs),
    /// Direct light per light set while the lights move, turn, stay put or dim, for several
    /// baked files of one scene side by side (voxel faces as the baseline): the first set from a
    /// scene that keeps nothing, and the later ones.
    Direct(direct::BenchDirectArgs),
    /// Run time against error across patch counts, ray counts and codecs, every error measured
    /// against the path-traced reference on the original triangles: a table, CSV and a plot.
    Tradeoff(tradeoff::BenchTradeoffArgs),
}

pub fn run(args: &BenchArgs) -> Result<()> {
    match &args.what {
        BenchWhat::Bake(a) => bake::run(a),
        BenchWhat::Rays(a) => rays::run(a),
        BenchWhat::Codecs(a) => codecs::run(a),
        BenchWhat::Engines(a) => engines::run(a),
        BenchWhat::Serve(a) => serve::run(a),
        BenchWhat::Tradeoff(a) => tradeoff::run(a),
        BenchWhat::Direct(a) => direct::run(a),
    }
}
