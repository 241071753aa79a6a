//! The near-field first bounce: light gathered from a source element where it is, not as the
//! element's mean (docs/design.md §4).
//!
//! The transport treats a source element's exitance `B0` as uniform over it. Under a point light
//! near the walls, or across a sharp sun shadow, it is not, and what a receiver gathers from its
//! close neighbours depends on which part of them it faces. Far away the difference averages out
//! over many rays; near, it does not (`bounce verify`'s first-bounce split measured almost all of
//! it within half a voxel). So the bake records, per transport row `i`, where its form-factor rays
//! that land within `radius` of their origin land: on which direct-light sample point of the
//! element they met (the nearest one on the surface hit, [`nearest_sample`]: an element
//! groups pieces of different planes). That is a sparse matrix `C` (rows: transport
//! rows; columns: sample points, `j · per_row + k` for sample `k` of row `j`; value: the share of
//! row `i`'s rays), and a relight adds
//!
//! ```text
//! ΔE_i = Σ_q C_iq · (ρ_q ⊙ E_q − ρ_j(q) ⊙ Ē_j(q))
//! ```
//!
//! to `E_ind = T · B0`, where `E_q` is the direct irradiance the relight already evaluates at
//! sample `q`, `Ē_j` the mean it takes of them, `ρ_j` the element's albedo and `ρ_q` the
//! sample's (below; the element's in files without it). The correction is zero-sum over each
//! source element's samples in expectation and exactly zero when direct light and albedo are
//! uniform over every element. It corrects the first bounce; the relight carries it through the
//! later ones (`bounce_engine::carried_source`: `T · (B0 + ρ ⊙ ΔE) + ΔE`), whose sources within
//! an element are still its mean.
//!
//! [`NearField::correction_with`] is the CPU twin of the GPU engine's `near_field.wgsl`.
//!
//! A sky needs the same correction: a surface sees more of it where it is open than in its
//! corners, and the corners are where near rays land. A row's sky view ([`crate::sky`]) is one
//! per row, so the matrix keeps a finer one for its sources: per sample point, the view of the
//! row's form-factor rays that start where it stands for (the same rule; format version 9). A
//! relight with a sky adds each sample's sky irradiance to its punctual light, and the row's
//! mean of them to the row's, before the one sparse pass ([`NearField::sky_samples`],
//! [`NearField::correction_with`]); the GPU engine does both on the device.
//!
//! An element is not one colour either: a textured surface's triangles have their own albedos.
//! A file from format version 11 keeps each sample point's (the albedo of the triangle it lies
//! on), and the correction reflects a landing's light with it: `ρ_q ⊙ E_q − ρ_j ⊙ Ē_j` in
//! place of `ρ_j ⊙ (E_q − Ē_j)`. A sample's triangle is not always the one its landings met,
//! so from format version 12 each entry keeps the mean albedo of the triangles its rays landed
//! on (`NearField::albedo`), and `ρ_q` is the entry's: `ΔE_i = Σ_e c_e (ρ_e ⊙ E_q − ρ_j ⊙ Ē_j)`.

use std::ops::Range;

use glam::Vec3;
use rayon::prelude::*;

use crate::formfactor::{FormFactorError, check_rows};
pub use crate::landings::Landings;
use crate::landings::landings_of;
use crate::sample::{check_albedo, nearest_sample};
use crate::sky::SkyVisibility;
use crate::surface::{SurfaceData, SurfaceScene};

/// How far from its origin a form-factor ray may land and still count as near, in voxels,
/// unless a bake asks otherwise.
pub const DEFAULT_NEAR_RADIUS: f32 = 1.0;
/// The largest radius a bake accepts, in voxels: beyond it the matrix grows towards `F`'s size
/// and the correction stops being near.
pub const MAX_NEAR_RADIUS: f32 = 4.0;
/// f32s a sample's sky view takes.
const SH_WORDS: usize = bounce_types::sh::SH_COEFFICIENTS;

/// The sparse near-field matrix `C` in CSR form.
#[derive(Debug, Clone, PartialEq)]
pub struct NearField {
    /// Sample points per transport row the columns count in (column `j · per_row + k`).
    pub per_row: u32,
    /// `rows + 1` offsets into `cols` and `values`, from 0, non-decreasing.
    pub row_ptr: Vec<u32>,
    /// Per entry, the sample point: strictly ascending within a row.
    pub cols: Vec<u32>,
    /// Per entry, the share of the row's rays that landed where that sample point stands for.
    pub values: Vec<f32>,
    /// Per sample point of these rows (`per_row` a row, in row order), its view of the sky: the
    /// [`SkyVisibility`] sum over the row's form-factor rays whose origin that sample stands
    /// for ([`nearest_sample`]). `None` in files from before version 9.
    pub sky: Option<SkyVisibility>,
    /// Per entry, the mean albedo of the triangles its rays landed on (each channel rounded to
    /// f16, as the file keeps it): what a landing reflects. `None` in files from before version
    /// 12, whose entries take their sample's albedo.
    pub albedo: Option<Vec<[f32; 3]>>,
}

