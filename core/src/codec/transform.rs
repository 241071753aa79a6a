//! Exact, texture-free building blocks of the thesis' "bc1" codec (docs/design.md §3, steps 1–3):
//! the sparse split of the largest entries, the 8-bit log quantisation, and the greedy row/column
//! reordering with its permutation helpers.
//!
//! Everything here works on plain slices so the codec module can feed it one channel of a
//! `DenseMatrix` (`data[c*n*n + i*n + j]`) without copying into another type.

use rayon::prelude::*;
use std::cmp::Ordering;
use std::sync::atomic::{AtomicU64, Ordering as AtomicOrdering};

/// The entries taken out of the dense matrix and kept exactly, in CSR form.
#[derive(Debug, Clone, PartialEq)]
pub struct SparsePart {
    pub n: usize,
    pub channels: usize,
    /// `n + 1` offsets into `col_idx`; row `i` owns `row_ptr[i]..row_ptr[i + 1]`.
    pub row_ptr: Vec<u32>,
    /// Column of each kept position, ascending within a row.
    pub col_idx: Vec<u32>,
    /// Channel-major: `values[c * nnz + k]` is channel `c` of position `k`. Every channel is stored
    /// for every kept position (a position is chosen by its largest channel), so some may be zero.
    pub values: Vec<f32>,
}

impl SparsePart {
    /// Number of kept positions (not values: each position carries `channels` values).
    pub fn nnz(&self) -> usize {
        self.col_idx.len()
    }

    /// Stored size: u32 row pointers and column indices plus f32 values.
    pub fn bytes(&self) -> usize {
        std::mem::size_of::<u32>() * (self.row_ptr.len() + self.col_idx.len())
            + std::mem::size_of::<f32>() * self.values.len()
    }

    /// `out[i] += Σ_k values[channel][k] * x[col_idx[k]]` over row `i`'s kept positions.
    ///
    /// # Panics
    /// If `channel >= self.channels` or `x` / `out` are not `n` long.
    pub fn matvec_add(&self, channel: usize, x: &[f32], out: &mut [f32]) {
        assert!(channel < self.channels, "channel {channel} out of range");
        assert_eq!(x.len(), self.n, "x must have n entries");
        assert_eq!(out.len(), self.n, "out must have n entries");
        let nnz = self.nnz();
        let vals = &self.values[channel * nnz..(channel + 1) * nnz];
        out.par_iter_mut().enumerate().for_each(|(i, o)| {
            let (lo, hi) = (self.row_ptr[i] as usize, self.row_ptr[i + 1] as usize);
            let acc: f32 = self.col_idx[lo..hi]
                .iter()
                .zip(&vals[lo..hi])
                .map(|(&j, &v)| v * x[j as usize])
                .sum();
            *o += acc;
        });
    }
}

/// Moves the largest `share` of the `n*n` entry positions into a [`SparsePart`] and zeroes them
/// in `channels` (each one channel, `n*n` row-major).
///
/// A position is ranked by its largest value over the channels, so all channels of a position
/// move together and the dense remainder keeps a single sparsity pattern. Exactly
/// `round(share * n*n)` positions are taken, ties going to the lower linear index so the split
/// is deterministic; positions whose channels are all zero are never taken (storing them would
/// cost bytes and gain nothing), so fewer are taken when fewer non-zero positions exist.
/// A `share` outside `0..=1` is clamped and a NaN `share` takes nothing: it is a codec parameter
/// that may come from a file, and clamping is the only sensible reading.
///
/// # Panics
/// If a channel is not `n*n` long or `n*n` does not fit in `u32` indices.
pub fn split_largest(channels: &mut [Vec<f32>], n: usize, share: f64) -> SparsePart {
    let nn = n * n;
    for ch in channels.iter() {
        assert_eq!(ch.len(), nn, "every channel must hold n*n entries");
    }
    assert!(u32::try_from(nn).is_ok(), "n*n must fit in u32 indices");

    let share = if share.is_nan() {
        0.0
    } else {
        share.clamp(0.0, 1.0)
    };
    let wanted = ((share * nn as f64).round() as usize).min(nn);

    // Key of a position: its largest channel. `f32::max` ignores a NaN operand, so a NaN entry
    // cannot hide a large one in another channel.
    let key = |p: usize| -> f32 {
        channels
            .iter()
            .map(|ch| ch[p])
            .fold(f32::NEG_INFINITY, f32::max)
    };
    let positions = select_largest(nn, wanted, key);
    let sparse = gather_positions(channels, n, &positions);
    for ch in channels.iter_mut() {
        for &p in &positions {
            ch[p as usize] = 0.0;
        }
    }
    sparse
}

