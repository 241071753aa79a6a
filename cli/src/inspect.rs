//! `bounce inspect`: what a baked file holds, for people (`text`) and tools (`--json`).

use std::path::PathBuf;

use anyhow::{Context, Result};
use bounce_core::format::{Baked, read_summary};
use bounce_core::meta::{AllBounces, BakeSettings, Bounces};
use clap::Args;
use serde_json::json;

use crate::bake::summary::{human_bytes, print_import_report, stage_list};

#[derive(Args, Debug)]
pub struct InspectArgs {
    /// A baked file written by `bounce bake`.
    pub file: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &InspectArgs) -> Result<()> {
    // The container summary reads even when a section is damaged, so show it before failing.
    let summary =
        read_summary(&args.file).with_context(|| format!("reading {}", args.file.display()))?;
    let baked = Baked::read(&args.file).with_context(|| format!("reading {}", args.file.display()));
    let sections: Vec<_> = summary
        .sections
        .iter()
        .map(|s| {
            json!({
                "kind": String::from_utf8_lossy(&s.entry.kind.0),
                "offset": s.entry.offset,
                "bytes": s.entry.len,
                "crc32": format!("{:08x}", s.entry.crc),
                "checksum_ok": s.crc_ok,
            })
        })
        .collect();
    let baked = match baked {
        Ok(b) => b,
        Err(e) => {
            if args.json {
                println!(
                    "{}",
                    json!({
                        "format_version": summary.header.format_version,
                        "file_bytes": summary.header.file_len,
                        "sections": sections,
                        "error": format!("{e:#}"),
                    })
                );
            }
            return Err(e);
        }
    };
    let m = &baked.meta;
    let s = &m.stats;
    let l = &baked.layout;
    // The share of the surface's form-factor rays that escaped, weighted by area: how much of
    // the scene a sky reaches.
    let sky_escaped = baked
        .sky
        .as_ref()
        .map(|sky| sky.mean_escaped(&baked.transport_layout().areas(m.settings.geometry)));
    if args.json {
        let doc = json!({
            "format_version": summary.header.format_version,
            "file_bytes": summary.header.file_len,
            "sections": sections,
            "source": m.source_name,
            "source_bytes": m.source_bytes,
            "tool_version": m.tool_version,
            "patches": l.len(),
            "geometry": m.settings.geometry,
            "surface_samples": baked.surface.as_ref().map(|s| s.per_patch),
            "landing_samples": baked.surface.as_ref().map(|s| s.per_patch - s.area_samples),
            "surface_triangles": baked.surface.as_ref().map(|s| s.triangles.len()),
            "near_field_radius": baked.near_field.as_ref().map(|_| m.settings.near_radius),
            "near_field_entries": baked.near_field.as_ref().map(|n| n.nnz()),
            "near_field_sky_view": baked.near_field.as_ref().map(|n| n.sky.is_some()),
            "sample_albedo": baked.surface.as_ref().map(|s| s.albedo.is_some()),
            "near_field_albedo": baked.near_field.as_ref().map(|n| n.albedo.is_some()),
            "sky_view_rows": baked.sky.as_ref().map(|s| s.len()),
            "sky_view_escaped_share": sky_escaped,
            "emitters": baked.emitters.as_ref().map(|e| e.groups.iter().map(|g| json!({
                "material": g.name,
                "node": g.node,
                "color": g.color,
                "strength": g.strength,
            })).collect::<Vec<_>>()),
            "probes": baked.probes.as_ref().map(|p| json!({
                "count": p.len(),
                "spacing": p.spacing,
                "rays_per_direction": p.rays,
                "entries": p.nnz(),
                // The share of the probes' rays that escape, over every direction: what
                // the probes see of a sky (null for a file without their sky view).
                "sky_escaped": p.sky.as_ref().map(|s| {
                    (0..s.len()).map(|i| s.escaped_fraction(i)).sum::<f64>() / s.len().max(1) as f64
                }),
            })),
            "surface_area": m.stats.surface_area,
            "unassigned_area": m.stats.unassigned_area,
            "bounces": m.settings.bounces,
            "channels": baked.transport.channels,
            "codec": baked.transport.codec,
            "codec_params": baked.transport.params,
            "matrix_bytes": baked.transport.payload.len(),
            "form_factors_stored": baked.form_factors.is_some(),
            "occupied_voxels_stored": baked.occupancy.as_ref().map(Vec::len),
            "model_stored": baked.model.is_some(),
            "model_bytes": baked.model.as_ref().map(Vec::len),
            "layout": {
                "origin": l.origin,
                "voxel_size": l.voxel_size,
                "dims": l.dims,
            },
            "settings": m.settings,
            "stats": s,
            "row_sum_min": s.row_sum_min,
            "row_sum_max": s.row_sum_max,
            "row_sum_mean": s.row_sum_mean,
            "reciprocity_error": s.reciprocity_error,
            "timings": m.timings,
            "import_report": m.import_report,
            "lights": m.lights,
        });
        // Beside `bounces` (one more key inside `json!` passes its recursion limit): how an
        // all-bounce file summed them, null for a number of bounces.
        let mut doc = doc;
        if let Some(o) = doc.as_object_mut() {
            o.insert(
                "all_bounces".into(),
                json!(all_bounces(&m.settings).map(|a| a.to_string())),
            );
        }
        println!("{}", serde_json::to_string_pretty(&doc)?);
        return Ok(());
    }
    println!("{}", args.file.display());
    println!(
        "  format        version {}, {}, {} sections",
        summary.header.format_version,
        human_bytes(summary.header.file_len),
        summary.sections.len()
    );
    for sec in &summary.sections {
        println!(
            "    {}  {:>12} at {:>10}  crc {:08x} {}",
            String::from_utf8_lossy(&sec.entry.kind.0),
            human_bytes(sec.entry.len),
            sec.entry.offset,
            sec.entry.crc,
            if sec.crc_ok { "ok" } else { "MISMATCH" }
        );
    }
    println!(
        "  source        {} ({}), bounce {}",
        m.source_name,
        human_bytes(m.source_bytes),
        m.tool_version
    );
    println!(
        "  layout        {} patches, voxel size {:.4}, grid {}×{}×{} from ({:.3}, {:.3}, {:.3})",
        l.len(),
        l.voxel_size,
        l.dims[0],
        l.dims[1],
        l.dims[2],
        l.origin[0],
        l.origin[1],
        l.origin[2]
    );
    let requested = match (m.settings.target_patches, m.settings.requested_voxel_size) {
        (Some(p), _) => format!("--patches {p}"),
        (_, Some(v)) => format!("--voxel-size {v}"),
        _ => String::from("-"),
    };
    let sum = all_bounces(&m.settings)
        .map(|a| format!(" --all-bounces {a}"))
        .unwrap_or_default();
    println!(
        "  settings      {requested}, --rays {}, --bounces {}{sum}, --seed {}",
        m.settings.rays_per_patch, m.settings.bounces, m.settings.seed
    );
    println!(
        "  transport     codec {}, {} channel(s), {}{}",
        baked.transport.codec,
        baked.transport.channels,
        human_bytes(baked.transport.payload.len() as u64),
        if baked.form_factors.is_some() {
            " (+ form factors)"
        } else {
            ""
        }
    );
    if let Some(near) = &baked.near_field {
        println!(
            "  near field    rays landing within {} voxel(s): {} entries over {} samples a row{}; {}",
            m.settings.near_radius,
            near.nnz(),
            near.per_row,
            match baked.surface.as_ref().map(|s| s.per_patch - s.area_samples) {
                Some(k) if k > 0 => format!(" ({k} of them placed where near rays land)"),
                _ => String::new(),
            },
            if near.sky.is_some() {
                "each sample's own sky view (a sky is corrected too)"
            } else {
                "no samples' sky view (a file from before version 9: a sky is not corrected)"
            }
        );
        let albedo = baked.surface.as_ref().is_some_and(|s| s.albedo.is_some());
        println!(
            "                {}",
            if near.albedo.is_some() {
                "each entry's own albedo (a landing reflects with the colour it landed on)"
            } else if albedo {
                "each sample's own albedo (a file from before version 12: a landing reflects \
                 with its sample's triangle's colour)"
            } else {
                "no samples' albedo (a file from before version 11: each row's is used)"
            }
        );
    }
    match (&baked.sky, sky_escaped) {
        (Some(sky), Some(share)) => println!(
            "  sky view      {} rows × 9 SH coefficients; {:.1}% of the surface's rays escape \
             (area-weighted)",
            sky.len(),
            share * 100.0
        ),
        _ => println!(
            "  sky view      none (baked by an older bounce): a sky lights nothing here, bake \
             again"
        ),
    }
    match &baked.emitters {
        Some(e) if e.groups.is_empty() => println!("  emitters      none (no emissive surface)"),
        Some(e) => {
            let covered = (0..e.rows()).filter(|&r| !e.row(r).is_empty()).count();
            let names: Vec<String> = e
                .groups
                .iter()
                .map(|g| {
                    format!(
                        "'{}'{} ({:.3}, {:.3}, {:.3}) × {}",
                        g.name,
                        g.node
                            .as_ref()
                            .map_or_else(String::new, |n| format!(" on node '{n}'")),
                        g.color[0],
                        g.color[1],
                        g.color[2],
                        g.strength
                    )
                })
                .collect();
            println!(
                "  emitters      {} over {covered} rows, a light set may change them by \
                 material or node: {}",
                e.groups.len(),
                names.join(", ")
            );
            if e.groups.iter().all(|g| g.node.is_none()) {
                println!(
                    "                (baked before emitters knew their nodes: changed by \
                     material only; bake again to change them by node)"
                );
            }
        }
        None => println!(
            "  emitters      none listed (voxel faces, or baked by an older bounce): emissive \
             surfaces keep their baked light"
        ),
    }
    match &baked.probes {
        Some(p) => println!(
            "  probes        {} at spacing {} × 6 directions, {} rays each; gather {} entries; {}",
            p.len(),
            p.spacing,
            p.rays,
            p.nnz(),
            match &p.sky {
                Some(s) => format!(
                    "sky view: {:.1}% of their rays escape",
                    100.0 * (0..s.len()).map(|i| s.escaped_fraction(i)).sum::<f64>()
                        / s.len().max(1) as f64
                ),
                None => "no sky view (baked before format version 8)".to_string(),
            }
        ),
        None => println!("  probes        none (bake with --probes to place them)"),
    }
    match &baked.model {
        Some(m) => println!(
            "  model         {} GLB (the scene, for the browser page)",
            human_bytes(m.len() as u64)
        ),
        None => println!("  model         none (baked with --no-model or by an older bounce)"),
    }
    println!(
        "  checks        row sums {:.4}..{:.4} (mean {:.4}), reciprocity {:.2}%, {} isolated",
        s.row_sum_min,
        s.row_sum_max,
        s.row_sum_mean,
        s.reciprocity_error * 100.0,
        s.isolated_patches
    );
    let total: f64 = m.timings.iter().map(|t| t.seconds).sum();
    println!("  bake time     {total:.2} s: {}", stage_list(&m.timings));
    print_import_report(&m.import_report, m.lights.len());
    Ok(())
}

/// How a file's all-bounce transport was summed: a file from before the clustered tail records
/// none and was solved exactly.
fn all_bounces(settings: &BakeSettings) -> Option<AllBounces> {
    (settings.bounces == Bounces::All).then(|| settings.all_bounces.unwrap_or(AllBounces::Exact))
}
