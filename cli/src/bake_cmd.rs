//! `bounce bake`: import, voxelise, trace, transport, write; then a summary.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use bounce_core::bake::{BakeOptions, CodecRequest, bake_file};
use bounce_core::format::Baked;
use bounce_core::formfactor::MAX_RAYS;
use bounce_core::import::pack_glb;
use bounce_core::meta::{BakeStats, Bounces, StageTiming};
use bounce_core::rays::Tracer;
use bounce_core::surface::{DEFAULT_SURFACE_SAMPLES, MAX_SURFACE_SAMPLES};
use bounce_core::voxel::{Geometry, PatchOrder, Resolution};
use clap::{Args, Subcommand};
use serde::{Deserialize, Serialize};

use crate::budget::{Budget, BudgetArgs};
use crate::memory::peak_rss_bytes;
use crate::progress::TermProgress;

/// The codec every bake asks for unless told otherwise (`bake`, `demo`, the first-run `serve`
/// and so the compose bake): the smallest matrix within [`DEFAULT_MAX_ERROR`], which on the
/// Cornell box and pandora is a BC1-class one, not the exact dense-f32 (12 bytes an entry).
pub const DEFAULT_CODEC: &str = "auto";

/// `--max-error`'s default: 1% relative L2 of the indirect irradiance. The method's own error
/// (patches and ray noise against a path-traced reference) is several times that, so the codec
/// adds little to what a viewer sees (README, "Accuracy").
pub const DEFAULT_MAX_ERROR: f64 = 0.01;

/// `--codec NAME` with `--max-error E` as the bake takes them.
pub fn codec_request(codec: &str, max_error: f64) -> CodecRequest {
    if codec == "auto" {
        CodecRequest::Auto { max_error }
    } else {
        CodecRequest::Named(codec.to_string())
    }
}

/// How a log line names a codec request: `bc1`, or `auto (max error 0.01)`.
pub fn codec_request_label(request: &CodecRequest) -> String {
    match request {
        CodecRequest::Named(name) => name.clone(),
        CodecRequest::Auto { max_error } => format!("auto (max error {max_error})"),
    }
}

/// `bounce bake`: a whole bake, or a step of a sharded one.
#[derive(Args, Debug)]
#[command(
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true,
    after_help = crate::shard_cmd::SHARDING_HELP
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
    Transport(crate::shard_cmd::TransportArgs),
    /// The last step of a sharded bake: assemble the shards, encode the transport, write the
    /// baked file.
    Merge(crate::shard_cmd::MergeArgs),
}

