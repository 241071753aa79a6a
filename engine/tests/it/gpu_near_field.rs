//! The GPU near-field correction ([`GpuSurfaceDirect::irradiance_near`]) against its CPU twin,
//! `NearField::correction` of `bounce_core::direct::direct_with_samples`, with a real matrix
//! (`near_field_rows`: 256 form-factor rays a row, a radius of one voxel) on two scenes of
//! `gpu_direct_surface.rs`: the closed box with a point light close to a wall, and the room with
//! a pillar and several light sets in one batch.
//!
//! **Tolerance.** Per row and channel against the row's scale, `Σ_e c · ρ_j · (|E_q| + |Ē_j|)`
//! (CPU values): the GPU sums the same terms in the same order, so a row agrees to a relative
//! `1e-4` unless a shadow ray flipped (`gpu_direct_surface.rs`) in a row its entries read. A
//! flip shows in that row's mean (a flip small enough to leave the mean's bits alone is far
//! below `1e-4` of the scale), and whatever flipped, a sample's value stays within
//! `[0, unshadowed]`, and so does the mean: a row reading rows whose GPU mean is not the CPU's
//! may differ by at most `Σ_e c · ρ_j · (unshadowed E_q + unshadowed Ē_j)` over those entries.
//! Each comparison prints its `NearAgreement`; on lavapipe no row needed the allowance.

use std::sync::{Arc, OnceLock};

use glam::Vec3;

use bounce_core::direct::{SampledDirect, ShadowScene, direct_with_samples};
use bounce_core::light::LightSet;
use bounce_core::nearfield::{NearField, Reflect, SkySamples, near_field_rows};
use bounce_core::patch::PatchLayout;
use bounce_core::scene::Scene;
use bounce_core::sky::{SkySum, SkyVisibility};
use bounce_core::surface::{
    SurfaceData, SurfaceScene, occluder_triangles_of, sample_points, scene_mesh,
};
use bounce_core::voxel::cluster_at;
use bounce_engine::gpu::{GpuContext, GpuError, GpuSurfaceDirect};

use crate::common::context;
use crate::gpu_direct::{SIZE, VOXEL, compare, pillar_sets, point, room, set};
use crate::gpu_direct_surface::{PER_PATCH, many_sets, median};

/// A surface scene with its near-field matrix, the rows' albedo and the CPU's shadow scenes
/// (against the triangles, and against nothing for the unshadowed values).
struct NearCase {
    layout: PatchLayout,
    data: SurfaceData,
    shadow: ShadowScene,
    open: ShadowScene,
    near: NearField,
    albedo: Vec<[f32; 3]>,
}

/// `area` of each row's `PER_PATCH` samples make its mean (the rest stand in for landing
/// samples: only the near field reads them).
fn near_case(scene: &Scene, voxel: f32, area: u32) -> NearCase {
    dense_near_case(scene, voxel, PER_PATCH, area)
}

/// [`near_case`] with `per_patch` samples a row.
fn dense_near_case(scene: &Scene, voxel: f32, per_patch: u32, area: u32) -> NearCase {
    let vox = cluster_at(scene, voxel).expect("the scene clusters");
    let pieces = vox.pieces.as_ref().expect("surface pieces");
    let mesh = Arc::new(scene_mesh(scene));
    let data = SurfaceData {
        triangles: occluder_triangles_of(&mesh),
        per_patch,
        area_samples: area,
        points: sample_points(pieces, per_patch, 7),
        albedo: None,
    };
    let rows = vox.transport_layout();
    let n = rows.len();
    let tracer = SurfaceScene::new(scene, mesh, rows, pieces);
    let near = near_field_rows(&tracer, &data, 0..n, 256, 11, voxel, &|_| {})
        .expect("the near field traces");
    near.check(n, n, per_patch).expect("a well-formed matrix");
    // Different per row and per channel, so a row read in the wrong place shows.
    let albedo = (0..n)
        .map(|j| {
            [
                0.2 + 0.6 * ((j * 7) % 13) as f32 / 12.0,
                0.3 + 0.5 * ((j * 5) % 11) as f32 / 10.0,
                0.1 + 0.8 * ((j * 3) % 7) as f32 / 6.0,
            ]
        })
        .collect();
    let open = SurfaceData {
        triangles: Vec::new(),
        ..data.clone()
    };
    NearCase {
        shadow: ShadowScene::surface(&data),
        open: ShadowScene::surface(&open),
        layout: rows.clone(),
        data,
        near,
        albedo,
    }
}

