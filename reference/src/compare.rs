//! How far a pipeline's indirect irradiance is from the reference, and where the error comes
//! from: the codec (compressed `T` against exact `T`), the method (exact `T` against the
//! reference), and the method's parts (direct light on patches rather than surfaces, the first
//! bounce's source held constant over an element, the transport), plus light where there should
//! be none and the per-patch distribution. `bounce verify` prints it; `bounce bench tradeoff`
//! measures every variant with the same [`rel_l2`].
//!
//! It compares arrays only: the pipeline's values come from the caller, so this module shares
//! nothing with the bake either.

use serde::Serialize;

/// Upper edges of the per-patch relative error histogram; the last bin is open.
pub const BINS: [f64; 7] = [0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0];

/// A per-patch error's denominator is at least this share of the RMS reference value: patches in
/// near darkness would otherwise turn a tiny absolute difference into a huge ratio.
pub const FLOOR: f64 = 0.05;

/// The error split, every part relative to the reference (see each field).
#[derive(Debug, Serialize)]
pub struct Report {
    pub patches: usize,
    /// What the patches stand for: `surface` or `voxel-faces`.
    pub geometry: String,
    pub codec: String,
    pub spp: u32,
    pub bounces: String,
    /// Compressed `T` against exact `T`, same patches.
    pub codec_rel_l2: f64,
    /// Exact `T` against the reference (includes the reference's own noise, below).
    pub method_rel_l2: f64,
    /// Compressed `T` against the reference.
    pub total_rel_l2: f64,
    /// The method error split in two. Lighting the voxel patches rather than the original
    /// surfaces: exact `T` on the pipeline's `B0` against exact `T` on `B0` from direct light at
    /// the reference points.
    pub direct_at_patches_rel_l2: f64,
    /// The transport itself (voxel geometry, form-factor noise): exact `T` on the surfaces'
    /// `B0` against the reference.
    pub transport_rel_l2: f64,
    /// Surface bakes: how far `E_ind` (exact `T`) moves when its first bounce takes `B0` where
    /// each form-factor ray lands instead of each element's mean (`bounce_core::pointwise`):
    /// what holding the source constant over an element costs. `None` for voxel faces.
    pub source_rel_l2: Option<f64>,
    /// Surface bakes: the method error with that first bounce: what is left is the transport's
    /// geometry, the later bounces' constant sources and the form factors' noise.
    pub method_pointwise_source_rel_l2: Option<f64>,
    /// Bakes with a near-field first bounce (`bounce_core::nearfield`): the method error
    /// without it, so what it gains shows beside `method_rel_l2`.
    pub method_without_near_field_rel_l2: Option<f64>,
    /// Bakes whose later bounces carry the near field's correction (more than one bounce): the
    /// method error with it in the first bounce alone, so what carrying it gains shows too.
    pub method_first_bounce_near_field_rel_l2: Option<f64>,
    /// `method_rel_l2` with the reference's noise taken out in quadrature.
    pub method_rel_l2_without_noise: f64,
    /// `‖stderr‖ / ‖reference‖`.
    pub reference_rel_stderr: f64,
    /// Light where there should be almost none: the share of the summed `E_ind` (exact `T`, all
    /// channels) that falls on patches whose reference is below a tenth of the median
    /// reference. Light crossing walls shows here.
    pub leak_share: f64,
    /// The reference's own share of its summed light on those same patches: what it puts there
    /// itself (a room lit only through doorways can fall under a tenth of the median). A leak
    /// is what `leak_share` adds beyond it.
    pub leak_reference_share: f64,
    /// Largest per-patch error of the compressed `T` against the reference, relative to the
    /// patch's reference value (floored at 5% of the RMS value).
    pub worst_patch_rel: f64,
    pub worst_patch: usize,
    pub patch_rel_p50: f64,
    pub patch_rel_p90: f64,
    pub patch_rel_p99: f64,
    /// Patches per error bin: upper edges `bin_edges`, then one bin above the last.
    pub histogram: Vec<usize>,
    pub bin_edges: Vec<f64>,
    /// How the reference placed its points.
    pub reference_points: String,
    pub reference_seconds: f64,
    pub exact_from: String,
}

