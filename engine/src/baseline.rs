//! The thesis' baselines, kept for comparison in `bounce bench engines`: classic radiosity, `k`
//! Jacobi steps with the single-bounce form factors `F` (what the thesis starts from, before it
//! precomputes `T`), on the CPU.

use bounce_core::codec::{CodecError, MatrixOp};
use bounce_core::patch::PatchLayout;

/// `E_ind = Σ_{h<k} F (D_ρ F)^h B0` by `k` products with `F`: `E₁ = F B0`, then each step
/// reflects the last bounce (`ρ ⊙ E_h`) and gathers it again. Equal to `T_k B0` in exact
/// arithmetic (docs/design.md §1); `k` products instead of one.
pub fn jacobi(
    f: &dyn MatrixOp,
    layout: &PatchLayout,
    b0: &[[f32; 3]],
    bounces: u32,
) -> Result<Vec<[f32; 3]>, CodecError> {
    let n = layout.len();
    let mut total = vec![[0.0f32; 3]; b0.len()];
    let mut exitance = b0.to_vec();
    let mut gathered = vec![[0.0f32; 3]; b0.len()];
    for h in 0..bounces {
        f.matvec_batch(&exitance, &mut gathered)?;
        for (t, g) in total.iter_mut().zip(&gathered) {
            for c in 0..3 {
                t[c] += g[c];
            }
        }
        if h + 1 < bounces {
            for (k, (e, g)) in exitance.iter_mut().zip(&gathered).enumerate() {
                let albedo = layout.patches[k % n].albedo;
                *e = std::array::from_fn(|c| albedo[c] * g[c]);
            }
        }
    }
    Ok(total)
}
