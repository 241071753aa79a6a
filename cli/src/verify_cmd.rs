//! `bounce verify`: the pipeline's indirect irradiance against the path-traced reference, with
//! the error split into what the codec adds and what the method (voxel simplification,
//! form-factor noise, patch-level direct light) does.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use bounce_core::bake::{
    BakeOptions, CodecRequest, NoProgress, Progress, bake_scene, options_of, simplify,
};
use bounce_core::codec;
use bounce_core::format::Baked;
use bounce_core::import::import_path;
use bounce_core::light::LightSet;
use bounce_core::matrix::DENSE_F32;
use bounce_core::pointwise;
use bounce_engine::{Engine, EngineChoice, Irradiance};
use bounce_reference::compare::{Meta, Report, Variants, compare};
use bounce_reference::{Options, Reference};
use clap::Args;

use crate::progress::TermProgress;
use crate::reference_cmd::{trace, trace_footprints};

#[derive(Args, Debug)]
pub struct VerifyArgs {
    /// The baked file to check.
    pub baked: PathBuf,
    /// The glTF/GLB scene it was baked from.
    pub scene: PathBuf,
    /// Light configuration, `{"lights": [...]}`; without it, the scene's own glTF lights.
    #[arg(long, value_name = "L.json")]
    pub lights: Option<PathBuf>,
    /// Reference sample paths per patch.
    #[arg(long, value_name = "N", default_value_t = 1024)]
    pub spp: u32,
    /// Reference seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// What a patch's reference value is: `footprints` (the average over the pieces of original
    /// triangles the patch stands for: what its value means) or `patches` (one point: its
    /// centroid moved onto the nearest surface).
    #[arg(long, value_name = "footprints|patches", default_value = "footprints")]
    pub points: String,
    /// Points drawn on each patch's footprint (they share --spp)
    /// [default: as many as --spp, one path each]. The standard error is taken across the
    /// points, so it counts how much the value varies over the patch; fewer points than paths
    /// leave more of that variation in the reference.
    #[arg(long, value_name = "M")]
    pub footprint_points: Option<usize>,
    /// The relight engine computing the pipeline's values: auto, gpu or cpu.
    #[arg(long, default_value = "cpu")]
    pub engine: String,
    /// Print the report as JSON on stdout instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Also write every patch's values as CSV: its reference point, the reference and its
    /// standard error, and the pipeline's values (compressed, exact, exact on the surfaces' B0,
    /// exact without the near field, exact with the first bounce taken where each ray lands; the
    /// last two empty where verify does not split them).
    #[arg(long, value_name = "FILE.csv")]
    pub patches_out: Option<PathBuf>,
    /// Reference sample paths per probe direction, for a file with probes (each probe is six
    /// points, one a direction).
    #[arg(long, value_name = "N", default_value_t = 1024)]
    pub probe_spp: u32,
    /// Leave out the source split: tracing the bake's form-factor rays again with the light
    /// where each lands (the report's "element-constant source" rows and the CSV's
    /// `pointwise_*` columns, left empty). It takes about as long as the bake's form factors;
    /// the rest of the report is the same.
    #[arg(long)]
    pub no_source_split: bool,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
}

