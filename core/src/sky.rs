//! Each transport row's view of the sky, kept from the form-factor rays that escape the scene.
//!
//! A row's form-factor rays are cosine-weighted about its pieces' normals (`pdf = cos θ / π`), so
//! for a sky radiance `L(ω)` the irradiance the row gets from the sky,
//! `E_sky = ∫ L(ω) V(ω) cos θ dω` averaged over the row's surface, is estimated by
//! `(π / N) Σ_escaped L(ω_i)` over its `N` rays. With `L(ω) = Σ L_lm Y_lm(ω)` (order-2 real
//! spherical harmonics, [`bounce_types::sh`]) that is
//!
//! ```text
//! E_sky = Σ_lm c_lm L_lm,      c_lm = (π / N) Σ_escaped Y_lm(ω_i)
//! ```
//!
//! and the 9 numbers `c_lm` are what a bake stores per row (the `SKYV` section). For a uniform
//! sky (`L00` alone, radiance `L = L00 · Y00`) it is the closed form `E_sky = π L · f`, `f` the
//! share of the row's rays that escaped: `c00 = π Y00 f`.
//!
//! Like the row of `F` it comes from, a row's term depends on its index and the seed alone (the
//! sum runs over the row's rays in order, in f64), so sharded bakes store the same bits.

use bounce_types::sh::{SH_BASIS_MAX, SH_COEFFICIENTS, sh_basis};
use glam::Vec3;
use rayon::prelude::*;

use crate::sample::{SamplePoint, nearest_sample};

/// Per transport row, the coefficients `c_lm` of the module doc.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SkyVisibility {
    pub rows: Vec<[f32; SH_COEFFICIENTS]>,
}

/// The running sum of one row's escaped directions.
#[derive(Debug, Clone, Copy, Default)]
pub struct SkySum {
    sum: [f64; SH_COEFFICIENTS],
}

impl SkySum {
    /// A ray escaped along unit `dir`.
    #[inline]
    pub fn add(&mut self, dir: Vec3) {
        let y = sh_basis([f64::from(dir.x), f64::from(dir.y), f64::from(dir.z)]);
        for (s, v) in self.sum.iter_mut().zip(y) {
            *s += v;
        }
    }

    /// The row's `c_lm` after `rays` rays.
    pub fn finish(&self, rays: u32) -> [f32; SH_COEFFICIENTS] {
        let w = std::f64::consts::PI / f64::from(rays.max(1));
        self.sum.map(|s| (s * w) as f32)
    }
}

/// One row's sky as its form-factor rays find it: the row's [`SkySum`] and, when the row's
/// direct-light sample points are given, each sample's, over the rays whose origin that sample
/// stands for ([`nearest_sample`]; what the near field corrects a sky with: [`crate::nearfield`]).
pub struct RowSky<'a> {
    pub row: SkySum,
    samples: &'a [SamplePoint],
    per_sample: Vec<(SkySum, u32)>,
}

