//! What a bake prints when it is done, and what `bounce inspect` shows of a baked file: the
//! summary, the stage times, the importer's report, sizes for people.

use std::path::Path;

use bounce_core::format::Baked;
use bounce_core::meta::StageTiming;
use bounce_core::voxel::Geometry;

use crate::memory::peak_rss_bytes;
use bounce_core::scene::ImportReport;

pub fn print_summary(baked: &Baked, out: &Path, file_bytes: u64, total_s: f64) {
    let m = &baked.meta;
    let s = &m.stats;
    println!("baked {} ({})", out.display(), human_bytes(file_bytes));
    println!(
        "  patches       {} (voxel size {:.4}, grid {}×{}×{}, {} occupied voxels, {} dropped as seeing nothing)",
        s.patches,
        s.voxel_size,
        baked.layout.dims[0],
        baked.layout.dims[1],
        baked.layout.dims[2],
        s.occupied_voxels,
        s.dropped_patches
    );
    if m.settings.geometry == Geometry::Surface {
        println!(
            "  surface       {} geometry: {:.4} of {:.4} units² ({:.2}%) belongs to no patch (dropped \
             patches that see nothing, surface inside closed solids, slivers); {} direct-light \
             samples a patch{}",
            m.settings.geometry,
            s.unassigned_area,
            s.surface_area,
            100.0 * s.unassigned_area / s.surface_area.max(f64::MIN_POSITIVE),
            m.settings.direct_samples,
            match m.settings.landing_samples {
                0 => String::new(),
                k => format!(" ({k} of them where near-field rays land)"),
            }
        );
        match &baked.near_field {
            Some(near) => println!(
                "  near field    rays landing within {} voxel(s): {} entries ({:.1} a row), {}",
                m.settings.near_radius,
                near.nnz(),
                near.nnz() as f64 / near.rows().max(1) as f64,
                human_bytes(near.stored_bytes())
            ),
            None => println!("  near field    none (--near-field 0)"),
        }
    } else {
        println!(
            "  surface       {} geometry (the thesis' baseline)",
            m.settings.geometry
        );
    }
    let share = |k: u64| 100.0 * k as f64 / s.rays.total().max(1) as f64;
    println!(
        "  rays          {} per patch, {} in all: {:.1}% reach a patch, {:.1}% escape, \
         {:.1}% stop on occluders, {:.1}% on back faces",
        m.settings.rays_per_patch,
        s.rays_total,
        share(s.rays.patch),
        share(s.rays.escaped),
        share(s.rays.occluder),
        share(s.rays.back_face)
    );
    let tail = s
        .grey_tail_rel_l2
        .map(|e| {
            format!(
                "; one grey tail past bounce {} for the three (it changes E_ind by {:.2}%)",
                bounce_core::tail::EXACT_BOUNCES,
                e * 100.0
            )
        })
        .unwrap_or_default();
    println!(
        "  transport     {} bounce(s), {}{tail}, codec {}, {}",
        m.settings.bounces,
        channels_line(s.channels, s.grey_rel_l2, m.settings.max_grey_error),
        baked.transport.codec,
        human_bytes(s.matrix_bytes)
    );
    if baked.transport.codec != bounce_core::matrix::DENSE_F32 {
        println!(
            "  codec error   {:.3e} relative L2 of indirect irradiance over {} probe light sets",
            s.codec_eind_rel_l2,
            bounce_core::bake::PROBE_LIGHT_SETS
        );
    }
    println!(
        "  row sums      min {:.4}  max {:.4}  mean {:.4}",
        s.row_sum_min, s.row_sum_max, s.row_sum_mean
    );
    println!(
        "  reciprocity   {:.2}% (area-weighted, from ray noise)",
        s.reciprocity_error * 100.0
    );
    if s.isolated_patches > 0 {
        println!(
            "  isolated      {} patch(es) see no other patch",
            s.isolated_patches
        );
    }
    if let Some(model) = &baked.model {
        println!(
            "  model         {} (the scene as one GLB, for the browser page)",
            human_bytes(model.len() as u64)
        );
    }
    println!("  time          {total_s:.2} s: {}", stage_list(&m.timings));
    if let Some(peak) = peak_rss_bytes() {
        println!("  peak memory   {}", human_bytes(peak));
    }
    print_import_report(&m.import_report, m.lights.len());
}

pub fn human_bytes(b: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = b as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{b} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

/// What the summary says of the transport's channels: why one, or why three.
fn channels_line(channels: usize, grey_rel_l2: f64, max_grey_error: f64) -> String {
    match (channels, grey_rel_l2 > 0.0) {
        (1, false) => "1 channel (colour cannot change it)".to_string(),
        (1, true) => format!(
            "1 grey channel (colour would change E_ind by {:.2}%, within --max-grey-error {:.2}%)",
            grey_rel_l2 * 100.0,
            max_grey_error * 100.0
        ),
        (c, _) => format!(
            "{c} channels (one grey channel would change E_ind by {:.2}%, over --max-grey-error {:.2}%)",
            grey_rel_l2 * 100.0,
            max_grey_error * 100.0
        ),
    }
}

/// `import 0.01s, voxelize 0.20s, ...`
pub fn stage_list(timings: &[StageTiming]) -> String {
    let stages: Vec<String> = timings
        .iter()
        .map(|t| format!("{} {:.2}s", t.stage, t.seconds))
        .collect();
    stages.join(", ")
}

/// The importer's report, one line per kind of thing skipped.
pub fn print_import_report(r: &ImportReport, lights: usize) {
    println!(
        "  import        {} triangles from {} primitives in {} meshes, {} light(s)",
        r.triangles, r.primitives, r.meshes, lights
    );
    let list = |label: &str, items: &[String]| {
        if !items.is_empty() {
            println!("  {label:<13} {}", items.join("; "));
        }
    };
    list("skipped", &r.skipped_primitives);
    if r.degenerate_triangles > 0 {
        println!(
            "  degenerate    {} zero-area triangle(s) dropped",
            r.degenerate_triangles
        );
    }
    list("textures", &r.missing_textures);
    list("lights", &r.skipped_lights);
    list("warnings", &r.warnings);
}
