//! Form factors with visibility, by cosine-weighted quasi-Monte-Carlo rays (traced by [`crate::rays`]).
//!
//! Row `i` of `F` is estimated by shooting `R` rays from patch `i`: origins uniform over the patch,
//! directions cosine-weighted about its normal, both from one 4-D Owen-scrambled Sobol sequence
//! (stratified in every 2-D projection). A ray that first hits the front of patch `j` adds `1/R` to
//! `F_ij`; rays that escape, or hit an occluder or the back of a patch, carry nothing. So every row
//! sums to at most 1 by construction, and only the row's own index and the seed decide its
//! samples: rows can be computed in any order, on any number of threads or processes, with
//! bit-identical results.

use std::ops::Range;

use glam::Vec3;
use rayon::prelude::*;
use thiserror::Error;

use crate::landings::{Landings, landings_of};
use crate::matrix::DenseMatrix;
use crate::patch::Quad;
pub use crate::rays::{RayFate, RayScene, RayTally, Tracer};
use crate::sample::{SamplePoint, nearest_sample};
use crate::sky::{RowSky, SkyVisibility};
use bounce_types::sh::SH_COEFFICIENTS;

#[derive(Debug, Error)]
pub enum FormFactorError {
    #[error("rays per patch must be at least 1")]
    NoRays,
    #[error("{0} rays per patch is more than the {MAX_RAYS} the sample sequence provides")]
    TooManyRays(u32),
    #[error("row range {start}..{end} is outside 0..{n}")]
    RowRange { start: usize, end: usize, n: usize },
}

/// The Owen-scrambled Sobol sequence (`sobol_burley`) has 2^16 points a seed.
pub const MAX_RAYS: u32 = 1 << 16;

/// Per-row seed: a hash of the bake seed and the row, so rows are independent streams.
pub(crate) fn row_seed(seed: u64, row: usize) -> u32 {
    // SplitMix64 finaliser.
    let mut z = seed ^ (row as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (z ^ (z >> 31)) as u32
}

/// Cosine-weighted direction about `quad`'s normal from two uniform numbers (Malley's method).
fn cosine_direction(quad: &Quad, u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (a, b) = (r * phi.cos(), r * phi.sin());
    let h = (1.0 - u1).max(0.0).sqrt();
    let (ua, va) = quad.tangent_axes();
    let mut d = Vec3::ZERO;
    d[ua] = a;
    d[va] = b;
    d[quad.face.axis()] = h * quad.face.sign();
    d
}

/// What form-factor rows are traced through: voxel faces ([`RayScene`]) or surface patches
/// ([`crate::surface::SurfaceScene`]).
pub trait RowTracer: Sync {
    fn patch_count(&self) -> usize;
    /// Shoot `rays` rays from patch `row`, adding to `counts[j]` each that reached patch `j`,
    /// to `seen.sky` every ray, escaped or not ([`crate::sky`]), and to `seen.near` each that
    /// landed near its origin.
    fn trace_row_sky(
        &self,
        row: usize,
        rays: u32,
        seed: u64,
        counts: &mut [u32],
        seen: &mut RowRays<'_>,
    ) -> RayTally;
    /// [`RowTracer::trace_row_sky`] without the sky.
    fn trace_row(&self, row: usize, rays: u32, seed: u64, counts: &mut [u32]) -> RayTally {
        self.trace_row_sky(row, rays, seed, counts, &mut RowRays::plain())
    }
    /// Whether any of `rays` probe rays (other samples than the row's) from `row` reaches a
    /// patch.
    fn sees_another(&self, row: usize, rays: u32, seed: u64) -> bool;
    /// Whether `row`'s surface lies where no viewer sees it: at least three quarters of the
    /// same probe rays meet the back of a single-sided surface, as they do from inside a closed
    /// solid. Voxel faces have no back faces: never.
    fn hidden(&self, _row: usize, _rays: u32, _seed: u64) -> bool {
        false
    }
}

impl RowTracer for RayScene {
    fn patch_count(&self) -> usize {
        RayScene::patch_count(self)
    }

    fn trace_row_sky(
        &self,
        row: usize,
        rays: u32,
        seed: u64,
        counts: &mut [u32],
        seen: &mut RowRays<'_>,
    ) -> RayTally {
        let quad = self.patch(row);
        let s = row_seed(seed, row);
        let mut tally = RayTally::default();
        for k in 0..rays {
            let [a, b, c, d] = sobol_burley::sample_4d(k, 0, s);
            // The origin lies exactly on the patch's plane and intersections need t > 0, so the
            // patch itself and coplanar neighbours are never hit: no epsilon offset to tune.
            let origin = quad.point(a, b);
            let dir = cosine_direction(quad, c, d);
            let fate = self.trace(row, origin, dir);
            match fate {
                RayFate::Patch(j) => counts[j] += 1,
                // Out of the voxel grid: nothing the scene holds stands in the way.
                RayFate::Escaped => seen.sky.escaped(dir),
                RayFate::Occluder | RayFate::BackFace => {}
            }
            tally.count(fate);
        }
        tally
    }

    fn sees_another(&self, row: usize, rays: u32, seed: u64) -> bool {
        let quad = self.patch(row);
        let s = row_seed(seed, row);
        (0..rays).any(|k| {
            let [a, b, c, d] = sobol_burley::sample_4d(k, PROBE_DIMENSION_SET, s);
            matches!(
                self.trace(row, quad.point(a, b), cosine_direction(quad, c, d)),
                RayFate::Patch(_)
            )
        })
    }
}

/// What a row's form-factor rays leave besides their counts.
pub struct RowRays<'a> {
    /// The row's view of the sky and its samples' ([`crate::sky`]).
    pub sky: RowSky<'a>,
    /// Where the rays that land near their origin land ([`crate::nearfield`]).
    pub near: NearRays<'a>,
}

