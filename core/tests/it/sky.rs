//! The sky view a bake keeps (`core/src/sky.rs`) against closed forms, in a unit box whose top
//! face is missing: each row's escaped share is its view factor to the opening, and an SH sky's
//! irradiance on a floor row is the sky's radiance integrated over the opening.
//!
//! Error bounds: a row's escaped share is the mean of `N` indicator values, so as a Monte-Carlo
//! estimate its standard error is at most `σ = √(f(1−f)/N)`; the rows' rays are Owen-scrambled
//! Sobol points, whose variance is no worse than that in practice (and usually far better), so
//! 4σ bounds every row. The closed forms are evaluated by quadrature over the row's pieces, to
//! well under the 2·10⁻³ allowed for them (a quarter of that changes when the quadrature is
//! halved, checked below).

use bounce_core::bake::{BakeOptions, NoProgress, bake_scene, simplify};
use bounce_core::format::Baked;
use bounce_core::meta::Bounces;
use bounce_core::patch::PieceTri;
use bounce_core::scene::{Scene, Triangle};
use bounce_core::sh::{SH_COEFFICIENTS, sh_basis, uniform_sh};
use bounce_core::voxel::{Geometry, Resolution};
use glam::{DVec3, Vec3};

const RAYS: u32 = 4096;

/// The unit box `[0, 1]³` with inward-facing one-sided walls and no top (`y = 1`).
pub(crate) fn open_box() -> Scene {
    let v = Vec3::new;
    let mut t: Vec<Triangle> = Vec::new();
    let walls = [
        (
            [v(0., 0., 0.), v(1., 0., 0.), v(1., 0., 1.), v(0., 0., 1.)],
            Vec3::Y,
        ),
        (
            [v(0., 0., 0.), v(0., 0., 1.), v(0., 1., 1.), v(0., 1., 0.)],
            Vec3::X,
        ),
        (
            [v(1., 0., 0.), v(1., 1., 0.), v(1., 1., 1.), v(1., 0., 1.)],
            Vec3::NEG_X,
        ),
        (
            [v(0., 0., 0.), v(0., 1., 0.), v(1., 1., 0.), v(1., 0., 0.)],
            Vec3::Z,
        ),
        (
            [v(0., 0., 1.), v(1., 0., 1.), v(1., 1., 1.), v(0., 1., 1.)],
            Vec3::NEG_Z,
        ),
    ];
    for (corners, n) in walls {
        crate::direct::rect(&mut t, corners, n);
    }
    Scene {
        triangles: t,
        ..Default::default()
    }
}

/// The opening, `y = 1`.
const OPENING: [[f64; 3]; 4] = [
    [0.0, 1.0, 0.0],
    [1.0, 1.0, 0.0],
    [1.0, 1.0, 1.0],
    [0.0, 1.0, 1.0],
];

pub(crate) fn options() -> BakeOptions {
    BakeOptions {
        resolution: Resolution::VoxelSize(0.125),
        rays: RAYS,
        seed: 7,
        bounces: Bounces::K(1),
        geometry: Geometry::Surface,
        near_radius: 0.0,
        ..BakeOptions::default()
    }
}

/// The view factor from a point `p` with unit normal `n` to a polygon wholly in front of it
/// (Lambert's contour formula): `(1/2π) Σ_edges θ_i n · (a_i × b_i)/|a_i × b_i|`.
fn point_to_polygon(p: DVec3, n: DVec3, polygon: &[[f64; 3]]) -> f64 {
    let mut sum = 0.0;
    for i in 0..polygon.len() {
        let a = (DVec3::from(polygon[i]) - p).normalize();
        let b = (DVec3::from(polygon[(i + 1) % polygon.len()]) - p).normalize();
        let c = a.cross(b);
        let len = c.length();
        if len > 1e-15 {
            sum += n.dot(c / len) * a.dot(b).clamp(-1.0, 1.0).acos();
        }
    }
    (sum / std::f64::consts::TAU).abs()
}

/// `f` averaged over the pieces by area: each piece cut into `m²` equal triangles, each taken at
/// its centroid.
fn row_mean(pieces: &[PieceTri], m: u32, f: &dyn Fn(DVec3, DVec3) -> f64) -> f64 {
    let (mut sum, mut area) = (0.0, 0.0);
    for t in pieces {
        let [a, b, c] = t.corners.map(|v| v.as_dvec3());
        let n = t.normal.as_dvec3().normalize();
        let w = f64::from(t.area) / f64::from(m * m);
        let mut at = |u: f64, v: f64| {
            sum += w * f(a + (b - a) * u + (c - a) * v, n);
            area += w;
        };
        let m = f64::from(m);
        for i in 0..m as u32 {
            for j in 0..(m as u32 - i) {
                let (i, j) = (f64::from(i), f64::from(j));
                at((3.0 * i + 1.0) / (3.0 * m), (3.0 * j + 1.0) / (3.0 * m));
                if i + j + 2.0 <= m {
                    at((3.0 * i + 2.0) / (3.0 * m), (3.0 * j + 2.0) / (3.0 * m));
                }
            }
        }
    }
    sum / area
}

