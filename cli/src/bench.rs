//! `bounce bench`: benchmark commands that print a table and write CSV, comparing variants
//! measured in one run. Each bake runs in a child process so its peak memory is its own.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use bounce_core::bake::{BakeOptions, simplify};
use bounce_core::formfactor::{RayScene, Tracer, form_factors};
use bounce_core::import::import_path;
use bounce_core::meta::Bounces;
use bounce_core::voxel::Resolution;
use clap::{Args, Subcommand};

use crate::bake_cmd::BakeReport;

#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchWhat,
}

#[derive(Subcommand, Debug)]
pub enum BenchWhat {
    /// Bake one scene at several patch counts: time per stage, peak memory, file size, checks.
    Bake(BenchBakeArgs),
    /// Form-factor ray tracing: the voxel-grid tracer against the obvhs BVH on the same patches.
    Rays(BenchRaysArgs),
    /// Every codec on one baked (dense-f32) transport: bytes, encode and product time, entry and
    /// indirect-irradiance error, side by side; the thesis' reordering table (0, 1, 2 passes, from
    /// the bake's patch order and from a shuffled one); optionally a sparse-share sweep; a plot.
    Codecs(crate::bench_codecs::BenchCodecsArgs),
    /// Relight engines (CPU, GPU) × codecs × batch sizes against the exact solve, with the
    /// thesis' baselines (classic radiosity with F, dense T, compressed T): latency, light sets
    /// per second, effective bandwidth, E_ind error.
    Engines(crate::bench_engines::BenchEnginesArgs),
    /// The lighting service under load on loopback: mixed gRPC and WebSocket viewers, light
    /// changes at a fixed rate on one or more sessions; change-to-frame latency per viewer,
    /// frames per second, order checked on every frame.
    Serve(crate::bench_serve::BenchServeArgs),
    /// Run time against error across patch counts, ray counts and codecs, every error measured
    /// against the path-traced reference on the original triangles: a table, CSV and a plot.
    Tradeoff(crate::bench_tradeoff::BenchTradeoffArgs),
}

