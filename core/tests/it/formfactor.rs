//! Form factors against Howell's analytic catalogue (docs/design.md §1) and their invariants.

use bounce_core::formfactor::{FormFactorError, MAX_RAYS, RayScene, form_factor_rows, stats};
use bounce_core::matrix::DenseMatrix;
use bounce_core::patch::{Face, Quad};

fn no_progress(_: u64) {}

/// `F` from patch 0 to patch 1 of a two-quad scene.
fn f01(a: Quad, b: Quad, rays: u32, seed: u64) -> f32 {
    let scene = RayScene::new(&[a, b], &[]);
    form_factor_rows(&scene, 0..1, rays, seed, &no_progress).unwrap()[1]
}

/// Quad in the XZ plane (tangent axes for Y are z then x).
fn horizontal(face: Face, y: f32, x: [f32; 2], z: [f32; 2]) -> Quad {
    Quad {
        face,
        plane: y,
        lo: [z[0], x[0]],
        hi: [z[1], x[1]],
    }
}

fn parallel_unit_squares() -> (Quad, Quad) {
    (
        horizontal(Face::PosY, 0.0, [0.0, 1.0], [0.0, 1.0]),
        horizontal(Face::NegY, 1.0, [0.0, 1.0], [0.0, 1.0]),
    )
}

fn perpendicular_unit_squares() -> (Quad, Quad) {
    // Floor facing up, wall at x = 0 facing +X: they share the edge x = 0, y = 0.
    let floor = horizontal(Face::PosY, 0.0, [0.0, 1.0], [0.0, 1.0]);
    let wall = Quad {
        face: Face::PosX,
        plane: 0.0,
        lo: [0.0, 0.0], // y, z
        hi: [1.0, 1.0],
    };
    (floor, wall)
}

fn rectangles_1_by_1_5() -> (Quad, Quad) {
    (
        horizontal(Face::PosY, 0.0, [0.0, 1.0], [0.0, 1.5]),
        horizontal(Face::NegY, 0.5, [0.0, 1.0], [0.0, 1.5]),
    )
}

/// Howell C-11: directly opposed parallel rectangles `a × b` at distance `c`.
fn parallel_rectangles(a: f64, b: f64, c: f64) -> f64 {
    let (x, y) = (a / c, b / c);
    let (x2, y2) = (x * x, y * y);
    2.0 / (std::f64::consts::PI * x * y)
        * (((1.0 + x2) * (1.0 + y2) / (1.0 + x2 + y2)).sqrt().ln()
            + x * (1.0 + y2).sqrt() * (x / (1.0 + y2).sqrt()).atan()
            + y * (1.0 + x2).sqrt() * (y / (1.0 + x2).sqrt()).atan()
            - x * x.atan()
            - y * y.atan())
}

#[test]
fn catalogue_values_are_what_design_md_quotes() {
    assert!((parallel_rectangles(1.0, 1.0, 1.0) - 0.1998).abs() < 1e-4);
    assert!((parallel_rectangles(1.0, 1.5, 0.5) - 0.4756).abs() < 1e-4);
}

#[test]
fn analytic_cases_within_one_percent_at_high_ray_count() {
    let cases = [
        ("parallel unit squares", parallel_unit_squares(), 0.1998f32),
        (
            "perpendicular unit squares",
            perpendicular_unit_squares(),
            0.2000,
        ),
        (
            "1 x 1.5 rectangles 0.5 apart",
            rectangles_1_by_1_5(),
            0.4756,
        ),
    ];
    for (name, (a, b), want) in cases {
        let got = f01(a, b, 1 << 16, 1);
        let rel = (got - want).abs() / want;
        assert!(rel < 0.01, "{name}: F = {got}, analytic {want} (rel {rel})");
    }
}

#[test]
fn error_shrinks_as_rays_grow() {
    let (a, b) = parallel_unit_squares();
    let exact = parallel_rectangles(1.0, 1.0, 1.0) as f32;
    let mean_err = |rays: u32| -> f32 {
        (0..8u64)
            .map(|seed| (f01(a, b, rays, seed) - exact).abs())
            .sum::<f32>()
            / 8.0
    };
    let errs: Vec<f32> = [16, 256, 4096, 65536].into_iter().map(mean_err).collect();
    for w in errs.windows(2) {
        assert!(w[1] < w[0], "errors do not shrink: {errs:?}");
    }
    // Stratified samples converge faster than the 1/√R of plain Monte Carlo: 4096× the rays
    // should cut the error by far more than 64×.
    assert!(errs[3] < errs[0] / 64.0, "{errs:?}");
}