/// What the report records of the run beside the errors: the bake's geometry, codec and bounces,
/// the reference's sample count, point placement and time, and where the exact `T` came from.
pub struct Meta {
    pub geometry: String,
    pub codec: String,
    pub spp: u32,
    pub bounces: String,
    pub placement: String,
    pub seconds: f64,
    pub exact_from: String,
}

/// `‖a − b‖ / ‖b‖` over all entries and channels (`‖a − b‖` when `b` is zero).
pub fn rel_l2(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    let (mut d, mut n) = (0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            d += (x[c] - y[c]) * (x[c] - y[c]);
            n += y[c] * y[c];
        }
    }
    if n > 0.0 { (d / n).sqrt() } else { d.sqrt() }
}

/// `‖a‖ / ‖b‖`: turns a relative L2 against `a` into one against `b`, so that every row of the
/// report is relative to the reference.
fn norm_ratio(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    let sq = |v: &[[f64; 3]]| v.iter().flatten().map(|x| x * x).sum::<f64>();
    let nb = sq(b);
    if nb > 0.0 { (sq(a) / nb).sqrt() } else { 1.0 }
}

pub fn widen(v: &[[f32; 3]]) -> Vec<[f64; 3]> {
    v.iter().map(|c| c.map(f64::from)).collect()
}

/// Other versions of the exact pipeline's `E_ind` the report splits the method error with, where
/// the bake has them.
#[derive(Debug, Clone, Copy, Default)]
pub struct Variants<'a> {
    /// The first bounce with `B0` where each form-factor ray lands, without the near field.
    pub pointwise_source: Option<&'a [[f32; 3]]>,
    /// Without the near-field first bounce.
    pub without_near_field: Option<&'a [[f32; 3]]>,
    /// With the near field's correction in the first bounce alone, the later bounces not
    /// carrying it.
    pub first_bounce_near_field: Option<&'a [[f32; 3]]>,
}