/// The `take` positions of `0..nn` with the largest positive `key`, ascending. Larger key first,
/// then lower index: a total order, so the selection is exact and deterministic. Positions whose
/// key is not positive are never taken, so fewer come back when fewer have one.
pub fn select_largest(nn: usize, take: usize, key: impl Fn(usize) -> f32 + Sync) -> Vec<u32> {
    let mut candidates: Vec<(f32, u32)> = (0..nn)
        .into_par_iter()
        .filter_map(|p| {
            let k = key(p);
            (k > 0.0).then_some((k, p as u32))
        })
        .collect();
    let take = take.min(candidates.len());
    let rank =
        |a: &(f32, u32), b: &(f32, u32)| -> Ordering { b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)) };
    if take < candidates.len() && take > 0 {
        candidates.select_nth_unstable_by(take - 1, rank);
    }
    candidates.truncate(take);
    let mut positions: Vec<u32> = candidates.into_iter().map(|(_, p)| p).collect();
    positions.sort_unstable();
    positions
}

/// A CSR part holding `channels`' values (each `n*n`, row-major) at `positions` (ascending
/// linear indices).
pub fn gather_positions<C: AsRef<[f32]>>(
    channels: &[C],
    n: usize,
    positions: &[u32],
) -> SparsePart {
    let n_ch = channels.len();
    let nnz = positions.len();
    let mut row_ptr = vec![0u32; n + 1];
    let mut col_idx = Vec::with_capacity(nnz);
    let mut values = vec![0.0f32; n_ch * nnz];
    for (k, &p) in positions.iter().enumerate() {
        let p = p as usize;
        let (i, j) = (p / n, p % n);
        row_ptr[i + 1] += 1;
        col_idx.push(j as u32);
        for (c, ch) in channels.iter().enumerate() {
            values[c * nnz + k] = ch.as_ref()[p];
        }
    }
    for i in 0..n {
        row_ptr[i + 1] += row_ptr[i];
    }
    SparsePart {
        n,
        channels: n_ch,
        row_ptr,
        col_idx,
        values,
    }
}

/// The log range the 8-bit codes span: `ln(x / max)` from -25 to 0.
const LOG_RANGE: f64 = 25.0;

/// Relative round-trip bound for a non-zero entry that was neither clamped at the bottom of the
/// range nor lifted from 0 to 1: half a code step is `25/255/2` in `ln x`, so
/// `|x' - x| / x <= exp(25/510) - 1` (the downward side, `1 - exp(-25/510)`, is smaller).
/// Exact maths; the f32 result of [`log_dequantize`] adds at most a few ulps on top.
pub const LOG_QUANT_REL_BOUND: f32 = 0.050_240_94;

/// The thesis' log quantisation of one channel: `q = round(255 * (ln(x / max) + 25) / 25)`,
/// clamped to `0..=255`, with `max` the channel's maximum. Returns the codes and that `max`.
///
/// Code 0 is reserved for exact zeros: a positive `x` whose code would round to 0 gets 1.
/// That matters because the block encoders downstream (BC1 in 3-colour mode, BC4) can reproduce
/// an exact 0 and the decoder maps code 0 back to 0.0, so zero form factors (occluded or
/// back-facing patch pairs, and the positions moved into the sparse part) stay exactly zero and
/// add no light; a tiny positive entry collapsing to 0 would instead be silently dropped.
///
/// Non-positive and NaN entries are coded 0 (transport is non-negative; callers validate
/// finiteness). An all-zero channel returns max 0.0 and all codes 0.
pub fn log_quantize(values: &[f32]) -> (Vec<u8>, f32) {
    let max = values
        .iter()
        .copied()
        .filter(|v| *v > 0.0)
        .fold(0.0f32, f32::max);
    if max <= 0.0 {
        return (vec![0; values.len()], 0.0);
    }
    let max64 = f64::from(max);
    let codes = values
        .par_iter()
        .map(|&x| {
            if x.is_nan() || x <= 0.0 {
                return 0;
            }
            // f64 so the boundaries between codes sit where the formula says and codes stay
            // monotonic in x.
            let t = 255.0 * ((f64::from(x) / max64).ln() + LOG_RANGE) / LOG_RANGE;
            t.round().clamp(1.0, 255.0) as u8
        })
        .collect();
    (codes, max)
}