fn closed_box() -> &'static NearCase {
    static CASE: OnceLock<NearCase> = OnceLock::new();
    CASE.get_or_init(|| near_case(&room(None, None), VOXEL, PER_PATCH))
}

fn room_with_pillar() -> &'static NearCase {
    static CASE: OnceLock<NearCase> = OnceLock::new();
    CASE.get_or_init(|| {
        near_case(
            &room(None, Some(([1.4, 2.2], 2.5))),
            SIZE / 18.5,
            PER_PATCH - 4,
        )
    })
}

fn upload(ctx: &GpuContext, case: &NearCase) -> GpuSurfaceDirect {
    upload_field(ctx, case, &case.near, Reflect::rows(&case.albedo))
}

/// The case's scene with `near` (the case's matrix, perhaps with a sky view) attached, with the
/// rows' and perhaps the samples' albedo.
fn upload_field(
    ctx: &GpuContext,
    case: &NearCase,
    near: &NearField,
    albedo: Reflect<'_>,
) -> GpuSurfaceDirect {
    GpuSurfaceDirect::upload(ctx, &case.data)
        .unwrap()
        .with_near_field(near, albedo)
        .unwrap()
}

/// What a comparison of `ΔE` found.
#[derive(Debug, Default)]
struct NearAgreement {
    rows: usize,
    /// Rows whose CPU `ΔE` is over 1% of their scale in some channel.
    nontrivial: usize,
    /// The largest `|ΔE|` of the CPU's, over all rows and channels.
    largest: f32,
    /// The worst difference over the scale among rows within rounding.
    worst_rel: f32,
    /// Rows whose GPU mean is not the CPU's bit for bit (a shadow ray may have flipped there).
    #[allow(
        dead_code,
        reason = "printed, not asserted: on hardware it may be every row"
    )]
    suspect_sources: usize,
    /// Rows that needed the allowance for those, and the worst share of it they used.
    flipped: usize,
    worst_flip: f32,
}

/// GPU `ΔE` of one light set against the CPU's through `near`, with the tolerance of the module
/// doc. `means` are the GPU's row means, `cpu` and `open` the CPU's direct light with and
/// without shadows, `sky` the set's sky at the samples when `near` corrects a sky, `albedo`
/// what the correction reflects with.
fn compare_near(
    near: &NearField,
    albedo: Reflect<'_>,
    delta: &[[f32; 3]],
    means: &[[f32; 3]],
    (cpu, open): (&SampledDirect, &SampledDirect),
    sky: Option<&SkySamples>,
) -> NearAgreement {
    let want = near.correction_with(albedo, &cpu.mean, &cpu.samples, sky);
    assert_eq!(delta.len(), want.len());
    let suspect: Vec<bool> = means.iter().zip(&cpu.mean).map(|(g, c)| g != c).collect();
    let k = near.per_row as usize;
    let mut a = NearAgreement {
        rows: want.len(),
        suspect_sources: suspect.iter().filter(|&&s| s).count(),
        ..NearAgreement::default()
    };
    let mut scales = vec![[0.0f32; 3]; want.len()];
    let mut allowances = vec![[0.0f32; 3]; want.len()];
    for (i, (scale, allowance)) in scales.iter_mut().zip(&mut allowances).enumerate() {
        let (cols, values) = near.row(i);
        let first = near.row_ptr[i] as usize;
        for (e, (&q, &c)) in cols.iter().zip(values).enumerate() {
            let (q, j) = (q as usize, q as usize / k);
            let rho_q = match &near.albedo {
                Some(landed) => landed[first + e],
                None => albedo.samples.map_or(albedo.rows[j], |a| a[q]),
            };
            for ch in 0..3 {
                let (rq, rj) = (c * rho_q[ch], c * albedo.rows[j][ch]);
                let (sq, sj) = sky.map_or((0.0, 0.0), |s| (s.per_sample[q][ch], s.mean[j][ch]));
                scale[ch] +=
                    rq * (cpu.samples[q][ch].abs() + sq) + rj * (cpu.mean[j][ch].abs() + sj);
                if suspect[j] {
                    allowance[ch] += rq * open.samples[q][ch] + rj * open.mean[j][ch];
                }
            }
        }
    }
    let floor = scales.iter().flatten().fold(0.0f32, |m, v| m.max(*v)) * 1e-7;
    for (i, ((g, w), (scale, allowance))) in delta
        .iter()
        .zip(&want)
        .zip(scales.iter().zip(&allowances))
        .enumerate()
    {
        let mut flip = false;
        let mut nontrivial = false;
        for ch in 0..3 {
            assert!(g[ch].is_finite(), "row {i}: {g:?}");
            a.largest = a.largest.max(w[ch].abs());
            nontrivial |= w[ch].abs() > 0.01 * scale[ch] && w[ch].abs() > floor;
            let diff = (g[ch] - w[ch]).abs();
            let rounding = 1e-4 * scale[ch] + floor;
            if diff <= rounding {
                a.worst_rel = a
                    .worst_rel
                    .max(diff / scale[ch].max(floor.max(f32::MIN_POSITIVE)));
            } else {
                flip = true;
                let used = (diff - rounding) / allowance[ch].max(f32::MIN_POSITIVE);
                assert!(
                    used <= 1.0,
                    "row {i} channel {ch}: GPU ΔE {} vs CPU {} (scale {}, allowance {} for rows \
                     whose mean differs)",
                    g[ch],
                    w[ch],
                    scale[ch],
                    allowance[ch]
                );
                a.worst_flip = a.worst_flip.max(used);
            }
        }
        a.flipped += usize::from(flip);
        a.nontrivial += usize::from(nontrivial);
    }
    a
}