impl<'a> RowSky<'a> {
    /// A tally for a row whose sample points lie at `samples` (none: the row's view alone).
    pub fn new(samples: &'a [SamplePoint]) -> RowSky<'a> {
        RowSky {
            row: SkySum::default(),
            samples,
            per_sample: vec![(SkySum::default(), 0); samples.len()],
        }
    }

    /// A ray that started at `origin`, on surface of unit normal `normal`, and went along unit
    /// `dir`, escaping or not.
    #[inline]
    pub fn ray(&mut self, origin: Vec3, normal: Vec3, dir: Vec3, escaped: bool) {
        if escaped {
            self.row.add(dir);
        }
        if self.samples.is_empty() {
            return;
        }
        let nearest = nearest_sample(self.samples, origin, normal);
        let (sum, n) = &mut self.per_sample[nearest];
        *n += 1;
        if escaped {
            sum.add(dir);
        }
    }

    /// A ray along unit `dir` escaped, from no particular sample.
    #[inline]
    pub fn escaped(&mut self, dir: Vec3) {
        self.row.add(dir);
    }

    /// The row's view after `rays` rays, and its samples' (`(π / N_s) Σ_escaped Y_lm` over the
    /// `N_s` rays a sample was given, so their ray-weighted mean is the row's view; a sample no
    /// ray started nearest to takes the row's).
    pub fn finish(&self, rays: u32) -> ([f32; SH_COEFFICIENTS], Vec<[f32; SH_COEFFICIENTS]>) {
        let row = self.row.finish(rays);
        let samples = self
            .per_sample
            .iter()
            .map(|(sum, n)| if *n == 0 { row } else { sum.finish(*n) })
            .collect();
        (row, samples)
    }
}

impl SkyVisibility {
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The share of row `i`'s rays that escaped: `c00 / (π Y00)`.
    pub fn escaped_fraction(&self, i: usize) -> f64 {
        f64::from(self.rows[i][0]) / (std::f64::consts::PI * SH_BASIS_MAX[0])
    }

    /// Per row, the irradiance a sky of radiance coefficients `sky` gives it, `Σ c_lm L_lm`
    /// per channel. An SH sky may ring below zero in some directions; a row that would get
    /// negative light from it gets none.
    ///
    /// In parallel: the near field's samples hold a view each (pandora: 189 k, evaluated for
    /// every light set with a sky); on one thread they took 2.6 ms a set, against 0.9 ms on two.
    pub fn irradiance(&self, sky: &[[f32; 3]; SH_COEFFICIENTS]) -> Vec<[f32; 3]> {
        self.rows
            .par_iter()
            .with_min_len(1024)
            .map(|c| {
                std::array::from_fn(|ch| {
                    let e: f64 = (0..SH_COEFFICIENTS)
                        .map(|k| f64::from(c[k]) * f64::from(sky[k][ch]))
                        .sum();
                    (e.max(0.0) as f32).min(f32::MAX)
                })
            })
            .collect()
    }

    /// What a reader checks: `rows` rows, every value finite and within what `N` rays can sum
    /// to (`|c_lm| ≤ π max|Y_lm|`, `c00 ≥ 0`).
    pub fn check(&self, rows: usize) -> Result<(), String> {
        if self.rows.len() != rows {
            return Err(format!(
                "{} rows, but the transport has {rows}",
                self.rows.len()
            ));
        }
        for (i, row) in self.rows.iter().enumerate() {
            for (k, &c) in row.iter().enumerate() {
                // A little slack for the f64 → f32 rounding of a row that escaped everywhere.
                let bound = std::f64::consts::PI * SH_BASIS_MAX[k] * (1.0 + 1e-5);
                let ok = c.is_finite() && f64::from(c).abs() <= bound && (k > 0 || c >= 0.0);
                if !ok {
                    return Err(format!(
                        "row {i}, coefficient {k}: {c} is not a sky view (finite, |c| ≤ {bound:.6}{})",
                        if k == 0 { ", not negative" } else { "" }
                    ));
                }
            }
        }
        Ok(())
    }

    /// Rows `range`.
    pub fn slice(&self, range: std::ops::Range<usize>) -> SkyVisibility {
        SkyVisibility {
            rows: self.rows[range].to_vec(),
        }
    }

    /// Consecutive row ranges joined, in order.
    pub fn concat(parts: impl IntoIterator<Item = SkyVisibility>) -> SkyVisibility {
        SkyVisibility {
            rows: parts.into_iter().flat_map(|p| p.rows).collect(),
        }
    }

