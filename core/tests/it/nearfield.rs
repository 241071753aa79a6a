//! The near-field first bounce (`bounce_core::nearfield`) on a real bake: its matrix holds a
//! subset of each row's form-factor rays, and its correction moves the first bounce towards the
//! one gathered with the light where every ray lands (`bounce_core::pointwise`), which is what it
//! approximates near by.

use std::path::Path;

use bounce_core::bake::{BakeOptions, NoProgress, bake_file, options_of, simplify};
use bounce_core::direct::{ShadowScene, direct_with_samples, exitance_b0};
use bounce_core::import::import_path;
use bounce_core::light::{Light, LightSet};
use bounce_core::pointwise::first_bounce;
use bounce_core::voxel::Resolution;

fn cornell() -> &'static Path {
    Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../assets/cornell-box/scene.gltf"
    ))
}

/// A point light close to the back wall, so the wall's elements are far from uniformly lit.
fn near_wall() -> LightSet {
    LightSet {
        lights: vec![Light::Point {
            position: [0.0, 1.0, -0.8],
            color: [1.0; 3],
            intensity: 3.0,
            range: None,
            name: None,
        }],
    }
}

fn norm(v: &[[f32; 3]]) -> f64 {
    v.iter()
        .flatten()
        .map(|&x| f64::from(x) * f64::from(x))
        .sum::<f64>()
        .sqrt()
}

#[test]
fn the_near_field_moves_the_first_bounce_towards_the_light_where_rays_land() {
    let options = BakeOptions {
        resolution: Resolution::TargetPatches(300),
        rays: 512,
        keep_form_factors: true,
        near_radius: 1.0,
        ..BakeOptions::default()
    };
    let baked = bake_file(cornell(), &options, &NoProgress).expect("the box bakes");
    let near = baked
        .near_field
        .as_ref()
        .expect("a surface bake keeps a near field");
    let rows = baked.transport_layout();
    let n = rows.len();
    let surface = baked.surface.as_ref().expect("surface geometry");
    near.check(n, n, surface.per_patch).expect("a valid matrix");
    assert!(near.nnz() > n, "{} entries for {n} rows", near.nnz());

    // Each row's near rays are some of its form-factor rays.
    let f = baked
        .form_factors
        .as_ref()
        .expect("kept")
        .decode()
        .expect("dense");
    for i in 0..n {
        let near_sum: f32 = near.row(i).1.iter().sum();
        let f_sum: f32 = (0..n).map(|j| f.get(0, i, j)).sum();
        assert!(
            near_sum <= f_sum + 1e-5,
            "row {i}: near {near_sum} > F {f_sum}"
        );
    }

    let lights = near_wall();
    let shadow = ShadowScene::of_baked(&baked);
    let sampled = direct_with_samples(&shadow, rows, &lights, surface.per_patch)
        .expect("surface scenes have samples");
    let albedo: Vec<[f32; 3]> = rows.patches.iter().map(|p| p.albedo).collect();
    let delta = near.correction(&albedo, &sampled.mean, &sampled.samples);

    // The first bounce with the light where each ray lands, against the elements' means.
    let scene = import_path(cornell()).expect("imports");
    let vox = simplify(&scene, &options_of(&baked.meta.settings, false)).expect("simplifies");
    assert_eq!(vox.transport_layout(), rows, "the same elements again");
    let b0 = exitance_b0(rows, &sampled.mean);
    let first = first_bounce(
        &scene,
        rows,
        vox.pieces.as_ref().expect("pieces"),
        &lights,
        &b0,
        options.rays,
        options.seed,
    );
    let shift: Vec<[f32; 3]> = first
        .pointwise
        .iter()
        .zip(&first.element)
        .map(|(p, e)| std::array::from_fn(|c| p[c] - e[c]))
        .collect();
    let left: Vec<[f32; 3]> = shift
        .iter()
        .zip(&delta)
        .map(|(s, d)| std::array::from_fn(|c| s[c] - d[c]))
        .collect();
    let element = norm(&first.element);
    println!(
        "first bounce {element:.4}: pointwise shift {:.4}, near-field correction {:.4}, shift \
         left {:.4}",
        norm(&shift),
        norm(&delta),
        norm(&left)
    );
    assert!(
        norm(&shift) > 0.02 * element,
        "the light must vary over elements for the test to mean anything"
    );
    assert!(
        norm(&delta) > 0.1 * norm(&shift),
        "a correction that does something"
    );
    assert!(
        norm(&left) < 0.8 * norm(&shift),
        "the correction explains part of the pointwise shift"
    );
}

/// The bake takes the near field in the form factors' own pass (each ray traced once); the
/// retrace `near_field_rows` traces the same rays again up to the radius. Both must keep the
/// same entries, bit for bit, or a sharded bake and an older file's twin would disagree.
#[test]
fn the_form_factors_pass_keeps_the_near_field_a_retrace_finds() {
    use std::sync::Arc;

    use bounce_core::formfactor::form_factor_rows_sampled;
    use bounce_core::nearfield::{NearField, near_field_rows};
    use bounce_core::surface::{
        SurfaceData, SurfaceScene, occluder_triangles_of, sample_points, scene_mesh,
    };
    use bounce_core::voxel::cluster_at;

    let scene = import_path(cornell()).expect("the box imports");
    let voxel = 0.25;
    let vox = cluster_at(&scene, voxel).expect("the box clusters");
    let pieces = vox.pieces.as_ref().expect("surface pieces");
    let mesh = Arc::new(scene_mesh(&scene));
    let per_patch = 8;
    let data = SurfaceData {
        triangles: occluder_triangles_of(&mesh),
        per_patch,
        area_samples: per_patch,
        points: sample_points(pieces, per_patch, 3),
        albedo: None,
    };
    let rows = vox.transport_layout();
    let n = rows.len();
    let tracer = SurfaceScene::new(&scene, mesh, rows, pieces);
    for (radius, range) in [(voxel, 0..n), (2.5 * voxel, 3..n - 5)] {
        let retraced = near_field_rows(&tracer, &data, range.clone(), 128, 5, radius, &|_| {})
            .expect("the retrace");
        let traced = form_factor_rows_sampled(
            &tracer,
            range.clone(),
            128,
            5,
            Some((&data.points, per_patch)),
            radius,
            &|_| {},
        )
        .expect("the form factors");
        let kept = NearField::from_landings(per_patch, traced.near.expect("a near field"));
        assert!(kept.nnz() > range.len(), "{} entries", kept.nnz());
        assert_eq!(kept.row_ptr, retraced.row_ptr, "radius {radius}");
        assert_eq!(kept.cols, retraced.cols, "radius {radius}");
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(&kept.values),
            bits(&retraced.values),
            "radius {radius}"
        );
        let albedo = |f: &NearField| {
            f.albedo
                .as_ref()
                .expect("each entry's albedo")
                .iter()
                .flatten()
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(albedo(&kept), albedo(&retraced), "radius {radius}");
        // The box's walls are not one colour: some entries landed on red or green.
        let tinted = kept
            .albedo
            .iter()
            .flatten()
            .filter(|a| (a[0] - a[1]).abs() > 0.1)
            .count();
        assert!(tinted > 0, "no entry landed on a coloured wall");
    }
}
