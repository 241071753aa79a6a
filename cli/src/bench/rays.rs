//! `bounce bench rays`: form-factor ray tracing, the voxel-grid tracer against the obvhs BVH on
//! the same patches.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use bounce_core::bake::{BakeOptions, simplify};
use bounce_core::formfactor::{RayScene, Tracer, form_factors};
use bounce_core::import::import_path;
use bounce_core::voxel::Resolution;
use clap::Args;

use super::table::emit;

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

pub fn run(args: &BenchRaysArgs) -> Result<()> {
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
