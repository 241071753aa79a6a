//! A bake split across processes (Kubernetes pods, or machines): the same result as one process,
//! bit for bit, in three steps.
//!
//! 1. **Form factors** (`bounce bake SCENE --shard I/N`): each shard imports and voxelises the
//!    scene (deterministic, so every shard gets the same patches) and traces its rows of `F`. A
//!    row depends only on its index and the seed ([`crate::formfactor`]).
//! 2. **Transport** (`bounce bake transport --shard I/M`): each shard reads every phase-1 shard,
//!    assembles the whole of `F` (a row of `T_k` needs all of `F`: `T_{m+1} = F + T_m D_ρ F`) and
//!    computes its rows of `T` in the transport's fixed row blocks ([`crate::transport`]), so the
//!    rows are the bits one process would compute. For `--bounces all` every shard factorises
//!    `I − D_ρ F` itself (the one step that is not per row; it is deterministic).
//! 3. **Merge** (`bounce bake merge`): assembles `T` and encodes it. The codecs other than the
//!    dense ones need all of `T` at once (the thesis codec's greedy row and column reordering, its
//!    global scale and its largest-entries share), so compression is not split. A merge of
//!    phase-1 shards computes the transport itself, for bakes where it is cheap (one bounce, or
//!    few patches).
//!
//! Shards carry the layout, the settings and where the scene came from, and every step checks
//! that its shards belong together: one bake, one split, each shard exactly once.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

use thiserror::Error;

use crate::bake::{self, BakeError, BakeOptions, MetaParts, Prepared, Progress, Stage, Timer};
use crate::format::{Baked, FormatError, ShardFile, ShardHeader};
use crate::formfactor;
use crate::matrix::{DenseMatrix, EncodedMatrix};
use crate::meta::StageTiming;
use crate::nearfield::NearField;
use crate::probe::{self, ProbeRows, Probes};
use crate::rays::RayTally;
use crate::sky::SkyVisibility;
use crate::transport;

pub use crate::format::{
    FormFactorSummary, Phase, SHARD_EXTENSION, ShardMeta, ShardSpec, shard_rows,
};

impl ShardSpec {
    /// `I/N` (shard `I` of `N`, from 0), or `N` alone with the index from `completion_index`
    /// (Kubernetes sets `JOB_COMPLETION_INDEX` in each pod of an Indexed Job).
    pub fn parse(arg: &str, completion_index: Option<&str>) -> Result<ShardSpec, ShardError> {
        let number = |s: &str, what: &str| {
            s.trim().parse::<u32>().map_err(|_| {
                ShardError::Spec(format!(
                    "--shard {arg}: {what} '{s}' is not a whole number (give I/N, shard I of N \
                     counting from 0, or N with the index in JOB_COMPLETION_INDEX)"
                ))
            })
        };
        let (index, count) = match arg.split_once('/') {
            Some((i, n)) => (number(i, "the index")?, number(n, "the count")?),
            None => {
                let count = number(arg, "the count")?;
                let index = completion_index.ok_or_else(|| {
                    ShardError::Spec(format!(
                        "--shard {arg} gives only the shard count; the index comes from \
                         JOB_COMPLETION_INDEX (set by a Kubernetes Indexed Job), which is not \
                         set: give --shard I/{arg}"
                    ))
                })?;
                (number(index, "JOB_COMPLETION_INDEX")?, count)
            }
        };
        if count == 0 || index >= count {
            return Err(ShardError::Spec(format!(
                "--shard: shard {index} of {count} does not exist (indices run from 0 to N-1)"
            )));
        }
        Ok(ShardSpec { index, count })
    }
}

