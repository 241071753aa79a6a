//! `bounce reference`: path-traced indirect irradiance on the original triangles, the
//! independent yardstick `bounce verify` measures the pipeline against.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use bounce_core::format::Baked;
use bounce_core::import::import_path;
use bounce_core::light::LightSet;
use bounce_core::meta::Bounces;
use bounce_core::patch::PatchLayout;
use bounce_reference::{Estimate, Options, Point, Reference, SnapReport};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

#[derive(Args, Debug)]
pub struct ReferenceArgs {
    /// The glTF/GLB scene (its original triangles are traced).
    pub scene: PathBuf,
    /// Light configuration, `{"lights": [...]}`; without it, the scene's own glTF lights.
    #[arg(long, value_name = "L.json")]
    pub lights: Option<PathBuf>,
    /// Where to estimate: `footprints` (per patch of --baked, the average over the pieces of
    /// original triangles it stands for), `patches` (one point a patch: its recorded centroid
    /// moved along its normal onto the nearest surface),
    /// `centroids` (the recorded centroids as they are, which can lie off the surfaces where a
    /// patch's triangles meet at an angle) or a JSON file
    /// `[{"position": [x,y,z], "normal": [x,y,z]}, ...]`.
    #[arg(
        long,
        value_name = "footprints|patches|centroids|FILE",
        default_value = "footprints"
    )]
    pub points: String,
    /// For --points footprints: points drawn on each patch's footprint (they share --spp)
    /// [default: as many as --spp, one path each]. The standard error is taken across the
    /// points, so it counts how much the value varies over the patch; fewer points than paths
    /// leave more of that variation in the reference.
    #[arg(long, value_name = "M")]
    pub footprint_points: Option<usize>,
    /// The baked file whose patches give the points (and, unless --bounces, the bounce count).
    #[arg(long, value_name = "FILE")]
    pub baked: Option<PathBuf>,
    /// Sample paths per point; the standard error falls as 1/√N.
    #[arg(long, value_name = "N", default_value_t = 1024)]
    pub spp: u32,
    /// Light bounces carried, as `bounce bake --bounces`: a number of at least 1, or "all"
    /// [default: the baked file's, else all].
    #[arg(long, value_name = "K|all")]
    pub bounces: Option<Bounces>,
    /// Seed: the same seed, points and --spp give the same values on any thread count.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write every point's estimate and standard error: .json or .csv.
    #[arg(long, value_name = "OUT")]
    pub out: Option<PathBuf>,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Estimates at a set of points and what it took.
pub(crate) struct Traced {
    pub points: Vec<Point>,
    pub estimates: Vec<Estimate>,
    pub snap: Option<SnapReport>,
    pub seconds: f64,
}

impl Traced {
    /// `‖stderr‖ / ‖mean‖` over all points and channels: the reference's own noise level.
    pub fn rel_stderr(&self) -> f64 {
        let (mut se, mut m) = (0.0, 0.0);
        for e in &self.estimates {
            for c in 0..3 {
                se += e.stderr[c] * e.stderr[c];
                m += e.mean[c] * e.mean[c];
            }
        }
        if m > 0.0 { (se / m).sqrt() } else { 0.0 }
    }
}

pub fn run(args: &ReferenceArgs) -> Result<()> {
    let footprint_points = args.footprint_points.unwrap_or(args.spp as usize).max(1);
    let scene =
        import_path(&args.scene).with_context(|| format!("importing {}", args.scene.display()))?;
    let baked = args
        .baked
        .as_deref()
        .map(|p| Baked::read(p).with_context(|| format!("reading {}", p.display())))
        .transpose()?;
    let lights = crate::lights_file::or_scene(args.lights.as_deref(), &scene)?;
    let reference = Reference::new(&scene)?;
    let bounces = args
        .bounces
        .or(baked.as_ref().map(|b| b.meta.settings.bounces))
        .unwrap_or(Bounces::All);
    let options = Options {
        spp: args.spp,
        bounces,
        seed: args.seed,
    };
    let (points, snap) = match (args.points.as_str(), &baked) {
        ("patches", Some(baked)) => {
            let (points, report) = reference.snap_patches(&baked.layout);
            (points, Some(report))
        }
        ("centroids", Some(baked)) => (Reference::patch_centroids(&baked.layout), None),
        ("footprints", Some(_)) => (Vec::new(), None),
        ("footprints" | "patches" | "centroids", None) => {
            bail!(
                "--points {} needs --baked FILE: the patches are in the baked file",
                args.points
            )
        }
        (file, _) => (read_points(Path::new(file))?, None),
    };
    let traced = match (&baked, args.points.as_str()) {
        (Some(baked), "footprints") => trace_footprints(
            &reference,
            &lights,
            &baked.layout,
            footprint_points,
            &options,
            args.quiet,
        )?,
        _ => trace(&reference, &lights, points, snap, &options, args.quiet)?,
    };
    let n = traced.points.len();
    eprintln!(
        "{n} points, {} triangles, {} spp, {} bounces: {:.2} s; mean E_ind {}, relative standard error {:.3}%",
        reference.triangles(),
        args.spp,
        bounces,
        traced.seconds,
        fmt_rgb(mean(&traced.estimates)),
        traced.rel_stderr() * 100.0
    );
    if let Some(s) = traced.snap {
        if args.points == "footprints" {
            eprintln!(
                "points: {} footprint points a patch; {} patches had none and used their snapped centroid",
                footprint_points, s.kept
            );
        } else {
            eprintln!(
                "points: {} patch centroids moved onto their surface, {} left where they were",
                s.snapped, s.kept
            );
        }
    }
    if let Some(out) = &args.out {
        write_out(out, &traced)?;
        eprintln!("wrote {}", out.display());
    }
    Ok(())
}