#[derive(Args, Debug)]
pub struct BakeArgs {
    // Both required, but `Option`s: the `transport` and `merge` steps parse without them.
    /// The scene: a .gltf (with its .bin and textures beside it) or a .glb file.
    #[arg(required = true)]
    pub scene: Option<PathBuf>,
    /// Where to write the baked file (written atomically: a failed bake leaves no partial file).
    /// With --shard, a FILE.bshard, or else a directory (created) to write ff-I-of-N.bshard in.
    #[arg(short, long, value_name = "OUT.bounce", required = true)]
    pub out: Option<PathBuf>,
    /// Compute only this shard's rows of the form factors (phase 1 of a sharded bake, see
    /// below): I/N is shard I of N (from 0); N alone takes I from JOB_COMPLETION_INDEX.
    #[arg(long, value_name = "I/N|N")]
    pub shard: Option<String>,
    /// Target patch count; the voxel size is searched so that the count lands near it.
    #[arg(
        long,
        value_name = "N",
        conflicts_with = "voxel_size",
        default_value_t = 2000
    )]
    pub patches: u32,
    /// Voxel edge length in scene units, instead of --patches.
    #[arg(long, value_name = "S")]
    pub voxel_size: Option<f32>,
    /// Rays cast from each patch to estimate its form factors.
    #[arg(long, value_name = "R", default_value_t = 2048)]
    pub rays: u32,
    /// Light bounces the transport carries: a number of at least 1, or "all".
    #[arg(long, value_name = "K|all", default_value = "3")]
    pub bounces: Bounces,
    /// Seed of the ray sequences; the same seed gives the same file on any thread count.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// What patches stand for: `surface` (the pieces of real triangles in each voxel, grouped by
    /// the direction they face; rays and shadows against the original triangles) or
    /// `voxel-faces` (the thesis' method, kept as a baseline: patches are voxel faces, rays walk
    /// the voxel occupancy).
    #[arg(long, value_name = "surface|voxel-faces", default_value = "surface")]
    pub geometry: Geometry,
    /// Direct-light sample points stored per patch (surface geometry): where the server
    /// evaluates each light, with shadow rays against the triangles.
    #[arg(long, value_name = "N", default_value_t = DEFAULT_SURFACE_SAMPLES)]
    pub direct_samples: u32,
    /// Ray tracer for voxel-face form factors: `grid` walks the voxel grid (exact for voxel
    /// patches), `bvh` uses an obvhs BVH over the patch quads. `bounce bench rays` compares
    /// them. Surface geometry always traces a BVH over the triangles.
    #[arg(long, default_value = "grid")]
    pub tracer: Tracer,
    /// How the transport is stored: auto (the smallest codec whose indirect-irradiance error
    /// stays within --max-error), or one by name: dense-f32 (exact), dense-f16, bc1 (the thesis
    /// codec), bc4, log8 (bc1's codes without blocks), bc1-resid (BC1 plus residual-chosen f16
    /// corrections).
    #[arg(long, value_name = "NAME|auto", default_value = DEFAULT_CODEC)]
    pub codec: String,
    /// For --codec auto: the largest relative L2 error of the indirect irradiance allowed, over
    /// the bake's probe light sets. The default, 1%, is well under the method's own error.
    #[arg(long, value_name = "E", default_value_t = DEFAULT_MAX_ERROR)]
    pub max_error: f64,
    /// How much carrying the transport in one grey channel (each surface's mean albedo) may
    /// change the indirect irradiance, relative L2 over the bake's probe light sets, before the
    /// bake keeps one channel per colour. One channel takes a third of the transport's time and
    /// size; colour only tints the light's second and later bounces. 0 keeps colour whenever
    /// albedos differ.
    #[arg(long, value_name = "E", default_value_t = bounce_core::transport::DEFAULT_MAX_GREY_ERROR)]
    pub max_grey_error: f64,
    /// Share of entries bc1/bc4/log8/bc1-resid keep exactly [default: 0.04 for bc1, bc4, log8 as the
    /// thesis; 0.08 for bc1-resid].
    #[arg(long, value_name = "S")]
    pub sparse_share: Option<f64>,
    /// Patch numbering (rows and columns of the transport): voxel scan order, or Morton
    /// (Z-order), which keeps nearby patches at nearby indices.
    #[arg(long, value_name = "scan|morton", default_value = "scan")]
    pub patch_order: PatchOrder,
    /// Also store the single-bounce form-factor matrix (doubles the file for k > 1).
    #[arg(long)]
    pub keep_form_factors: bool,
    /// Leave the scene's model out of the baked file. By default it is kept, packed into one
    /// GLB (meshes, materials, textures), so that `bounce serve` can hand it to the browser page.
    #[arg(long)]
    pub no_model: bool,
    /// No progress bars or stage lines; the summary is still printed.
    #[arg(short, long)]
    pub quiet: bool,
    /// Also write the bake's statistics, stage timings and peak memory as JSON here.
    #[arg(long, value_name = "REPORT.json")]
    pub report_json: Option<PathBuf>,
    #[command(flatten)]
    pub budget: BudgetArgs,
}

impl BakeArgs {
    pub fn options(&self) -> Result<BakeOptions> {
        if self.rays == 0 || self.rays > MAX_RAYS {
            bail!("--rays must be from 1 to {MAX_RAYS}, got {}", self.rays);
        }
        if !(1..=MAX_SURFACE_SAMPLES).contains(&self.direct_samples) {
            bail!(
                "--direct-samples must be from 1 to {MAX_SURFACE_SAMPLES}, got {}",
                self.direct_samples
            );
        }
        if !(0.0..=1.0).contains(&self.max_grey_error) {
            bail!(
                "--max-grey-error must be from 0 to 1, got {}",
                self.max_grey_error
            );
        }
        Ok(BakeOptions {
            resolution: match self.voxel_size {
                Some(s) => Resolution::VoxelSize(s),
                None => Resolution::TargetPatches(self.patches),
            },
            rays: self.rays,
            seed: self.seed,
            bounces: self.bounces,
            keep_form_factors: self.keep_form_factors,
            tracer: self.tracer,
            codec: codec_request(&self.codec, self.max_error),
            sparse_share: self.sparse_share,
            patch_order: self.patch_order,
            geometry: self.geometry,
            direct_samples: self.direct_samples,
            max_grey_error: self.max_grey_error,
        })
    }
}