#[derive(Debug, Error)]
pub enum ShardError {
    #[error("{}: {error}", path.display())]
    Read { path: PathBuf, error: FormatError },
    #[error("cannot list {}: {error}", path.display())]
    List {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("no shards given (a directory stands for its *.{SHARD_EXTENSION} files)")]
    NoShards,
    #[error("{0}")]
    Spec(String),
    #[error(transparent)]
    Bake(#[from] BakeError),
    #[error("{} holds {} rows, but this step reads {} rows", path.display(), found.name(), expected.name())]
    WrongPhase {
        path: PathBuf,
        found: Phase,
        expected: Phase,
    },
    #[error(
        "{} is one of {count} shards but {} is one of {first_count}: the shards of a step must \
         come from one split (stale shards of an earlier run in the directory?)",
        path.display(), first.display()
    )]
    CountMismatch {
        path: PathBuf,
        count: u32,
        first: PathBuf,
        first_count: u32,
    },
    #[error("shard {index}/{count} is given twice: {} and {}", first.display(), second.display())]
    Duplicate {
        index: u32,
        count: u32,
        first: PathBuf,
        second: PathBuf,
    },
    #[error(
        "{missing_count} of {count} shards missing: {} (every shard 0..{count} must be given once)",
        list_indices(missing)
    )]
    Missing {
        /// The first few missing indices.
        missing: Vec<u32>,
        missing_count: u64,
        count: u32,
    },
    #[error(
        "{} and {} are not shards of the same bake: their {what} differ",
        first.display(), second.display()
    )]
    Mismatch {
        first: PathBuf,
        second: PathBuf,
        what: &'static str,
    },
    #[error("{} changed while the shards were read", path.display())]
    Changed { path: PathBuf },
}

fn list_indices(indices: &[u32]) -> String {
    let list: Vec<String> = indices.iter().map(|i| i.to_string()).collect();
    list.join(", ")
}

/// How many missing indices an error lists.
const MISSING_LISTED: usize = 10;

/// Phase 1: shard `spec` of the form factors of the scene at `path`.
pub fn form_factor_shard(
    path: &Path,
    options: &BakeOptions,
    spec: ShardSpec,
    progress: &dyn Progress,
) -> Result<ShardFile, ShardError> {
    // The merge encodes, but a codec it would refuse is better refused before the tracing.
    bake::check_codec_options(options)?;
    bake::check_probe_options(options)?;
    let mut timer = Timer::new(progress);
    let (scene, source) = bake::import_timed(path, &mut timer)?;
    let Prepared {
        vox,
        rays,
        surface,
        tracer,
        emitters,
    } = bake::prepare(&scene, options, &mut timer)?;
    drop(scene);
    let n = vox.transport_layout().len();
    let rows = shard_rows(n, spec.index, spec.count);
    let samples = bake::samples_for_sky(surface.as_ref(), options);
    let voxel_size = vox.layout.voxel_size;
    let traced = timer.run(Stage::FormFactors, rows.len() as u64, || {
        formfactor::form_factor_rows_sampled(
            rays.tracer(),
            rows.clone(),
            options.rays,
            options.seed,
            samples,
            options.near_radius * voxel_size,
            &|k| progress.advance(k),
        )
    });
    let traced = traced.map_err(BakeError::from)?;
    let (f_rows, tally, sky_rows) = (traced.f, traced.tally, traced.sky);
    let near_rows = timer.run(Stage::NearField, 0, || {
        Ok::<_, BakeError>(bake::near_field(traced.near, traced.samples_sky, samples))
    })?;
    // Every shard places all the probes (the placement is cheap beside the gathers, and the
    // merge checks that they agree) and gathers its share of their rows, split as the rows.
    let probe_rows = match (&options.probes, &rays) {
        (None, _) => None,
        (Some(p), bake::Rows::Surface(scene)) => Some(timer.run(Stage::Probes, 0, || {
            let placed = probe::place_probes(&vox.layout, &vox.occupied, scene, p, options.seed)?;
            let range = shard_rows(placed.gather_rows(), spec.index, spec.count);
            Ok::<_, BakeError>(probe::gather_rows(
                scene,
                placed,
                range,
                options.seed,
                &|k| progress.advance(k),
            ))
        })?),
        (Some(_), bake::Rows::Voxels(_)) => return Err(bake::probes_need_surface().into()),
    };
    drop(rays);
    let meta = ShardMeta {
        phase: Phase::FormFactors,
        index: spec.index,
        count: spec.count,
        first_row: rows.start,
        end_row: rows.end,
        patches: n,
        channels: 1,
        grey_rel_l2: 0.0,
        grey_tail_rel_l2: None,
        tool_version: env!("CARGO_PKG_VERSION").to_string(),
        settings: bake::settings(options, tracer),
        keep_form_factors: options.keep_form_factors,
        source,
        occupied_voxels: vox.occupied_voxels,
        dropped_patches: vox.dropped_patches,
        surface_area: vox.total_area,
        unassigned_area: vox.unassigned_area,
        rays: tally,
        form_factors: None,
        inherited_timings: Vec::new(),
        timings: timer.timings,
    };
    Ok(ShardFile {
        header: ShardHeader {
            meta,
            elements: bake::file_elements(&vox),
            layout: vox.layout,
            occupancy: vox.occupied,
            surface,
            emitters,
        },
        rows: f_rows,
        form_factor_rows: None,
        near_rows,
        sky_rows,
        probe_rows,
        // The caller packs the model when the bake keeps it ([`crate::import::pack_glb`]).
        model: None,
    })
}

