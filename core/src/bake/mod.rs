//! The bake pipeline: scene → patches → form factors → transport → baked file contents.
//!
//! Each stage reports progress through [`Progress`] and its wall time into the file's metadata;
//! the caller decides how progress is shown and where the file goes.

pub mod shard;

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use thiserror::Error;

use crate::codec::error::{irradiance_errors, probe_light_sets};
use crate::codec::{self, CodecError};
use crate::emitter::Emitters;
use crate::format::Baked;
use crate::formfactor::{self, FormFactorError, FormFactorStats, RayScene, RowTracer};
use crate::import::{self, ImportError};
use crate::matrix::{DENSE_F32, DenseMatrix, EncodedMatrix};
pub use crate::meta::SourceInfo;
use crate::meta::{AllBounces, BakeMeta, BakeSettings, BakeStats, Bounces, StageTiming};
use crate::nearfield::NearField;
use crate::patch::PatchLayout;
use crate::probe;
use crate::rays::Tracer;
use crate::scene::Scene;
use crate::sky::SkyVisibility;
use crate::surface::{self, SurfaceData, SurfaceScene};
use crate::tail::Clusters;
use crate::transport::{self, TransportError};
use crate::trimesh::TriMesh;
use crate::voxel::{self, Geometry, Resolution, VoxelError};

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
    /// How [`Bounces::All`] is summed.
    pub all_bounces: AllBounces,
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
    /// What patches stand for: real surface pieces, or the thesis' voxel faces.
    pub geometry: voxel::Geometry,
    /// Direct-light sample points stored per patch (surface geometry).
    pub direct_samples: u32,
    /// How many of those lie where near-field rays land rather than spread by area
    /// ([`SurfaceScene::landing_samples`]); 0 without a near field.
    pub landing_samples: u32,
    /// How much one grey transport channel may change `E_ind` before the bake keeps three
    /// ([`transport::choose_channels`]).
    pub max_grey_error: f64,
    /// How far from its origin a form-factor ray may land and count for the near-field first
    /// bounce ([`crate::nearfield`]), in voxels; 0 stores no near field (surface geometry only).
    pub near_radius: f32,
    /// Irradiance probes for moving objects ([`crate::probe`]); `None` places none (surface
    /// geometry only).
    pub probes: Option<crate::probe::ProbeOptions>,
}

/// Which codec stores the transport.
#[derive(Debug, Clone, PartialEq)]
pub enum CodecRequest {
    /// This codec (`dense-f32`, `dense-f16`, `bc1`, `bc4`, `log8`, `bc1-resid`).
    Named(String),
    /// The smallest codec whose `E_ind` relative L2 error stays within `max_error`.
    Auto { max_error: f64 },
}

/// Probe options a bake can run with.
pub(crate) fn check_probe_options(options: &BakeOptions) -> Result<(), BakeError> {
    match &options.probes {
        Some(p) => p.check().map_err(BakeError::Options),
        None => Ok(()),
    }
}

pub(crate) fn probes_need_surface() -> BakeError {
    BakeError::Options(
        "probes need surface geometry: bake without --geometry voxel-faces, or without probes"
            .into(),
    )
}

/// Light configurations the bake measures codec error with (see `codec::error::probe_light_sets`).
pub const PROBE_LIGHT_SETS: usize = 8;