impl RowRays<'_> {
    /// Nothing kept but the row's own sky view.
    pub fn plain() -> RowRays<'static> {
        RowRays {
            sky: RowSky::new(&[]),
            near: NearRays::none(),
        }
    }
}

/// One row's rays that land within `radius` of their origin, each as the direct-light sample
/// point of the row it landed on that stands for where it landed ([`nearest_sample`]: the
/// nearest on the surface met): a row of the near-field matrix, taken in the form
/// factors' own pass so the rays are traced once.
pub struct NearRays<'a> {
    radius: f32,
    /// Every row's sample points, `per_row` a row.
    samples: &'a [SamplePoint],
    per_row: usize,
    /// Per landing, its sample point and the albedo of the triangle it met.
    hits: Vec<(u32, Vec3)>,
}

impl<'a> NearRays<'a> {
    /// Keeps nothing.
    pub fn none() -> NearRays<'static> {
        NearRays {
            radius: 0.0,
            samples: &[],
            per_row: 0,
            hits: Vec::new(),
        }
    }

    /// Keeps the rays that land closer than `radius` (scene units), against `samples` (every
    /// row's, `per_row` a row).
    pub fn new(radius: f32, samples: &'a [SamplePoint], per_row: usize) -> NearRays<'a> {
        NearRays {
            radius,
            samples,
            per_row,
            hits: Vec::new(),
        }
    }

    /// A ray landed at `point`, `t` from its origin, on row `row`'s surface of unit normal
    /// `normal` (the side it met), on a triangle of albedo `albedo`.
    #[inline]
    pub fn landed(&mut self, t: f32, point: Vec3, normal: Vec3, row: usize, albedo: Vec3) {
        let k = self.per_row;
        if t < self.radius && k > 0 {
            let own = &self.samples[row * k..(row + 1) * k];
            self.hits.push((
                (row * k + nearest_sample(own, point, normal)) as u32,
                albedo,
            ));
        }
    }

    /// The row of the near-field matrix after `rays` rays: per sample point landed on
    /// (ascending), the share of the rays and their mean albedo.
    pub fn finish(mut self, rays: u32) -> Vec<Landings> {
        landings_of(&mut self.hits, rays)
    }
}

/// Sobol dimension set of the visibility probe, apart from the one the form factors use, so the
/// probe's rays are not the first rays of the rows.
const PROBE_DIMENSION_SET: u32 = 1;