/// GPU `ΔE` and means for `sets` against the CPU's, through the case's matrix; returns the GPU's
/// `ΔE`.
fn check(ctx: &GpuContext, name: &str, case: &NearCase, sets: &[LightSet]) -> Vec<Vec<[f32; 3]>> {
    check_field(
        ctx,
        name,
        case,
        &case.near,
        Reflect::rows(&case.albedo),
        sets,
    )
}

/// [`check`] through `near`: the case's matrix, perhaps with a sky view its sets' skies are
/// corrected through.
fn check_field(
    ctx: &GpuContext,
    name: &str,
    case: &NearCase,
    near: &NearField,
    albedo: Reflect<'_>,
    sets: &[LightSet],
) -> Vec<Vec<[f32; 3]>> {
    let n = case.layout.len();
    assert!(near.nnz() > 0, "{name}: an empty near field");
    eprintln!(
        "{name}: {n} rows, {} near-field entries ({:.1} a row)",
        near.nnz(),
        near.nnz() as f64 / n as f64
    );
    let gpu = upload_field(ctx, case, near, albedo);
    let per_patch = case.data.per_patch;
    let (means, delta) = gpu.irradiance_near(sets, per_patch).unwrap();
    let delta = delta.expect("all samples used: a correction");
    assert_eq!((means.len(), delta.len()), (sets.len(), sets.len()));
    // `gather_samples` sums what `gather` sums.
    assert_eq!(
        means,
        gpu.irradiance(sets, per_patch).unwrap(),
        "{name}: means"
    );
    for (k, s) in sets.iter().enumerate() {
        let cpu = direct_with_samples(&case.shadow, &case.layout, s, per_patch).unwrap();
        let open = direct_with_samples(&case.open, &case.layout, s, per_patch).unwrap();
        assert_eq!(cpu.count, per_patch);
        let direct = compare(&means[k], &cpu.mean, &open.mean, per_patch);
        let sky = s
            .sky_sh()
            .and_then(|sky| near.sky_samples_averaging(&sky, case.data.area_samples));
        let a = compare_near(
            near,
            albedo,
            &delta[k],
            &means[k],
            (&cpu, &open),
            sky.as_ref(),
        );
        let brightest = cpu.mean.iter().flatten().fold(0.0f32, |m, v| m.max(*v));
        eprintln!("{name} set {k}: direct {direct:?}, brightest row {brightest}; near field {a:?}");
        // Not vacuous: the correction matters on a fair share of the rows, and somewhere by
        // more than rounding of the direct light.
        assert!(
            a.nontrivial * 20 >= a.rows && a.largest > 1e-3 * brightest,
            "{name} set {k}: a trivial correction, {a:?}"
        );
    }
    delta
}

#[test]
fn point_light_near_a_wall_corrects_as_the_cpu() {
    let Some(ctx) = context() else { return };
    let sets = [
        // Close to the floor's edge along a wall: where the floor and the wall meet, each sees
        // the other's lit and dark ends.
        set(vec![point([0.3, 0.35, 1.8], 4.0, None)]),
        set(vec![point([2.1, 2.6, 1.9], 10.0, Some(3.0))]),
    ];
    check(ctx, "closed box", closed_box(), &sets);
}