pub fn run(args: &VerifyArgs) -> Result<()> {
    let footprint_points = args.footprint_points.unwrap_or(args.spp as usize).max(1);
    let baked =
        Baked::read(&args.baked).with_context(|| format!("reading {}", args.baked.display()))?;
    let scene =
        import_path(&args.scene).with_context(|| format!("importing {}", args.scene.display()))?;
    let lights = crate::lights_file::or_scene(args.lights.as_deref(), &scene)?;
    if let Some(warning) =
        crate::lights_file::sky_warning(&baked, &args.baked, std::iter::once(&lights))
    {
        eprintln!("warning: {warning}");
    }
    let (exact, exact_from) = exact_transport(&baked, &scene, &args.scene, args.quiet)?;

    let engine = Engine::new(args.engine.parse::<EngineChoice>()?)?;
    let relight_all = |scene: &bounce_engine::Scene| -> Result<Irradiance> {
        let mut lit = engine.relight(scene, std::slice::from_ref(&lights))?;
        Ok(lit.remove(0))
    };
    let relight = |scene: &bounce_engine::Scene| -> Result<Vec<[f32; 3]>> {
        Ok(relight_all(scene)?.indirect)
    };
    let mut exact_scene = engine.load(exact.as_ref().unwrap_or(&baked))?;
    let exact_lit = relight_all(&exact_scene)?;
    let exact_e = exact_lit.indirect.clone();
    // The file as it is: its own transport, and its probes' light.
    let file_lit = match &exact {
        Some(_) => relight_all(&engine.load(&baked)?)?,
        None => exact_lit,
    };
    let compressed = file_lit.indirect;
    if let Err(why) = engine.near_field(&exact_scene) {
        eprintln!("verify: the file's near field is not applied: {why}");
    }
    // What carrying the near field through the later bounces gains.
    let first_bounce_near = if exact_scene.near_carried() {
        exact_scene.first_bounce_near_field();
        Some(relight(&exact_scene)?)
    } else {
        None
    };
    // The near field's gain, and the base the pointwise split starts from.
    let without_near = if engine.near_field(&exact_scene) == Ok(true) {
        exact_scene.disable_near_field();
        Some(relight(&exact_scene)?)
    } else {
        None
    };

    let reference = Reference::new(&scene)?;
    let options = Options {
        spp: args.spp,
        bounces: baked.meta.settings.bounces,
        seed: args.seed,
    };
    let (traced, placement) = match args.points.as_str() {
        "patches" => {
            let (points, snap) = reference.snap_patches(&baked.layout);
            let traced = trace(
                &reference,
                &lights,
                points,
                Some(snap),
                &options,
                args.quiet,
            )?;
            let placement = format!(
                "one point a patch: {} centroids moved onto their surface, {} left",
                snap.snapped, snap.kept
            );
            (traced, placement)
        }
        "footprints" => {
            let traced = trace_footprints(
                &reference,
                &lights,
                &baked.layout,
                footprint_points,
                &options,
                args.quiet,
            )?;
            let placement = format!(
                "{} footprint points a patch ({} patches with none found used their snapped centroid)",
                footprint_points,
                traced.snap.map_or(0, |s| s.kept)
            );
            (traced, placement)
        }
        other => bail!("--points {other}: give footprints or patches"),
    };
    let reference_e: Vec<[f64; 3]> = traced.estimates.iter().map(|e| e.mean).collect();
    // The exact transport applied to direct light evaluated on the original surfaces (over the
    // same footprints or points as the reference) instead of on the voxel patches: what is left
    // against the reference is the transport's own error (voxel geometry, form-factor noise).
    let surface_direct = if args.points == "footprints" {
        reference.footprint_direct(&lights, &baked.layout, footprint_points, args.seed)
    } else {
        reference.direct(&lights, &traced.points)
    };
    let b0: Vec<[f32; 3]> = baked
        .layout
        .patches
        .iter()
        .zip(&surface_direct)
        .map(|(p, e)| std::array::from_fn(|c| p.emission[c] + p.albedo[c] * e[c] as f32))
        .collect();
    let exact_op = codec::decode(&exact.as_ref().unwrap_or(&baked).transport)?;
    // With elements, each takes its patch's reference direct light (the reference knows
    // patches, not elements), and the result is restricted to the patches as a relight is.
    let surface_lit = match &baked.elements {
        Some(e) => {
            let rows = e.spread(&surface_direct);
            let b0: Vec<[f32; 3]> = e
                .layout
                .patches
                .iter()
                .zip(&rows)
                .map(|(p, e)| std::array::from_fn(|c| p.emission[c] + p.albedo[c] * e[c] as f32))
                .collect();
            let mut lit = vec![[0.0f32; 3]; b0.len()];
            exact_op.matvec_batch(&b0, &mut lit)?;
            e.restrict(&baked.layout, &lit)
        }
        None => {
            let mut lit = vec![[0.0f32; 3]; b0.len()];
            exact_op.matvec_batch(&b0, &mut lit)?;
            lit
        }
    };

    let pointwise = if args.no_source_split {
        None
    } else {
        pointwise_source(
            &baked,
            &scene,
            &engine,
            &exact_scene,
            &lights,
            without_near.as_deref().unwrap_or(&exact_e),
            args.quiet,
        )?
    };
    let report = compare(
        &compressed,
        &exact_e,
        &surface_lit,
        &reference_e,
        Variants {
            pointwise_source: pointwise.as_deref(),
            without_near_field: without_near.as_deref(),
            first_bounce_near_field: first_bounce_near.as_deref(),
        },
        traced.rel_stderr(),
        Meta {
            geometry: baked.meta.settings.geometry.to_string(),
            codec: baked.transport.codec.clone(),
            spp: args.spp,
            bounces: baked.meta.settings.bounces.to_string(),
            placement,
            seconds: traced.seconds,
            exact_from,
        },
    );
    if let Some(path) = &args.patches_out {
        let mut csv = String::from(
            "patch,x,y,z,nx,ny,nz,ref_r,ref_g,ref_b,se_r,se_g,se_b,compressed_r,compressed_g,\
             compressed_b,exact_r,exact_g,exact_b,surface_b0_r,surface_b0_g,surface_b0_b,\
             without_near_r,without_near_g,without_near_b,pointwise_r,pointwise_g,pointwise_b,\
             first_bounce_near_r,first_bounce_near_g,first_bounce_near_b\n",
        );
        // Columns of a split verify could not make here (no near field, a sky) stay empty.
        let optional = |v: Option<&[[f32; 3]]>, i: usize| -> Vec<String> {
            match v {
                Some(v) => v[i].iter().map(|x| x.to_string()).collect(),
                None => vec![String::new(); 3],
            }
        };
        for (i, (p, e)) in traced.points.iter().zip(&traced.estimates).enumerate() {
            let row: Vec<String> = p
                .position
                .iter()
                .chain(&p.normal)
                .map(|v| v.to_string())
                .chain(e.mean.iter().chain(&e.stderr).map(|v| v.to_string()))
                .chain(
                    compressed[i]
                        .iter()
                        .chain(&exact_e[i])
                        .chain(&surface_lit[i])
                        .map(|v| v.to_string()),
                )
                .chain(optional(without_near.as_deref(), i))
                .chain(optional(pointwise.as_deref(), i))
                .chain(optional(first_bounce_near.as_deref(), i))
                .collect();
            csv += &format!("{i},{}\n", row.join(","));
        }
        std::fs::write(path, csv).with_context(|| format!("writing {}", path.display()))?;
    }
    let probes = match &baked.probes {
        Some(_) => Some(check_probes(
            &baked,
            &file_lit.probes,
            &reference,
            &lights,
            args,
        )?),
        None => None,
    };
    if args.json {
        let mut value = serde_json::to_value(&report)?;
        if let (Some(p), Some(map)) = (&probes, value.as_object_mut()) {
            map.insert("probes".into(), serde_json::to_value(p)?);
        }
        println!("{}", serde_json::to_string_pretty(&value)?);
    } else {
        print_table(&report);
        if let Some(p) = &probes {
            println!(
                "probes: {} × 6 directions against the reference ({} paths a direction, {:.1} s): \
                 rel L2 {:.2}% (the reference's noise {:.2}%), total {:.4} of the reference's",
                p.probes,
                p.spp,
                p.seconds,
                p.rel_l2 * 100.0,
                p.noise * 100.0,
                p.total
            );
        }
    }
    Ok(())
}