struct OpenBox {
    baked: Baked,
    pieces: bounce_core::patch::Pieces,
}

fn bake_open_box() -> OpenBox {
    let scene = open_box();
    let options = options();
    let baked = bake_scene(&scene, "open-box", &options, &NoProgress).unwrap();
    // Through the file, as a server would read it.
    let baked = Baked::from_bytes(&baked.to_bytes().unwrap()).unwrap();
    let vox = simplify(&scene, &options).unwrap();
    assert_eq!(vox.transport_layout(), baked.transport_layout());
    OpenBox {
        baked,
        pieces: vox.pieces.unwrap(),
    }
}

/// A uniform sky of radiance `L` gives each row `π L f`, `f` its view factor to the opening.
#[test]
fn an_open_box_sees_the_sky_through_its_opening() {
    let OpenBox { baked, pieces } = bake_open_box();
    let sky = baked.sky.as_ref().expect("a new bake keeps its sky view");
    let n = sky.len();
    assert!(n >= 5 * 64, "{n} rows");
    let radiance = 1.5f32;
    let e = sky.irradiance(&uniform_sh([radiance; 3]));
    let (mut worst, mut signed, mut var) = (0.0f64, 0.0f64, 0.0f64);
    for (row, e_row) in e.iter().enumerate() {
        let exact = row_mean(pieces.of(row), 16, &|p, n| point_to_polygon(p, n, &OPENING));
        let coarse = row_mean(pieces.of(row), 8, &|p, n| point_to_polygon(p, n, &OPENING));
        assert!(
            (exact - coarse).abs() < 5e-4,
            "row {row}: quadrature {exact} {coarse}"
        );
        let f = sky.escaped_fraction(row);
        // The closed form of a uniform sky: E = π L f, in every channel.
        let want_e = std::f64::consts::PI * f64::from(radiance) * f;
        assert!((f64::from(e_row[0]) - want_e).abs() < 1e-4 * want_e.max(1.0));
        assert_eq!(e_row[0], e_row[2]);
        let sigma = (exact * (1.0 - exact) / f64::from(RAYS)).sqrt();
        let err = f - exact;
        assert!(
            err.abs() <= 4.0 * sigma + 2e-3,
            "row {row}: escaped {f:.4}, view factor to the opening {exact:.4} (σ {sigma:.4})"
        );
        worst = worst.max(err.abs() / (sigma + 1e-3));
        signed += err;
        var += sigma * sigma;
    }
    // No bias: the rows' errors are independent, so their mean is within 4 of its σ.
    let mean = signed / n as f64;
    assert!(
        mean.abs() <= 4.0 * var.sqrt() / n as f64 + 5e-4,
        "mean error {mean:.2e} over {n} rows"
    );
    eprintln!("open box: {n} rows, worst |error| / (σ + 1e-3) = {worst:.2}, mean error {mean:.2e}");
    // The floor's rows together see the opening as the floor does: Howell's parallel unit
    // squares at unit distance, F = 0.1998.
    let floor: Vec<usize> = (0..n)
        .filter(|&r| baked.transport_layout().patches[r].normal[1] > 0.99)
        .collect();
    let areas = baked.transport_layout().areas(Geometry::Surface);
    let total: f64 = floor.iter().map(|&r| f64::from(areas[r])).sum();
    let seen: f64 = floor
        .iter()
        .map(|&r| f64::from(areas[r]) * sky.escaped_fraction(r))
        .sum();
    assert!((total - 1.0).abs() < 1e-4, "floor area {total}");
    assert!(
        (seen / total - 0.1998).abs() < 2e-3,
        "floor sees {}",
        seen / total
    );
}