/// Phase 2: shard `spec` of the transport, from every phase-1 shard of the bake.
pub fn transport_shard(
    inputs: &[PathBuf],
    spec: ShardSpec,
    progress: &dyn Progress,
) -> Result<ShardFile, ShardError> {
    let members = gather(inputs, Some(Phase::FormFactors))?;
    let model = model_of(&members)?;
    let mut timer = Timer::new(progress);
    let first = members[0].header.clone();
    let n = first.meta.patches;
    let Assembled {
        rows: f,
        near,
        sky,
        probes,
        ..
    } = timer.run(Stage::ReadShards, n as u64, || {
        assemble(&members, 1, false, progress)
    })?;
    let options = bake::options_of(&first.meta.settings, first.meta.keep_form_factors);
    let stats =
        bake::check_form_factors(&f, first.transport_layout(), first.meta.settings.geometry)?;
    let summary = FormFactorSummary {
        stats,
        crc32: crc32fast::hash(&crate::format::f32_le_bytes(&f.data)),
    };
    let rows = shard_rows(n, spec.index, spec.count);
    let albedo: Vec<[f32; 3]> = first
        .transport_layout()
        .patches
        .iter()
        .map(|p| p.albedo)
        .collect();
    let plan = bake::plan_transport(&f, first.transport_layout(), &options, &mut timer)?;
    let channels = plan.colour.channels;
    let t_rows = timer.run(Stage::Transport, (rows.len() * channels) as u64, || {
        transport::transport_channel_rows(
            &f,
            &albedo,
            channels,
            options.bounces,
            plan.tail(),
            rows.clone(),
            &|k| progress.advance(k),
        )
    });
    let t_rows = t_rows.map_err(BakeError::from)?;
    let form_factor_rows = options
        .keep_form_factors
        .then(|| f.data[rows.start * n..rows.end * n].to_vec());
    let meta = ShardMeta {
        phase: Phase::Transport,
        index: spec.index,
        count: spec.count,
        first_row: rows.start,
        end_row: rows.end,
        patches: n,
        channels,
        grey_rel_l2: plan.colour.grey_rel_l2,
        grey_tail_rel_l2: plan.grey_tail_rel_l2(),
        form_factors: Some(summary),
        rays: members
            .iter()
            .fold(RayTally::default(), |a, m| a + m.header.meta.rays),
        inherited_timings: sum_timings(members.iter().map(|m| &m.header.meta.timings)),
        timings: timer.timings,
        ..first.meta
    };
    Ok(ShardFile {
        header: ShardHeader {
            meta,
            layout: first.layout,
            occupancy: first.occupancy,
            surface: first.surface,
            elements: first.elements,
            emitters: first.emitters,
        },
        rows: t_rows,
        form_factor_rows,
        near_rows: near.map(|all| slice_rows(&all, rows.clone())),
        sky_rows: sky.slice(rows.clone()),
        probe_rows: probes
            .map(|p| probe_share(&p, spec, &members[0].path))
            .transpose()?,
        model,
    })
}