/// Inverse of [`log_quantize`]: 0 maps to 0.0, otherwise `max * exp(25*q/255 - 25)`.
pub fn log_dequantize(q: u8, max: f32) -> f32 {
    if q == 0 {
        return 0.0;
    }
    (f64::from(max) * (LOG_RANGE * f64::from(q) / 255.0 - LOG_RANGE).exp()) as f32
}

/// Bytes summed per inner step of the SAD before the running total is compared with the best
/// distance found so far; small enough to prune early, large enough that the compare costs
/// nothing next to the SAD, and the partial sum fits u32 (`255 * 4096`).
const SAD_CHUNK: usize = 4096;

/// Sum of absolute differences of two equally long byte slices.
///
/// On x86-64 this uses `psadbw` (SSE2, part of the x86-64 baseline, so no runtime detection):
/// one instruction per 16 bytes, which keeps the chain memory-bound. The plain-loop version
/// measured 4x slower while rows sat in cache (1.4x on 4000x12000), as LLVM widens it to u32
/// lanes instead of matching `psadbw`.
#[cfg(target_arch = "x86_64")]
#[inline]
fn sad_chunk(a: &[u8], b: &[u8]) -> u32 {
    use std::arch::x86_64::{
        __m128i, _mm_add_epi64, _mm_cvtsi128_si64, _mm_loadu_si128, _mm_sad_epu8,
        _mm_setzero_si128, _mm_unpackhi_epi64,
    };
    let len = a.len().min(b.len());
    let mut i = 0;
    // SAFETY: SSE2 is part of the x86-64 baseline, so these intrinsics are always available;
    // `i + 16 <= len` keeps both 16-byte reads inside their slices, and `_mm_loadu_si128` has
    // no alignment requirement.
    let lanes = unsafe {
        let mut acc = _mm_setzero_si128();
        while i + 16 <= len {
            let va = _mm_loadu_si128(a.as_ptr().add(i).cast::<__m128i>());
            let vb = _mm_loadu_si128(b.as_ptr().add(i).cast::<__m128i>());
            acc = _mm_add_epi64(acc, _mm_sad_epu8(va, vb));
            i += 16;
        }
        _mm_cvtsi128_si64(acc) + _mm_cvtsi128_si64(_mm_unpackhi_epi64(acc, acc))
    };
    let tail: u32 = a[i..len]
        .iter()
        .zip(&b[i..len])
        .map(|(&x, &y)| u32::from(x.abs_diff(y)))
        .sum();
    // Each 64-bit lane holds at most 255 * len / 2, far below u32::MAX for a chunk.
    lanes as u32 + tail
}

/// Portable fallback of the SAD above.
#[cfg(not(target_arch = "x86_64"))]
#[inline]
fn sad_chunk(a: &[u8], b: &[u8]) -> u32 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| u32::from(x.abs_diff(y)))
        .sum()
}

/// SAD between two rows, or `None` as soon as the partial sum exceeds `bound` (the final sum can
/// only be larger, so such a row can never be the nearest).
#[inline]
fn sad_bounded(a: &[u8], b: &[u8], bound: u64) -> Option<u64> {
    let mut total = 0u64;
    for (ca, cb) in a.chunks(SAD_CHUNK).zip(b.chunks(SAD_CHUNK)) {
        total += u64::from(sad_chunk(ca, cb));
        if total > bound {
            return None;
        }
    }
    Some(total)
}