/// The file's probes against the reference.
#[derive(Debug, serde::Serialize)]
struct ProbeCheck {
    probes: usize,
    spp: u32,
    seconds: f64,
    /// Relative L2 over every probe direction and channel.
    rel_l2: f64,
    /// The reference's own standard error, relative to it the same way.
    noise: f64,
    /// Summed probe light over the reference's (green channel).
    total: f64,
}

/// `lit`, the probes' light from the file's relight, against the reference. Each probe
/// direction is a reference point at the probe with that axis as its normal. A
/// probe gathers the surfaces' exitance, which holds their indirect light of the bake's
/// bounces, so the reference carries one bounce more. Under a sky a probe also holds the sky it
/// sees directly (when the file has the probes' sky view), so the reference's direct light of
/// the sky alone is added at the same points.
fn check_probes(
    baked: &Baked,
    lit: &[[f32; 3]],
    reference: &Reference,
    lights: &LightSet,
    args: &VerifyArgs,
) -> Result<ProbeCheck> {
    let Some(probes) = &baked.probes else {
        bail!("the file has no probes");
    };
    let points: Vec<bounce_reference::Point> = probes
        .positions
        .iter()
        .flat_map(|&position| {
            bounce_core::patch::Face::ALL.map(|f| bounce_reference::Point {
                position,
                normal: f.normal().to_array(),
            })
        })
        .collect();
    let options = Options {
        spp: args.probe_spp,
        bounces: match baked.meta.settings.bounces {
            bounce_core::meta::Bounces::K(k) => bounce_core::meta::Bounces::K(k + 1),
            all => all,
        },
        seed: args.seed,
    };
    let start = std::time::Instant::now();
    let bar = TermProgress::new(args.quiet);
    bar.begin(bounce_core::bake::Stage::Probes, points.len() as u64);
    let mut estimates = reference.estimate(lights, &points, &options, &|n| bar.advance(n))?;
    let sees_sky = probes.sky.is_some() && lights.sky_sh().is_some();
    if sees_sky {
        let sky_only = LightSet {
            lights: lights
                .lights
                .iter()
                .filter(|l| matches!(l, bounce_core::light::Light::Sky { .. }))
                .cloned()
                .collect(),
        };
        for (e, d) in estimates
            .iter_mut()
            .zip(reference.direct(&sky_only, &points))
        {
            for (m, d) in e.mean.iter_mut().zip(d) {
                *m += d;
            }
        }
    } else if lights.sky_sh().is_some() {
        eprintln!(
            "verify: the file's probes have no view of the sky (baked before format version 8):              they see the sky only off the surfaces, and are checked so"
        );
    }
    let seconds = start.elapsed().as_secs_f64();
    bar.end(bounce_core::bake::Stage::Probes, seconds);
    let (mut num, mut den, mut var) = (0.0f64, 0.0f64, 0.0f64);
    for (g, e) in lit.iter().zip(&estimates) {
        for ((g, m), se) in g.iter().zip(e.mean).zip(e.stderr) {
            num += (f64::from(*g) - m).powi(2);
            den += m * m;
            var += se * se;
        }
    }
    let den = den.max(1e-300);
    Ok(ProbeCheck {
        probes: probes.len(),
        spp: args.probe_spp,
        seconds,
        rel_l2: (num / den).sqrt(),
        noise: (var / den).sqrt(),
        total: lit.iter().map(|g| f64::from(g[1])).sum::<f64>()
            / estimates.iter().map(|e| e.mean[1]).sum::<f64>().max(1e-300),
    })
}