/// The last step: the baked file from every shard of one phase. From phase-2 shards it assembles
/// and encodes `T`; from phase-1 shards it computes `T` first, as one process would.
pub fn merge(inputs: &[PathBuf], progress: &dyn Progress) -> Result<Baked, ShardError> {
    let members = gather(inputs, None)?;
    let model = model_of(&members)?;
    let mut timer = Timer::new(progress);
    let first = members[0].header.clone();
    let m0 = &first.meta;
    let n = m0.patches;
    let options = bake::options_of(&m0.settings, m0.keep_form_factors);
    bake::check_codec_options(&options)?;
    let (t, f, near_field, sky, probes, stats, rays, mut timings, (grey_rel_l2, grey_tail_rel_l2)) =
        match m0.phase {
            Phase::Transport => {
                let Assembled {
                    rows: t,
                    form_factors: f,
                    near,
                    sky,
                    probes,
                } = timer.run(Stage::ReadShards, n as u64, || {
                    assemble(&members, m0.channels, m0.keep_form_factors, progress)
                })?;
                // gather checked that every shard has the same summary.
                let stats = m0.form_factors.map(|s| s.stats).ok_or(ShardError::Read {
                    path: members[0].path.clone(),
                    error: FormatError::BadShard("no form-factor statistics".to_string()),
                })?;
                let mut timings = m0.inherited_timings.clone();
                timings.extend(sum_timings(members.iter().map(|m| &m.header.meta.timings)));
                (
                    t,
                    f,
                    near,
                    sky,
                    probes,
                    stats,
                    m0.rays,
                    timings,
                    (m0.grey_rel_l2, m0.grey_tail_rel_l2),
                )
            }
            Phase::FormFactors => {
                let Assembled {
                    rows: f,
                    near,
                    sky,
                    probes,
                    ..
                } = timer.run(Stage::ReadShards, n as u64, || {
                    assemble(&members, 1, false, progress)
                })?;
                let rows = first.transport_layout();
                let stats = bake::check_form_factors(&f, rows, first.meta.settings.geometry)?;
                let (plan, t) = bake::transport_timed(&f, rows, &options, &mut timer, &|k| {
                    progress.advance(k)
                })?;
                let rays = members
                    .iter()
                    .fold(RayTally::default(), |a, m| a + m.header.meta.rays);
                let timings = sum_timings(members.iter().map(|m| &m.header.meta.timings));
                (
                    t,
                    m0.keep_form_factors.then_some(f),
                    near,
                    sky,
                    probes,
                    stats,
                    rays,
                    timings,
                    (plan.colour.grey_rel_l2, plan.grey_tail_rel_l2()),
                )
            }
        };
    let (transport, codec_err) =
        bake::encode_timed(&t, first.transport_layout(), &options, &mut timer)?;
    let channels = t.channels;
    drop(t);
    let form_factors = f.as_ref().map(EncodedMatrix::encode_dense_f32);
    timings.extend(timer.timings);
    let meta = bake::build_meta(MetaParts {
        settings: m0.settings.clone(),
        source: m0.source.clone(),
        voxel_size: first.layout.voxel_size,
        occupied_voxels: m0.occupied_voxels,
        dropped_patches: m0.dropped_patches,
        surface_area: m0.surface_area,
        unassigned_area: m0.unassigned_area,
        patches: first.layout.len(),
        elements: n,
        rays,
        form_factors: stats,
        channels,
        grey_rel_l2,
        grey_tail_rel_l2,
        matrix_bytes: transport.payload.len() as u64,
        codec_eind_rel_l2: codec_err,
        timings: sum_timings([&timings]),
    });
    Ok(Baked {
        meta,
        layout: first.layout,
        transport,
        form_factors,
        near_field,
        sky: Some(sky),
        emitters: first.emitters,
        probes,
        occupancy: first.surface.is_none().then_some(first.occupancy),
        surface: first.surface,
        elements: first.elements,
        model,
    })
}