pub fn compare(
    compressed: &[[f32; 3]],
    exact: &[[f32; 3]],
    surface_lit: &[[f32; 3]],
    reference: &[[f64; 3]],
    variants: Variants<'_>,
    reference_rel_stderr: f64,
    meta: Meta,
) -> Report {
    let (compressed, exact, surface_lit) = (widen(compressed), widen(exact), widen(surface_lit));
    let pointwise_source = variants.pointwise_source.map(widen);
    // The pointwise split is of the pipeline without its near field: the near field is part of
    // what the pointwise first bounce replaces.
    let plain = variants.without_near_field.map(widen);
    let base = plain.as_ref().unwrap_or(&exact);
    let method = rel_l2(&exact, reference);
    let norm = |c: &[f64; 3]| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    let rms = (reference.iter().map(|r| norm(r).powi(2)).sum::<f64>()
        / reference.len().max(1) as f64)
        .sqrt();
    let floor = (FLOOR * rms).max(f64::MIN_POSITIVE);
    let per_patch: Vec<f64> = compressed
        .iter()
        .zip(reference)
        .map(|(c, r)| {
            let d = [c[0] - r[0], c[1] - r[1], c[2] - r[2]];
            norm(&d) / norm(r).max(floor)
        })
        .collect();
    let (worst_patch, worst) = per_patch
        .iter()
        .copied()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap_or((0, 0.0));
    let mut sorted = per_patch.clone();
    sorted.sort_by(f64::total_cmp);
    let q = |p: f64| {
        sorted
            .get(((sorted.len() as f64 - 1.0) * p).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    let mut histogram = vec![0; BINS.len() + 1];
    for e in &per_patch {
        histogram[BINS.iter().position(|edge| e <= edge).unwrap_or(BINS.len())] += 1;
    }
    Report {
        patches: reference.len(),
        geometry: meta.geometry,
        codec: meta.codec,
        spp: meta.spp,
        bounces: meta.bounces,
        codec_rel_l2: rel_l2(&compressed, &exact),
        method_rel_l2: method,
        direct_at_patches_rel_l2: rel_l2(&exact, &surface_lit),
        transport_rel_l2: rel_l2(&surface_lit, reference),
        total_rel_l2: rel_l2(&compressed, reference),
        source_rel_l2: pointwise_source
            .as_ref()
            .map(|p| rel_l2(base, p) * norm_ratio(p, reference)),
        method_pointwise_source_rel_l2: pointwise_source.as_ref().map(|p| rel_l2(p, reference)),
        method_without_near_field_rel_l2: plain.as_ref().map(|p| rel_l2(p, reference)),
        method_first_bounce_near_field_rel_l2: variants
            .first_bounce_near_field
            .map(|v| rel_l2(&widen(v), reference)),
        method_rel_l2_without_noise: (method * method
            - reference_rel_stderr * reference_rel_stderr)
            .max(0.0)
            .sqrt(),
        reference_rel_stderr,
        leak_share: leak_share(&exact, reference),
        leak_reference_share: leak_share(reference, reference),
        worst_patch_rel: worst,
        worst_patch,
        patch_rel_p50: q(0.5),
        patch_rel_p90: q(0.9),
        patch_rel_p99: q(0.99),
        histogram,
        bin_edges: BINS.to_vec(),
        reference_points: meta.placement,
        reference_seconds: meta.seconds,
        exact_from: meta.exact_from,
    }
}

/// See [`Report::leak_share`].
pub fn leak_share(pipeline: &[[f64; 3]], reference: &[[f64; 3]]) -> f64 {
    let sum = |c: &[f64; 3]| c[0] + c[1] + c[2];
    let mut refs: Vec<f64> = reference.iter().map(sum).collect();
    refs.sort_by(f64::total_cmp);
    let Some(&median) = refs.get(refs.len() / 2) else {
        return 0.0;
    };
    let total: f64 = pipeline.iter().map(sum).sum();
    let dark: f64 = pipeline
        .iter()
        .zip(reference)
        .filter(|(_, r)| sum(r) < 0.1 * median)
        .map(|(p, _)| sum(p))
        .sum();
    // An empty sum of f64 is −0.0, which a report would print as "-0.00%".
    if total > 0.0 { dark / total + 0.0 } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta() -> Meta {
        Meta {
            geometry: "surface".into(),
            codec: "bc1".into(),
            spp: 4,
            bounces: "3".into(),
            placement: "test".into(),
            seconds: 0.0,
            exact_from: "test".into(),
        }
    }

    #[test]
    fn errors_split_into_codec_and_method() {
        let reference = [[1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [0.0, 0.0, 0.0]];
        let exact = [[1.1, 1.1, 1.1], [2.0, 2.0, 2.0], [0.0, 0.0, 0.0]];
        let compressed = [[1.1, 1.1, 1.1], [2.0, 2.0, 2.0], [0.01, 0.01, 0.01]];
        let r = compare(
            &compressed,
            &exact,
            &exact,
            &reference,
            Variants::default(),
            0.0,
            meta(),
        );
        // ‖(0.1,0.1,0.1)‖ / ‖ref‖ = √0.03 / √15.
        assert!((r.method_rel_l2 - (0.03f64 / 15.0).sqrt()).abs() < 1e-6);
        assert!((r.codec_rel_l2 - (0.0003f64 / (3.0 * 1.21 + 12.0)).sqrt()).abs() < 1e-6);
        // The dark patch's error is measured against the floor, not against zero.
        let rms = (15.0f64 / 3.0).sqrt();
        let dark = (0.0003f64).sqrt() / (FLOOR * rms);
        let first = (0.03f64).sqrt() / 3f64.sqrt();
        assert!((r.worst_patch_rel - dark.max(first)).abs() < 1e-6);
        assert_eq!(r.histogram.iter().sum::<usize>(), 3);
        assert_eq!(r.histogram[0], 1, "the exact patch");
        // The dark patch (reference 0, below a tenth of the median sum 3) gets nothing from the
        // exact T, and 0.03 of 9.33 from the compressed one.
        assert_eq!(r.leak_share, 0.0);
        let leak = leak_share(&widen(&compressed), &reference);
        assert!((leak - 0.03 / 9.33).abs() < 1e-9, "{leak}");
        // Noise removal never goes below zero.
        let noisy = compare(
            &compressed,
            &exact,
            &exact,
            &reference,
            Variants::default(),
            1.0,
            meta(),
        );
        assert_eq!(noisy.method_rel_l2_without_noise, 0.0);
    }

    #[test]
    fn relative_l2_is_against_the_second_argument() {
        let b = [[3.0, 0.0, 0.0], [0.0, 4.0, 0.0]];
        let a = [[3.0, 0.0, 0.0], [0.0, 4.0, 5.0]];
        assert!((rel_l2(&a, &b) - 1.0).abs() < 1e-12);
        assert_eq!(rel_l2(&b, &b), 0.0);
        // Against zero it is the absolute norm, not a division by zero.
        let zero = [[0.0; 3]; 2];
        assert!((rel_l2(&a, &zero) - (9.0f64 + 16.0 + 25.0).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn the_first_bounce_source_splits_the_method_error() {
        let reference = [[1.0; 3], [2.0; 3]];
        let exact = [[1.2; 3], [2.0; 3]];
        // The pointwise first bounce lands halfway between the exact T and the reference.
        let pointwise = [[1.1f32; 3], [2.0; 3]];
        let r = compare(
            &exact,
            &exact,
            &exact,
            &reference,
            Variants {
                pointwise_source: Some(&pointwise),
                ..Variants::default()
            },
            0.0,
            meta(),
        );
        let norm_ref = (3.0f64 + 12.0).sqrt();
        let tenth = (3.0f64 * 0.01).sqrt();
        let within = |x: f64, y: f64| (x - y).abs() < 1e-6;
        assert!(within(r.method_rel_l2, 2.0 * tenth / norm_ref));
        assert!(within(
            r.method_pointwise_source_rel_l2.unwrap(),
            tenth / norm_ref
        ));
        // Relative to the reference, not to the pointwise values: ‖exact − pointwise‖ / ‖ref‖.
        assert!(within(r.source_rel_l2.unwrap(), tenth / norm_ref), "{r:?}");
        assert_eq!(r.codec_rel_l2, 0.0);
        assert!(r.patch_rel_p50 <= r.patch_rel_p90 && r.patch_rel_p90 <= r.patch_rel_p99);
        assert!(r.patch_rel_p99 <= r.worst_patch_rel);
        assert_eq!(r.worst_patch, 0);
    }

    #[test]
    fn the_near_field_shows_beside_the_method_error_and_the_split_starts_without_it() {
        let reference = [[1.0; 3], [2.0; 3]];
        let plain = [[1.2f32; 3], [2.0; 3]];
        let with_near = [[1.1f32; 3], [2.0; 3]];
        let first_bounce_only = [[1.15f32; 3], [2.0; 3]];
        let pointwise = [[1.0f32; 3], [2.0; 3]];
        let r = compare(
            &with_near,
            &with_near,
            &with_near,
            &reference,
            Variants {
                pointwise_source: Some(&pointwise),
                without_near_field: Some(&plain),
                first_bounce_near_field: Some(&first_bounce_only),
            },
            0.0,
            meta(),
        );
        let norm_ref = (3.0f64 + 12.0).sqrt();
        let tenth = (3.0f64 * 0.01).sqrt();
        let within = |x: f64, y: f64| (x - y).abs() < 1e-6;
        assert!(within(r.method_rel_l2, tenth / norm_ref), "{r:?}");
        assert!(within(
            r.method_without_near_field_rel_l2.unwrap(),
            2.0 * tenth / norm_ref
        ));
        assert!(within(
            r.method_first_bounce_near_field_rel_l2.unwrap(),
            1.5 * tenth / norm_ref
        ));
        // The source's share is measured from the pipeline without the near field.
        assert!(
            within(r.source_rel_l2.unwrap(), 2.0 * tenth / norm_ref),
            "{r:?}"
        );
        assert!(within(r.method_pointwise_source_rel_l2.unwrap(), 0.0));
    }

    #[test]
    fn nothing_leaks_where_every_patch_is_lit() {
        let reference = [[1.0; 3], [1.0; 3], [0.5; 3]];
        assert_eq!(leak_share(&reference, &reference), 0.0);
        // Positive zero: a report prints "0.00%", not "-0.00%".
        assert!(leak_share(&reference, &reference).is_sign_positive());
        // A dim patch under a tenth of the median holds its own share of the reference.
        let dim = [[1.0; 3], [1.0; 3], [0.05; 3]];
        assert!((leak_share(&dim, &dim) - 0.05 / 2.05).abs() < 1e-12);
        assert_eq!(leak_share(&[], &[]), 0.0);
        // A patch the reference leaves dark gets a third of the light: a third leaks.
        let dark = [[1.0; 3], [1.0; 3], [0.0; 3]];
        let lit = [[1.0; 3], [1.0; 3], [1.0; 3]];
        assert!((leak_share(&lit, &dark) - 1.0 / 3.0).abs() < 1e-12);
    }
}