    /// The area-weighted mean escaped share over rows of areas `areas`: what `bounce inspect`
    /// reports.
    pub fn mean_escaped(&self, areas: &[f32]) -> f64 {
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (i, &a) in areas.iter().enumerate().take(self.rows.len()) {
            num += f64::from(a) * self.escaped_fraction(i);
            den += f64::from(a);
        }
        if den > 0.0 { num / den } else { 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounce_types::sh::uniform_sh;

    #[test]
    fn a_uniform_sky_gives_pi_l_times_the_escaped_share() {
        // 3 of 4 rays escaped, in any directions: only c00 meets a uniform sky.
        let mut s = SkySum::default();
        for d in [Vec3::Y, Vec3::X, Vec3::new(0.0, 0.6, 0.8)] {
            s.add(d);
        }
        let sky = SkyVisibility {
            rows: vec![s.finish(4)],
        };
        assert!((sky.escaped_fraction(0) - 0.75).abs() < 1e-6);
        let e = sky.irradiance(&uniform_sh([2.0, 1.0, 0.0]));
        let want = std::f32::consts::PI * 0.75;
        assert!((e[0][0] - 2.0 * want).abs() < 1e-5, "{e:?}");
        assert!((e[0][1] - want).abs() < 1e-5 && e[0][2] == 0.0, "{e:?}");
        assert_eq!(sky.check(1), Ok(()));
    }

    #[test]
    fn each_sample_sees_the_sky_of_the_rays_that_start_nearest_it() {
        let at = |x: f32| SamplePoint {
            position: [x, 0.0, 0.0],
            normal: [0.0, 1.0, 0.0],
        };
        let samples = [at(0.0), at(1.0), at(5.0)];
        let mut tally = RowSky::new(&samples);
        // Near sample 0: 4 rays, 3 escape. Near sample 1: 4 rays, 1 escapes. Sample 2: none.
        for k in 0..4 {
            tally.ray(Vec3::new(0.1, 0.0, 0.0), Vec3::Y, Vec3::Y, k < 3);
            tally.ray(Vec3::new(0.9, 0.0, 0.0), Vec3::Y, Vec3::X, k < 1);
        }
        let (row, views) = tally.finish(8);
        let share =
            |c: &[f32; SH_COEFFICIENTS]| f64::from(c[0]) / (std::f64::consts::PI * SH_BASIS_MAX[0]);
        assert!((share(&row) - 0.5).abs() < 1e-6);
        assert!((share(&views[0]) - 0.75).abs() < 1e-6);
        assert!((share(&views[1]) - 0.25).abs() < 1e-6);
        // A sample no ray started nearest to takes the row's view.
        assert_eq!(views[2], row);
        // Weighted by their rays, the samples' views are the row's.
        for k in 0..SH_COEFFICIENTS {
            let mean = 0.5 * (views[0][k] + views[1][k]);
            assert!((mean - row[k]).abs() < 1e-6, "coefficient {k}");
        }
        // Without samples the row's view is the same.
        let mut plain = RowSky::new(&[]);
        for k in 0..4 {
            plain.ray(Vec3::new(0.1, 0.0, 0.0), Vec3::Y, Vec3::Y, k < 3);
            plain.ray(Vec3::new(0.9, 0.0, 0.0), Vec3::Y, Vec3::X, k < 1);
        }
        let (alone, none) = plain.finish(8);
        assert_eq!((alone, none.len()), (row, 0));
    }

    #[test]
    fn values_no_rays_could_give_are_refused() {
        let mut s = SkySum::default();
        s.add(Vec3::Y);
        let good = s.finish(1);
        assert!(SkyVisibility { rows: vec![good] }.check(1).is_ok());
        assert!(SkyVisibility { rows: vec![good] }.check(2).is_err());
        for (k, v) in [
            (0, -0.1),
            (0, 0.9),
            (1, 1.6),
            (3, f32::NAN),
            (8, f32::INFINITY),
        ] {
            let mut row = good;
            row[k] = v;
            let e = SkyVisibility { rows: vec![row] }.check(1).unwrap_err();
            assert!(e.contains(&format!("coefficient {k}")), "{e}");
        }
    }
}
