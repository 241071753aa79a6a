//! `bounce bench tradeoff`: run time against error across patch counts, ray counts and codecs,
//! each error measured against the path-traced reference (averaged over each patch's footprint,
//! as `bounce verify` does by default), so a setting can be chosen by what it costs and what it
//! gets wrong. Both geometries (surface patches and the thesis' voxel faces) run in one
//! invocation, so the chart shows what the surface method gains at what cost.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use bounce_core::bake::{BakeOptions, CodecRequest, NoProgress, bake_scene};
use bounce_core::codec;
use bounce_core::format::Baked;
use bounce_core::import::import_path;
use bounce_core::matrix::{DENSE_F32, EncodedMatrix};
use bounce_core::meta::Bounces;
use bounce_core::nearfield::MAX_NEAR_RADIUS;
use bounce_core::surface::MAX_SURFACE_SAMPLES;
use bounce_core::voxel::{Geometry, Resolution};
use bounce_engine::{Engine, EngineChoice};
use bounce_reference::{Options, Reference};
use clap::Args;

use super::plot::{Point, plot_error};
use crate::reference_cmd::trace_footprints;
use bounce_reference::compare::{rel_l2, widen};

#[derive(Args, Debug)]
pub struct BenchTradeoffArgs {
    /// The scene (.gltf or .glb).
    pub scene: PathBuf,
    /// Light configuration, `{"lights": [...]}`; without it, the scene's own glTF lights.
    #[arg(long, value_name = "L.json")]
    pub lights: Option<PathBuf>,
    /// Patch counts, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "500,1000,2000")]
    pub patches: Vec<u32>,
    /// Form-factor rays per patch, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "256,1024,4096")]
    pub rays: Vec<u32>,
    /// Codecs, comma separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "dense-f32,dense-f16,bc1,bc1-resid"
    )]
    pub codecs: Vec<String>,
    /// Patch geometries, comma separated: `surface` and/or `voxel-faces`.
    #[arg(long, value_delimiter = ',', default_value = "surface,voxel-faces")]
    pub geometries: Vec<Geometry>,
    /// Near-field radii in voxels, comma separated (surface geometry; 0 bakes none).
    #[arg(long, value_delimiter = ',', default_value = "1")]
    pub near_field: Vec<f32>,
    /// Direct-light sample points stored a row, comma separated (surface geometry; a relight
    /// uses them all).
    #[arg(long, value_delimiter = ',', default_value = "32")]
    pub direct_samples: Vec<u32>,
    /// Light bounces each bake carries (`bounce bake --bounces`): "all" or a number.
    #[arg(long, default_value = "all")]
    pub bounces: Bounces,
    /// Reference sample paths per patch.
    #[arg(long, default_value_t = 2048)]
    pub spp: u32,
    /// Relight engine timed: auto, gpu or cpu.
    #[arg(long, default_value = "cpu")]
    pub engine: String,
    /// Timed relights per variant; the table shows the median.
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Write the table as CSV here too.
    #[arg(long, value_name = "OUT.csv")]
    pub csv: Option<PathBuf>,
    /// Draw error against bake time and against relight time (SVG).
    #[arg(long, value_name = "OUT.svg")]
    pub plot: Option<PathBuf>,
}

struct Row {
    geometry: Geometry,
    patches: usize,
    rays: u32,
    /// Direct-light samples a row and near-field radius (surface geometry; 0 for voxel faces).
    samples: u32,
    near_field: f32,
    codec: String,
    bake_s: f64,
    encode_s: f64,
    bytes: usize,
    relight_ms: f64,
    codec_rel_l2: f64,
    method_rel_l2: f64,
    total_rel_l2: f64,
    reference_rel_stderr: f64,
}