impl NearField {
    /// An empty matrix over no rows, without the samples' sky view.
    pub fn empty(per_row: u32) -> NearField {
        NearField {
            per_row,
            row_ptr: vec![0],
            cols: Vec::new(),
            values: Vec::new(),
            sky: None,
            albedo: None,
        }
    }

    pub fn rows(&self) -> usize {
        self.row_ptr.len().saturating_sub(1)
    }

    pub fn nnz(&self) -> usize {
        self.cols.len()
    }

    /// The bytes this matrix takes in a baked file's `NEAR` section (`crate::format`): offsets,
    /// columns and shares, the samples' sky view and the entries' albedo (f16×3).
    pub fn stored_bytes(&self) -> u64 {
        let words = self.row_ptr.len()
            + 2 * self.nnz()
            + self.sky.as_ref().map_or(0, |s| s.rows.len() * SH_WORDS);
        16 + 4 * words as u64 + self.albedo.as_ref().map_or(0, |a| 6 * a.len() as u64)
    }

    /// Row `i`'s columns and values.
    pub fn row(&self, i: usize) -> (&[u32], &[f32]) {
        let r = self.row_ptr[i] as usize..self.row_ptr[i + 1] as usize;
        (&self.cols[r.clone()], &self.values[r])
    }

    /// Why this matrix does not fit `rows` rows of a transport of `total_rows` rows with
    /// `per_row` stored sample points each, if it does not: offsets in order and in range,
    /// columns ascending within a row and inside the samples, values finite and positive, each
    /// row's sum at most 1 (its rays). A shard holds some rows; a baked file all of them.
    pub fn check(&self, rows: usize, total_rows: usize, per_row: u32) -> Result<(), String> {
        if self.per_row != per_row {
            return Err(format!(
                "its columns count {} samples a row, the scene has {per_row}",
                self.per_row
            ));
        }
        if self.rows() != rows {
            return Err(format!(
                "{} rows, but the transport has {rows}",
                self.rows()
            ));
        }
        if self.row_ptr.first() != Some(&0) {
            return Err("row offsets do not start at 0".into());
        }
        if self.cols.len() != self.values.len()
            || self.row_ptr.last().copied() != Some(self.cols.len() as u32)
        {
            return Err(format!(
                "the row offsets end at {:?}, with {} columns and {} values",
                self.row_ptr.last(),
                self.cols.len(),
                self.values.len()
            ));
        }
        if let Some(i) = self.row_ptr.windows(2).position(|w| w[0] > w[1]) {
            return Err(format!("row {i}'s offsets decrease"));
        }
        let samples = total_rows as u64 * u64::from(per_row);
        for i in 0..rows {
            let (cols, values) = self.row(i);
            if let Some(w) = cols.windows(2).find(|w| w[0] >= w[1]) {
                return Err(format!(
                    "row {i}'s columns are not strictly ascending ({} then {})",
                    w[0], w[1]
                ));
            }
            if let Some(&c) = cols.iter().find(|&&c| u64::from(c) >= samples) {
                return Err(format!(
                    "row {i} names sample {c}, past the {samples} stored"
                ));
            }
            if let Some(v) = values.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
                return Err(format!("row {i} holds {v}, not a positive share"));
            }
            // Shares of one row's rays: a little over 1 is f32 rounding of many terms.
            let sum: f64 = values.iter().map(|&v| f64::from(v)).sum();
            if sum > 1.0 + 1e-4 {
                return Err(format!("row {i}'s shares sum to {sum}, over 1"));
            }
        }
        if let Some(sky) = &self.sky {
            // One view a sample: its "rows" are the samples.
            sky.check(rows * per_row as usize)
                .map_err(|m| format!("the samples' sky view: {m}"))?;
        }
        match &self.albedo {
            Some(albedo) => check_albedo(albedo, self.cols.len(), "entry"),
            None => Ok(()),
        }
    }

    /// The matrix of `rows` (each a row's entries, columns ascending), without the samples'
    /// sky view.
    pub fn from_rows(per_row: u32, rows: Vec<Vec<(u32, f32)>>) -> NearField {
        let mut out = NearField::empty(per_row);
        for row in rows {
            for (c, v) in row {
                out.cols.push(c);
                out.values.push(v);
            }
            out.row_ptr.push(out.cols.len() as u32);
        }
        out
    }

    /// The matrix of a bake's `rows` (each a row's [`Landings`], samples ascending), with each
    /// entry's albedo and without the samples' sky view.
    pub fn from_landings(per_row: u32, rows: Vec<Vec<Landings>>) -> NearField {
        let mut out = NearField::empty(per_row);
        let mut albedo = Vec::new();
        for row in rows {
            for e in row {
                out.cols.push(e.sample);
                out.values.push(e.share);
                albedo.push(e.albedo);
            }
            out.row_ptr.push(out.cols.len() as u32);
        }
        out.albedo = Some(albedo);
        out
    }

    /// The rows of `parts` one after the other (shards of one bake, in row order). The samples'
    /// sky view, and the entries' albedo, are kept when every part has them.
    pub fn concat(per_row: u32, parts: impl IntoIterator<Item = NearField>) -> NearField {
        let mut out = NearField::empty(per_row);
        let mut skies = Some(Vec::new());
        let mut albedo = Some(Vec::new());
        for p in parts {
            let base = out.cols.len() as u32;
            out.row_ptr
                .extend(p.row_ptr.iter().skip(1).map(|&o| base + o));
            out.cols.extend(p.cols);
            out.values.extend(p.values);
            skies = skies.zip(p.sky).map(|(mut all, sky)| {
                all.push(sky);
                all
            });
            albedo = albedo.zip(p.albedo).map(|(mut all, part)| {
                all.extend(part);
                all
            });
        }
        out.sky = skies.map(SkyVisibility::concat);
        out.albedo = albedo;
        out
    }

    /// One light set's sky (its 9 SH radiance coefficients) at the sample points: each
    /// sample's irradiance through its own view, and each row's plain mean of its samples'.
    /// What [`Self::correction_with`] adds to the punctual lights' values, so one pass corrects
    /// both. `None` without the samples' view (a file from before version 9). The GPU twin is
    /// `sky_samples` in `near_field.wgsl` (in f32 where this sums each sample's irradiance in
    /// f64).
    pub fn sky_samples(
        &self,
        sky: &[[f32; 3]; bounce_types::sh::SH_COEFFICIENTS],
    ) -> Option<SkySamples> {
        self.sky_samples_averaging(sky, self.per_row)
    }

    /// [`Self::sky_samples`] with each row's mean over its first `averaged` samples only: those
    /// spread by area (`SurfaceData::area_samples`), whose mean the punctual lights' is too; the
    /// landing samples after them are not in it.
    pub fn sky_samples_averaging(
        &self,
        sky: &[[f32; 3]; bounce_types::sh::SH_COEFFICIENTS],
        averaged: u32,
    ) -> Option<SkySamples> {
        let view = self.sky.as_ref()?;
        let per_sample = view.irradiance(sky);
        let k = self.per_row as usize;
        let averaged = (averaged as usize).clamp(1, k.max(1));
        let mean = per_sample
            .chunks(k.max(1))
            .map(|samples| {
                let samples = &samples[..averaged.min(samples.len())];
                let sum = samples.iter().fold(Vec3::ZERO, |s, &e| s + Vec3::from(e));
                (sum / samples.len() as f32).to_array()
            })
            .collect();
        Some(SkySamples { per_sample, mean })
    }

    /// `ΔE` of one light set's sky alone, per row: [`Self::correction_with`] of its
    /// [`Self::sky_samples`], no punctual light and the rows' albedo. `None` without the
    /// samples' view.
    ///
    /// # Panics
    /// If `albedo` does not have one entry per row.
    pub fn sky_correction(
        &self,
        albedo: &[[f32; 3]],
        sky: &[[f32; 3]; bounce_types::sh::SH_COEFFICIENTS],
    ) -> Option<Vec<[f32; 3]>> {
        let sky = self.sky_samples(sky)?;
        let zeros = vec![[0.0; 3]; sky.per_sample.len()];
        Some(self.correction_with(
            Reflect::rows(albedo),
            &vec![[0.0; 3]; self.rows()],
            &zeros,
            Some(&sky),
        ))
    }

    /// `ΔE` of one light set, per row, from the direct irradiance at every sample point
    /// (`per_sample[j · per_row + k]`), each row's mean of its samples (`mean[j]`, as the relight
    /// computes it) and the rows' albedo: [`Self::correction_with`] without a sky, each sample
    /// taking its row's albedo.
    ///
    /// # Panics
    /// As [`Self::correction_with`].
    pub fn correction(
        &self,
        albedo: &[[f32; 3]],
        mean: &[[f32; 3]],
        per_sample: &[[f32; 3]],
    ) -> Vec<[f32; 3]> {
        self.correction_with(Reflect::rows(albedo), mean, per_sample, None)
    }

    /// `ΔE_i = Σ_q C_iq (ρ_q ⊙ e_q − ρ_j ⊙ ē_j)`: what row `i`'s near rays gather from the
    /// exitance where they land (`ρ_q`, the albedo where they landed, times the irradiance of
    /// sample `q`, `e_q = E_q + s_q`) rather than from their element's (`ρ_j`, the row's albedo,
    /// times the mean `ē_j = Ē_j + s̄_j`), with `s` a sky's [`Self::sky_samples`] when given.
    /// `ρ_q` is the entry's own albedo ([`Self::albedo`]) where the matrix keeps it, else the
    /// sample's (`albedo.samples`), else the row's. The
    /// punctual lights and the sky are corrected in one pass over the entries. Summed per row in
    /// entry order, in f32: the GPU twin (`near_field.wgsl`, after `sky_samples` added the sky
    /// on the device) sums in the same order.
    ///
    /// # Panics
    /// If the slices do not have one entry per row (`albedo.rows`, `mean`, `sky.mean`) and per
    /// sample (`albedo.samples`, `per_sample`, `sky.per_sample`): a caller's bug.
    pub fn correction_with(
        &self,
        albedo: Reflect<'_>,
        mean: &[[f32; 3]],
        per_sample: &[[f32; 3]],
        sky: Option<&SkySamples>,
    ) -> Vec<[f32; 3]> {
        let (n, k) = (self.rows(), self.per_row as usize);
        assert_eq!(albedo.rows.len(), n, "one albedo per row");
        assert_eq!(mean.len(), n, "one mean per row");
        assert_eq!(per_sample.len(), n * k, "one value per sample point");
        if let Some(a) = albedo.samples {
            assert_eq!(a.len(), n * k, "one albedo per sample point");
        }
        if let Some(sky) = sky {
            assert_eq!(
                sky.per_sample.len(),
                n * k,
                "one sky value per sample point"
            );
            assert_eq!(sky.mean.len(), n, "one sky mean per row");
        }
        // A set no light reaches has nothing to correct: skip the pass over every entry
        // (pandora: 1.5 M) rather than sum its zeros.
        let dark = |v: &[[f32; 3]]| v.iter().all(|v| *v == [0.0; 3]);
        if dark(per_sample)
            && dark(mean)
            && sky.is_none_or(|s| dark(&s.per_sample) && dark(&s.mean))
        {
            return vec![[0.0; 3]; n];
        }
        // Sample `q`'s light and row `j`'s mean of its samples', the sky's added when given.
        let sample_light = |q: usize| match sky {
            Some(sky) => Vec3::from(per_sample[q]) + Vec3::from(sky.per_sample[q]),
            None => Vec3::from(per_sample[q]),
        };
        let row_light = |j: usize| match sky {
            Some(sky) => Vec3::from(mean[j]) + Vec3::from(sky.mean[j]),
            None => Vec3::from(mean[j]),
        };
        // Per row, whether it is lit: any light on the row's mean or on one of its
        // samples. An entry landing on a dark row adds exactly zero (`c · (a · 0 − ρ · 0)`),
        // and a sum of zeros from +0 is +0, so a row whose entries all land on dark rows is +0
        // without reading its values: the same bits for a fraction of the reads where one lamp
        // lights a corner of a level (pandora under the corridor light: most rows).
        let lit_rows: Vec<bool> = (0..n)
            .into_par_iter()
            .map(|j| {
                row_light(j) != Vec3::ZERO
                    || (j * k..(j + 1) * k).any(|q| sample_light(q) != Vec3::ZERO)
            })
            .collect();
        // Lit rows before each row: a row whose entries' rows (ascending, as its columns are)
        // span only dark rows is settled from its first and last column.
        let mut lit_before = Vec::with_capacity(n + 1);
        lit_before.push(0u32);
        for &on in &lit_rows {
            lit_before.push(lit_before.last().copied().unwrap_or(0) + u32::from(on));
        }
        let reaches_light = |i: usize| {
            let cols = &self.cols[self.row_ptr[i] as usize..self.row_ptr[i + 1] as usize];
            let (Some(&first), Some(&last)) = (cols.first(), cols.last()) else {
                return false;
            };
            let (lo, hi) = (first as usize / k, last as usize / k);
            lit_before[hi + 1] != lit_before[lo] && cols.iter().any(|&q| lit_rows[q as usize / k])
        };
        if let Some(landed) = &self.albedo {
            // Each entry reflects with its own albedo: per sample its light, per row its
            // element's exitance, once, and the albedo read an entry. Without a sky a sample's
            // light is its value as given, read in place.
            let with_sky: Option<Vec<Vec3>> =
                sky.map(|_| (0..n * k).into_par_iter().map(sample_light).collect());
            let e = |q: usize| match &with_sky {
                Some(e) => e[q],
                None => Vec3::from(per_sample[q]),
            };
            let exitance: Vec<Vec3> = (0..n)
                .into_par_iter()
                .map(|j| Vec3::from(albedo.rows[j]) * row_light(j))
                .collect();
            return (0..n)
                .into_par_iter()
                .map(|i| {
                    if !reaches_light(i) {
                        return [0.0; 3];
                    }
                    let r = self.row_ptr[i] as usize..self.row_ptr[i + 1] as usize;
                    let mut sum = Vec3::ZERO;
                    for ((&q, &c), &a) in self.cols[r.clone()]
                        .iter()
                        .zip(&self.values[r.clone()])
                        .zip(&landed[r])
                    {
                        let q = q as usize;
                        sum += c * (Vec3::from(a) * e(q) - exitance[q / k]);
                    }
                    sum.to_array()
                })
                .collect();
        }
        // Each sample's departure from its element's exitance, once: a sample is met by many
        // rows' near rays (pandora: 1.5 M entries over 190 k samples), and the row sums then
        // read one value an entry instead of three.
        let departure: Vec<Vec3> = (0..n * k)
            .into_par_iter()
            .map(|q| {
                let j = q / k;
                let rho_q = Vec3::from(albedo.samples.map_or(albedo.rows[j], |a| a[q]));
                rho_q * sample_light(q) - Vec3::from(albedo.rows[j]) * row_light(j)
            })
            .collect();
        (0..n)
            .into_par_iter()
            .map(|i| {
                if !reaches_light(i) {
                    return [0.0; 3];
                }
                let (cols, values) = self.row(i);
                let mut sum = Vec3::ZERO;
                for (&q, &c) in cols.iter().zip(values) {
                    sum += c * departure[q as usize];
                }
                sum.to_array()
            })
            .collect()
    }
}