/// Rows `rows` of a whole near-field matrix.
fn slice_rows(all: &NearField, rows: Range<usize>) -> NearField {
    let (lo, hi) = (all.row_ptr[rows.start], all.row_ptr[rows.end]);
    NearField {
        per_row: all.per_row,
        row_ptr: all.row_ptr[rows.start..=rows.end]
            .iter()
            .map(|&p| p - lo)
            .collect(),
        cols: all.cols[lo as usize..hi as usize].to_vec(),
        values: all.values[lo as usize..hi as usize].to_vec(),
        albedo: all
            .albedo
            .as_ref()
            .map(|a| a[lo as usize..hi as usize].to_vec()),
        sky: all.sky.as_ref().map(|sky| {
            let k = all.per_row as usize;
            sky.slice(rows.start * k..rows.end * k)
        }),
    }
}

/// The model the shards carry, from the first: every shard of one bake packed the same scene
/// (`gather` checked that their sources match), so one read is enough.
fn model_of(members: &[Member]) -> Result<Option<Vec<u8>>, ShardError> {
    let Some(first) = members.first() else {
        return Ok(None);
    };
    ShardFile::read_model(&first.path).map_err(|error| ShardError::Read {
        path: first.path.clone(),
        error,
    })
}

/// Stage times added up by stage name, in the order stages first appear: in a merged file a
/// stage's time is its total over the shards that ran it.
fn sum_timings<'a>(lists: impl IntoIterator<Item = &'a Vec<StageTiming>>) -> Vec<StageTiming> {
    let mut out: Vec<StageTiming> = Vec::new();
    for t in lists.into_iter().flatten() {
        match out.iter_mut().find(|o| o.stage == t.stage) {
            Some(o) => o.seconds += t.seconds,
            None => out.push(t.clone()),
        }
    }
    out
}

/// A shard found among a step's inputs.
struct Member {
    path: PathBuf,
    header: ShardHeader,
}

/// The shard files `inputs` name: files as given, directories as their `*.bshard` files in
/// name order.
pub fn expand_inputs(inputs: &[PathBuf]) -> Result<Vec<PathBuf>, ShardError> {
    let mut out = Vec::new();
    for p in inputs {
        if p.is_dir() {
            let list = |error| ShardError::List {
                path: p.clone(),
                error,
            };
            let mut found = Vec::new();
            for entry in std::fs::read_dir(p).map_err(list)? {
                let path = entry.map_err(list)?.path();
                if path.extension().is_some_and(|e| e == SHARD_EXTENSION) && path.is_file() {
                    found.push(path);
                }
            }
            found.sort();
            out.extend(found);
        } else {
            out.push(p.clone());
        }
    }
    Ok(out)
}