/// An SH sky: each floor row gets `∫ L(ω) cos θ dω` over the opening, by quadrature over the
/// opening; the bound is the Monte-Carlo one with each ray's value at most `π max L`.
#[test]
fn an_sh_sky_weighs_each_direction() {
    let OpenBox { baked, pieces } = bake_open_box();
    let sky = baked.sky.as_ref().unwrap();
    // Brighter overhead (Y10 is along z, Y1−1 along y in the basis' own axes), a little tinted.
    let mut coeffs = [[0.0f32; 3]; SH_COEFFICIENTS];
    coeffs[0] = [3.0, 3.0, 3.5];
    coeffs[1] = [1.2, 1.0, 0.8];
    coeffs[2] = [0.3, 0.3, 0.3];
    coeffs[3] = [-0.2, -0.2, -0.2];
    coeffs[6] = [0.25, 0.25, 0.25];
    coeffs[8] = [-0.3, 0.0, 0.3];
    let radiance = |d: DVec3, c: usize| -> f64 {
        let y = sh_basis(d.to_array());
        (0..SH_COEFFICIENTS)
            .map(|k| y[k] * f64::from(coeffs[k][c]))
            .sum()
    };
    let e = sky.irradiance(&coeffs);
    // The opening in K × K cells, each at its centre.
    const K: usize = 48;
    let cells: Vec<DVec3> = (0..K * K)
        .map(|i| {
            let (a, b) = ((i % K) as f64 + 0.5, (i / K) as f64 + 0.5);
            DVec3::new(a / K as f64, 1.0, b / K as f64)
        })
        .collect();
    let l_max = cells
        .iter()
        .map(|&q| radiance((q - DVec3::new(0.5, 0.0, 0.5)).normalize(), 2).abs())
        .fold(0.0f64, f64::max)
        * 1.5;
    let floor = (0..sky.len()).filter(|&r| baked.transport_layout().patches[r].normal[1] > 0.99);
    let mut checked = 0;
    for row in floor {
        for (c, &got) in e[row].iter().enumerate() {
            let exact = row_mean(pieces.of(row), 4, &|p, n| {
                let da = 1.0 / (K * K) as f64;
                cells
                    .iter()
                    .map(|&q| {
                        let d = q - p;
                        let r2 = d.length_squared();
                        let w = d.normalize();
                        // cos at the point × cos at the opening (normal −y) / r²
                        radiance(w, c) * n.dot(w) * w.y / r2 * da
                    })
                    .sum()
            });
            let f = sky.escaped_fraction(row);
            let sigma = std::f64::consts::PI * l_max * (f / f64::from(RAYS)).sqrt();
            let got = f64::from(got);
            assert!(
                (got - exact).abs() <= 4.0 * sigma + 2e-3 * std::f64::consts::PI * l_max,
                "row {row} channel {c}: {got:.4} against {exact:.4} (σ {sigma:.4})"
            );
        }
        checked += 1;
    }
    assert!(checked >= 64, "{checked} floor rows");
}

/// Voxel-face bakes keep a sky view too, from their rays that leave the voxel grid: one row a
/// patch, the rows' escaped shares adding up to the rays the bake's tally counts as escaped, no
/// sky for a face looking down. Voxel faces may stand up to a voxel off the surfaces, so the
/// floor's share is held to Howell's 0.1998 within 0.01 only (its 64 faces' mean has a Monte-Carlo
/// σ near 0.001).
#[test]
fn voxel_face_bakes_keep_a_sky_view_too() {
    let scene = open_box();
    let options = BakeOptions {
        geometry: Geometry::VoxelFaces,
        ..options()
    };
    let baked = bake_scene(&scene, "open-box", &options, &NoProgress).unwrap();
    let sky = baked.sky.as_ref().expect("voxel faces keep a sky view");
    let rows = baked.transport_layout();
    assert_eq!(sky.len(), rows.len());
    let escaped: f64 = (0..sky.len()).map(|r| sky.escaped_fraction(r)).sum();
    let tally = baked.meta.stats.rays;
    let counted = tally.escaped as f64 / f64::from(RAYS);
    assert!(
        (escaped - counted).abs() < 1e-3 * counted.max(1.0),
        "{escaped} against the tally's {counted}"
    );
    for (r, p) in rows.patches.iter().enumerate() {
        if p.normal[1] < -0.5 {
            assert_eq!(sky.escaped_fraction(r), 0.0, "a face looking down, row {r}");
        }
    }
    let floor: Vec<usize> = (0..sky.len())
        .filter(|&r| rows.patches[r].normal[1] > 0.99)
        .collect();
    let mean = floor.iter().map(|&r| sky.escaped_fraction(r)).sum::<f64>() / floor.len() as f64;
    eprintln!(
        "voxel faces: {} rows, floor's mean escaped share {mean:.4}",
        sky.len()
    );
    assert!((mean - 0.1998).abs() < 0.01, "{mean}");
}