#[test]
fn reciprocity_holds_between_unequal_patches() {
    let (a, b) = rectangles_1_by_1_5();
    // Beside the gap between a and b, so it neither blocks them nor ties with b.
    let small = horizontal(Face::NegY, 0.3, [1.2, 1.7], [0.5, 1.0]);
    let scene = RayScene::new(&[a, b, small], &[]);
    let rows = form_factor_rows(&scene, 0..3, 1 << 14, 3, &no_progress).unwrap();
    let f = DenseMatrix {
        n: 3,
        channels: 1,
        data: rows,
    };
    let areas = [a.area(), b.area(), small.area()];
    let s = stats(&f, &areas);
    assert!(s.reciprocity_error < 0.01, "{s:?}");
    assert!(s.row_sum_max <= 1.0);
}

#[test]
fn ray_counts_beyond_the_sequence_are_refused() {
    let (a, b) = parallel_unit_squares();
    let scene = RayScene::new(&[a, b], &[]);
    assert!(form_factor_rows(&scene, 0..1, MAX_RAYS, 1, &no_progress).is_ok());
    assert!(matches!(
        form_factor_rows(&scene, 0..1, MAX_RAYS + 1, 1, &no_progress),
        Err(FormFactorError::TooManyRays(_))
    ));
    assert!(matches!(
        form_factor_rows(&scene, 0..1, 0, 1, &no_progress),
        Err(FormFactorError::NoRays)
    ));
}

#[test]
fn occluders_block_and_back_faces_absorb() {
    let (a, b) = parallel_unit_squares();
    // A black plate between them, larger than both.
    let plate = horizontal(Face::PosY, 0.5, [-1.0, 2.0], [-1.0, 2.0]);
    let scene = RayScene::new(&[a, b], &[plate]);
    let rows = form_factor_rows(&scene, 0..2, 4096, 1, &no_progress).unwrap();
    assert_eq!(rows, vec![0.0; 4]);
    // Turn b around: a sees only its back, which reflects nothing.
    let b_back = Quad {
        face: Face::PosY,
        ..b
    };
    assert_eq!(f01(a, b_back, 4096, 1), 0.0);
}

#[test]
fn rows_are_deterministic_and_independent_of_threads_and_ranges() {
    // A closed unit box of 6 × 4 patches per wall.
    let mut quads = Vec::new();
    let k = 4;
    let s = 1.0 / k as f32;
    for face in Face::ALL {
        for u in 0..k {
            for v in 0..k {
                let plane = if face.sign() > 0.0 { 0.0 } else { 1.0 };
                quads.push(Quad {
                    face,
                    plane,
                    lo: [u as f32 * s, v as f32 * s],
                    hi: [(u + 1) as f32 * s, (v + 1) as f32 * s],
                });
            }
        }
    }
    let n = quads.len();
    let scene = RayScene::new(&quads, &[]);
    let full = form_factor_rows(&scene, 0..n, 2048, 42, &no_progress).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let single = pool.install(|| form_factor_rows(&scene, 0..n, 2048, 42, &no_progress).unwrap());
    assert_eq!(full, single);
    let part = form_factor_rows(&scene, 30..70, 2048, 42, &no_progress).unwrap();
    assert_eq!(part, full[30 * n..70 * n]);
    let other_seed = form_factor_rows(&scene, 0..n, 2048, 43, &no_progress).unwrap();
    assert_ne!(full, other_seed);

    // Closed box: every ray lands on a patch, so every row sums to 1 (up to f32 rounding),
    // and nothing sees itself.
    let f = DenseMatrix {
        n,
        channels: 1,
        data: full,
    };
    let st = stats(&f, &vec![s * s; n]);
    assert!(st.row_sum_max <= 1.0 + 1e-5, "{st:?}");
    assert!(st.row_sum_min >= 1.0 - 1e-5, "{st:?}");
    // 2048 rays over 96 patches is about 21 hits an entry: reciprocity holds only to the
    // sampling noise, a few per cent in this aggregate.
    assert!(st.reciprocity_error < 0.1, "{st:?}");
    for i in 0..n {
        assert_eq!(f.get(0, i, i), 0.0);
    }
}