pub fn run(args: &BenchTradeoffArgs) -> Result<()> {
    let scene =
        import_path(&args.scene).with_context(|| format!("importing {}", args.scene.display()))?;
    let lights = crate::lights_file::or_scene(args.lights.as_deref(), &scene)?;
    let reference = Reference::new(&scene)?;
    let engine = Engine::new(args.engine.parse::<EngineChoice>()?)?;
    eprintln!("relight engine: {}", engine.describe());
    let name = args
        .scene
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    if let Some(r) = args
        .near_field
        .iter()
        .find(|r| !(0.0..=MAX_NEAR_RADIUS).contains(*r))
    {
        bail!("--near-field {r}: radii are from 0 to {MAX_NEAR_RADIUS} voxels");
    }
    if let Some(n) = args
        .direct_samples
        .iter()
        .find(|n| !(1..=MAX_SURFACE_SAMPLES).contains(*n))
    {
        bail!("--direct-samples {n}: from 1 to {MAX_SURFACE_SAMPLES}");
    }
    let mut rows = Vec::new();
    for &geometry in &args.geometries {
        // Sample points and the near field are surface geometry's; voxel faces bake once.
        let lighting: Vec<(u32, f32)> = match geometry {
            Geometry::Surface => args
                .direct_samples
                .iter()
                .flat_map(|&s| args.near_field.iter().map(move |&r| (s, r)))
                .collect(),
            Geometry::VoxelFaces => vec![(0, 0.0)],
        };
        for &target in &args.patches {
            // The layout does not depend on the ray count (isolated patches are found with a fixed
            // probe), so one reference serves every ray count of a patch count; checked below.
            let mut traced: Option<(bounce_core::patch::PatchLayout, Vec<[f64; 3]>, f64)> = None;
            for (&rays, &(samples, near_field)) in args
                .rays
                .iter()
                .flat_map(|r| lighting.iter().map(move |l| (r, l)))
            {
                let direct_samples = if samples > 0 {
                    samples
                } else {
                    BakeOptions::default().direct_samples
                };
                let options = BakeOptions {
                    resolution: Resolution::TargetPatches(target),
                    rays,
                    bounces: args.bounces,
                    geometry,
                    codec: CodecRequest::Named(DENSE_F32.to_string()),
                    direct_samples,
                    landing_samples: bounce_core::surface::default_landing_samples(direct_samples),
                    near_radius: near_field,
                    ..BakeOptions::default()
                };
                let start = Instant::now();
                let exact = bake_scene(&scene, &name, &options, &NoProgress)?;
                let bake_s = start.elapsed().as_secs_f64();
                if !matches!(&traced, Some((layout, ..)) if *layout == exact.layout) {
                    let options = Options {
                        spp: args.spp,
                        bounces: args.bounces,
                        seed: 1,
                    };
                    // One footprint point per path, as `verify` draws them: the standard
                    // error then counts how the value varies over each patch.
                    let points = args.spp as usize;
                    let t = trace_footprints(
                        &reference,
                        &lights,
                        &exact.layout,
                        points,
                        &options,
                        false,
                    )?;
                    let values = t.estimates.iter().map(|e| e.mean).collect();
                    traced = Some((exact.layout.clone(), values, t.rel_stderr()));
                }
                let Some((_, reference_e, stderr)) = &traced else {
                    unreachable!("set just above")
                };
                let dense = codec::decode(&exact.transport)?.to_dense();
                let (exact_e, _) = relight(&engine, &exact, &lights, 1)?;
                for name in &args.codecs {
                    let start = Instant::now();
                    let encoded = if name == DENSE_F32 {
                        EncodedMatrix::encode_dense_f32(&dense)
                    } else {
                        codec::configured(name, None)?.encode(&dense)?
                    };
                    let encode_s = start.elapsed().as_secs_f64();
                    let bytes = encoded.payload.len();
                    let variant = Baked {
                        transport: encoded,
                        ..exact.clone()
                    };
                    let (e, relight_ms) = relight(&engine, &variant, &lights, args.repeat)?;
                    let row = Row {
                        geometry,
                        patches: exact.layout.len(),
                        rays,
                        samples,
                        near_field,
                        codec: name.clone(),
                        bake_s,
                        encode_s,
                        bytes,
                        relight_ms,
                        codec_rel_l2: rel_l2(&e, &exact_e),
                        method_rel_l2: rel_l2(&exact_e, reference_e),
                        total_rel_l2: rel_l2(&e, reference_e),
                        reference_rel_stderr: *stderr,
                    };
                    eprintln!(
                        "{geometry}, {} patches, {} rays, {}: total error {:.2}%",
                        row.patches,
                        rays,
                        series(&row),
                        row.total_rel_l2 * 100.0
                    );
                    rows.push(row);
                }
            }
        }
    }
    print_table(&rows);
    if let Some(path) = &args.csv {
        std::fs::write(path, csv(&rows)).with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    if let Some(path) = &args.plot {
        let points: Vec<Point> = rows
            .iter()
            .map(|r| Point {
                label: format!("{}p/{}r", r.patches, r.rays),
                series: series(r),
                x: [r.bake_s + r.encode_s, r.relight_ms],
                rel_l2: r.total_rel_l2,
            })
            .collect();
        plot_error(
            path,
            &format!("{name}: E_ind error against the path-traced reference"),
            &points,
            [
                "bake time (form factors, transport, encode), s",
                "relight time, ms",
            ],
        )?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// What a plot series and the progress lines call a row's variant: its geometry, and for
/// surface geometry its samples and near field, then its codec.
fn series(r: &Row) -> String {
    match r.geometry {
        Geometry::Surface => format!(
            "{} {}s near {} {}",
            r.geometry, r.samples, r.near_field, r.codec
        ),
        Geometry::VoxelFaces => format!("{} {}", r.geometry, r.codec),
    }
}

/// `E_ind` for `lights` and the median relight time over `repeat` runs.
fn relight(
    engine: &Engine,
    baked: &Baked,
    lights: &bounce_core::light::LightSet,
    repeat: usize,
) -> Result<(Vec<[f64; 3]>, f64)> {
    let loaded = engine.load(baked)?;
    let mut times = Vec::new();
    let mut last = Vec::new();
    for _ in 0..repeat.max(1) {
        let (mut lit, t) = engine.relight_timed(&loaded, std::slice::from_ref(lights))?;
        times.push((t.direct_s + t.indirect_s) * 1e3);
        last = lit.remove(0).indirect;
    }
    times.sort_by(f64::total_cmp);
    Ok((widen(&last), times[times.len() / 2]))
}

const HEADER: [&str; 14] = [
    "geometry",
    "patches",
    "rays",
    "samples",
    "near_field",
    "codec",
    "bake_s",
    "encode_s",
    "bytes",
    "relight_ms",
    "codec_rel_l2",
    "method_rel_l2",
    "total_rel_l2",
    "reference_rel_stderr",
];

fn fields(r: &Row) -> [String; 14] {
    [
        r.geometry.to_string(),
        r.patches.to_string(),
        r.rays.to_string(),
        r.samples.to_string(),
        r.near_field.to_string(),
        r.codec.clone(),
        format!("{:.3}", r.bake_s),
        format!("{:.3}", r.encode_s),
        r.bytes.to_string(),
        format!("{:.2}", r.relight_ms),
        format!("{:.5}", r.codec_rel_l2),
        format!("{:.5}", r.method_rel_l2),
        format!("{:.5}", r.total_rel_l2),
        format!("{:.5}", r.reference_rel_stderr),
    ]
}

fn csv(rows: &[Row]) -> String {
    let mut s = HEADER.join(",") + "\n";
    for r in rows {
        s += &(fields(r).join(",") + "\n");
    }
    s
}

fn print_table(rows: &[Row]) {
    let mut s = format!("| {} |\n|", HEADER.join(" | "));
    for _ in HEADER {
        s += "---|";
    }
    s += "\n";
    for r in rows {
        let _ = writeln!(s, "| {} |", fields(r).join(" | "));
    }
    print!("{s}");
}
