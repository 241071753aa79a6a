//! The bake's options on the command line, and how they become core's [`BakeOptions`].

use std::path::PathBuf;

use anyhow::{Result, bail};
use bounce_core::bake::{BakeOptions, CodecRequest};
use bounce_core::formfactor::MAX_RAYS;
use bounce_core::meta::{AllBounces, Bounces};
use bounce_core::nearfield::{DEFAULT_NEAR_RADIUS, MAX_NEAR_RADIUS};
use bounce_core::probe::ProbeOptions;
use bounce_core::rays::Tracer;
use bounce_core::surface::{DEFAULT_SURFACE_SAMPLES, MAX_SURFACE_SAMPLES, default_landing_samples};
use bounce_core::voxel::{Geometry, PatchOrder, Resolution};
use clap::Args;

use super::budget::BudgetArgs;

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
    /// Light bounces the transport carries: "all" (what a path tracer or a camera sees) or a
    /// number of at least 1. Three leave out the rest: 12% of the Cornell box's indirect light
    /// and 8% of `pandora`'s (under a corridor light), more in brighter rooms.
    #[arg(long, value_name = "K|all", default_value = "all")]
    pub bounces: Bounces,
    /// How --bounces all sums them: `clustered` (the first three exactly, the rest on clusters
    /// of 2×2×2 voxels or coarser, one per face direction; seconds) or `exact` (one LU
    /// factorisation of the whole system in f64: its time and memory grow as rows³ and rows²,
    /// minutes and gigabytes at 10,000 rows).
    #[arg(long, value_name = "clustered|exact", default_value = "clustered")]
    pub all_bounces: AllBounces,
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
    /// evaluates each light, with shadow rays against the triangles. More resolve the shadow
    /// edges inside a patch: on `pandora` 128 took a sun's error from 11.6% to 9.7% for about
    /// twice the CPU's direct light per set (with more than 32 by area, a patch traces every
    /// fourth first and leaves the rest dark where none of those is reached).
    #[arg(long, value_name = "N", default_value_t = DEFAULT_SURFACE_SAMPLES)]
    pub direct_samples: u32,
    /// How many of those --direct-samples to place where near-field rays land (where surfaces
    /// meet and shadows start) rather than spread by area: they sharpen the near field's
    /// correction and cost no more rays. The rest, spread by area, make each patch's mean.
    /// Needs a near field; less than --direct-samples. Default: a quarter of them.
    #[arg(long, value_name = "K")]
    pub landing_samples: Option<u32>,
    /// Near-field first bounce (surface geometry): form-factor rays that land within R voxels
    /// of where they start also record the direct-light sample point they land nearest, and a
    /// relight gathers the light there rather than the element's mean (docs/design.md §4).
    /// 0 stores none.
    #[arg(long, value_name = "R", default_value_t = DEFAULT_NEAR_RADIUS)]
    pub near_field: f32,
    /// Place irradiance probes for moving objects (surface geometry; with --shard, each shard
    /// gathers its share): on a grid of 2 voxels in the empty space near surfaces, each
    /// gathering the surfaces' light from six directions (docs/design.md §2, "Probes").
    /// --probe-spacing implies it.
    #[arg(long)]
    pub probes: bool,
    /// The probes' grid spacing in scene units (default 2 voxels).
    #[arg(long, value_name = "S")]
    pub probe_spacing: Option<f32>,
    /// Rays each probe direction gathers with.
    #[arg(long, value_name = "R", default_value_t = bounce_core::probe::DEFAULT_PROBE_RAYS)]
    pub probe_rays: u32,
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
        let landing_samples = self
            .landing_samples
            .unwrap_or_else(|| default_landing_samples(self.direct_samples));
        if landing_samples >= self.direct_samples {
            bail!(
                "--landing-samples must be less than --direct-samples ({}), got {}: at least one \
                 sample a patch is spread by area for its mean",
                self.direct_samples,
                landing_samples
            );
        }
        if !(0.0..=MAX_NEAR_RADIUS).contains(&self.near_field) {
            bail!(
                "--near-field must be from 0 to {MAX_NEAR_RADIUS} voxels, got {}",
                self.near_field
            );
        }
        if self.probes || self.probe_spacing.is_some() {
            let probes = ProbeOptions {
                spacing: self.probe_spacing,
                rays: self.probe_rays,
            };
            if let Err(e) = probes.check() {
                bail!("{e}");
            }
            if matches!(self.geometry, Geometry::VoxelFaces) {
                bail!("--probes needs surface geometry, not --geometry voxel-faces");
            }
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
            all_bounces: self.all_bounces,
            keep_form_factors: self.keep_form_factors,
            tracer: self.tracer,
            codec: codec_request(&self.codec, self.max_error),
            sparse_share: self.sparse_share,
            patch_order: self.patch_order,
            geometry: self.geometry,
            direct_samples: self.direct_samples,
            landing_samples,
            max_grey_error: self.max_grey_error,
            near_radius: self.near_field,
            probes: (self.probes || self.probe_spacing.is_some()).then_some(ProbeOptions {
                spacing: self.probe_spacing,
                rays: self.probe_rays,
            }),
        })
    }
}