impl Default for BakeOptions {
    fn default() -> Self {
        BakeOptions {
            resolution: Resolution::TargetPatches(2000),
            rays: 2048,
            seed: 1,
            bounces: Bounces::All,
            all_bounces: AllBounces::Clustered,
            keep_form_factors: false,
            tracer: Tracer::Grid,
            codec: CodecRequest::Named(DENSE_F32.to_string()),
            sparse_share: None,
            patch_order: voxel::PatchOrder::Scan,
            geometry: voxel::Geometry::Surface,
            direct_samples: crate::surface::DEFAULT_SURFACE_SAMPLES,
            landing_samples: crate::surface::default_landing_samples(
                crate::surface::DEFAULT_SURFACE_SAMPLES,
            ),
            max_grey_error: transport::DEFAULT_MAX_GREY_ERROR,
            near_radius: crate::nearfield::DEFAULT_NEAR_RADIUS,
            probes: None,
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
    /// The near-field matrix: the form-factor rays that land close by, traced again that far.
    NearField,
    /// Direct-light sample points: spread by area, and placed where near-field rays land.
    Samples,
    /// Irradiance probes: placed, then gathered at (counted in probes).
    Probes,
    /// Whether one grey channel carries the transport (measured on the probe light sets), and
    /// the clusters an all-bounce tail is summed on.
    Channels,
    Transport,
    Encode,
    /// A sharded bake's step reading (and checking) the shards it continues from.
    ReadShards,
}

impl Stage {
    pub fn name(self) -> &'static str {
        match self {
            Stage::Import => "import",
            Stage::Voxelize => "voxelize",
            Stage::RayScene => "ray scene",
            Stage::FormFactors => "form factors",
            Stage::NearField => "near field",
            Stage::Samples => "samples",
            Stage::Probes => "probes",
            Stage::Channels => "channels",
            Stage::Transport => "transport",
            Stage::Encode => "encode",
            Stage::ReadShards => "read shards",
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
    #[error(transparent)]
    Probes(#[from] probe::ProbeError),
    #[error(
        "no patch sees another: all {patches} patches (down to voxel size {voxel_size}) send \
         every ray into open space or onto occluders, so there is no indirect light to \
         precompute (is the scene a single open surface, are its normals facing away from each \
         other, or are its details smaller than the voxels? try a smaller --voxel-size)"
    )]
    NoInterreflection { patches: usize, voxel_size: f32 },
}

/// Runs stages, reporting them to a [`Progress`] and recording their wall times.
pub(crate) struct Timer<'a> {
    pub progress: &'a dyn Progress,
    pub timings: Vec<StageTiming>,
}

impl<'a> Timer<'a> {
    pub fn new(progress: &'a dyn Progress) -> Self {
        Timer {
            progress,
            timings: Vec::new(),
        }
    }