/// A surface bake's exact `E_ind` (without the near field, `exact_e`) with its first bounce
/// gathered with `B0` where each form-factor ray lands (`bounce_core::pointwise`), the later
/// bounces carrying the change as a relight carries the near field's, restricted to the patches
/// as a relight is: `E_ind + restrict(d + T · (ρ ⊙ d))`, `d = pointwise − F · B0` (`d` alone
/// for a one-bounce transport). The rays are the bake's
/// (its seed and count, its elements found again from its recorded settings). `None` for voxel
/// faces.
fn pointwise_source(
    baked: &Baked,
    scene: &bounce_core::scene::Scene,
    engine: &Engine,
    loaded: &bounce_engine::Scene,
    lights: &LightSet,
    exact_e: &[[f32; 3]],
    quiet: bool,
) -> Result<Option<Vec<[f32; 3]>>> {
    let Some(elements) = &baked.elements else {
        return Ok(None);
    };
    if lights.sky_sh().is_some() {
        // Its landings would need the sky's direct light, which only rows have (their baked
        // view), not points.
        eprintln!(
            "verify: the source split traces punctual lights where each ray lands, not a sky; \
             it is left out"
        );
        return Ok(None);
    }
    let s = &baked.meta.settings;
    if !quiet {
        eprintln!("tracing the form-factor rays again, with the light where each lands");
    }
    let vox = simplify(scene, &options_of(s, false))?;
    let (rows, Some(pieces)) = (vox.transport_layout(), vox.pieces.as_ref()) else {
        return Ok(None);
    };
    if *rows != elements.layout {
        // A file from another version (or of another scene): the rest of the report stands.
        eprintln!(
            "verify: the file's settings give other elements here ({} against {}): the scene is \
             not the one baked, or the file was baked by another version; the source split is \
             left out",
            rows.len(),
            elements.len()
        );
        return Ok(None);
    }
    let direct = engine
        .direct_on_rows(loaded, std::slice::from_ref(lights))?
        .remove(0);
    let b0 = loaded.exitance(lights, &direct)?;
    // The pointwise first bounce reads each triangle's own emission: the set's changes go there.
    let changed;
    let scene = if lights.emissive().next().is_some() {
        let mut copy = scene.clone();
        bounce_core::emitter::apply_to_scene(&mut copy, lights)?;
        changed = copy;
        &changed
    } else {
        scene
    };
    let first = pointwise::first_bounce(scene, rows, pieces, lights, &b0, s.rays_per_patch, s.seed);
    let mut shift: Vec<[f32; 3]> = first
        .pointwise
        .iter()
        .zip(&first.element)
        .map(|(p, e)| std::array::from_fn(|c| p[c] - e[c]))
        .collect();
    // The later bounces carry the first bounce's change as a relight carries the near field's
    // (`bounce_engine::carried_source`): `T · (ρ ⊙ shift)` on top.
    if bounce_engine::carries_near_field(s.bounces) {
        let reflected: Vec<[f32; 3]> = shift
            .iter()
            .zip(&rows.patches)
            .map(|(d, p)| std::array::from_fn(|c| p.albedo[c] * d[c]))
            .collect();
        let mut carried = vec![[0.0f32; 3]; shift.len()];
        engine.indirect(loaded, &reflected, &mut carried)?;
        for (d, t) in shift.iter_mut().zip(&carried) {
            *d = std::array::from_fn(|c| d[c] + t[c]);
        }
    }
    let shift = elements.restrict(&baked.layout, &shift);
    Ok(Some(
        exact_e
            .iter()
            .zip(&shift)
            .map(|(e, d)| std::array::from_fn(|c| e[c] + d[c]))
            .collect(),
    ))
}