#[test]
fn pillar_room_with_several_sets_corrects_as_the_cpu() {
    let Some(ctx) = context() else { return };
    check(ctx, "pillar", room_with_pillar(), &pillar_sets());
}

/// Rows of 48 samples, 36 of them by area (so the pilot rule, `bounce_core::direct::pilots_apply`,
/// decides which rays are traced, landing samples included): the per-sample values the device
/// keeps for the correction follow it as the CPU's do.
#[test]
fn dense_rows_correct_as_the_cpu() {
    let Some(ctx) = context() else { return };
    let case = dense_near_case(&room(None, Some(([1.4, 2.2], 2.5))), SIZE / 12.0, 48, 36);
    check(ctx, "pillar, 48 samples", &case, &pillar_sets());
}

/// `near` with a sky view per sample: made up, but each one a view 8 rays could give (0 to 7
/// of them escaped, along directions from a fixed hash), and different from sample to sample so
/// that a sample read in the wrong place shows.
fn with_sky_view(near: &NearField) -> NearField {
    let samples = near.rows() * near.per_row as usize;
    let rows = (0..samples)
        .map(|q| {
            let mut sum = SkySum::default();
            for r in 0..(q * 5 + q / 3) % 8 {
                let theta = ((q * 7 + r * 13) % 17) as f32 * 0.37;
                let phi = ((q * 3 + r * 5) % 11) as f32 * 0.57;
                sum.add(Vec3::new(
                    theta.sin() * phi.cos(),
                    theta.cos(),
                    theta.sin() * phi.sin(),
                ));
            }
            sum.finish(8)
        })
        .collect();
    let field = NearField {
        sky: Some(SkyVisibility { rows }),
        ..near.clone()
    };
    let n = field.rows();
    field
        .check(n, n, field.per_row)
        .expect("views rays could give");
    field
}

/// A sky's part of the correction runs on the device, in the same pass as the punctual lights',
/// and a landing reflects with the albedo where it landed (or, in a file before version 12, its
/// sample's): the twin of `NearField::correction_with` of the CPU's samples, the entries' or the
/// samples' albedo and the sky at the samples, for a sky with a light, a sky alone, an SH sky
/// that rings below zero, and sets without a sky in the same batch; sliced batches give the same
/// bits.
#[test]
fn a_sky_is_corrected_on_the_device_as_on_the_cpu() {
    let Some(ctx) = context() else { return };
    let case = room_with_pillar();
    let mut near = with_sky_view(&case.near);
    // Each entry's albedo, different from entry to entry, so an entry read in the wrong place
    // shows (the room's own triangles are few colours).
    near.albedo = Some(
        (0..near.nnz())
            .map(|e| {
                let f = |m: usize, d: usize| ((e * m) % d) as f32 / (d - 1) as f32;
                [0.1 + 0.9 * f(7, 11), 0.2 + 0.7 * f(5, 13), 0.9 * f(3, 7)]
            })
            .collect(),
    );
    let json = |text: &str| {
        let set = LightSet::from_json(text).expect("a light set");
        set.validate().expect("valid lights");
        set
    };
    let sets = [
        json(
            r#"{"lights": [{"type": "point", "position": [0.7, 3.0, 0.8], "intensity": 12},
                           {"type": "sky", "color": [1.0, 0.8, 0.6]}]}"#,
        ),
        // Strong first-order terms: some samples' views ring below zero and are clamped.
        json(
            r#"{"lights": [{"type": "sky", "sh": [[0.4,0.4,0.4],[1.5,0,0],[0,1.5,0],[0,0,1.5],
                            [0.3,0.3,0.3],[0,0,0],[-0.4,-0.4,-0.4],[0,0,0],[0.2,0.1,0]]}]}"#,
        ),
        set(vec![point([3.1, 1.2, 2.9], 8.0, Some(5.0))]),
        LightSet { lights: vec![] },
    ];
    // The last set lights nothing: `check_field` asks every set for a correction that matters.
    let lit = &sets[..3];
    // Each sample's albedo about its row's, some darker and some brighter (a textured element).
    let k = PER_PATCH as usize;
    let samples: Vec<[f32; 3]> = (0..case.layout.len() * k)
        .map(|q| {
            let f = 0.6 + 0.8 * ((q * 7) % 5) as f32 / 4.0;
            case.albedo[q / k].map(|a| (a * f).min(1.0))
        })
        .collect();
    let albedo = Reflect {
        rows: &case.albedo,
        samples: Some(&samples),
    };
    let delta = check_field(ctx, "pillar under a sky", case, &near, albedo, lit);
    // A file from before version 12: each landing reflects with its sample's albedo.
    let by_sample = NearField {
        albedo: None,
        ..near.clone()
    };
    let sampled = check_field(
        ctx,
        "pillar, samples' albedo",
        case,
        &by_sample,
        albedo,
        lit,
    );
    assert_ne!(sampled[0], delta[0], "the entries' albedo is the one taken");
    let gpu = upload_field(ctx, case, &near, albedo);
    let all = gpu.irradiance_near(&sets, PER_PATCH).unwrap().1;
    let all = all.expect("a correction");
    assert_eq!(
        all[..3],
        delta[..],
        "a dark set beside them changes nothing"
    );
    assert!(all[3].iter().all(|e| *e == [0.0; 3]), "nothing lights");
    // The sky moved the correction, and only where a set has one.
    let no_view = NearField {
        sky: None,
        ..near.clone()
    };
    let plain = upload_field(ctx, case, &no_view, albedo)
        .irradiance_near(lit, PER_PATCH)
        .unwrap()
        .1;
    let plain = plain.expect("a correction");
    assert_ne!(delta[0], plain[0], "the sky with a light");
    assert!(delta[1].iter().flatten().any(|v| *v != 0.0), "a sky alone");
    assert!(plain[1].iter().all(|e| *e == [0.0; 3]));
    assert_eq!(delta[2], plain[2], "no sky: the punctual correction's bits");
    // One set a slice, and pieces of a few patches: the same bits.
    let n = case.layout.len() as u64;
    let one_set = n * 12 * u64::from(PER_PATCH);
    let split = upload_field(ctx, case, &near, albedo)
        .with_rays_per_piece(500)
        .with_binding_limit(one_set + 5);
    let (_, d) = split.irradiance_near(&sets, PER_PATCH).unwrap();
    assert_eq!(d, Some(all));
}

