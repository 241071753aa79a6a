//! The bake pipeline: scene → patches → form factors → transport → baked file contents.
//!
//! Each stage reports progress through [`Progress`] and its wall time into the file's metadata;
//! the caller decides how progress is shown and where the file goes.

use std::path::Path;
use std::time::Instant;

use thiserror::Error;

use crate::codec::error::{irradiance_errors, probe_light_sets};
use crate::codec::{self, CodecError};
use crate::format::Baked;
use crate::formfactor::{self, FormFactorError, RayScene};
use crate::import::{self, ImportError};
use crate::matrix::{DENSE_F32, EncodedMatrix};
use crate::meta::{BakeMeta, BakeSettings, BakeStats, Bounces, StageTiming};
use crate::rays::Tracer;
use crate::scene::Scene;
use crate::transport::{self, TransportError};
use crate::voxel::{self, Resolution, VoxelError};

/// Rays per patch of the visibility probe that finds patches seeing nothing.
pub const PROBE_RAYS: u32 = 64;

/// What a bake is asked to do.
#[derive(Debug, Clone, PartialEq)]
pub struct BakeOptions {
    pub resolution: Resolution,
    /// Rays per patch for its form-factor row.
    pub rays: u32,
    pub seed: u64,
    pub bounces: Bounces,
    /// Also store the single-bounce form factors (for baselines and re-deriving `T` later).
    pub keep_form_factors: bool,
    pub tracer: Tracer,
    /// How the transport is stored.
    pub codec: CodecRequest,
    /// Share of entries the thesis-family codecs keep exactly; `None` takes each codec's own
    /// default (bc1 and bc4: the thesis' 4%; bc1-resid: 8%).
    pub sparse_share: Option<f64>,
    /// The order patches (rows and columns of `T`) are numbered in.
    pub patch_order: voxel::PatchOrder,
}

/// Which codec stores the transport.
#[derive(Debug, Clone, PartialEq)]
pub enum CodecRequest {
    /// This codec (`dense-f32`, `dense-f16`, `bc1`, `bc4`, `log8`, `bc1-resid`).
    Named(String),
    /// The smallest codec whose `E_ind` relative L2 error stays within `max_error`.
    Auto { max_error: f64 },
}

/// Light configurations the bake measures codec error with (see `codec::error::probe_light_sets`).
pub const PROBE_LIGHT_SETS: usize = 8;

impl Default for BakeOptions {
    fn default() -> Self {
        BakeOptions {
            resolution: Resolution::TargetPatches(2000),
            rays: 2048,
            seed: 1,
            bounces: Bounces::K(3),
            keep_form_factors: false,
            tracer: Tracer::Grid,
            codec: CodecRequest::Named(DENSE_F32.to_string()),
            sparse_share: None,
            patch_order: voxel::PatchOrder::Scan,
        }
    }
}

/// The stages of a bake, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    Import,
    Voxelize,
    /// Building what rays are traced against (the voxel grid or a BVH).
    RayScene,
    FormFactors,
    Transport,
    Encode,
}

impl Stage {
    pub fn name(self) -> &'static str {
        match self {
            Stage::Import => "import",
            Stage::Voxelize => "voxelize",
            Stage::RayScene => "ray scene",
            Stage::FormFactors => "form factors",
            Stage::Transport => "transport",
            Stage::Encode => "encode",
        }
    }
}

/// Receives progress. `advance` is called from worker threads.
pub trait Progress: Sync {
    /// A stage starts; `total` is its unit count (rows), 0 when it has no meaningful count.
    fn begin(&self, stage: Stage, total: u64);
    fn advance(&self, n: u64);
    /// The stage ended after `seconds`.
    fn end(&self, stage: Stage, seconds: f64);
}

/// Shows nothing.
pub struct NoProgress;

impl Progress for NoProgress {
    fn begin(&self, _: Stage, _: u64) {}
    fn advance(&self, _: u64) {}
    fn end(&self, _: Stage, _: f64) {}
}

