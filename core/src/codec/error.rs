//! Codec error, measured two ways (docs/design.md §4): on matrix entries, as the thesis tabulated
//! it, and on the indirect irradiance `E_ind = T B0` for light configurations, which is what a
//! viewer sees. Every channel counts (the thesis' own code compared only red).

use crate::matrix::DenseMatrix;
use crate::patch::PatchLayout;

use super::{CodecError, MatrixOp};

/// Absolute entry errors `|T' − T|` over all entries and channels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EntryErrors {
    pub mean: f64,
    pub max: f64,
    pub sum: f64,
}

pub fn entry_errors(exact: &DenseMatrix, approx: &DenseMatrix) -> EntryErrors {
    // A one-channel matrix stands for all three colours; compare channel by channel.
    let channels = exact.channels.max(approx.channels);
    let n = exact.n;
    let (mut sum, mut max) = (0.0f64, 0.0f64);
    for c in 0..channels {
        let a = exact.channel(c.min(exact.channels - 1));
        let b = approx.channel(c.min(approx.channels - 1));
        for (&x, &y) in a.iter().zip(b) {
            let d = (x as f64 - y as f64).abs();
            sum += d;
            max = max.max(d);
        }
    }
    let count = (n * n * channels).max(1) as f64;
    EntryErrors {
        mean: sum / count,
        max,
        sum,
    }
}

/// Errors of `E_ind` over a batch of light configurations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IrradianceErrors {
    /// `‖E' − E‖₂ / ‖E‖₂` over all patches, colours and configurations.
    pub rel_l2: f64,
    /// The worst patch: `‖E'_i − E_i‖ / ‖E_i‖` over patches whose `‖E_i‖` is at least 1% of the
    /// configuration's mean (relative error of nearly unlit patches says nothing).
    pub rel_max: f64,
}

pub fn irradiance_errors(
    exact: &dyn MatrixOp,
    approx: &dyn MatrixOp,
    b0: &[[f32; 3]],
) -> Result<IrradianceErrors, CodecError> {
    let n = exact.n();
    let mut e = vec![[0.0f32; 3]; b0.len()];
    let mut a = vec![[0.0f32; 3]; b0.len()];
    exact.matvec_batch(b0, &mut e)?;
    approx.matvec_batch(b0, &mut a)?;
    let norm = |v: [f32; 3]| v.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt();
    let diff = |p: [f32; 3], q: [f32; 3]| norm([p[0] - q[0], p[1] - q[1], p[2] - q[2]]);
    let (mut num, mut den, mut worst) = (0.0f64, 0.0f64, 0.0f64);
    for (set_e, set_a) in e.chunks(n.max(1)).zip(a.chunks(n.max(1))) {
        let mean = set_e.iter().map(|&v| norm(v)).sum::<f64>() / n.max(1) as f64;
        for (&p, &q) in set_e.iter().zip(set_a) {
            let d = diff(p, q);
            num += d * d;
            den += norm(p) * norm(p);
            if norm(p) >= 0.01 * mean && norm(p) > 0.0 {
                worst = worst.max(d / norm(p));
            }
        }
    }
    Ok(IrradianceErrors {
        rel_l2: if den > 0.0 { (num / den).sqrt() } else { 0.0 },
        rel_max: worst,
    })
}

/// Initial exitance `B0 = ρ ⊙ E_direct` for `count` light configurations: the first lights every
/// patch equally, the others are point lights at deterministic spots inside the scene's grid,
/// with cosine and inverse-square falloff from the patch centroids but no shadows. A stand-in for
/// the direct-light engine (issue 5): it gives `B0` the localised structure real lights have, which
/// is what stresses a codec.
pub fn probe_light_sets(layout: &PatchLayout, count: usize) -> Vec<[f32; 3]> {
    let n = layout.len();
    let mut out = Vec::with_capacity(n * count);
    let s = layout.voxel_size;
    let size = [
        layout.dims[0] as f32 * s,
        layout.dims[1] as f32 * s,
        layout.dims[2] as f32 * s,
    ];
    for k in 0..count {
        if k == 0 {
            out.extend(layout.patches.iter().map(|p| p.albedo));
            continue;
        }
        // Low-discrepancy spots (golden-ratio steps) in the middle 80% of the grid.
        let g = [0.618_034f32, 0.754_877_7, 0.569_840_3];
        let mut pos = [0.0f32; 3];
        for a in 0..3 {
            let u = (0.5 + g[a] * k as f32).fract();
            pos[a] = layout.origin[a] + size[a] * (0.1 + 0.8 * u);
        }
        let falloff = (s * 0.5).powi(2);
        out.extend(layout.patches.iter().map(|p| {
            let d = [
                pos[0] - p.centroid[0],
                pos[1] - p.centroid[1],
                pos[2] - p.centroid[2],
            ];
            let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            let r = r2.sqrt().max(1e-12);
            let cos = (d[0] * p.normal[0] + d[1] * p.normal[1] + d[2] * p.normal[2]) / r;
            // Scaled so a patch one voxel away, facing the light, gets about 1.
            let e = cos.max(0.0) * s * s / r2.max(falloff);
            [p.albedo[0] * e, p.albedo[1] * e, p.albedo[2] * e]
        }));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::dense::DenseOp;

    #[test]
    fn identical_matrices_have_no_error_and_a_scaled_one_has_its_scale() {
        let n = 4;
        let t = DenseMatrix {
            n,
            channels: 1,
            data: (0..16).map(|v| v as f32 / 16.0).collect(),
        };
        let mut t2 = t.clone();
        t2.data.iter_mut().for_each(|v| *v *= 1.1);
        let e = entry_errors(&t, &t);
        assert_eq!((e.mean, e.max, e.sum), (0.0, 0.0, 0.0));
        let e = entry_errors(&t, &t2);
        assert!((e.max - 0.09375).abs() < 1e-6 && e.sum > 0.0, "{e:?}");

        let b0: Vec<[f32; 3]> = (0..n * 2).map(|i| [1.0, i as f32, 0.5]).collect();
        let exact = DenseOp::from(t);
        let scaled = DenseOp::from(t2);
        let r = irradiance_errors(&exact, &exact, &b0).unwrap();
        assert_eq!(r.rel_l2, 0.0);
        let r = irradiance_errors(&exact, &scaled, &b0).unwrap();
        assert!((r.rel_l2 - 0.1).abs() < 1e-5, "{r:?}");
        assert!((r.rel_max - 0.1).abs() < 1e-5, "{r:?}");
    }
}