/// The exact (`dense-f32`) transport on the same patches: the file itself when it is exact,
/// else baked again from the file's recorded settings (same seed, so the same form factors).
fn exact_transport(
    baked: &Baked,
    scene: &bounce_core::scene::Scene,
    path: &std::path::Path,
    quiet: bool,
) -> Result<(Option<Baked>, String)> {
    if baked.transport.codec == DENSE_F32 {
        return Ok((None, "the file (dense-f32)".into()));
    }
    let s = &baked.meta.settings;
    if s.target_patches.is_none() && s.requested_voxel_size.is_none() {
        bail!("the baked file records neither a patch count nor a voxel size");
    }
    let options = BakeOptions {
        codec: CodecRequest::Named(DENSE_F32.to_string()),
        sparse_share: None,
        ..options_of(s, false)
    };
    if !quiet {
        eprintln!(
            "re-baking {} as dense-f32 for the exact transport",
            path.display()
        );
    }
    let progress = TermProgress::new(quiet);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let exact = if quiet {
        bake_scene(scene, &name, &options, &NoProgress)?
    } else {
        bake_scene(scene, &name, &options, &progress)?
    };
    if exact.layout != baked.layout {
        bail!(
            "baking {} again with the file's settings gives other patches ({} against {}): the \
             scene is not the one baked, or the file was baked by another version",
            path.display(),
            exact.layout.len(),
            baked.layout.len()
        );
    }
    Ok((Some(exact), "re-baked as dense-f32".into()))
}