/// Reads the headers of the shards `inputs` name and checks that they are the whole of one step
/// of one bake: one phase (`expected`, or the first shard's), one split, every index once, and
/// the same settings, scene, layout and build. Sorted by index.
fn gather(inputs: &[PathBuf], expected: Option<Phase>) -> Result<Vec<Member>, ShardError> {
    let paths = expand_inputs(inputs)?;
    let mut members = Vec::with_capacity(paths.len());
    for path in paths {
        let header = ShardHeader::read(&path).map_err(|error| ShardError::Read {
            path: path.clone(),
            error,
        })?;
        members.push(Member { path, header });
    }
    let Some(first) = members.first() else {
        return Err(ShardError::NoShards);
    };
    let phase = expected.unwrap_or(first.header.meta.phase);
    for m in &members {
        if m.header.meta.phase != phase {
            return Err(ShardError::WrongPhase {
                path: m.path.clone(),
                found: m.header.meta.phase,
                expected: phase,
            });
        }
    }
    let count = first.header.meta.count;
    for m in &members[1..] {
        if m.header.meta.count != count {
            return Err(ShardError::CountMismatch {
                path: m.path.clone(),
                count: m.header.meta.count,
                first: first.path.clone(),
                first_count: count,
            });
        }
        if let Some(what) = difference(&first.header, &m.header) {
            return Err(ShardError::Mismatch {
                first: first.path.clone(),
                second: m.path.clone(),
                what,
            });
        }
    }
    let mut by_index: BTreeMap<u32, &Path> = BTreeMap::new();
    for m in &members {
        let index = m.header.meta.index;
        if let Some(prev) = by_index.insert(index, &m.path) {
            return Err(ShardError::Duplicate {
                index,
                count,
                first: prev.to_path_buf(),
                second: m.path.clone(),
            });
        }
    }
    // Every index is below `count` (checked on reading), so with no duplicates a shortfall in
    // number is exactly the missing ones.
    let missing_count = u64::from(count) - by_index.len() as u64;
    if missing_count > 0 {
        let missing = (0..count)
            .filter(|i| !by_index.contains_key(i))
            .take(MISSING_LISTED)
            .collect();
        return Err(ShardError::Missing {
            missing,
            missing_count,
            count,
        });
    }
    members.sort_by_key(|m| m.header.meta.index);
    Ok(members)
}

/// What differs between two shards that must come from one bake, if anything.
fn difference(a: &ShardHeader, b: &ShardHeader) -> Option<&'static str> {
    let (x, y) = (&a.meta, &b.meta);
    if x.tool_version != y.tool_version {
        Some("bounce versions")
    } else if x.settings != y.settings || x.keep_form_factors != y.keep_form_factors {
        Some("bake settings")
    } else if x.source != y.source {
        Some("source scenes")
    } else if a.layout != b.layout || x.patches != y.patches {
        Some("patch layouts")
    } else if a.occupancy != b.occupancy
        || x.occupied_voxels != y.occupied_voxels
        || x.dropped_patches != y.dropped_patches
        || a.surface != b.surface
        || a.elements != b.elements
        || a.emitters != b.emitters
    {
        Some("voxelisations")
    } else if x.channels != y.channels {
        Some("channel counts")
    } else if x.form_factors != y.form_factors || (x.phase == Phase::Transport && x.rays != y.rays)
    {
        Some("form factors (phase-2 shards computed from different phase-1 shards)")
    } else {
        None
    }
}

/// Reads each member's rows (every checksum verified) into one matrix: `channels` of `T` or
/// `F`, and `F` from the `FROW` sections when `form_factors`. One shard is in memory at a time.
fn assemble(
    members: &[Member],
    channels: usize,
    form_factors: bool,
    progress: &dyn Progress,
) -> Result<Assembled, ShardError> {
    let n = members.first().map_or(0, |m| m.header.meta.patches);
    let mut out = DenseMatrix::zeros(n, channels);
    let mut ff = form_factors.then(|| DenseMatrix::zeros(n, 1));
    // The reader requires NROW exactly when the bake has a near field: all or none have it.
    let mut near: Option<Vec<NearField>> = Some(Vec::with_capacity(members.len()));
    let mut sky = Vec::with_capacity(members.len());
    let mut probe_parts = Vec::new();
    for m in members {
        let read_err = |error| ShardError::Read {
            path: m.path.clone(),
            error,
        };
        let file = ShardFile::read(&m.path).map_err(read_err)?;
        if file.header != m.header {
            return Err(ShardError::Changed {
                path: m.path.clone(),
            });
        }
        let meta = &file.header.meta;
        let rows = meta.first_row..meta.end_row;
        copy_rows(&mut out, &file.rows, &rows);
        if let Some(ff) = ff.as_mut() {
            // The reader requires FROW exactly when the shard keeps F.
            let f_rows = file.form_factor_rows.as_deref().ok_or_else(|| {
                read_err(FormatError::BadShard("no form-factor rows".to_string()))
            })?;
            copy_rows(ff, f_rows, &rows);
        }
        near = near.zip(file.near_rows).map(|(mut parts, rows)| {
            parts.push(rows);
            parts
        });
        sky.push(file.sky_rows);
        probe_parts.extend(file.probe_rows);
        progress.advance(rows.len() as u64);
    }
    let near = match (
        near,
        &members.first().and_then(|m| m.header.surface.as_ref()),
    ) {
        (Some(parts), Some(surface)) if !members.is_empty() => {
            Some(NearField::concat(surface.per_patch, parts))
        }
        _ => None,
    };
    // The reader requires PROW exactly when the bake places probes, and the settings agree.
    let probes = if probe_parts.is_empty() {
        None
    } else {
        let joined = ProbeRows::join(probe_parts).map_err(|m| ShardError::Read {
            path: members[0].path.clone(),
            error: FormatError::BadShard(format!("the shards' probes do not join: {m}")),
        })?;
        Some(joined)
    };
    Ok(Assembled {
        rows: out,
        form_factors: ff,
        near,
        sky: SkyVisibility::concat(sky),
        probes,
    })
}