#[derive(Debug, Error)]
pub enum BakeError {
    #[error(transparent)]
    Import(#[from] ImportError),
    #[error(transparent)]
    Voxel(#[from] VoxelError),
    #[error(transparent)]
    FormFactor(#[from] FormFactorError),
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Codec(#[from] CodecError),
    #[error("{0}")]
    Options(String),
    #[error(
        "no patch sees another: all {patches} patches (down to voxel size {voxel_size}) send \
         every ray into open space or onto occluders, so there is no indirect light to \
         precompute (is the scene a single open surface, are its normals facing away from each \
         other, or are its details smaller than the voxels? try a smaller --voxel-size)"
    )]
    NoInterreflection { patches: usize, voxel_size: f32 },
}

struct Timer<'a> {
    progress: &'a dyn Progress,
    timings: Vec<StageTiming>,
}

impl Timer<'_> {
    fn run<T>(&mut self, stage: Stage, total: u64, f: impl FnOnce() -> T) -> T {
        self.progress.begin(stage, total);
        let start = Instant::now();
        let out = f();
        let seconds = start.elapsed().as_secs_f64();
        self.progress.end(stage, seconds);
        self.timings.push(StageTiming {
            stage: stage.name().to_string(),
            seconds,
        });
        out
    }
}

/// Import a glTF/GLB file and bake it.
pub fn bake_file(
    path: &Path,
    options: &BakeOptions,
    progress: &dyn Progress,
) -> Result<Baked, BakeError> {
    check_codec_options(options)?;
    let mut timer = Timer {
        progress,
        timings: Vec::new(),
    };
    let scene = timer.run(Stage::Import, 0, || import::import_path(path))?;
    let source_bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    bake_with(&scene, &name, source_bytes, options, timer)
}

/// Bake an already imported scene.
pub fn bake_scene(
    scene: &Scene,
    source_name: &str,
    options: &BakeOptions,
    progress: &dyn Progress,
) -> Result<Baked, BakeError> {
    check_codec_options(options)?;
    let timer = Timer {
        progress,
        timings: Vec::new(),
    };
    bake_with(scene, source_name, 0, options, timer)
}

/// Voxelise `scene` into the patches a bake uses. Patches that see no other patch get no
/// indirect light and give none, so they are dropped while the voxel size is searched and
/// `--patches` counts patches that matter.
pub fn simplify(scene: &Scene, options: &BakeOptions) -> Result<voxel::Voxelization, BakeError> {
    let drop_isolated = |mut v: voxel::Voxelization| {
        let probe = RayScene::voxels(&v.layout, &v.occupied, &v.occluders, options.tracer);
        let isolated = formfactor::isolated_patches(&probe, PROBE_RAYS, options.seed);
        v.drop_patches(&isolated);
        v
    };
    let mut vox = voxel::voxelize_refined(scene, options.resolution, &drop_isolated).map_err(
        |e| match e {
            VoxelError::AllDropped { candidates, size } => BakeError::NoInterreflection {
                patches: candidates,
                voxel_size: size,
            },
            e => BakeError::Voxel(e),
        },
    )?;
    vox.layout.reorder(options.patch_order);
    Ok(vox)
}

/// Refuse bad codec options before any expensive work.
fn check_codec_options(options: &BakeOptions) -> Result<(), BakeError> {
    if let Some(share) = options.sparse_share
        && !(0.0..=1.0).contains(&share)
    {
        return Err(BakeError::Options(format!(
            "--sparse-share must be between 0 and 1, got {share}"
        )));
    }
    match &options.codec {
        CodecRequest::Named(name) => {
            codec::configured(name, options.sparse_share)?;
        }
        CodecRequest::Auto { max_error } => {
            if !(max_error.is_finite() && *max_error > 0.0) {
                return Err(BakeError::Options(format!(
                    "--max-error must be a positive number, got {max_error}"
                )));
            }
        }
    }
    Ok(())
}