    pub fn run<T>(&mut self, stage: Stage, total: u64, f: impl FnOnce() -> T) -> T {
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

/// Import `path` as a stage of `timer`; also says where it came from.
pub(crate) fn import_timed(
    path: &Path,
    timer: &mut Timer<'_>,
) -> Result<(Scene, SourceInfo), BakeError> {
    let scene = timer.run(Stage::Import, 0, || import::import_path(path))?;
    let source_bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let source = SourceInfo::of(&scene, &name, source_bytes);
    Ok((scene, source))
}

/// Import a glTF/GLB file and bake it.
pub fn bake_file(
    path: &Path,
    options: &BakeOptions,
    progress: &dyn Progress,
) -> Result<Baked, BakeError> {
    check_codec_options(options)?;
    let mut timer = Timer::new(progress);
    let (scene, source) = import_timed(path, &mut timer)?;
    bake_with(&scene, source, options, timer)
}

/// Bake an already imported scene.
pub fn bake_scene(
    scene: &Scene,
    source_name: &str,
    options: &BakeOptions,
    progress: &dyn Progress,
) -> Result<Baked, BakeError> {
    check_codec_options(options)?;
    let source = SourceInfo::of(scene, source_name, 0);
    bake_with(scene, source, options, Timer::new(progress))
}

/// Simplify `scene` into the patches a bake uses. Patches that see no other patch get no
/// indirect light and give none, so they are dropped while the voxel size is searched and
/// `--patches` counts patches that matter.
pub fn simplify(scene: &Scene, options: &BakeOptions) -> Result<voxel::Voxelization, BakeError> {
    let mesh =
        (options.geometry == Geometry::Surface).then(|| Arc::new(surface::scene_mesh(scene)));
    simplify_with(scene, options, mesh.as_ref())
}

/// [`simplify`] with the scene's triangle BVH (surface geometry only) built by the caller, once
/// for every candidate voxel size.
fn simplify_with(
    scene: &Scene,
    options: &BakeOptions,
    mesh: Option<&Arc<TriMesh>>,
) -> Result<voxel::Voxelization, BakeError> {
    let drop_isolated = |mut v: voxel::Voxelization| {
        let (isolated, hidden) = match (&v.pieces, mesh) {
            (Some(pieces), Some(mesh)) => {
                let probe = SurfaceScene::new(scene, mesh.clone(), v.transport_layout(), pieces);
                let isolated = formfactor::isolated_patches(&probe, PROBE_RAYS, options.seed);
                let hidden =
                    formfactor::hidden_patches(&probe, &isolated, PROBE_RAYS, options.seed);
                (isolated, hidden)
            }
            _ => {
                let probe = RayScene::voxels(&v.layout, &v.occupied, &v.occluders, options.tracer);
                (
                    formfactor::isolated_patches(&probe, PROBE_RAYS, options.seed),
                    Vec::new(),
                )
            }
        };
        v.drop_patches(&isolated, &hidden);
        v
    };
    let mut vox =
        voxel::simplify_refined(scene, options.resolution, options.geometry, &drop_isolated)
            .map_err(|e| match e {
                VoxelError::AllDropped { candidates, size } => BakeError::NoInterreflection {
                    patches: candidates,
                    voxel_size: size,
                },
                e => BakeError::Voxel(e),
            })?;
    vox.reorder(options.patch_order);
    Ok(vox)
}

/// The elements a file keeps: none when every patch is one element standing for all of it, as a
/// file without elements means.
pub(crate) fn file_elements(vox: &voxel::Voxelization) -> Option<crate::element::Elements> {
    let e = vox.elements.as_ref()?;
    let trivial = e.len() == vox.layout.len() && e.layout.patches == vox.layout.patches;
    (!trivial).then(|| e.clone())
}

/// Refuse bad codec options before any expensive work.
pub(crate) fn check_codec_options(options: &BakeOptions) -> Result<(), BakeError> {
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
    t: &DenseMatrix,
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

/// The scene simplified and ready to trace. Simplification and the isolated-patch probe are
/// deterministic, so every shard of a sharded bake redoes this and gets the same bits.
pub(crate) struct Prepared {
    pub vox: voxel::Voxelization,
    pub rays: Rows,
    /// What direct light needs at run time (surface geometry).
    pub surface: Option<SurfaceData>,
    /// The tracer recorded in the settings: the BVH over triangles for surface geometry.
    pub tracer: Tracer,
    /// The emissive materials and the rows they cover (surface geometry).
    pub emitters: Option<Emitters>,
}

pub(crate) fn prepare(
    scene: &Scene,
    options: &BakeOptions,
    timer: &mut Timer<'_>,
) -> Result<Prepared, BakeError> {
    let mesh = match options.geometry {
        Geometry::Surface => Some(Arc::new(
            timer.run(Stage::RayScene, 0, || surface::scene_mesh(scene)),
        )),
        Geometry::VoxelFaces => None,
    };
    let vox = timer.run(Stage::Voxelize, 0, || {
        simplify_with(scene, options, mesh.as_ref())
    })?;
    match (mesh, &vox.pieces) {
        (Some(mesh), Some(pieces)) => {
            let triangles = surface::occluder_triangles_of(&mesh);
            let emitters = Emitters::of_pieces(scene, pieces);
            let rays = SurfaceScene::new(scene, mesh, vox.transport_layout(), pieces);
            let landing = landing_samples(options);
            let area = options.direct_samples - landing;
            let (points, albedo) = timer.run(Stage::Samples, 0, || {
                rays.landing_samples(
                    scene,
                    area,
                    landing,
                    options.rays,
                    options.seed,
                    options.near_radius * vox.transport_layout().voxel_size,
                )
            });
            let surface = SurfaceData {
                triangles,
                per_patch: options.direct_samples,
                area_samples: area,
                points,
                albedo: Some(albedo),
            };
            Ok(Prepared {
                vox,
                rays: Rows::Surface(Box::new(rays)),
                surface: Some(surface),
                tracer: Tracer::Bvh,
                emitters: Some(emitters),
            })
        }
        _ => {
            let rays = timer.run(Stage::RayScene, 0, || {
                RayScene::voxels(&vox.layout, &vox.occupied, &vox.occluders, options.tracer)
            });
            let tracer = rays.tracer();
            Ok(Prepared {
                vox,
                rays: Rows::Voxels(Box::new(rays)),
                surface: None,
                tracer,
                emitters: None,
            })
        }
    }
}

/// How many of a row's samples a surface bake places where near-field rays land: none without
/// a near field (nothing reads them), and always at least one spread by area (the row's mean).
pub(crate) fn landing_samples(options: &BakeOptions) -> u32 {
    if options.near_radius > 0.0 {
        options
            .landing_samples
            .min(options.direct_samples.saturating_sub(1))
    } else {
        0
    }
}

/// Where the sample points lie that the form factors' pass gives each row's rays to, for the
/// samples' sky view ([`crate::sky::RowSky`]): a surface bake's, when it keeps a near field (the
/// view's only use), with their count a row.
pub(crate) fn samples_for_sky<'a>(
    surface: Option<&'a SurfaceData>,
    options: &BakeOptions,
) -> Option<(&'a [crate::surface::SamplePoint], u32)> {
    surface
        .filter(|_| options.near_radius > 0.0)
        .map(|s| (&s.points[..], s.per_patch))
}

/// What the transport's rows are traced through.
pub(crate) enum Rows {
    Surface(Box<SurfaceScene>),
    Voxels(Box<RayScene>),
}

impl Rows {
    pub fn tracer(&self) -> &dyn RowTracer {
        match self {
            Rows::Surface(s) => s.as_ref(),
            Rows::Voxels(v) => v.as_ref(),
        }
    }
}

/// The near-field matrix of the rows the form factors' pass traced, with the samples' sky view:
/// `None` where the pass kept none (voxel faces, or a radius of 0).
pub(crate) fn near_field(
    rows: Option<Vec<Vec<crate::nearfield::Landings>>>,
    samples_sky: Option<SkyVisibility>,
    samples: Option<(&[crate::surface::SamplePoint], u32)>,
) -> Option<NearField> {
    let (rows, (_, per_row)) = (rows?, samples?);
    let mut near = NearField::from_landings(per_row, rows);
    near.sky = samples_sky;
    Some(near)
}

/// The form-factor checks a bake records; refuses a scene where no patch sees another.
pub(crate) fn check_form_factors(
    f: &DenseMatrix,
    layout: &PatchLayout,
    geometry: Geometry,
) -> Result<FormFactorStats, BakeError> {
    let n = layout.len();
    let ff = formfactor::stats(f, &layout.areas(geometry));
    if ff.isolated == n {
        return Err(BakeError::NoInterreflection {
            patches: n,
            voxel_size: layout.voxel_size,
        });
    }
    Ok(ff)
}

/// How many channels the transport of form factors `f` on `rows` carries
/// ([`transport::choose_channels`], measured on the probe light sets the codec is measured on).
pub(crate) fn choose_channels(
    f: &DenseMatrix,
    rows: &PatchLayout,
    options: &BakeOptions,
) -> Result<transport::ChannelChoice, BakeError> {
    let albedo: Vec<[f32; 3]> = rows.patches.iter().map(|p| p.albedo).collect();
    let probes = probe_light_sets(rows, PROBE_LIGHT_SETS);
    Ok(transport::choose_channels(
        f,
        &albedo,
        options.bounces,
        &probes,
        options.max_grey_error,
    )?)
}

/// The clusters an all-bounce transport's tail is summed on, when the bake sums it so
/// ([`crate::tail`]).
pub(crate) fn tail_clusters(
    rows: &PatchLayout,
    f: &DenseMatrix,
    options: &BakeOptions,
) -> Option<Clusters> {
    (options.bounces == Bounces::All && options.all_bounces == AllBounces::Clustered)
        .then(|| Clusters::of_layout(rows, f))
}

/// What a bake computes its transport with ([`plan_transport`]).
pub(crate) struct TransportPlan {
    pub colour: transport::ChannelChoice,
    /// The clusters an all-bounce tail is summed on ([`tail_clusters`]).
    pub clusters: Option<Clusters>,
    /// Three channels whose clustered tail is bounced once on the mean albedo: it changes
    /// `E_ind` by at most `--max-grey-error` ([`transport::Tail::ClusteredGrey`]).
    pub grey_tail: bool,
}

impl TransportPlan {
    /// How the transport sums all bounces.
    pub fn tail(&self) -> transport::Tail<'_> {
        match (&self.clusters, self.grey_tail) {
            (Some(c), true) => transport::Tail::ClusteredGrey(c),
            (Some(c), false) => transport::Tail::Clustered(c),
            (None, _) => transport::Tail::Exact,
        }
    }

    /// What the file records of a grey tail: how much it changes `E_ind`, where it was taken.
    pub fn grey_tail_rel_l2(&self) -> Option<f64> {
        self.colour.grey_tail_rel_l2.filter(|_| self.grey_tail)
    }
}

/// What the transport of `f` on `rows` is computed with, as the channels stage of `timer`: its
/// channel count ([`choose_channels`]), the tail's clusters ([`tail_clusters`]) and whether
/// three channels share one grey tail. Deterministic, so every shard of a bake plans alike.
pub(crate) fn plan_transport(
    f: &DenseMatrix,
    rows: &PatchLayout,
    options: &BakeOptions,
    timer: &mut Timer<'_>,
) -> Result<TransportPlan, BakeError> {
    timer.run(Stage::Channels, 0, || {
        let colour = choose_channels(f, rows, options)?;
        let clusters = tail_clusters(rows, f, options);
        let grey_tail = colour.channels == 3
            && clusters.is_some()
            && colour
                .grey_tail_rel_l2
                .is_some_and(|e| e <= options.max_grey_error);
        Ok(TransportPlan {
            colour,
            clusters,
            grey_tail,
        })
    })
}

/// The whole transport of `f` on `rows`, planned ([`plan_transport`]) and computed as the
/// channels and transport stages of `timer`: what a one-process bake and a merge of form-factor
/// shards both do.
pub(crate) fn transport_timed(
    f: &DenseMatrix,
    rows: &PatchLayout,
    options: &BakeOptions,
    timer: &mut Timer<'_>,
    advance: &(dyn Fn(u64) + Sync),
) -> Result<(TransportPlan, DenseMatrix), BakeError> {
    let albedo: Vec<[f32; 3]> = rows.patches.iter().map(|p| p.albedo).collect();
    let plan = plan_transport(f, rows, options, timer)?;
    let channels = plan.colour.channels;
    let t = timer.run(Stage::Transport, (f.n * channels) as u64, || {
        transport::transport(f, &albedo, options.bounces, plan.tail(), channels, advance)
    })?;
    Ok((plan, t))
}

/// Store `t` with the requested codec, as the encode stage of `timer`; also its `E_ind` error.
pub(crate) fn encode_timed(
    t: &DenseMatrix,
    layout: &PatchLayout,
    options: &BakeOptions,
    timer: &mut Timer<'_>,
) -> Result<(EncodedMatrix, f64), BakeError> {
    let probe = probe_light_sets(layout, PROBE_LIGHT_SETS);
    timer.run(Stage::Encode, 0, || encode_transport(t, &probe, options))
}

/// The settings a bake records (and shards of one bake must share).
pub(crate) fn settings(options: &BakeOptions, tracer: Tracer) -> BakeSettings {
    let (target_patches, requested_voxel_size) = match options.resolution {
        Resolution::TargetPatches(p) => (Some(p), None),
        Resolution::VoxelSize(s) => (None, Some(s)),
    };
    BakeSettings {
        target_patches,
        requested_voxel_size,
        rays_per_patch: options.rays,
        seed: options.seed,
        bounces: options.bounces,
        all_bounces: (options.bounces == Bounces::All).then_some(options.all_bounces),
        tracer,
        codec: match &options.codec {
            CodecRequest::Named(name) => name.clone(),
            CodecRequest::Auto { .. } => "auto".to_string(),
        },
        sparse_share: options.sparse_share,
        patch_order: options.patch_order,
        geometry: options.geometry,
        direct_samples: match options.geometry {
            Geometry::Surface => options.direct_samples,
            Geometry::VoxelFaces => 0,
        },
        landing_samples: match options.geometry {
            Geometry::Surface => landing_samples(options),
            Geometry::VoxelFaces => 0,
        },
        max_grey_error: options.max_grey_error,
        probes: match options.geometry {
            Geometry::Surface => options.probes,
            Geometry::VoxelFaces => None,
        },
        near_radius: match options.geometry {
            Geometry::Surface => options.near_radius,
            Geometry::VoxelFaces => 0.0,
        },
        max_error: match options.codec {
            CodecRequest::Auto { max_error } => Some(max_error),
            CodecRequest::Named(_) => None,
        },
    }
}

/// The options that gave `settings` (the inverse of [`settings`]), for the steps of a sharded
/// bake that start from shards rather than from a command line.
pub fn options_of(settings: &BakeSettings, keep_form_factors: bool) -> BakeOptions {
    BakeOptions {
        resolution: match (settings.target_patches, settings.requested_voxel_size) {
            (_, Some(s)) => Resolution::VoxelSize(s),
            (Some(p), None) => Resolution::TargetPatches(p),
            (None, None) => BakeOptions::default().resolution,
        },
        rays: settings.rays_per_patch,
        seed: settings.seed,
        bounces: settings.bounces,
        all_bounces: settings.all_bounces.unwrap_or(AllBounces::Exact),
        keep_form_factors,
        tracer: settings.tracer,
        codec: match (settings.codec.as_str(), settings.max_error) {
            ("auto", Some(max_error)) => CodecRequest::Auto { max_error },
            (name, _) => CodecRequest::Named(name.to_string()),
        },
        sparse_share: settings.sparse_share,
        patch_order: settings.patch_order,
        geometry: settings.geometry,
        direct_samples: settings.direct_samples,
        landing_samples: settings.landing_samples,
        max_grey_error: settings.max_grey_error,
        near_radius: settings.near_radius,
        probes: settings.probes,
    }
}

/// What a baked file's metadata is made of, whether the bake ran in one process or in shards.
pub(crate) struct MetaParts {
    pub settings: BakeSettings,
    pub source: SourceInfo,
    pub voxel_size: f32,
    pub occupied_voxels: usize,
    pub dropped_patches: usize,
    pub patches: usize,
    pub elements: usize,
    pub rays: crate::rays::RayTally,
    pub form_factors: FormFactorStats,
    pub channels: usize,
    pub grey_rel_l2: f64,
    pub grey_tail_rel_l2: Option<f64>,
    pub matrix_bytes: u64,
    pub codec_eind_rel_l2: f64,
    pub timings: Vec<StageTiming>,
    pub surface_area: f64,
    pub unassigned_area: f64,
}

pub(crate) fn build_meta(p: MetaParts) -> BakeMeta {
    let ff = p.form_factors;
    BakeMeta {
        tool_version: env!("CARGO_PKG_VERSION").to_string(),
        source_name: p.source.source_name,
        source_bytes: p.source.source_bytes,
        stats: BakeStats {
            patches: p.patches,
            elements: p.elements,
            voxel_size: p.voxel_size,
            occupied_voxels: p.occupied_voxels,
            dropped_patches: p.dropped_patches,
            rays_total: p.elements as u64 * u64::from(p.settings.rays_per_patch),
            rays: p.rays,
            row_sum_min: ff.row_sum_min,
            row_sum_max: ff.row_sum_max,
            row_sum_mean: ff.row_sum_mean,
            reciprocity_error: ff.reciprocity_error,
            isolated_patches: ff.isolated,
            channels: p.channels,
            grey_rel_l2: p.grey_rel_l2,
            grey_tail_rel_l2: p.grey_tail_rel_l2,
            matrix_bytes: p.matrix_bytes,
            codec_eind_rel_l2: p.codec_eind_rel_l2,
            surface_area: p.surface_area,
            unassigned_area: p.unassigned_area,
        },
        settings: p.settings,
        timings: p.timings,
        import_report: p.source.import_report,
        lights: p.source.lights,
    }
}

fn bake_with(
    scene: &Scene,
    source: SourceInfo,
    options: &BakeOptions,
    mut timer: Timer<'_>,
) -> Result<Baked, BakeError> {
    check_probe_options(options)?;
    let progress = timer.progress;
    let advance = |n: u64| progress.advance(n);

    let Prepared {
        vox,
        rays,
        surface,
        tracer,
        emitters,
    } = prepare(scene, options, &mut timer)?;
    let rows = vox.transport_layout();
    let n = rows.len();
    let samples = samples_for_sky(surface.as_ref(), options);
    let traced = timer.run(Stage::FormFactors, n as u64, || {
        formfactor::form_factor_rows_sampled(
            rays.tracer(),
            0..n,
            options.rays,
            options.seed,
            samples,
            options.near_radius * rows.voxel_size,
            &advance,
        )
    })?;
    let (tally, sky) = (traced.tally, traced.sky);
    let near_field = timer.run(Stage::NearField, 0, || {
        Ok::<_, BakeError>(near_field(traced.near, traced.samples_sky, samples))
    })?;
    let f = DenseMatrix {
        n,
        channels: 1,
        data: traced.f,
    };
    let probes = match (&options.probes, &rays) {
        (None, _) => None,
        (Some(p), Rows::Surface(scene)) => Some(timer.run(Stage::Probes, 0, || {
            probe::bake_probes(rows, &vox.occupied, scene, p, options.seed, &advance)
        })?),
        (Some(_), Rows::Voxels(_)) => return Err(probes_need_surface()),
    };
    drop(rays);
    let ff = check_form_factors(&f, rows, options.geometry)?;

    let (plan, t) = transport_timed(&f, rows, options, &mut timer, &advance)?;
    let channels = plan.colour.channels;

    let (transport, codec_err) = encode_timed(&t, rows, options, &mut timer)?;
    drop(t);
    let form_factors = options
        .keep_form_factors
        .then(|| EncodedMatrix::encode_dense_f32(&f));

    let meta = build_meta(MetaParts {
        settings: settings(options, tracer),
        source,
        voxel_size: vox.layout.voxel_size,
        occupied_voxels: vox.occupied_voxels,
        dropped_patches: vox.dropped_patches,
        patches: vox.layout.len(),
        elements: n,
        rays: tally,
        form_factors: ff,
        channels,
        grey_rel_l2: plan.colour.grey_rel_l2,
        grey_tail_rel_l2: plan.grey_tail_rel_l2(),
        matrix_bytes: transport.payload.len() as u64,
        codec_eind_rel_l2: codec_err,
        timings: timer.timings,
        surface_area: vox.total_area,
        unassigned_area: vox.unassigned_area,
    });
    let elements = file_elements(&vox);
    Ok(Baked {
        meta,
        layout: vox.layout,
        elements,
        transport,
        form_factors,
        // The runtime traces shadow rays against what the form factors were traced against:
        // the triangles (surface geometry) or the voxels (voxel faces).
        occupancy: surface.is_none().then_some(vox.occupied),
        surface,
        near_field,
        sky: Some(sky),
        emitters,
        probes,
        // The caller decides whether the file keeps the scene ([`crate::import::pack_glb`]).
        model: None,
    })
}