/// Every shard's rows put together.
struct Assembled {
    rows: DenseMatrix,
    /// `F`, when asked for.
    form_factors: Option<DenseMatrix>,
    /// The whole near-field matrix, when the bake has one.
    near: Option<NearField>,
    /// Every row's sky view.
    sky: SkyVisibility,
    /// The probes, gather rows joined, when the bake places them.
    probes: Option<Probes>,
}

/// Shard `spec`'s share of the probes' gather rows (split as the transport's rows are).
fn probe_share(p: &Probes, spec: ShardSpec, path: &Path) -> Result<ProbeRows, ShardError> {
    let range = shard_rows(p.len() * probe::DIRECTIONS, spec.index, spec.count);
    p.rows(range).ok_or_else(|| ShardError::Read {
        path: path.to_path_buf(),
        error: FormatError::BadShard("probes without their sky view".to_string()),
    })
}

/// Rows `rows` of every channel of `m` from `src` (channel-major, as a shard stores them). The
/// lengths were checked on reading.
fn copy_rows(m: &mut DenseMatrix, src: &[f32], rows: &Range<usize>) {
    let n = m.n;
    let per_channel = rows.len() * n;
    for c in 0..m.channels {
        let dst = &mut m.channel_mut(c)[rows.start * n..rows.end * n];
        dst.copy_from_slice(&src[c * per_channel..(c + 1) * per_channel]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_specs_read_with_or_without_the_job_index() {
        let spec = |i, n| ShardSpec { index: i, count: n };
        assert_eq!(ShardSpec::parse("2/4", None).unwrap(), spec(2, 4));
        assert_eq!(ShardSpec::parse("4", Some("3")).unwrap(), spec(3, 4));
        // An explicit index wins over the job's.
        assert_eq!(ShardSpec::parse("0/4", Some("3")).unwrap(), spec(0, 4));
        for (arg, env, says) in [
            ("4", None, "JOB_COMPLETION_INDEX"),
            ("4", Some("4"), "does not exist"),
            ("4/4", None, "does not exist"),
            ("0/0", None, "does not exist"),
            ("a/4", None, "not a whole number"),
            ("4", Some("x"), "JOB_COMPLETION_INDEX 'x'"),
            ("-1/4", None, "not a whole number"),
        ] {
            let e = ShardSpec::parse(arg, env).unwrap_err().to_string();
            assert!(e.contains(says), "{arg} {env:?}: {e}");
        }
    }

    #[test]
    fn timings_add_up_by_stage() {
        let t = |s: &str, x| StageTiming {
            stage: s.to_string(),
            seconds: x,
        };
        let a = vec![t("import", 1.0), t("form factors", 2.0)];
        let b = vec![t("import", 0.5), t("form factors", 4.0), t("encode", 1.0)];
        assert_eq!(
            sum_timings([&a, &b]),
            vec![t("import", 1.5), t("form factors", 6.0), t("encode", 1.0)]
        );
    }
}
