//! Order-2 real spherical harmonics: the basis a sky's radiance is given in, and the basis the
//! bake stores each row's view of the sky in.
//!
//! The standard real basis `Y_lm`, `l ≤ 2`, orthonormal over the sphere, indexed
//! `l(l + 1) + m` (so `[Y00, Y1−1, Y10, Y11, Y2−2, Y2−1, Y20, Y21, Y22]`), in the scene's own
//! world axes (glTF: +Y up). For a unit direction `(x, y, z)`:
//!
//! ```text
//! Y00  = 1/(2√π)                  = 0.282095
//! Y1−1 = √(3/4π) y                Y10 = √(3/4π) z            Y11 = √(3/4π) x      (0.488603)
//! Y2−2 = √(15/4π) xy              Y2−1 = √(15/4π) yz         Y21 = √(15/4π) xz    (1.092548)
//! Y20  = √(5/16π) (3z² − 1)       (0.315392)
//! Y22  = √(15/16π) (x² − y²)      (0.546274)
//! ```
//!
//! A radiance `L(ω) = Σ L_lm Y_lm(ω)` is given by its 9 coefficients per colour channel.

/// Coefficients of an order-2 expansion.
pub const SH_COEFFICIENTS: usize = 9;

const C0: f64 = 0.282_094_791_773_878_14; // 1/(2√π)
const C1: f64 = 0.488_602_511_902_919_9; // √(3/4π)
const C2: f64 = 1.092_548_430_592_079_2; // √(15/4π)
const C20: f64 = 0.315_391_565_252_520_05; // √(5/16π)
const C22: f64 = 0.546_274_215_296_039_6; // √(15/16π)

/// `Y_lm(d)` for the unit vector `d`, in the order of the module doc.
#[inline]
pub fn sh_basis(d: [f64; 3]) -> [f64; SH_COEFFICIENTS] {
    let [x, y, z] = d;
    [
        C0,
        C1 * y,
        C1 * z,
        C1 * x,
        C2 * x * y,
        C2 * y * z,
        C20 * (3.0 * z * z - 1.0),
        C2 * x * z,
        C22 * (x * x - y * y),
    ]
}

/// The largest `|Y_lm|` over the sphere, per coefficient: what bounds a stored sky view.
pub const SH_BASIS_MAX: [f64; SH_COEFFICIENTS] =
    [C0, C1, C1, C1, C2 * 0.5, C2 * 0.5, C20 * 2.0, C2 * 0.5, C22];

/// The coefficients of a radiance that is `color` in every direction: only `L00 = color / Y00`.
pub fn uniform_sh(color: [f32; 3]) -> [[f32; 3]; SH_COEFFICIENTS] {
    let mut out = [[0.0; 3]; SH_COEFFICIENTS];
    out[0] = color.map(|c| (f64::from(c) / C0) as f32);
    out
}

/// Radiance of the expansion `coeffs` in unit direction `d`, per channel.
pub fn sh_radiance(coeffs: &[[f32; 3]; SH_COEFFICIENTS], d: [f64; 3]) -> [f64; 3] {
    let y = sh_basis(d);
    std::array::from_fn(|c| {
        (0..SH_COEFFICIENTS)
            .map(|k| y[k] * f64::from(coeffs[k][c]))
            .sum()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uniform directions from a fixed Fibonacci lattice: deterministic, and fine enough that
    /// the sphere integrals below converge to 1e-4.
    fn sphere(n: usize) -> impl Iterator<Item = [f64; 3]> {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        (0..n).map(move |i| {
            let z = 1.0 - (2 * i + 1) as f64 / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            [r * phi.cos(), r * phi.sin(), z]
        })
    }

    #[test]
    fn the_basis_is_orthonormal() {
        let n = 200_000;
        let mut gram = [[0.0f64; SH_COEFFICIENTS]; SH_COEFFICIENTS];
        for d in sphere(n) {
            let y = sh_basis(d);
            for a in 0..SH_COEFFICIENTS {
                for b in 0..SH_COEFFICIENTS {
                    gram[a][b] += y[a] * y[b];
                }
            }
        }
        let w = 4.0 * std::f64::consts::PI / n as f64;
        for (a, row) in gram.iter().enumerate() {
            for (b, g) in row.iter().enumerate() {
                let want = if a == b { 1.0 } else { 0.0 };
                assert!((g * w - want).abs() < 1e-4, "<Y{a}, Y{b}> = {}", g * w);
            }
        }
    }

    #[test]
    fn the_bounds_hold_and_are_reached() {
        let mut seen = [0.0f64; SH_COEFFICIENTS];
        for d in sphere(100_000) {
            for (s, y) in seen.iter_mut().zip(sh_basis(d)) {
                *s = s.max(y.abs());
            }
        }
        for k in 0..SH_COEFFICIENTS {
            assert!(seen[k] <= SH_BASIS_MAX[k] * (1.0 + 1e-12), "{k}");
            assert!(seen[k] > SH_BASIS_MAX[k] * 0.999, "{k}: {}", seen[k]);
        }
    }

    #[test]
    fn a_uniform_sky_is_its_colour_everywhere() {
        let sh = uniform_sh([1.0, 0.5, 0.0]);
        for d in sphere(50) {
            let l = sh_radiance(&sh, d);
            assert!((l[0] - 1.0).abs() < 1e-6 && (l[1] - 0.5).abs() < 1e-6 && l[2] == 0.0);
        }
    }
}