/// Greedy nearest-neighbour chain over `n_rows` rows of `row_len` bytes (`rows` row-major):
/// starts from row 0 and repeatedly appends the unvisited row with the smallest sum of absolute
/// differences to the last appended one, ties going to the lower index. Returns `perm` with
/// `perm[k]` = the original row placed at position `k`.
///
/// Row 0 as the start keeps the chain deterministic and cheap; the bake order is usually
/// spatially coherent already, and a greedy chain's quality depends far more on the later jumps
/// than on where it starts. For columns, pass the transposed matrix.
///
/// O(n_rows² · row_len): each step scans all unvisited rows in parallel (rayon), and a row's SAD
/// stops early once it exceeds the best distance any thread has found in this step.
///
/// # Panics
/// If `rows.len() != n_rows * row_len` or `n_rows` does not fit in u32.
pub fn greedy_chain(rows: &[u8], n_rows: usize, row_len: usize) -> Vec<u32> {
    assert_eq!(
        rows.len(),
        n_rows * row_len,
        "rows must hold n_rows * row_len bytes"
    );
    assert!(u32::try_from(n_rows).is_ok(), "n_rows must fit in u32");
    if n_rows == 0 {
        return Vec::new();
    }
    let row = |i: usize| &rows[i * row_len..(i + 1) * row_len];

    let mut perm = Vec::with_capacity(n_rows);
    perm.push(0u32);
    // Order of `unvisited` does not matter: ties are broken on the row index itself.
    let mut unvisited: Vec<u32> = (1..n_rows as u32).collect();
    let mut last = 0usize;

    while !unvisited.is_empty() {
        let current = row(last);
        let best = AtomicU64::new(u64::MAX);
        let (_, _, pos) = unvisited
            .par_iter()
            .enumerate()
            .with_min_len(8)
            .fold(
                || (u64::MAX, u32::MAX, usize::MAX),
                |acc, (pos, &cand)| {
                    // Prune against the tighter of this thread's and everyone's best; strictly
                    // greater is pruned, so an equal-distance row survives for the tie-break.
                    let bound = acc.0.min(best.load(AtomicOrdering::Relaxed));
                    match sad_bounded(current, row(cand as usize), bound) {
                        Some(d) if (d, cand) < (acc.0, acc.1) => {
                            best.fetch_min(d, AtomicOrdering::Relaxed);
                            (d, cand, pos)
                        }
                        _ => acc,
                    }
                },
            )
            .min_by_key(|&(d, cand, _)| (d, cand))
            // The overall nearest row is never pruned (its distance never exceeds any bound),
            // so the minimum is a real candidate, not a fold identity.
            .expect("unvisited is non-empty");
        let next = unvisited.swap_remove(pos);
        perm.push(next);
        last = next as usize;
    }
    perm
}

/// Reorders an n×n row-major matrix: `out[k][l] = m[row_perm[k]][col_perm[l]]`.
///
/// With `P` the row gather and `Q` the column gather, `(P M Q)(Qᵀ x) = P (M x)`: a reordered
/// matrix multiplies a gathered vector and yields the gathered result, so reordering is lossless.
///
/// # Panics
/// If `m` is not `n*n` long or either permutation is not a permutation of `0..n` (validate
/// permutations read from a file with [`is_permutation`] first).
pub fn permute<T: Copy>(m: &[T], n: usize, row_perm: &[u32], col_perm: &[u32]) -> Vec<T> {
    assert_eq!(m.len(), n * n, "matrix must hold n*n entries");
    assert!(
        is_permutation(row_perm, n),
        "row_perm is not a permutation of 0..n"
    );
    assert!(
        is_permutation(col_perm, n),
        "col_perm is not a permutation of 0..n"
    );
    let mut out = Vec::with_capacity(n * n);
    for &r in row_perm {
        let src = &m[r as usize * n..(r as usize + 1) * n];
        out.extend(col_perm.iter().map(|&c| src[c as usize]));
    }
    out
}

/// The inverse permutation: `invert(p)[p[k]] = k`.
///
/// # Panics
/// If `perm` is not a permutation of `0..perm.len()`.
pub fn invert(perm: &[u32]) -> Vec<u32> {
    assert!(is_permutation(perm, perm.len()), "not a permutation");
    let mut inv = vec![0u32; perm.len()];
    for (k, &p) in perm.iter().enumerate() {
        inv[p as usize] = k as u32;
    }
    inv
}

/// Is `perm` a permutation of `0..n` (length `n`, every value below `n`, no repeats)?
pub fn is_permutation(perm: &[u32], n: usize) -> bool {
    if perm.len() != n {
        return false;
    }
    let mut seen = vec![false; n];
    for &p in perm {
        match seen.get_mut(p as usize) {
            Some(s) if !*s => *s = true,
            _ => return false,
        }
    }
    true
}