pub fn run(command: &BakeCommand) -> Result<()> {
    match &command.step {
        Some(BakeStep::Transport(args)) => crate::shard_cmd::transport(args),
        Some(BakeStep::Merge(args)) => crate::shard_cmd::merge(args),
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
        let spec = crate::shard_cmd::spec(shard)?;
        return crate::shard_cmd::form_factors(
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
/// an error naming the budget and the stage, and nothing is written (see [`crate::budget`]).
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

pub fn print_summary(baked: &Baked, out: &Path, file_bytes: u64, total_s: f64) {
    let m = &baked.meta;
    let s = &m.stats;
    println!("baked {} ({})", out.display(), human_bytes(file_bytes));
    println!(
        "  patches       {} (voxel size {:.4}, grid {}×{}×{}, {} occupied voxels, {} dropped as seeing nothing)",
        s.patches,
        s.voxel_size,
        baked.layout.dims[0],
        baked.layout.dims[1],
        baked.layout.dims[2],
        s.occupied_voxels,
        s.dropped_patches
    );
    if m.settings.geometry == Geometry::Surface {
        println!(
            "  surface       {} geometry: {:.4} of {:.4} units² ({:.2}%) belongs to no patch; {} \
             direct-light samples a patch",
            m.settings.geometry,
            s.unassigned_area,
            s.surface_area,
            100.0 * s.unassigned_area / s.surface_area.max(f64::MIN_POSITIVE),
            m.settings.direct_samples
        );
    } else {
        println!(
            "  surface       {} geometry (the thesis' baseline)",
            m.settings.geometry
        );
    }
    let share = |k: u64| 100.0 * k as f64 / s.rays.total().max(1) as f64;
    println!(
        "  rays          {} per patch, {} in all: {:.1}% reach a patch, {:.1}% escape, \
         {:.1}% stop on occluders, {:.1}% on back faces",
        m.settings.rays_per_patch,
        s.rays_total,
        share(s.rays.patch),
        share(s.rays.escaped),
        share(s.rays.occluder),
        share(s.rays.back_face)
    );
    println!(
        "  transport     {} bounce(s), {}, codec {}, {}",
        m.settings.bounces,
        channels_line(s.channels, s.grey_rel_l2, m.settings.max_grey_error),
        baked.transport.codec,
        human_bytes(s.matrix_bytes)
    );
    if baked.transport.codec != bounce_core::matrix::DENSE_F32 {
        println!(
            "  codec error   {:.3e} relative L2 of indirect irradiance over {} probe light sets",
            s.codec_eind_rel_l2,
            bounce_core::bake::PROBE_LIGHT_SETS
        );
    }
    println!(
        "  row sums      min {:.4}  max {:.4}  mean {:.4}",
        s.row_sum_min, s.row_sum_max, s.row_sum_mean
    );
    println!(
        "  reciprocity   {:.2}% (area-weighted, from ray noise)",
        s.reciprocity_error * 100.0
    );
    if s.isolated_patches > 0 {
        println!(
            "  isolated      {} patch(es) see no other patch",
            s.isolated_patches
        );
    }
    if let Some(model) = &baked.model {
        println!(
            "  model         {} (the scene as one GLB, for the browser page)",
            human_bytes(model.len() as u64)
        );
    }
    println!(
        "  time          {total_s:.2} s: {}",
        crate::inspect::stage_list(&m.timings)
    );
    if let Some(peak) = peak_rss_bytes() {
        println!("  peak memory   {}", human_bytes(peak));
    }
    crate::inspect::print_import_report(&m.import_report, m.lights.len());
}

pub fn human_bytes(b: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = b as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{b} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

/// What the summary says of the transport's channels: why one, or why three.
fn channels_line(channels: usize, grey_rel_l2: f64, max_grey_error: f64) -> String {
    match (channels, grey_rel_l2 > 0.0) {
        (1, false) => "1 channel (colour cannot change it)".to_string(),
        (1, true) => format!(
            "1 grey channel (colour would change E_ind by {:.2}%, within --max-grey-error {:.2}%)",
            grey_rel_l2 * 100.0,
            max_grey_error * 100.0
        ),
        (c, _) => format!(
            "{c} channels (one grey channel would change E_ind by {:.2}%, over --max-grey-error {:.2}%)",
            grey_rel_l2 * 100.0,
            max_grey_error * 100.0
        ),
    }
}