/// Slices and pieces change where the values wait, not what a row sums: the same bits from one
/// pass, from pieces of one patch, and from slices of one light set that the per-sample values
/// alone force.
#[test]
fn sliced_batches_give_the_same_correction() {
    let Some(ctx) = context() else { return };
    let case = room_with_pillar();
    let n = case.layout.len() as u64;
    let mut sets = many_sets(7);
    // Nothing that lights, between lit sets: its samples are dark, and so is its correction.
    sets.insert(2, LightSet { lights: vec![] });
    let (means, delta) = upload(ctx, case).irradiance_near(&sets, PER_PATCH).unwrap();
    let delta = delta.unwrap();
    assert!(delta[2].iter().all(|e| *e == [0.0; 3]));
    assert!(delta[0].iter().flatten().any(|v| *v != 0.0));
    // A set's per-sample values take `PER_PATCH` times its output: a limit between the two
    // slices the batch by them alone.
    let one_set = n * 12 * u64::from(PER_PATCH);
    for (cap, limit) in [
        (48, u64::MAX),
        (1000, u64::MAX),
        (u64::MAX, one_set * 2 + 5),
    ] {
        let split = upload(ctx, case)
            .with_rays_per_piece(cap)
            .with_binding_limit(limit);
        let (m, d) = split.irradiance_near(&sets, PER_PATCH).unwrap();
        assert_eq!(
            m, means,
            "{cap} rays a piece, {limit} bytes a binding: means"
        );
        assert_eq!(
            d.as_ref(),
            Some(&delta),
            "{cap} rays a piece, {limit} bytes a binding"
        );
    }
    // Room for the means but not for one set's samples: the correction is refused, the plain
    // direct light is not.
    let tight = upload(ctx, case).with_binding_limit(one_set - 1);
    assert_eq!(tight.irradiance(&sets, PER_PATCH).unwrap(), means);
    match tight.irradiance_near(&sets, PER_PATCH) {
        Err(GpuError::TooLarge { what, .. }) => assert!(what.contains("sample"), "{what}"),
        other => panic!("expected TooLarge, got {:?}", other.map(|r| r.0.len())),
    }
}