/// Which patches see no other patch in `rays` probe rays. Such a patch can neither receive nor
/// give indirect light (by reciprocity nothing sees it either), so a bake can drop it. A patch
/// that sees others through less than about `1/rays` of its hemisphere may be dropped too; the
/// light it would have exchanged is of that order.
pub fn isolated_patches(scene: &dyn RowTracer, rays: u32, seed: u64) -> Vec<bool> {
    (0..scene.patch_count())
        .into_par_iter()
        .map(|i| !scene.sees_another(i, rays, seed))
        .collect()
}

/// Of the `isolated` patches ([`isolated_patches`]), which are hidden ([`RowTracer::hidden`]):
/// surface no viewer sees, rather than surface in the open that sees nothing.
pub fn hidden_patches(scene: &dyn RowTracer, isolated: &[bool], rays: u32, seed: u64) -> Vec<bool> {
    isolated
        .par_iter()
        .enumerate()
        .map(|(i, &isolated)| isolated && scene.hidden(i, rays, seed))
        .collect()
}

/// Form-factor rows `rows` (row-major, `rows.len() × n`), with visibility. `progress` is called
/// with the number of rows finished since the last call.
pub fn form_factor_rows(
    scene: &dyn RowTracer,
    rows: Range<usize>,
    rays: u32,
    seed: u64,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<f32>, FormFactorError> {
    form_factor_rows_tallied(scene, rows, rays, seed, progress).map(|(rows, _)| rows)
}

/// Whether rows `rows` of `n`, each traced with `rays` rays, can be traced: what every caller
/// that retraces a bake's rows (form factors, the near field) checks first.
pub(crate) fn check_rows(rows: &Range<usize>, rays: u32, n: usize) -> Result<(), FormFactorError> {
    if rays == 0 {
        return Err(FormFactorError::NoRays);
    }
    if rays > MAX_RAYS {
        return Err(FormFactorError::TooManyRays(rays));
    }
    if rows.start > rows.end || rows.end > n {
        return Err(FormFactorError::RowRange {
            start: rows.start,
            end: rows.end,
            n,
        });
    }
    Ok(())
}

/// As [`form_factor_rows`], also telling where the rays that reached no patch went.
pub fn form_factor_rows_tallied(
    scene: &dyn RowTracer,
    rows: Range<usize>,
    rays: u32,
    seed: u64,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(Vec<f32>, RayTally), FormFactorError> {
    form_factor_rows_sampled(scene, rows, rays, seed, None, 0.0, progress).map(|t| (t.f, t.tally))
}

/// What [`form_factor_rows_sampled`] traced.
pub struct Traced {
    /// The rows of `F`, row-major.
    pub f: Vec<f32>,
    pub tally: RayTally,
    /// Each row's view of the sky.
    pub sky: SkyVisibility,
    /// With samples, each sample's view of the sky, `per_row` a row in row order.
    pub samples_sky: Option<SkyVisibility>,
    /// With samples and a near radius, each row's near-field row ([`NearRays::finish`]).
    pub near: Option<Vec<Vec<Landings>>>,
}

/// As [`form_factor_rows_tallied`], also each row's view of the sky from the same rays
/// ([`crate::sky`]) and, with `samples` (every row's direct-light sample points, `per_row` a
/// row), each sample's view of the sky from the row's rays that start nearest it
/// ([`crate::sky::RowSky`]) and, when `near_radius` is above 0, the rows of the near-field
/// matrix ([`NearRays`]): the rays that land closer than `near_radius` to their origin.
pub fn form_factor_rows_sampled(
    scene: &dyn RowTracer,
    rows: Range<usize>,
    rays: u32,
    seed: u64,
    samples: Option<(&[SamplePoint], u32)>,
    near_radius: f32,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Traced, FormFactorError> {
    let n = scene.patch_count();
    check_rows(&rows, rays, n)?;
    let k = samples.map_or(0, |(_, k)| k as usize);
    if let Some((points, _)) = samples {
        assert!(points.len() >= n * k, "sample points for every row");
    }
    let keep_near = samples.is_some() && near_radius > 0.0;
    let mut out = vec![0.0f32; rows.len() * n];
    let mut sky = vec![[0.0f32; SH_COEFFICIENTS]; rows.len()];
    // One (unused) view a row without samples, so the rows zip in step.
    let mut per_sample = vec![[0.0f32; SH_COEFFICIENTS]; rows.len() * k.max(1)];
    let mut near = vec![Vec::new(); rows.len()];
    let inv = 1.0 / rays as f32;
    let tally = out
        .par_chunks_mut(n.max(1))
        .zip(sky.par_iter_mut())
        .zip(per_sample.par_chunks_mut(k.max(1)))
        .zip(near.par_iter_mut())
        .enumerate()
        .map_init(
            || vec![0u32; n],
            |counts, (r, (((row_out, sky_out), samples_out), near_out))| {
                counts.fill(0);
                let row = rows.start + r;
                let own = samples.map_or(&[][..], |(p, _)| &p[row * k..(row + 1) * k]);
                let mut seen = RowRays {
                    sky: RowSky::new(own),
                    near: match samples {
                        Some((all, _)) if keep_near => NearRays::new(near_radius, all, k),
                        _ => NearRays::none(),
                    },
                };
                let tally = scene.trace_row_sky(row, rays, seed, counts, &mut seen);
                for (o, &c) in row_out.iter_mut().zip(counts.iter()) {
                    *o = c as f32 * inv;
                }
                let (view, views) = seen.sky.finish(rays);
                *sky_out = view;
                samples_out[..views.len()].copy_from_slice(&views);
                *near_out = seen.near.finish(rays);
                progress(1);
                tally
            },
        )
        .reduce(RayTally::default, |a, b| a + b);
    Ok(Traced {
        f: out,
        tally,
        sky: SkyVisibility { rows: sky },
        samples_sky: samples.map(|_| SkyVisibility { rows: per_sample }),
        near: keep_near.then_some(near),
    })
}

/// The whole single-bounce form-factor matrix.
pub fn form_factors(
    scene: &dyn RowTracer,
    rays: u32,
    seed: u64,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(DenseMatrix, RayTally), FormFactorError> {
    let n = scene.patch_count();
    let (data, tally) = form_factor_rows_tallied(scene, 0..n, rays, seed, progress)?;
    Ok((
        DenseMatrix {
            n,
            channels: 1,
            data,
        },
        tally,
    ))
}

/// Checks of the form-factor invariants, reported by the bake and `bounce inspect`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FormFactorStats {
    pub row_sum_min: f32,
    pub row_sum_max: f32,
    pub row_sum_mean: f32,
    /// `Σ|A_i F_ij − A_j F_ji| / Σ(A_i F_ij + A_j F_ji)` over all pairs.
    pub reciprocity_error: f32,
    /// Rows that reach no patch at all.
    pub isolated: usize,
}

/// The sums are taken per row, then over rows in order, so the result does not depend on the
/// thread count: a sharded bake computes it in another process and must get the same bits.
pub fn stats(f: &DenseMatrix, areas: &[f32]) -> FormFactorStats {
    let n = f.n;
    let m = f.channel(0);
    // Per row: its sum, and the reciprocity terms of the pairs (i, j > i).
    let rows: Vec<(f64, f64, f64)> = (0..n)
        .into_par_iter()
        .map(|i| {
            let sum = m[i * n..(i + 1) * n].iter().map(|&v| v as f64).sum();
            let (mut num, mut den) = (0.0f64, 0.0f64);
            for j in i + 1..n {
                let a = areas[i] as f64 * m[i * n + j] as f64;
                let b = areas[j] as f64 * m[j * n + i] as f64;
                num += (a - b).abs();
                den += a + b;
            }
            (sum, num, den)
        })
        .collect();
    let (mut lo, mut hi, mut total) = (f64::INFINITY, 0.0f64, 0.0);
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for &(s, a, b) in &rows {
        lo = lo.min(s);
        hi = hi.max(s);
        total += s;
        num += a;
        den += b;
    }
    FormFactorStats {
        row_sum_min: if n == 0 { 0.0 } else { lo as f32 },
        row_sum_max: hi as f32,
        row_sum_mean: if n == 0 {
            0.0
        } else {
            (total / n as f64) as f32
        },
        reciprocity_error: if den > 0.0 { (num / den) as f32 } else { 0.0 },
        isolated: rows.iter().filter(|r| r.0 == 0.0).count(),
    }
}
