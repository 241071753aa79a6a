//! `bounce relight`: one batch of light configurations through an engine, irradiance per patch
//! out as JSON or CSV.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use bounce_core::format::Baked;
use bounce_core::light::LightSet;
use bounce_engine::{Engine, EngineChoice, Irradiance};
use clap::Args;

#[derive(Args, Debug)]
pub struct RelightArgs {
    /// A file from `bounce bake`.
    pub baked: PathBuf,
    /// Light configuration, `{"lights": [...]}` (glTF KHR_lights_punctual names and units).
    /// Repeat for a batch; without it, the scene's own glTF lights.
    #[arg(long, value_name = "L.json")]
    pub lights: Vec<PathBuf>,
    /// `auto` takes the GPU when an adapter exists, else the CPU, and says which.
    #[arg(long, value_name = "auto|gpu|cpu", default_value = "auto")]
    pub engine: String,
    /// Direct-light samples per patch [default: every sample point a surface bake stores, which
    /// its near-field first bounce needs; 16 for voxel faces]. Voxel faces round it down to a
    /// square, at most 256; a surface bake uses at most what it stores, and fewer leave its near
    /// field out.
    #[arg(long, value_name = "N")]
    pub samples: Option<u32>,
    /// Write direct and indirect irradiance per patch here: `.json` or `.csv`.
    #[arg(long, value_name = "OUT.json|OUT.csv")]
    pub out: Option<PathBuf>,
}

pub fn run(args: &RelightArgs) -> Result<()> {
    let choice: EngineChoice = args.engine.parse()?;
    if args.samples == Some(0) {
        bail!("--samples must be at least 1");
    }
    let format = match &args.out {
        None => None,
        Some(p) => Some(OutFormat::of(p)?),
    };
    let baked =
        Baked::read(&args.baked).with_context(|| format!("reading {}", args.baked.display()))?;
    let (names, sets) = light_sets(args, &baked)?;
    if let Some(warning) = crate::lights_file::sky_warning(&baked, &args.baked, &sets) {
        eprintln!("warning: {warning}");
    }

    let mut engine = Engine::new(choice)?;
    engine.samples = args.samples;
    eprintln!("engine: {}", engine.describe());
    if let Some(why) = engine.fallback() {
        eprintln!("  (no GPU: {why})");
    }
    let scene = engine.load(&baked).with_context(|| {
        format!(
            "loading {} on the {} engine",
            args.baked.display(),
            engine.kind()
        )
    })?;
    let (lit, timing) = engine.relight_timed(&scene, &sets)?;
    eprintln!(
        "{} patches, codec {}, {} light set(s): direct {:.1} ms, indirect {:.1} ms",
        baked.layout.len(),
        scene.codec(),
        sets.len(),
        timing.direct_s * 1e3,
        timing.indirect_s * 1e3
    );
    match engine.near_field(&scene) {
        Ok(true) => eprintln!(
            "  near-field first bounce applied ({} samples a row, in the direct time)",
            engine.samples_for(&scene)
        ),
        Ok(false) => {}
        Err(why) => eprintln!("  near-field first bounce left out: {why}"),
    }
    for (name, l) in names.iter().zip(&lit) {
        let (d_mean, d_max) = stats(&l.direct);
        let (i_mean, i_max) = stats(&l.indirect);
        eprintln!(
            "  {name}: direct mean {d_mean:.4} max {d_max:.4}, indirect mean {i_mean:.4} max {i_max:.4}"
        );
        if !l.probes.is_empty() {
            let (p_mean, p_max) = stats(&l.probes);
            eprintln!(
                "    {} probes × 6 directions: mean {p_mean:.4} max {p_max:.4}",
                l.probes.len() / 6
            );
        }
    }
    if let (Some(path), Some(format)) = (&args.out, format) {
        let text = match format {
            OutFormat::Json => to_json(
                &engine,
                scene.codec(),
                scene.probe_positions(),
                &names,
                &lit,
            )?,
            OutFormat::Csv => to_csv(&lit),
        };
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

#[derive(Clone, Copy)]
enum OutFormat {
    Json,
    Csv,
}

impl OutFormat {
    fn of(path: &Path) -> Result<OutFormat> {
        match path.extension().and_then(|e| e.to_str()) {
            Some("json") => Ok(OutFormat::Json),
            Some("csv") => Ok(OutFormat::Csv),
            _ => bail!("--out {}: give a .json or .csv file", path.display()),
        }
    }
}

/// The light sets of the batch and a name for each (its file, or "scene lights").
fn light_sets(args: &RelightArgs, baked: &Baked) -> Result<(Vec<String>, Vec<LightSet>)> {
    if args.lights.is_empty() {
        if baked.meta.lights.is_empty() {
            bail!(
                "the scene has no lights of its own: give a light configuration with --lights L.json"
            );
        }
        return Ok((
            vec!["scene lights".to_string()],
            vec![LightSet {
                lights: baked.meta.lights.clone(),
            }],
        ));
    }
    let mut names = Vec::new();
    let mut sets = Vec::new();
    for path in &args.lights {
        let set = crate::lights_file::read(path)?;
        names.push(path.display().to_string());
        sets.push(set);
    }
    Ok((names, sets))
}

fn stats(v: &[[f32; 3]]) -> (f64, f64) {
    let lum = |c: &[f32; 3]| f64::from(c[0] + c[1] + c[2]) / 3.0;
    let sum: f64 = v.iter().map(lum).sum();
    let max = v.iter().map(lum).fold(0.0f64, f64::max);
    (sum / v.len().max(1) as f64, max)
}

fn to_json(
    engine: &Engine,
    codec: &str,
    scene_probes: Option<&[[f32; 3]]>,
    names: &[String],
    lit: &[Irradiance],
) -> Result<String> {
    let sets: Vec<serde_json::Value> = names
        .iter()
        .zip(lit)
        .map(|(name, l)| {
            serde_json::json!({
                "lights": name,
                "direct": l.direct,
                "indirect": l.indirect,
                // Per probe its six directions (+X, −X, +Y, −Y, +Z, −Z); empty without probes.
                "probes": l.probes.chunks(6).collect::<Vec<_>>(),
            })
        })
        .collect();
    Ok(serde_json::to_string(&serde_json::json!({
        "engine": engine.describe(),
        "codec": codec,
        "patches": lit.first().map_or(0, |l| l.direct.len()),
        "units": "irradiance per patch, linear RGB (lux for photometric lights)",
        "probe_positions": scene_probes,
        "sets": sets,
    }))?)
}

fn to_csv(lit: &[Irradiance]) -> String {
    let mut out =
        String::from("set,patch,direct_r,direct_g,direct_b,indirect_r,indirect_g,indirect_b\n");
    for (k, l) in lit.iter().enumerate() {
        for (i, (d, e)) in l.direct.iter().zip(&l.indirect).enumerate() {
            let _ = writeln!(
                out,
                "{k},{i},{},{},{},{},{},{}",
                d[0], d[1], d[2], e[0], e[1], e[2]
            );
        }
    }
    out
}
