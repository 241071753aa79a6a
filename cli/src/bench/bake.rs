//! `bounce bench bake`: one scene baked at several patch counts, each in a child process so its
//! peak memory is its own: time per stage, peak memory, file size and the bake's own checks.

use std::path::PathBuf;
use std::process::Command;

use anyhow::{Context, Result, bail};
use clap::Args;

use super::table::emit;
use crate::bake::BakeReport;
use bounce_core::meta::Bounces;

#[derive(Args, Debug)]
pub struct BenchBakeArgs {
    /// The scene to bake (.gltf or .glb).
    pub scene: PathBuf,
    /// Patch counts to bake, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "1000,4000,8000")]
    pub patches: Vec<u32>,
    #[arg(long, default_value_t = 2048)]
    pub rays: u32,
    /// Light bounces each bake carries (`bounce bake --bounces`): "all" or a number.
    #[arg(long, default_value = "all")]
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

const STAGES: [&str; 7] = [
    "import",
    "voxelize",
    "ray scene",
    "form factors",
    "transport",
    "encode",
    "write",
];

pub fn run(args: &BenchBakeArgs) -> Result<()> {
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