/// The albedos a near-field correction reflects with: each row's (its element's, what `B0`
/// takes) and, when the file keeps them, each sample point's ([`crate::surface::SurfaceData`]'s
/// `albedo`; without them a sample takes its row's).
#[derive(Debug, Clone, Copy)]
pub struct Reflect<'a> {
    pub rows: &'a [[f32; 3]],
    pub samples: Option<&'a [[f32; 3]]>,
}

impl<'a> Reflect<'a> {
    /// The rows' albedo alone: every sample takes its row's.
    pub fn rows(rows: &'a [[f32; 3]]) -> Reflect<'a> {
        Reflect {
            rows,
            samples: None,
        }
    }
}

/// One light set's sky at the sample points ([`NearField::sky_samples`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SkySamples {
    /// Per sample point, the sky's irradiance through its own view.
    pub per_sample: Vec<[f32; 3]>,
    /// Per row, the plain mean of its samples' values.
    pub mean: Vec<[f32; 3]>,
}

/// Rows `rows` of the near-field matrix of `tracer`'s transport rows: form-factor rays (the
/// bake's, by `rays` and `seed`) that land within `radius` (scene units) of their origin, each
/// credited to the sample point of `surface` (its `per_patch` a row) that stands for where it
/// landed ([`nearest_sample`]).
/// The bake keeps these rows in the form factors' own pass, which traces each ray once
/// ([`crate::formfactor::NearRays`]); this retrace of the same rays up to `radius` is its twin
/// (the test `the_form_factors_pass_keeps_the_near_field_a_retrace_finds` holds them to the same
/// bits) and what the GPU near-field tests build their matrices with. It keeps no sky view.
pub fn near_field_rows(
    tracer: &SurfaceScene,
    surface: &SurfaceData,
    rows: Range<usize>,
    rays: u32,
    seed: u64,
    radius: f32,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<NearField, FormFactorError> {
    let n = tracer.row_count();
    check_rows(&rows, rays, n)?;
    let (samples, per_row) = (&surface.points, surface.per_patch);
    let k = per_row as usize;
    assert!(
        k > 0 && samples.len() >= n * k,
        "sample points for every row"
    );
    let per: Vec<Vec<Landings>> = rows
        .into_par_iter()
        .map_init(Vec::new, |hits: &mut Vec<(u32, Vec3)>, i| {
            hits.clear();
            for r in 0..rays {
                let Some((point, normal, j, albedo)) = tracer.near_landing(i, r, seed, radius)
                else {
                    continue;
                };
                let nearest = nearest_sample(&samples[j * k..(j + 1) * k], point, normal);
                hits.push(((j * k + nearest) as u32, albedo));
            }
            progress(1);
            landings_of(hits, rays)
        })
        .collect();
    Ok(NearField::from_landings(per_row, per))
}

/// A small matrix the tests of this module and of its file section share.
#[cfg(test)]
pub(crate) fn test_field() -> NearField {
    tests::field()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sky::SkySum;

    pub(super) fn field() -> NearField {
        // Two rows, two samples a row: row 0 sees samples 2 and 3 (row 1's), row 1 sample 0.
        NearField {
            per_row: 2,
            row_ptr: vec![0, 2, 3],
            cols: vec![2, 3, 0],
            values: vec![0.25, 0.125, 0.5],
            sky: Some(SkyVisibility {
                rows: (0..4).map(|s| view(0.1 * (s + 1) as f64)).collect(),
            }),
            albedo: None,
        }
    }

    /// A sample's sky view when a share `f` of its rays escaped straight up.
    fn view(f: f64) -> [f32; 9] {
        let mut sum = SkySum::default();
        let n = 100;
        for _ in 0..(f * n as f64).round() as u32 {
            sum.add(Vec3::Y);
        }
        sum.finish(n)
    }

    #[test]
    fn a_uniform_source_changes_nothing() {
        let f = field();
        let albedo = [[0.5; 3], [0.8; 3]];
        let per_sample = [[2.0; 3], [2.0; 3], [7.0; 3], [7.0; 3]];
        let mean = [[2.0; 3], [7.0; 3]];
        assert_eq!(f.correction(&albedo, &mean, &per_sample), vec![[0.0; 3]; 2]);
    }

    #[test]
    fn a_dark_set_is_corrected_by_nothing_but_a_lit_sample_is_not_skipped() {
        let f = field();
        let albedo = [[0.5; 3], [0.8; 3]];
        assert_eq!(
            f.correction(&albedo, &[[0.0; 3]; 2], &[[0.0; 3]; 4]),
            vec![[0.0; 3]; 2]
        );
        // One lit sample of row 1 (mean 0.5 over its two): rows that met row 1 see it.
        let d = f.correction(
            &albedo,
            &[[0.0; 3], [0.5; 3]],
            &[[0.0; 3], [0.0; 3], [1.0; 3], [0.0; 3]],
        );
        assert_ne!(d[0], [0.0; 3], "{d:?}");
    }

    #[test]
    fn the_correction_follows_the_samples_each_row_met() {
        let f = field();
        let albedo = [[0.5, 0.5, 0.5], [0.8, 0.4, 0.2]];
        // Row 1's samples: 10 and 2, mean 6; row 0's: 4 and 0, mean 2.
        let per_sample = [[4.0; 3], [0.0; 3], [10.0; 3], [2.0; 3]];
        let mean = [[2.0; 3], [6.0; 3]];
        let d = f.correction(&albedo, &mean, &per_sample);
        // Row 0: 0.25 · ρ1 · (10 − 6) + 0.125 · ρ1 · (2 − 6) = ρ1 · 0.5.
        let want0 = [0.4, 0.2, 0.1];
        // Row 1: 0.5 · ρ0 · (4 − 2) = 0.5.
        for c in 0..3 {
            assert!((d[0][c] - want0[c]).abs() < 1e-6, "{d:?}");
            assert!((d[1][c] - 0.5).abs() < 1e-6, "{d:?}");
        }
    }

    #[test]
    fn check_refuses_what_a_reader_must_not_trust() {
        let f = field();
        assert_eq!(f.check(2, 2, 2), Ok(()));
        assert!(f.check(3, 3, 2).is_err());
        assert!(f.check(2, 2, 4).is_err());
        // One row of a shard, columns over the whole transport.
        let (first, _) = f.row(0);
        let shard = NearField {
            per_row: 2,
            row_ptr: vec![0, 2],
            cols: first.to_vec(),
            values: vec![0.25, 0.125],
            sky: None,
            albedo: None,
        };
        assert_eq!(shard.check(1, 2, 2), Ok(()));
        assert!(shard.check(1, 1, 2).unwrap_err().contains("past"));
        let mut bad = f.clone();
        bad.cols[1] = 2;
        assert!(bad.check(2, 2, 2).unwrap_err().contains("ascending"));
        let mut bad = f.clone();
        bad.cols[2] = 4;
        assert!(bad.check(2, 2, 2).unwrap_err().contains("past"));
        let mut bad = f.clone();
        bad.values[0] = f32::NAN;
        assert!(bad.check(2, 2, 2).is_err());
        let mut bad = f.clone();
        bad.values[0] = 0.9;
        assert!(bad.check(2, 2, 2).unwrap_err().contains("over 1"));
        let mut bad = f;
        bad.row_ptr[1] = 4;
        assert!(bad.check(2, 2, 2).is_err());
    }

    #[test]
    fn concat_keeps_the_rows_in_order() {
        let f = field();
        let parts = [
            NearField {
                per_row: 2,
                row_ptr: vec![0, 2],
                cols: vec![2, 3],
                values: vec![0.25, 0.125],
                sky: f.sky.as_ref().map(|s| s.slice(0..2)),
                albedo: None,
            },
            NearField {
                per_row: 2,
                row_ptr: vec![0, 1],
                cols: vec![0],
                values: vec![0.5],
                sky: f.sky.as_ref().map(|s| s.slice(2..4)),
                albedo: None,
            },
        ];
        let mut without = parts.clone();
        assert_eq!(NearField::concat(2, parts), f);
        // A part without the samples' view leaves the whole without one.
        without[1].sky = None;
        assert_eq!(NearField::concat(2, without).sky, None);
    }

    #[test]
    fn a_sky_is_corrected_by_the_view_where_the_near_rays_land() {
        let f = field();
        let albedo = [[0.5; 3], [0.8; 3]];
        let white = bounce_types::sh::uniform_sh([1.0, 1.0, 1.0]);
        let d = f
            .sky_correction(&albedo, &white)
            .expect("the field has the view");
        // Uniform radiance 1: a sample's irradiance is π times its escaped share. Row 1's
        // samples (0.3, 0.4; mean 0.35) are met by row 0 with shares 0.25 and 0.125; row 0's
        // (0.1, 0.2; mean 0.15) by row 1 at sample 0 with 0.5.
        let pi = std::f32::consts::PI;
        let want0 = 0.8 * pi * (0.25 * (0.3 - 0.35) + 0.125 * (0.4 - 0.35));
        let want1 = 0.5 * pi * 0.5 * (0.1 - 0.15);
        for c in 0..3 {
            assert!((d[0][c] - want0).abs() < 1e-5, "{d:?} against {want0}");
            assert!((d[1][c] - want1).abs() < 1e-5, "{d:?} against {want1}");
        }
        // The same view at every sample corrects nothing; no view, no correction.
        let mut even = field();
        even.sky = Some(SkyVisibility {
            rows: vec![view(0.5); 4],
        });
        assert_eq!(
            even.sky_correction(&albedo, &white),
            Some(vec![[0.0; 3]; 2])
        );
        even.sky = None;
        assert_eq!(even.sky_correction(&albedo, &white), None);
    }

    #[test]
    fn one_pass_corrects_the_lights_and_the_sky_as_two_do() {
        let f = field();
        let albedo = [[0.5, 0.5, 0.5], [0.8, 0.4, 0.2]];
        let per_sample = [[4.0; 3], [0.0; 3], [10.0; 3], [2.0; 3]];
        let mean = [[2.0; 3], [6.0; 3]];
        let mut sky = bounce_types::sh::uniform_sh([1.0, 0.5, 2.0]);
        sky[1] = [0.3, 0.1, 0.0];
        let at = f.sky_samples(&sky).expect("the field has the view");
        // Each row's mean is the plain mean of its samples'.
        for (row, m) in at.per_sample.chunks(2).zip(&at.mean) {
            let sum = Vec3::from(row[0]) + Vec3::from(row[1]) - 2.0 * Vec3::from(*m);
            assert!(sum.abs().max_element() < 1e-6, "{at:?}");
        }
        let both = f.correction_with(Reflect::rows(&albedo), &mean, &per_sample, Some(&at));
        let lights = f.correction(&albedo, &mean, &per_sample);
        let sky_alone = f.sky_correction(&albedo, &sky).unwrap();
        for i in 0..2 {
            for c in 0..3 {
                let want = lights[i][c] + sky_alone[i][c];
                assert!((both[i][c] - want).abs() < 1e-5, "{both:?} against {want}");
            }
        }
        assert_ne!(both, lights, "the sky moved something");
        // A sky alone is not skipped as a dark set.
        let dark = f.correction_with(
            Reflect::rows(&albedo),
            &[[0.0; 3]; 2],
            &[[0.0; 3]; 4],
            Some(&at),
        );
        assert_eq!(dark, sky_alone);
    }

    #[test]
    fn a_landing_reflects_with_the_albedo_of_its_sample() {
        let f = field();
        let rows = [[0.5; 3], [0.6; 3]];
        // Row 1's samples: a dark and a bright triangle around its mean albedo.
        let samples = [[0.5; 3], [0.5; 3], [0.2, 0.3, 0.4], [1.0, 0.9, 0.8]];
        let reflect = Reflect {
            rows: &rows,
            samples: Some(&samples),
        };
        // Uniform light over every element: the rows' albedo alone corrects nothing; the
        // samples' reflects what each landing's triangle does.
        let per_sample = [[2.0; 3], [2.0; 3], [7.0; 3], [7.0; 3]];
        let mean = [[2.0; 3], [7.0; 3]];
        assert_eq!(f.correction(&rows, &mean, &per_sample), vec![[0.0; 3]; 2]);
        let d = f.correction_with(reflect, &mean, &per_sample, None);
        // Row 0: 0.25 · 7 · (0.2 − 0.6) + 0.125 · 7 · (1.0 − 0.6) on the red channel.
        let want0 = 0.25 * 7.0 * (0.2 - 0.6) + 0.125 * 7.0 * (1.0 - 0.6);
        assert!((d[0][0] - want0).abs() < 1e-5, "{d:?} against {want0}");
        // Row 1 met row 0's sample 0, whose albedo is its row's: nothing.
        assert!(Vec3::from(d[1]).abs().max_element() < 1e-6, "{d:?}");
        // Samples that take their rows' albedo give the rows' correction exactly.
        let same = [[0.5; 3], [0.5; 3], [0.6; 3], [0.6; 3]];
        let lit = [[4.0; 3], [0.0; 3], [10.0; 3], [2.0; 3]];
        let lit_mean = [[2.0; 3], [6.0; 3]];
        let a = f.correction_with(
            Reflect {
                rows: &rows,
                samples: Some(&same),
            },
            &lit_mean,
            &lit,
            None,
        );
        assert_eq!(a, f.correction(&rows, &lit_mean, &lit));
    }

    #[test]
    fn a_landing_reflects_with_the_albedo_where_it_landed() {
        let rows = [[0.5; 3], [0.6; 3]];
        // Each entry's own albedo: row 0's landings on row 1's samples met a dark and a bright
        // triangle; row 1's landing on row 0's sample 0 met one of its row's colour.
        let mut f = field();
        f.albedo = Some(vec![[0.2, 0.3, 0.4], [1.0, 0.9, 0.8], [0.5; 3]]);
        assert_eq!(f.check(2, 2, 2), Ok(()));
        // Uniform light over every element: what each landing reflects differs by its albedo.
        let per_sample = [[2.0; 3], [2.0; 3], [7.0; 3], [7.0; 3]];
        let mean = [[2.0; 3], [7.0; 3]];
        let d = f.correction_with(Reflect::rows(&rows), &mean, &per_sample, None);
        let want0 = 0.25 * 7.0 * (0.2 - 0.6) + 0.125 * 7.0 * (1.0 - 0.6);
        assert!((d[0][0] - want0).abs() < 1e-5, "{d:?} against {want0}");
        assert!(Vec3::from(d[1]).abs().max_element() < 1e-6, "{d:?}");
        // The entries' albedo wins over the samples': the same result with samples of another
        // colour.
        let samples = [[0.9; 3]; 4];
        let reflect = Reflect {
            rows: &rows,
            samples: Some(&samples),
        };
        assert_eq!(
            f.correction_with(reflect, &mean, &per_sample, None),
            d,
            "the entries' albedo is the one taken"
        );
        // Entries that each take their sample's albedo give the samples' correction, sky and
        // all.
        let samples = [[0.5; 3], [0.5; 3], [0.2, 0.3, 0.4], [1.0, 0.9, 0.8]];
        let reflect = Reflect {
            rows: &rows,
            samples: Some(&samples),
        };
        let lit = [[4.0; 3], [0.0; 3], [10.0; 3], [2.0; 3]];
        let lit_mean = [[2.0; 3], [6.0; 3]];
        let sky = f
            .sky_samples(&bounce_types::sh::uniform_sh([1.0, 0.5, 2.0]))
            .expect("the field has the view");
        let mut plain = f.clone();
        plain.albedo = None;
        let want = plain.correction_with(reflect, &lit_mean, &lit, Some(&sky));
        let mut own = f.clone();
        own.albedo = Some(f.cols.iter().map(|&q| samples[q as usize]).collect());
        let got = own.correction_with(Reflect::rows(&rows), &lit_mean, &lit, Some(&sky));
        for (g, w) in got.iter().zip(&want) {
            assert!(
                (Vec3::from(*g) - Vec3::from(*w)).abs().max_element() < 1e-6,
                "{got:?} against {want:?}"
            );
        }
    }

    #[test]
    fn the_entries_albedo_is_checked_and_kept_through_shards() {
        let mut f = field();
        f.albedo = Some(vec![[0.2; 3], [1.0; 3], [0.5; 3]]);
        let mut short = f.clone();
        short.albedo.as_mut().unwrap().pop();
        assert_eq!(
            short.check(2, 2, 2).unwrap_err(),
            "2 entry albedos, 3 expected"
        );
        let mut over = f.clone();
        over.albedo.as_mut().unwrap()[1] = [1.5, 0.0, 0.0];
        assert_eq!(
            over.check(2, 2, 2).unwrap_err(),
            "entry 1's albedo [1.5, 0.0, 0.0] is not within [0, 1]"
        );
        let mut nan = f.clone();
        nan.albedo.as_mut().unwrap()[0][2] = f32::NAN;
        assert!(nan.check(2, 2, 2).is_err());
        // Two shards of one bake concatenate to the whole, albedo and all.
        let (cols0, values0) = f.row(0);
        let (cols1, values1) = f.row(1);
        let part =
            |cols: &[u32], values: &[f32], albedo: &[[f32; 3]], sky: Range<usize>| NearField {
                per_row: 2,
                row_ptr: vec![0, cols.len() as u32],
                cols: cols.to_vec(),
                values: values.to_vec(),
                sky: f.sky.as_ref().map(|s| s.slice(sky)),
                albedo: Some(albedo.to_vec()),
            };
        let a = f.albedo.clone().unwrap();
        let parts = [
            part(cols0, values0, &a[..2], 0..2),
            part(cols1, values1, &a[2..], 2..4),
        ];
        assert_eq!(NearField::concat(2, parts.clone()), f);
        // A part without it leaves the whole without it.
        let mut without = parts;
        without[0].albedo = None;
        assert_eq!(NearField::concat(2, without).albedo, None);
    }
}