/// Store `t` with the requested codec; also returns its `E_ind` error against `t` over `probe`.
fn encode_transport(
    t: &crate::matrix::DenseMatrix,
    probe: &[[f32; 3]],
    options: &BakeOptions,
) -> Result<(EncodedMatrix, f64), BakeError> {
    match &options.codec {
        CodecRequest::Named(name) if name == DENSE_F32 => {
            Ok((EncodedMatrix::encode_dense_f32(t), 0.0))
        }
        CodecRequest::Named(name) => {
            let enc = codec::configured(name, options.sparse_share)?.encode(t)?;
            let exact = codec::dense::DenseOp::from(t.clone());
            let err = irradiance_errors(&exact, codec::decode(&enc)?.as_ref(), probe)?.rel_l2;
            Ok((enc, err))
        }
        CodecRequest::Auto { max_error } => {
            let choice = codec::choose(t, probe, *max_error, options.sparse_share)?;
            Ok((choice.encoded, choice.rel_l2))
        }
    }
}

fn bake_with(
    scene: &Scene,
    source_name: &str,
    source_bytes: u64,
    options: &BakeOptions,
    mut timer: Timer<'_>,
) -> Result<Baked, BakeError> {
    let progress = timer.progress;
    let advance = |n: u64| progress.advance(n);

    let vox = timer.run(Stage::Voxelize, 0, || simplify(scene, options))?;
    let layout = vox.layout;
    let n = layout.len();
    let rays = timer.run(Stage::RayScene, 0, || {
        RayScene::voxels(&layout, &vox.occupied, &vox.occluders, options.tracer)
    });
    let tracer = rays.tracer();
    let (f, tally) = timer.run(Stage::FormFactors, n as u64, || {
        formfactor::form_factors(&rays, options.rays, options.seed, &advance)
    })?;
    drop(rays);
    let ff = formfactor::stats(&f, &vec![layout.patch_area(); n]);
    if ff.isolated == n {
        return Err(BakeError::NoInterreflection {
            patches: n,
            voxel_size: layout.voxel_size,
        });
    }

    let albedo: Vec<[f32; 3]> = layout.patches.iter().map(|p| p.albedo).collect();
    let channels = transport::channels_needed(&albedo, options.bounces);
    let t = timer.run(Stage::Transport, (n * channels) as u64, || {
        transport::transport(&f, &albedo, options.bounces, &advance)
    })?;

    let probe = probe_light_sets(&layout, PROBE_LIGHT_SETS);
    let (transport, codec_err) =
        timer.run(Stage::Encode, 0, || encode_transport(&t, &probe, options))?;
    let form_factors = options
        .keep_form_factors
        .then(|| EncodedMatrix::encode_dense_f32(&f));

    let (target_patches, requested_voxel_size) = match options.resolution {
        Resolution::TargetPatches(p) => (Some(p), None),
        Resolution::VoxelSize(s) => (None, Some(s)),
    };
    let meta = BakeMeta {
        tool_version: env!("CARGO_PKG_VERSION").to_string(),
        source_name: source_name.to_string(),
        source_bytes,
        settings: BakeSettings {
            target_patches,
            requested_voxel_size,
            rays_per_patch: options.rays,
            seed: options.seed,
            bounces: options.bounces,
            tracer,
            codec: match &options.codec {
                CodecRequest::Named(name) => name.clone(),
                CodecRequest::Auto { .. } => "auto".to_string(),
            },
            sparse_share: options.sparse_share,
            patch_order: options.patch_order,
            max_error: match options.codec {
                CodecRequest::Auto { max_error } => Some(max_error),
                CodecRequest::Named(_) => None,
            },
        },
        stats: BakeStats {
            patches: n,
            voxel_size: layout.voxel_size,
            occupied_voxels: vox.occupied_voxels,
            dropped_patches: vox.dropped_patches,
            rays_total: n as u64 * options.rays as u64,
            rays: tally,
            row_sum_min: ff.row_sum_min,
            row_sum_max: ff.row_sum_max,
            row_sum_mean: ff.row_sum_mean,
            reciprocity_error: ff.reciprocity_error,
            isolated_patches: ff.isolated,
            channels,
            matrix_bytes: transport.payload.len() as u64,
            codec_eind_rel_l2: codec_err,
        },
        timings: timer.timings,
        import_report: scene.report.clone(),
        lights: scene.lights.clone(),
    };
    Ok(Baked {
        meta,
        layout,
        transport,
        form_factors,
        // The runtime traces shadow rays against the voxels the form factors were traced
        // against.
        occupancy: Some(vox.occupied),
    })
}
