//! What a baked file says about how it was made: settings, statistics, timings and the import
//! report. Stored as JSON in the file's metadata section and shown by `bounce inspect`.

use serde::{Deserialize, Serialize};

use crate::light::Light;
use crate::scene::{ImportReport, Scene};

/// How many light bounces the transport carries: `k` (a number) or all of them (`"all"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Bounces {
    K(u32),
    All,
}

impl std::fmt::Display for Bounces {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Bounces::K(k) => write!(f, "{k}"),
            Bounces::All => f.write_str("all"),
        }
    }
}

impl std::str::FromStr for Bounces {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.eq_ignore_ascii_case("all") {
            return Ok(Bounces::All);
        }
        match s.parse::<u32>() {
            Ok(k) if k >= 1 => Ok(Bounces::K(k)),
            _ => Err(format!(
                "bounces must be a whole number of at least 1 or \"all\", got '{s}'"
            )),
        }
    }
}

impl Serialize for Bounces {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Bounces::K(k) => s.serialize_u32(*k),
            Bounces::All => s.serialize_str("all"),
        }
    }
}

impl<'de> Deserialize<'de> for Bounces {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            N(u32),
            S(String),
        }
        match Raw::deserialize(d)? {
            Raw::N(k) if k >= 1 => Ok(Bounces::K(k)),
            Raw::N(k) => Err(serde::de::Error::custom(format!("bounces {k} < 1"))),
            Raw::S(s) => s.parse().map_err(serde::de::Error::custom),
        }
    }
}

/// How a bake of all bounces sums them (`crate::transport::Tail`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AllBounces {
    /// The first three by Horner, the rest on clusters of rows (`crate::tail`).
    Clustered,
    /// One LU factorisation of `I − D_ρ F`: exact, `n³` work.
    Exact,
}

impl std::fmt::Display for AllBounces {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            AllBounces::Clustered => "clustered",
            AllBounces::Exact => "exact",
        })
    }
}

impl std::str::FromStr for AllBounces {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "clustered" => Ok(AllBounces::Clustered),
            "exact" => Ok(AllBounces::Exact),
            _ => Err(format!(
                "all bounces are summed \"clustered\" or \"exact\", got '{s}'"
            )),
        }
    }
}

/// The knobs a bake was run with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BakeSettings {
    /// Requested patch count, when the voxel size was searched for.
    pub target_patches: Option<u32>,
    /// Requested voxel size, when given directly.
    pub requested_voxel_size: Option<f32>,
    /// Rays cast from each patch for its form-factor row.
    pub rays_per_patch: u32,
    pub seed: u64,
    pub bounces: Bounces,
    /// How `bounces` "all" was summed; absent for a number of bounces, and in files from before
    /// the clustered tail, which were all exact.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub all_bounces: Option<AllBounces>,
    /// The ray tracer that estimated the form factors (`grid` falls back to `bvh` on huge grids).
    pub tracer: crate::rays::Tracer,
    /// The codec asked for: a codec name, or `auto` (the smallest within `max_error`).
    #[serde(default = "default_codec")]
    pub codec: String,
    /// Share of entries the thesis-family codecs keep exactly, when the bake set one (otherwise
    /// each codec's default, which the codec parameters record).
    #[serde(default)]
    pub sparse_share: Option<f64>,
    /// For `auto`: the largest `E_ind` relative L2 error allowed.
    #[serde(default)]
    pub max_error: Option<f64>,
    /// The order patches are numbered in.
    #[serde(default = "default_patch_order")]
    pub patch_order: crate::voxel::PatchOrder,
    /// What patches stand for. Files from before surface patches were voxel faces.
    #[serde(default = "crate::voxel::Geometry::voxel_faces")]
    pub geometry: crate::voxel::Geometry,
    /// Direct-light sample points stored per patch (surface geometry; 0 for voxel faces, whose
    /// samples are drawn on the face at run time).
    #[serde(default)]
    pub direct_samples: u32,
    /// How many of those lie where near-field rays land (`surface::SurfaceScene::landing_samples`);
    /// 0 in files without, and in files from before them.
    #[serde(default)]
    pub landing_samples: u32,
    /// The largest change of `E_ind` one grey transport channel may make before the bake keeps
    /// three (`transport::choose_channels`). Files from before the choice kept three whenever
    /// albedos differed, which is 0.
    #[serde(default)]
    pub max_grey_error: f64,
    /// The near-field radius in voxels ([`crate::nearfield`]); 0 in files without a near field,
    /// and in files from before it.
    #[serde(default)]
    pub near_radius: f32,
    /// How the bake placed irradiance probes ([`crate::probe`]); absent when it placed none, as
    /// in files from before probes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub probes: Option<crate::probe::ProbeOptions>,
}