/// Traces `points` with a progress bar.
pub(crate) fn trace(
    reference: &Reference,
    lights: &LightSet,
    points: Vec<Point>,
    snap: Option<SnapReport>,
    options: &Options,
    quiet: bool,
) -> Result<Traced> {
    let bar = bar(points.len() as u64, quiet);
    let start = Instant::now();
    let estimates = reference.estimate(lights, &points, options, &|n| bar.inc(n))?;
    bar.finish_and_clear();
    Ok(Traced {
        points,
        estimates,
        snap,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Footprint-averaged estimates for every patch of `layout`, with a progress bar. `snap.kept`
/// counts the patches whose footprint was empty (they used their snapped centroid).
pub(crate) fn trace_footprints(
    reference: &Reference,
    lights: &LightSet,
    layout: &PatchLayout,
    points_per_patch: usize,
    options: &Options,
    quiet: bool,
) -> Result<Traced> {
    let bar = bar(layout.len() as u64, quiet);
    let start = Instant::now();
    let (estimates, points, fallbacks) =
        reference
            .estimate_footprints(lights, layout, points_per_patch, options, &|n| bar.inc(n))?;
    bar.finish_and_clear();
    Ok(Traced {
        points,
        estimates,
        snap: Some(SnapReport {
            snapped: layout.len() - fallbacks,
            kept: fallbacks,
        }),
        seconds: start.elapsed().as_secs_f64(),
    })
}

fn bar(len: u64, quiet: bool) -> ProgressBar {
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(len).with_style(
            ProgressStyle::with_template(
                "{prefix:>14} [{bar:40}] {pos}/{len} points  {elapsed_precise} eta {eta}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        )
    };
    bar.set_prefix("reference");
    bar
}

fn read_points(path: &Path) -> Result<Vec<Point>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let points: Vec<Point> = serde_json::from_str(&text).with_context(|| {
        format!(
            "{}: expected [{{\"position\": [x, y, z], \"normal\": [x, y, z]}}, ...]",
            path.display()
        )
    })?;
    if points.is_empty() {
        bail!("{}: no points", path.display());
    }
    Ok(points)
}

pub(crate) fn mean(estimates: &[Estimate]) -> [f64; 3] {
    let n = estimates.len().max(1) as f64;
    let mut m = [0.0; 3];
    for e in estimates {
        for (m, v) in m.iter_mut().zip(e.mean) {
            *m += v / n;
        }
    }
    m
}

pub(crate) fn fmt_rgb(c: [f64; 3]) -> String {
    format!("({:.4}, {:.4}, {:.4})", c[0], c[1], c[2])
}

#[derive(Serialize)]
struct PointOut {
    position: [f32; 3],
    normal: [f32; 3],
    e_ind: [f64; 3],
    stderr: [f64; 3],
}

fn write_out(path: &Path, traced: &Traced) -> Result<()> {
    let text = match path.extension().and_then(|e| e.to_str()) {
        Some("json") => {
            let points: Vec<PointOut> = traced
                .points
                .iter()
                .zip(&traced.estimates)
                .map(|(p, e)| PointOut {
                    position: p.position,
                    normal: p.normal,
                    e_ind: e.mean,
                    stderr: e.stderr,
                })
                .collect();
            serde_json::to_string_pretty(&serde_json::json!({
                "seconds": traced.seconds,
                "rel_stderr": traced.rel_stderr(),
                "points": points,
            }))?
        }
        Some("csv") => {
            let mut s = String::from("index,x,y,z,nx,ny,nz,r,g,b,se_r,se_g,se_b\n");
            for (i, (p, e)) in traced.points.iter().zip(&traced.estimates).enumerate() {
                let [x, y, z] = p.position;
                let [nx, ny, nz] = p.normal;
                s += &format!(
                    "{i},{x},{y},{z},{nx},{ny},{nz},{},{},{},{},{},{}\n",
                    e.mean[0], e.mean[1], e.mean[2], e.stderr[0], e.stderr[1], e.stderr[2]
                );
            }
            s
        }
        _ => bail!("--out {}: give a .json or .csv file", path.display()),
    };
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}