#[derive(Args, Debug)]
pub struct BenchRaysArgs {
    /// The scene (.gltf or .glb).
    pub scene: PathBuf,
    /// Patch counts, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "1000,4000")]
    pub patches: Vec<u32>,
    #[arg(long, default_value_t = 1024)]
    pub rays: u32,
    /// Timed runs per tracer; the table shows the median.
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Write the table as CSV here too.
    #[arg(long, value_name = "OUT.csv")]
    pub csv: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct BenchBakeArgs {
    /// The scene to bake (.gltf or .glb).
    pub scene: PathBuf,
    /// Patch counts to bake, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "1000,4000,8000")]
    pub patches: Vec<u32>,
    #[arg(long, default_value_t = 2048)]
    pub rays: u32,
    #[arg(long, default_value = "3")]
    pub bounces: Bounces,
    /// The codec each bake stores (`bounce bake --codec`). The exact dense-f32 by default, so
    /// the table times the pipeline itself; `auto` adds the encode-every-codec search that a
    /// plain `bounce bake` runs.
    #[arg(long, value_name = "NAME|auto", default_value = bounce_core::matrix::DENSE_F32)]
    pub codec: String,
    /// Write the table as CSV here too.
    #[arg(long, value_name = "OUT.csv")]
    pub csv: Option<PathBuf>,
}

pub fn run(args: &BenchArgs) -> Result<()> {
    match &args.what {
        BenchWhat::Bake(a) => bench_bake(a),
        BenchWhat::Rays(a) => bench_rays(a),
        BenchWhat::Codecs(a) => crate::bench_codecs::run(a),
        BenchWhat::Engines(a) => crate::bench_engines::run(a),
        BenchWhat::Serve(a) => crate::bench_serve::run(a),
        BenchWhat::Tradeoff(a) => crate::bench_tradeoff::run(a),
    }
}

const STAGES: [&str; 7] = [
    "import",
    "voxelize",
    "ray scene",
    "form factors",
    "transport",
    "encode",
    "write",
];

fn bench_bake(args: &BenchBakeArgs) -> Result<()> {
    if args.patches.is_empty() {
        bail!("--patches needs at least one count");
    }
    let exe = std::env::current_exe().context("locating the bounce binary")?;
    let dir = tempfile::tempdir().context("creating a scratch directory")?;
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    eprintln!(
        "bench bake: {} at {:?} patches, {} rays, {} bounce(s), {threads} thread(s)",
        args.scene.display(),
        args.patches,
        args.rays,
        args.bounces
    );
    let mut header = vec!["patches_target", "patches", "voxel_size", "channels"];
    let stage_cols: Vec<String> = STAGES
        .iter()
        .map(|s| format!("{}_s", s.replace(' ', "_")))
        .collect();
    header.extend(stage_cols.iter().map(String::as_str));
    header.extend([
        "total_s",
        "peak_rss_mib",
        "file_mib",
        "row_sum_mean",
        "ray_escaped",
        "reciprocity_error",
    ]);
    let mut rows: Vec<Vec<String>> = Vec::new();
    for &target in &args.patches {
        let out = dir.path().join(format!("{target}.bounce"));
        let report_path = dir.path().join(format!("{target}.json"));
        let status = Command::new(&exe)
            .arg("bake")
            .arg(&args.scene)
            .arg("-o")
            .arg(&out)
            .args(["--patches", &target.to_string()])
            .args(["--rays", &args.rays.to_string()])
            .args(["--bounces", &args.bounces.to_string()])
            .args(["--codec", &args.codec])
            .arg("--quiet")
            .arg("--report-json")
            .arg(&report_path)
            .stdout(std::process::Stdio::null())
            .status()
            .context("running bounce bake")?;
        if !status.success() {
            bail!("bake at {target} patches failed ({status})");
        }
        let report: BakeReport = serde_json::from_slice(
            &std::fs::read(&report_path).context("reading the bake report")?,
        )
        .context("parsing the bake report")?;
        let _ = std::fs::remove_file(&out);
        let s = &report.stats;
        let mut row = vec![
            target.to_string(),
            s.patches.to_string(),
            format!("{:.4}", s.voxel_size),
            s.channels.to_string(),
        ];
        for stage in STAGES {
            let t: f64 = report
                .timings
                .iter()
                .filter(|t| t.stage == stage)
                .map(|t| t.seconds)
                .sum();
            row.push(format!("{t:.2}"));
        }
        let mib = |b: u64| b as f64 / (1024.0 * 1024.0);
        row.push(format!("{:.2}", report.wall_seconds));
        row.push(
            report
                .peak_rss_bytes
                .map_or("-".into(), |b| format!("{:.0}", mib(b))),
        );
        row.push(format!("{:.1}", mib(report.file_bytes)));
        row.push(format!("{:.4}", s.row_sum_mean));
        row.push(format!(
            "{:.4}",
            s.rays.escaped as f64 / s.rays.total().max(1) as f64
        ));
        row.push(format!("{:.4}", s.reciprocity_error));
        eprintln!("  {target} patches: {:.2} s", report.wall_seconds);
        rows.push(row);
    }
    emit(&header, &rows, args.csv.as_deref())
}

fn bench_rays(args: &BenchRaysArgs) -> Result<()> {
    if args.patches.is_empty() || args.repeat == 0 || args.rays == 0 {
        bail!("--patches, --repeat and --rays must be non-empty and positive");
    }
    let scene =
        import_path(&args.scene).with_context(|| format!("importing {}", args.scene.display()))?;
    let threads = rayon::current_num_threads();
    eprintln!(
        "bench rays: {} at {:?} patches, {} rays a patch, median of {}, {threads} thread(s)",
        args.scene.display(),
        args.patches,
        args.rays,
        args.repeat
    );
    let header = [
        "patches",
        "tracer",
        "build_s",
        "trace_s_median",
        "mrays_per_s",
        "speedup_vs_bvh",
        "reach_patch",
        "escaped",
        "entries_differing",
        "max_entry_diff",
    ];
    let mut rows = Vec::new();
    for &target in &args.patches {
        let options = BakeOptions {
            resolution: Resolution::TargetPatches(target),
            // The tracers compared here are the voxel-face ones.
            geometry: bounce_core::voxel::Geometry::VoxelFaces,
            ..BakeOptions::default()
        };
        let vox = simplify(&scene, &options)?;
        let n = vox.layout.len();
        let mut results = Vec::new();
        for tracer in [Tracer::Bvh, Tracer::Grid] {
            let start = Instant::now();
            let rs = RayScene::voxels(&vox.layout, &vox.occupied, &vox.occluders, tracer);
            let build = start.elapsed().as_secs_f64();
            let mut times = Vec::new();
            let mut last = None;
            for _ in 0..args.repeat {
                let start = Instant::now();
                let out = form_factors(&rs, args.rays, 1, &|_| {})?;
                times.push(start.elapsed().as_secs_f64());
                last = Some(out);
            }
            times.sort_by(f64::total_cmp);
            let median = times[times.len() / 2];
            let Some((f, tally)) = last else {
                bail!("no timed run");
            };
            eprintln!("  {n} patches, {tracer}: {median:.3} s");
            results.push((rs.tracer(), build, median, f, tally));
        }
        let bvh_time = results[0].2;
        let bvh_f = results[0].3.data.clone();
        for (tracer, build, median, f, tally) in &results {
            let (mut differing, mut max_diff) = (0usize, 0.0f32);
            for (a, b) in f.data.iter().zip(&bvh_f) {
                if a != b {
                    differing += 1;
                    max_diff = max_diff.max((a - b).abs());
                }
            }
            let total = tally.total().max(1) as f64;
            rows.push(vec![
                n.to_string(),
                tracer.to_string(),
                format!("{build:.3}"),
                format!("{median:.3}"),
                format!("{:.2}", total / median / 1e6),
                format!("{:.2}", bvh_time / median),
                format!("{:.4}", tally.patch as f64 / total),
                format!("{:.4}", tally.escaped as f64 / total),
                format!("{:.2e}", differing as f64 / (n * n).max(1) as f64),
                format!("{max_diff:.2e}"),
            ]);
        }
    }
    emit(&header, &rows, args.csv.as_deref())
}

/// Print the table and write it as CSV when asked.
pub fn emit(header: &[&str], rows: &[Vec<String>], csv: Option<&std::path::Path>) -> Result<()> {
    print!("{}", table(header, rows));
    if let Some(path) = csv {
        let mut text = header.join(",");
        text.push('\n');
        for r in rows {
            text.push_str(&r.join(","));
            text.push('\n');
        }
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// A plain aligned text table.
fn table(header: &[&str], rows: &[Vec<String>]) -> String {
    let mut widths: Vec<usize> = header.iter().map(|h| h.len()).collect();
    for r in rows {
        for (w, c) in widths.iter_mut().zip(r) {
            *w = (*w).max(c.len());
        }
    }
    let mut out = String::new();
    let line = |cells: Vec<&str>, out: &mut String| {
        let cells: Vec<String> = cells
            .iter()
            .zip(&widths)
            .map(|(c, w)| format!("{c:>w$}"))
            .collect();
        let _ = writeln!(out, "{}", cells.join("  "));
    };
    line(header.to_vec(), &mut out);
    for r in rows {
        line(r.iter().map(String::as_str).collect(), &mut out);
    }
    out
}