fn default_patch_order() -> crate::voxel::PatchOrder {
    crate::voxel::PatchOrder::Scan
}

fn default_codec() -> String {
    crate::matrix::DENSE_F32.to_string()
}

/// Figures measured during the bake.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct BakeStats {
    pub patches: usize,
    /// Rows of the transport: the elements the patches split into (surface geometry), or the
    /// patches. 0 in files from before elements, whose rows are the patches.
    #[serde(default)]
    pub elements: usize,
    pub voxel_size: f32,
    pub occupied_voxels: usize,
    /// Candidate patches dropped because their probe rays reached no other patch.
    pub dropped_patches: usize,
    /// Rays traced for the form factors: rows × rays per row.
    pub rays_total: u64,
    /// Where the form-factor rays ended.
    #[serde(default)]
    pub rays: crate::rays::RayTally,
    pub row_sum_min: f32,
    pub row_sum_max: f32,
    pub row_sum_mean: f32,
    /// Area-weighted relative reciprocity error of the form factors:
    /// `Σ|A_i F_ij − A_j F_ji| / Σ(A_i F_ij + A_j F_ji)`.
    pub reciprocity_error: f32,
    /// Patches whose rays hit no other patch.
    pub isolated_patches: usize,
    pub channels: usize,
    /// How much carrying the transport in one grey channel changes `E_ind` against three
    /// (relative L2 over the probe light sets): one channel is kept when this is at most
    /// `transport::GREY_TOLERANCE`. 0 where colour cannot matter, and in older files.
    #[serde(default)]
    pub grey_rel_l2: f64,
    /// Where three channels share one grey tail (all bounces, clustered): how much that changes
    /// `E_ind` against each colour's own tail, as `grey_rel_l2` is measured. `None` where each
    /// channel has its own tail, and in older files.
    #[serde(default)]
    pub grey_tail_rel_l2: Option<f64>,
    pub matrix_bytes: u64,
    /// `E_ind` relative L2 error of the stored matrix against the exact one, over the probe light
    /// sets of `codec::error::probe_light_sets` (0 for `dense-f32`).
    #[serde(default)]
    pub codec_eind_rel_l2: f64,
    /// Surface area of the scene (both sides of double-sided triangles), world units².
    #[serde(default)]
    pub surface_area: f64,
    /// Of that, the area that belongs to no patch (dropped patches, clipping slivers): light
    /// reaching it is lost to the transport. Surface geometry only.
    #[serde(default)]
    pub unassigned_area: f64,
}

/// Wall time of one bake stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageTiming {
    pub stage: String,
    pub seconds: f64,
}

/// Everything about a bake that is not the layout or the matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BakeMeta {
    /// `bounce-core` version that wrote the file.
    pub tool_version: String,
    /// The scene file as given on the command line (file name only, no directories).
    pub source_name: String,
    pub source_bytes: u64,
    pub settings: BakeSettings,
    pub stats: BakeStats,
    pub timings: Vec<StageTiming>,
    pub import_report: ImportReport,
    /// The scene's own lights (`KHR_lights_punctual`), the default light configuration.
    pub lights: Vec<Light>,
}

/// Where a bake's scene came from: recorded in the baked file, and in every shard of a sharded
/// bake so that the merge can refuse shards of different scenes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceInfo {
    /// The scene file's name (no directories).
    pub source_name: String,
    pub source_bytes: u64,
    pub import_report: ImportReport,
    pub lights: Vec<Light>,
}

impl SourceInfo {
    pub(crate) fn of(scene: &Scene, source_name: &str, source_bytes: u64) -> Self {
        SourceInfo {
            source_name: source_name.to_string(),
            source_bytes,
            import_report: scene.report.clone(),
            lights: scene.lights.clone(),
        }
    }
}