/// The correction needs every sample the matrix's columns name, and a matrix to apply.
#[test]
fn no_correction_without_every_sample_or_a_matrix() {
    let Some(ctx) = context() else { return };
    let case = closed_box();
    let sets = [set(vec![point([0.25, 2.0, 1.8], 4.0, None)])];
    let gpu = upload(ctx, case);
    let (means, delta) = gpu.irradiance_near(&sets, 4).unwrap();
    assert_eq!(delta, None, "4 of {PER_PATCH} samples");
    assert_eq!(means, gpu.irradiance(&sets, 4).unwrap());
    // More than stored is clamped to all of them.
    assert!(gpu.irradiance_near(&sets, 64).unwrap().1.is_some());
    let plain = GpuSurfaceDirect::upload(ctx, &case.data).unwrap();
    let (m, d) = plain.irradiance_near(&sets, PER_PATCH).unwrap();
    assert_eq!(d, None, "no matrix attached");
    assert_eq!(m, plain.irradiance(&sets, PER_PATCH).unwrap());
    // No light set: nothing to correct, but a correction of nothing.
    assert_eq!(
        gpu.irradiance_near(&[], PER_PATCH).unwrap(),
        (vec![], Some(vec![]))
    );
    // A matrix without entries corrects nothing.
    let n = case.layout.len();
    let empty = NearField {
        per_row: PER_PATCH,
        row_ptr: vec![0; n + 1],
        cols: Vec::new(),
        values: Vec::new(),
        sky: None,
        albedo: Some(Vec::new()),
    };
    let (_, d) = GpuSurfaceDirect::upload(ctx, &case.data)
        .unwrap()
        .with_near_field(&empty, Reflect::rows(&case.albedo))
        .unwrap()
        .irradiance_near(&sets, PER_PATCH)
        .unwrap();
    assert_eq!(d, Some(vec![vec![[0.0; 3]; n]]));
}

#[test]
fn a_matrix_that_does_not_fit_is_refused() {
    let Some(ctx) = context() else { return };
    let case = closed_box();
    let n = case.layout.len();
    let attach = |near: &NearField, albedo: &[[f32; 3]]| {
        GpuSurfaceDirect::upload(ctx, &case.data)
            .unwrap()
            .with_near_field(near, Reflect::rows(albedo))
            .map(|_| ())
    };
    let refused = |what: &str, r: Result<(), GpuError>| match r {
        Err(e @ GpuError::NearField(_)) => eprintln!("{what}: {e}"),
        Err(e) => panic!("{what}: expected NearField, got {e}"),
        Ok(()) => panic!("{what}: accepted"),
    };
    assert!(attach(&case.near, &case.albedo).is_ok());
    refused("albedo short", attach(&case.near, &case.albedo[1..]));
    let mut more = case.albedo.clone();
    more.push([0.5; 3]);
    refused("albedo long", attach(&case.near, &more));
    let other_per_row = NearField {
        per_row: PER_PATCH / 2,
        ..case.near.clone()
    };
    refused("per_row", attach(&other_per_row, &case.albedo));
    let fewer_rows = NearField::concat(PER_PATCH, [NearField::empty(PER_PATCH)]);
    refused("rows", attach(&fewer_rows, &case.albedo[..0]));
    let mut past = case.near.clone();
    if let Some(last) = past.cols.last_mut() {
        *last = (n as u32) * PER_PATCH;
    }
    refused("a column past the samples", attach(&past, &case.albedo));
}

/// What the correction adds to the GPU's direct light on the pillar room at batch 1 and 8, and
/// the CPU twin's cost; prints only (run with `--ignored --nocapture`).
#[test]
#[ignore = "a measurement; run with --ignored --nocapture"]
fn near_field_timing() {
    let Some(ctx) = context() else { return };
    let case = room_with_pillar();
    let gpu = upload(ctx, case);
    let all = many_sets(8);
    for batch in [1, 8] {
        let sets = &all[..batch];
        let plain = median(7, || {
            gpu.irradiance(sets, PER_PATCH).unwrap();
        });
        let near = median(7, || {
            gpu.irradiance_near(sets, PER_PATCH).unwrap();
        });
        let cpu = median(7, || {
            for s in sets {
                let d = direct_with_samples(&case.shadow, &case.layout, s, PER_PATCH).unwrap();
                case.near.correction(&case.albedo, &d.mean, &d.samples);
            }
        });
        eprintln!(
            "near field, {} rows, {} entries, batch {batch}: GPU direct {:.1} ms, with ΔE {:.1} \
             ms; CPU both {:.1} ms ({} threads)",
            case.layout.len(),
            case.near.nnz(),
            plain * 1e3,
            near * 1e3,
            cpu * 1e3,
            rayon::current_num_threads()
        );
    }
}