fn print_table(r: &Report) {
    let pct = |v: f64| format!("{:.2}%", v * 100.0);
    println!(
        "{} patches ({}), codec {}, {} bounces; reference {} spp in {:.1} s ({}); exact T: {}",
        r.patches,
        r.geometry,
        r.codec,
        r.bounces,
        r.spp,
        r.reference_seconds,
        r.reference_points,
        r.exact_from
    );
    println!("| error (relative L2 of E_ind) | value |");
    println!("|---|---:|");
    println!(
        "| codec: compressed T vs exact T | {} |",
        pct(r.codec_rel_l2)
    );
    println!(
        "| method: exact T vs reference | {} |",
        pct(r.method_rel_l2)
    );
    if let Some(plain) = r.method_without_near_field_rel_l2 {
        println!(
            "| · the same without the near-field first bounce | {} |",
            pct(plain)
        );
    }
    if let Some(first) = r.method_first_bounce_near_field_rel_l2 {
        println!(
            "| · the same with the near field in the first bounce only (the later bounces not carrying it) | {} |",
            pct(first)
        );
    }
    match (r.source_rel_l2, r.method_pointwise_source_rel_l2) {
        (Some(source), Some(rest)) => {
            println!(
                "| · the element-constant source: E_ind moves by this when the first bounce takes B0 where each ray lands | {} |",
                pct(source)
            );
            println!(
                "| · method with that first bounce (geometry, later bounces, form-factor noise) | {} |",
                pct(rest)
            );
        }
        _ => {
            println!(
                "| · of which direct light at the patches' samples, not the reference's | {} |",
                pct(r.direct_at_patches_rel_l2)
            );
            println!(
                "| · of which transport (geometry, form-factor noise) | {} |",
                pct(r.transport_rel_l2)
            );
        }
    }
    println!(
        "| method, reference noise removed | {} |",
        pct(r.method_rel_l2_without_noise)
    );
    println!(
        "| total: compressed T vs reference | {} |",
        pct(r.total_rel_l2)
    );
    println!(
        "| reference's own standard error | {} |",
        pct(r.reference_rel_stderr)
    );
    println!(
        "| leak: share of E_ind on patches the reference leaves under a tenth of its median | {} |",
        pct(r.leak_share)
    );
    println!(
        "| · the reference's own share of its light on those patches | {} |",
        pct(r.leak_reference_share)
    );
    println!(
        "per patch (total, relative to the patch's reference): p50 {}, p90 {}, p99 {}, worst {} (patch {})",
        pct(r.patch_rel_p50),
        pct(r.patch_rel_p90),
        pct(r.patch_rel_p99),
        pct(r.worst_patch_rel),
        r.worst_patch
    );
    let mut lo = 0.0;
    for (i, count) in r.histogram.iter().enumerate() {
        let label = match r.bin_edges.get(i) {
            Some(hi) => format!("{:>5} – {:<5}", pct(lo), pct(*hi)),
            None => format!("   > {:<7}", pct(lo)),
        };
        let bar = "#".repeat((60 * count).div_ceil(r.patches.max(1)));
        println!("  {label} {count:>6} {bar}");
        lo = r.bin_edges.get(i).copied().unwrap_or(lo);
    }
}
