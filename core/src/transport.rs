//! The multi-bounce transport matrix `T`: indirect irradiance `E_ind = T B0` (docs/design.md §1).
//!
//! `T_k = Σ_{h<k} F (D_ρ F)^h` is evaluated by Horner from the right,
//! `T_{m+1} = F + T_m (D_ρ F)`, because then every row block of `T` needs only its own rows of
//! `T_m` and the whole of `G = D_ρ F`: a row range can be computed alone (a sharded bake) and gives
//! the same bits. `T_∞ = F (I − D_ρ F)^{-1}` comes from one LU factorisation of `I − G` and a
//! solve per row block (`X (I − G) = F_R`, i.e. `(I − G)ᵀ Xᵀ = F_Rᵀ`), in f64 so that albedos near
//! 1 stay accurate.
//!
//! A level's `F` is sparse (a row meets a hundred elements of ten thousand), and then the Horner
//! steps run row by row over the nonzeros instead of as dense products
//! ([`SPARSE_MAX_DENSITY`]): `pandora`'s transport takes 4 s instead of 38.
//!
//! Blocks are a fixed [`ROW_BLOCK`] rows of the global matrix and each block's products run
//! sequentially inside faer, so the arithmetic for a row never depends on the thread count or on
//! which other rows were asked for.

use std::ops::Range;

use faer::linalg::solvers::{PartialPivLu, Solve};
use faer::{Accum, Mat, MatMut, MatRef, Par};
use rayon::prelude::*;
use thiserror::Error;

use crate::matrix::DenseMatrix;
use crate::meta::Bounces;
use crate::tail::{self, Clusters};

/// How [`Bounces::All`] is summed.
#[derive(Debug, Clone, Copy)]
pub enum Tail<'a> {
    /// `T_∞` from one LU factorisation of `I − D_ρ F` in f64: exact, `n³` work and `3 n²` f64s.
    Exact,
    /// [`tail::EXACT_BOUNCES`] bounces by Horner, the rest on these clusters of rows
    /// (`crate::tail`).
    Clustered(&'a Clusters),
    /// As `Clustered`, but the tail is bounced once on each patch's mean albedo and added to
    /// every channel's exact bounces: a third of the tail's cost, where colour after the third
    /// bounce changes `E_ind` little ([`ChannelChoice::grey_tail_rel_l2`]).
    ClusteredGrey(&'a Clusters),
}

/// Rows per block of work; part of the arithmetic's definition (see the module doc). Each block
/// re-packs `G` inside faer, so larger blocks amortise that: 256 rows measured about 20% faster
/// than 64 at 4,000 patches (`bounce bench bake`), while 8,000 patches still make 32 blocks to
/// share among cores.
pub const ROW_BLOCK: usize = 256;

/// Albedo is clamped below this for the transport: at 1 a closed scene never loses energy and
/// `I − D_ρ F` is singular.
pub const MAX_ALBEDO: f32 = 0.999;

#[derive(Debug, Error)]
pub enum TransportError {
    #[error("form factors must be one square channel, got {channels} channel(s) of {n}×{n}")]
    FormFactorShape { n: usize, channels: usize },
    #[error("{albedos} albedos for {n} patches")]
    AlbedoCount { albedos: usize, n: usize },
    #[error("albedo of patch {patch} is not finite")]
    AlbedoNotFinite { patch: usize },
    #[error("row range {start}..{end} is outside 0..{n}")]
    RowRange { start: usize, end: usize, n: usize },
    #[error("the radiosity system is singular: some closed part of the scene reflects all light")]
    Singular,
    #[error(transparent)]
    Clusters(#[from] tail::ClusterError),
}

/// The largest change of `E_ind` (relative L2, over the bake's probe light sets) that carrying
/// the transport in one grey channel may make, by default, before the bake keeps three: a tenth
/// of the method's own error on the levels measured, and within the codec's default budget twice
/// over.
pub const DEFAULT_MAX_GREY_ERROR: f64 = 0.02;

/// How many colour channels the transport carries, and what one would cost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelChoice {
    /// 1: one channel on each patch's mean albedo; 3: one per colour.
    pub channels: usize,
    /// How much one grey channel changes `E_ind` against three (relative L2 over the probe
    /// light sets): 0 where colour cannot matter (one bounce, or every albedo grey).
    pub grey_rel_l2: f64,
    /// For all bounces in three channels: how much bouncing only the light past the first
    /// [`tail::EXACT_BOUNCES`] on the mean albedo changes `E_ind` ([`Tail::ClusteredGrey`]);
    /// `None` where it was not measured.
    pub grey_tail_rel_l2: Option<f64>,
}

/// One channel when colour cannot change the transport (a single bounce, or every albedo
/// grey) or changes it by at most `max_grey_error`; three otherwise.
///
/// Colour enters `T` only through the albedos of the patches light bounces off on its way
/// (`F D_ρ F …`), so a scene of gently tinted surfaces loses little by bouncing on their mean
/// albedo, and its transport costs a third: three products of `n³` become one. The change is
/// measured, not guessed: `T · B0` in three channels against one, on `probes` (`count` light sets
/// of one `B0` per row, row-major by set), by the same Horner steps as the transport but on
/// vectors, so it costs a few passes over `F`. Deterministic for any thread count, so every
/// shard of a sharded bake decides alike. Without probes a coloured scene keeps three channels.
pub fn choose_channels(
    f: &DenseMatrix,
    albedo: &[[f32; 3]],
    bounces: Bounces,
    probes: &[[f32; 3]],
    max_grey_error: f64,
) -> Result<ChannelChoice, TransportError> {
    let n = f.n;
    check_inputs(f, albedo)?;
    let grey = albedo.iter().all(|a| a[0] == a[1] && a[1] == a[2]);
    if bounces == Bounces::K(1) || grey || n == 0 {
        return Ok(ChannelChoice {
            channels: 1,
            grey_rel_l2: 0.0,
            grey_tail_rel_l2: None,
        });
    }
    let count = probes.len() / n;
    if count == 0 {
        // Nothing to measure the change on: keep the colour.
        return Ok(ChannelChoice {
            channels: 3,
            grey_rel_l2: 0.0,
            grey_tail_rel_l2: None,
        });
    }
    // Columns: for each probe set, its three colours bounced on their own albedo, then the same
    // three on the mean albedo.
    let width = count * 6;
    let rho: Vec<[f64; 4]> = albedo
        .iter()
        .map(|a| {
            let c = |v: f32| f64::from(v.clamp(0.0, MAX_ALBEDO));
            [c(a[0]), c(a[1]), c(a[2]), c(grey_albedo(*a))]
        })
        .collect();
    let b0 = Mat::<f64>::from_fn(n, width, |i, col| {
        let (set, k) = (col / 6, col % 6);
        f64::from(probes[set * n + i][k % 3])
    });
    let albedo_of = |i: usize, col: usize| {
        let k = col % 6;
        if k < 3 { rho[i][k] } else { rho[i][3] }
    };
    // w_1 = F b; w_{m+1} = F (b + D w_m): w_k = T_k b.
    let steps = match bounces {
        Bounces::K(k) => k as usize,
        // Enough bounces for the difference to settle: it is a sum of decaying terms.
        Bounces::All => 256,
    };
    let fm = MatRef::from_row_major_slice(&f.data, n, n);
    // A level's F is sparse: its nonzeros alone, or the up to 256 steps of all bounces cost
    // `n² · width` each (on `pandora` about 20 s of a bake, for a decision).
    let sparse = (density(f) <= SPARSE_MAX_DENSITY).then(|| sparse_rows(f, &vec![1.0; n]));
    let mut w = Mat::<f64>::zeros(n, width);
    let mut prev_norm = f64::INFINITY;
    // `T_K b` in both albedos, for the grey tail's measure.
    let mut exact_part: Option<Mat<f64>> = None;
    for step in 0..steps {
        let x = Mat::<f64>::from_fn(n, width, |i, col| {
            b0[(i, col)]
                + if step == 0 {
                    0.0
                } else {
                    albedo_of(i, col) * w[(i, col)]
                }
        });
        w = match &sparse {
            Some(csr) => sparse_f64_product(csr, x.as_ref()),
            None => mat_f64_product(fm, x.as_ref()),
        };
        if bounces == Bounces::All && step + 1 == tail::EXACT_BOUNCES as usize {
            exact_part = Some(w.clone());
        }
        if bounces == Bounces::All {
            let norm = w.norm_l2();
            if (norm - prev_norm).abs() <= 1e-6 * norm {
                break;
            }
            prev_norm = norm;
        }
    }
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for set in 0..count {
        for c in 0..3 {
            let (rgb, one) = (set * 6 + c, set * 6 + 3 + c);
            for i in 0..n {
                let (a, b) = (w[(i, rgb)], w[(i, one)]);
                num += (a - b) * (a - b);
                den += a * a;
            }
        }
    }
    let grey_rel_l2 = if den > 0.0 { (num / den).sqrt() } else { 0.0 };
    // The grey tail: each colour's first bounces, and past them the grey light's rest.
    let grey_tail_rel_l2 = exact_part.map(|w_k| {
        let mut num = 0.0f64;
        for set in 0..count {
            for c in 0..3 {
                let (rgb, one) = (set * 6 + c, set * 6 + 3 + c);
                for i in 0..n {
                    let mixed = w_k[(i, rgb)] + (w[(i, one)] - w_k[(i, one)]);
                    num += (w[(i, rgb)] - mixed) * (w[(i, rgb)] - mixed);
                }
            }
        }
        if den > 0.0 { (num / den).sqrt() } else { 0.0 }
    });
    Ok(ChannelChoice {
        channels: if grey_rel_l2 <= max_grey_error { 1 } else { 3 },
        grey_rel_l2,
        grey_tail_rel_l2,
    })
}

/// `F X` for an f32 `F` and an f64 `X`, by row blocks of `F`, each sequential: the same bits on
/// any thread count.
fn mat_f64_product(f: MatRef<'_, f32>, x: MatRef<'_, f64>) -> Mat<f64> {
    let (n, width) = (f.nrows(), x.ncols());
    let blocks: Vec<Mat<f64>> = (0..n.div_ceil(ROW_BLOCK))
        .into_par_iter()
        .map(|b| {
            let r = b * ROW_BLOCK..((b + 1) * ROW_BLOCK).min(n);
            let fr = Mat::<f64>::from_fn(r.len(), n, |i, j| f64::from(f[(r.start + i, j)]));
            let mut out = Mat::<f64>::zeros(r.len(), width);
            faer::linalg::matmul::matmul(
                out.as_mut(),
                Accum::Replace,
                fr.as_ref(),
                x,
                1.0,
                Par::Seq,
            );
            out
        })
        .collect();
    Mat::<f64>::from_fn(n, width, |i, col| {
        blocks[i / ROW_BLOCK][(i % ROW_BLOCK, col)]
    })
}

/// `F X` for `F` by its nonzeros ([`sparse_rows`] with unit albedo) and an f64 `X`, each row
/// summed in column order: the same bits on any thread count.
fn sparse_f64_product((ptr, cols, vals): &Csr, x: MatRef<'_, f64>) -> Mat<f64> {
    let (n, width) = (x.nrows(), x.ncols());
    let xr: Vec<f64> = (0..n)
        .flat_map(|j| (0..width).map(move |c| x[(j, c)]))
        .collect();
    let out: Vec<f64> = (0..n)
        .into_par_iter()
        .flat_map_iter(|i| {
            let mut acc = vec![0.0f64; width];
            for (&j, &v) in cols[ptr[i]..ptr[i + 1]]
                .iter()
                .zip(&vals[ptr[i]..ptr[i + 1]])
            {
                let v = f64::from(v);
                let xj = &xr[j as usize * width..(j as usize + 1) * width];
                for (a, &b) in acc.iter_mut().zip(xj) {
                    *a += v * b;
                }
            }
            acc
        })
        .collect();
    Mat::<f64>::from_fn(n, width, |i, c| out[i * width + c])
}

/// The albedo one grey channel bounces on: the mean of the three, and exactly the value itself
/// when they are equal (so a grey scene's transport does not change by a rounding).
fn grey_albedo(a: [f32; 3]) -> f32 {
    if a[0] == a[1] && a[1] == a[2] {
        a[0]
    } else {
        (a[0] + a[1] + a[2]) / 3.0
    }
}

/// The albedo channel `channel` of a transport of `channels` channels bounces on, clamped to
/// `[0, MAX_ALBEDO]`: its own colour, or the mean of the three when the transport is grey.
pub fn channel_albedo(albedo: &[[f32; 3]], channel: usize, channels: usize) -> Vec<f32> {
    albedo
        .iter()
        .map(|a| {
            let v = if channels == 1 {
                grey_albedo(*a)
            } else {
                a[channel.min(2)]
            };
            v.clamp(0.0, MAX_ALBEDO)
        })
        .collect()
}

fn check_inputs(f: &DenseMatrix, albedo: &[[f32; 3]]) -> Result<(), TransportError> {
    let n = f.n;
    if f.channels != 1 || f.data.len() != n * n {
        return Err(TransportError::FormFactorShape {
            n,
            channels: f.channels,
        });
    }
    if albedo.len() != n {
        return Err(TransportError::AlbedoCount {
            albedos: albedo.len(),
            n,
        });
    }
    if let Some(patch) = albedo.iter().position(|a| !a.iter().all(|v| v.is_finite())) {
        return Err(TransportError::AlbedoNotFinite { patch });
    }
    Ok(())
}

/// The full transport for `bounces` in `channels` channels (1 or 3, see [`choose_channels`]).
pub fn transport(
    f: &DenseMatrix,
    albedo: &[[f32; 3]],
    bounces: Bounces,
    tail: Tail<'_>,
    channels: usize,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<DenseMatrix, TransportError> {
    Ok(DenseMatrix {
        n: f.n,
        channels,
        data: transport_channel_rows(f, albedo, channels, bounces, tail, 0..f.n, progress)?,
    })
}

/// Rows `rows` of every channel of a transport of `channels` channels, channel by channel
/// (`channels × rows.len() × n`): [`transport_rows`] of each, but a grey tail
/// ([`Tail::ClusteredGrey`]) is computed once for the three.
pub fn transport_channel_rows(
    f: &DenseMatrix,
    albedo: &[[f32; 3]],
    channels: usize,
    bounces: Bounces,
    tail: Tail<'_>,
    rows: Range<usize>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<f32>, TransportError> {
    if let (Bounces::All, Tail::ClusteredGrey(clusters), 3) = (bounces, tail, channels) {
        check_rows(f, albedo, &rows)?;
        return grey_tail_rows(f, albedo, 0..3, clusters, rows, progress);
    }
    let mut out = Vec::with_capacity(rows.len() * f.n * channels);
    for c in 0..channels {
        out.extend(transport_rows(
            f,
            albedo,
            (c, channels),
            bounces,
            tail,
            rows.clone(),
            progress,
        )?);
    }
    Ok(out)
}

fn check_rows(
    f: &DenseMatrix,
    albedo: &[[f32; 3]],
    rows: &Range<usize>,
) -> Result<(), TransportError> {
    check_inputs(f, albedo)?;
    if rows.start > rows.end || rows.end > f.n {
        return Err(TransportError::RowRange {
            start: rows.start,
            end: rows.end,
            n: f.n,
        });
    }
    Ok(())
}

/// Rows `rows` of channel `channel.0` of a transport of `channel.1` channels, row-major
/// (`rows.len() × n`). `progress` receives the number of rows finished.
pub fn transport_rows(
    f: &DenseMatrix,
    albedo: &[[f32; 3]],
    channel: (usize, usize),
    bounces: Bounces,
    tail: Tail<'_>,
    rows: Range<usize>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<f32>, TransportError> {
    let n = f.n;
    check_rows(f, albedo, &rows)?;
    let rho = channel_albedo(albedo, channel.0, channel.1);
    match bounces {
        Bounces::K(1) => {
            progress(rows.len() as u64);
            Ok(f.data[rows.start * n..rows.end * n].to_vec())
        }
        Bounces::K(k) => Ok(horner_rows(f, &rho, k, rows, progress)),
        Bounces::All => match tail {
            Tail::Exact => infinite_rows(f, &rho, rows, progress),
            Tail::Clustered(clusters) => clustered_rows(f, &rho, clusters, rows, progress),
            Tail::ClusteredGrey(clusters) if channel.1 == 3 => {
                let c = channel.0.min(2);
                grey_tail_rows(f, albedo, c..c + 1, clusters, rows, progress)
            }
            // One channel is grey already.
            Tail::ClusteredGrey(clusters) => clustered_rows(f, &rho, clusters, rows, progress),
        },
    }
}

/// `G = D_ρ F`: row `j` of `F` scaled by `ρ_j`.
fn scaled_rows<T: Copy + Send + Sync>(
    f: &DenseMatrix,
    rho: &[f32],
    convert: impl Fn(f32) -> T + Sync,
) -> Vec<T> {
    let n = f.n;
    f.data
        .par_chunks(n.max(1))
        .zip(rho.par_iter())
        .flat_map_iter(|(row, &r)| row.iter().map(|&v| convert(v * r)).collect::<Vec<_>>())
        .collect()
}

/// Calls `work` for every global row block that intersects `rows`, in parallel, and returns the
/// rows asked for. `work(block_rows, out)` fills `out` (`block_rows.len() × n`).
fn by_blocks(
    n: usize,
    rows: Range<usize>,
    progress: &(dyn Fn(u64) + Sync),
    work: impl Fn(Range<usize>, &mut [f32]) + Sync,
) -> Vec<f32> {
    let first = rows.start / ROW_BLOCK;
    let last = rows.end.div_ceil(ROW_BLOCK);
    let blocks: Vec<Vec<f32>> = (first..last)
        .into_par_iter()
        .map(|b| {
            let r = b * ROW_BLOCK..((b + 1) * ROW_BLOCK).min(n);
            let mut out = vec![0.0f32; r.len() * n];
            work(r.clone(), &mut out);
            // Count only the rows that were asked for.
            progress((r.end.min(rows.end) - r.start.max(rows.start)) as u64);
            let lo = (rows.start.max(r.start) - r.start) * n;
            let hi = (rows.end.min(r.end) - r.start) * n;
            out.truncate(hi);
            out.drain(..lo);
            out
        })
        .collect();
    blocks.concat()
}

/// Above this share of nonzero entries, `F` is multiplied as a dense matrix; at or below it,
/// row by row over its nonzeros ([`sparse_horner_rows`]). A dense product does `n³`
/// multiply-adds a bounce at the machine's peak; the sparse one about `density · n³`, scattered,
/// far slower each. A room's `F` is dense, a level's is not. Measured on this project's 2-core
/// machine, 3 bounces (`bounce bake SCENE --patches P --codec dense-f32`, the transport stage,
/// each path forced in turn): the Cornell box (3 channels) at 8.7–13.6% nonzero, sparse 44.1 s
/// against dense 12.4 s at 4,000 patches and 9.6 s against 2.4 s at 2,000; `pandora` at 0.8%
/// (a row meets about 94 of 11,810 elements), sparse 4.2 s against dense 38.2 s. The crossover
/// lies between about 2.5% and 7%.
pub const SPARSE_MAX_DENSITY: f64 = 0.03;

/// The share of `F`'s entries that are not zero.
fn density(f: &DenseMatrix) -> f64 {
    let nonzero: usize = f
        .data
        .par_chunks(f.n.max(1))
        .map(|row| row.iter().filter(|&&v| v != 0.0).count())
        .sum();
    nonzero as f64 / (f.data.len().max(1)) as f64
}

fn horner_rows(
    f: &DenseMatrix,
    rho: &[f32],
    k: u32,
    rows: Range<usize>,
    progress: &(dyn Fn(u64) + Sync),
) -> Vec<f32> {
    if density(f) <= SPARSE_MAX_DENSITY {
        sparse_horner_rows(f, rho, k, rows, progress)
    } else {
        dense_horner_rows(f, rho, k, rows, progress)
    }
}

/// [`horner_rows`] for a dense `F`: row blocks of `X_m` times the whole of `G` in faer.
fn dense_horner_rows(
    f: &DenseMatrix,
    rho: &[f32],
    k: u32,
    rows: Range<usize>,
    progress: &(dyn Fn(u64) + Sync),
) -> Vec<f32> {
    let n = f.n;
    let g = scaled_rows(f, rho, |v| v);
    let g = MatRef::from_row_major_slice(&g, n, n);
    by_blocks(n, rows, progress, |r, out| {
        dense_block(f, g, k, r, out);
    })
}

/// Rows `r` of `T_k` (`k ≥ 2`) into `out` by dense Horner steps; returns the same rows of
/// `T_{k−1}`.
fn dense_block(
    f: &DenseMatrix,
    g: MatRef<'_, f32>,
    k: u32,
    r: Range<usize>,
    out: &mut [f32],
) -> Vec<f32> {
    let n = f.n;
    dense_steps(&f.data[r.start * n..r.end * n], g, k, out)
}

/// `X_k` for `X_1 = S`, `X_{m+1} = S + X_m G` (`k ≥ 2`), `S` being rows `start` (`rows × n`),
/// into `out`; returns `X_{k−1}`. With `S` rows of `F` these are rows of `T_k` and `T_{k−1}`.
fn dense_steps(start: &[f32], g: MatRef<'_, f32>, k: u32, out: &mut [f32]) -> Vec<f32> {
    let n = g.ncols();
    let m = start.len() / n.max(1);
    let mut x = start.to_vec();
    for step in 1..k {
        if step > 1 {
            x.copy_from_slice(out);
        }
        // out = S + X G
        out.copy_from_slice(start);
        faer::linalg::matmul::matmul(
            MatMut::from_row_major_slice_mut(out, m, n),
            Accum::Add,
            MatRef::from_row_major_slice(&x, m, n),
            g,
            1.0f32,
            Par::Seq,
        );
    }
    x
}

/// A matrix by rows, its nonzeros only: `(row offsets, columns, values)`.
type Csr = (Vec<usize>, Vec<u32>, Vec<f32>);

/// `G = D_ρ F` by rows, its nonzeros only.
fn sparse_rows(f: &DenseMatrix, rho: &[f32]) -> Csr {
    let n = f.n;
    let per_row: Vec<Vec<(u32, f32)>> = f
        .data
        .par_chunks(n.max(1))
        .zip(rho.par_iter())
        .map(|(row, &r)| {
            row.iter()
                .enumerate()
                .filter(|(_, v)| **v != 0.0)
                .map(|(j, &v)| (j as u32, v * r))
                .collect()
        })
        .collect();
    let mut ptr = Vec::with_capacity(n + 1);
    ptr.push(0);
    let (mut cols, mut vals) = (Vec::new(), Vec::new());
    for row in per_row {
        for (c, v) in row {
            cols.push(c);
            vals.push(v);
        }
        ptr.push(cols.len());
    }
    (ptr, cols, vals)
}

/// [`horner_rows`] for a sparse `F`: each row on its own, `X_{m+1} = F_i + X_m G` with `X_m G`
/// summed over `X_m`'s nonzeros in column order, so a row's arithmetic depends on nothing but
/// `F`, `ρ` and its index (any thread count, any row range: the same bits).
fn sparse_horner_rows(
    f: &DenseMatrix,
    rho: &[f32],
    k: u32,
    rows: Range<usize>,
    progress: &(dyn Fn(u64) + Sync),
) -> Vec<f32> {
    let n = f.n;
    let g = sparse_rows(f, rho);
    let mut out = vec![0.0f32; rows.len() * n];
    out.par_chunks_mut(n.max(1)).enumerate().for_each_init(
        || (vec![0.0f32; n], Vec::<usize>::with_capacity(n)),
        |(x, nonzero), (r, out_row)| {
            let f_row = &f.data[(rows.start + r) * n..(rows.start + r + 1) * n];
            sparse_row(f_row, k, &g, x, nonzero, out_row);
            progress(1);
        },
    );
    out
}

/// One row of `T_k` (`k ≥ 2`) into `out_row` by sparse Horner steps over `G`'s nonzeros
/// (`(row offsets, columns, values)`, [`sparse_rows`]); leaves the row of `T_{k−1}` in `x`.
fn sparse_row(
    f_row: &[f32],
    k: u32,
    (ptr, cols, vals): &Csr,
    x: &mut [f32],
    nonzero: &mut Vec<usize>,
    out_row: &mut [f32],
) {
    let n = f_row.len();
    x.copy_from_slice(f_row);
    for step in 1..k {
        if step > 1 {
            x.copy_from_slice(out_row);
        }
        nonzero.clear();
        nonzero.extend((0..n).filter(|&c| x[c] != 0.0));
        out_row.copy_from_slice(f_row);
        for &c in nonzero.iter() {
            let xc = x[c];
            let (cs, vs) = (&cols[ptr[c]..ptr[c + 1]], &vals[ptr[c]..ptr[c + 1]]);
            for (&j, &v) in cs.iter().zip(vs) {
                out_row[j as usize] += xc * v;
            }
        }
    }
}

/// `G = D_ρ F` as the Horner steps read it: by nonzeros for a sparse `F`, dense otherwise.
enum Steps {
    Sparse(Csr),
    Dense(Vec<f32>),
}

impl Steps {
    fn new(f: &DenseMatrix, rho: &[f32]) -> Self {
        if density(f) <= SPARSE_MAX_DENSITY {
            Steps::Sparse(sparse_rows(f, rho))
        } else {
            Steps::Dense(scaled_rows(f, rho, |v| v))
        }
    }

    /// [`dense_steps`] (or the same steps row by row over the nonzeros) on rows `start`, with
    /// the arithmetic of a `k`-bounce transport's rows.
    fn run(&self, start: &[f32], n: usize, k: u32, out: &mut [f32]) -> Vec<f32> {
        match self {
            Steps::Dense(g) => dense_steps(start, MatRef::from_row_major_slice(g, n, n), k, out),
            Steps::Sparse(g) => {
                let mut prev = vec![0.0f32; out.len()];
                let mut nonzero = Vec::with_capacity(n);
                for ((s, o), p) in start
                    .chunks(n)
                    .zip(out.chunks_mut(n))
                    .zip(prev.chunks_mut(n))
                {
                    sparse_row(s, k, g, p, &mut nonzero, o);
                }
                prev
            }
        }
    }
}

/// `T_c`, the clustered all-bounce transport of albedo `rho` (`crate::tail`): the clusters' mean
/// rows of `F` through the same Horner steps give `R T_K` and `R T_{K−1}`.
fn coarse_of(
    f: &DenseMatrix,
    rho: &[f32],
    clusters: &Clusters,
    steps: &Steps,
) -> Result<Vec<f32>, TransportError> {
    let n = f.n;
    if clusters.rows() != n {
        return Err(tail::ClusterError::Count {
            clusters: clusters.rows(),
            rows: n,
        }
        .into());
    }
    let rf = tail::cluster_rows(f, clusters);
    let m = clusters.len();
    let mut rt = vec![0.0f32; m * n];
    let prev: Vec<Vec<f32>> = rf
        .par_chunks(ROW_BLOCK * n.max(1))
        .zip(rt.par_chunks_mut(ROW_BLOCK * n.max(1)))
        .map(|(s, o)| steps.run(s, n, tail::EXACT_BOUNCES, o))
        .collect();
    tail::coarse_transport(&rt, &prev.concat(), rho, clusters).ok_or(TransportError::Singular)
}

/// Channels `chans` (of three) with the grey tail ([`Tail::ClusteredGrey`]), channel by
/// channel: per row block, the grey light's tail once (`(Δ_K D_ρ̄ P) T̄_c`, from the grey
/// Horner steps), added to each channel's own `T_K`. A row's bits depend only on `F`, the
/// albedos and the clusters, so one channel asked alone is that channel of the three.
fn grey_tail_rows(
    f: &DenseMatrix,
    albedo: &[[f32; 3]],
    chans: Range<usize>,
    clusters: &Clusters,
    rows: Range<usize>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<f32>, TransportError> {
    let n = f.n;
    let k = tail::EXACT_BOUNCES;
    let grey = channel_albedo(albedo, 0, 1);
    let grey_steps = Steps::new(f, &grey);
    let coarse = coarse_of(f, &grey, clusters, &grey_steps)?;
    let colour: Vec<Steps> = chans
        .clone()
        .map(|c| Steps::new(f, &channel_albedo(albedo, c, 3)))
        .collect();
    let (first, last) = (rows.start / ROW_BLOCK, rows.end.div_ceil(ROW_BLOCK));
    let blocks: Vec<Vec<Vec<f32>>> = (first..last)
        .into_par_iter()
        .map(|b| {
            let r = b * ROW_BLOCK..((b + 1) * ROW_BLOCK).min(n);
            let start = &f.data[r.start * n..r.end * n];
            let mut grey_k = vec![0.0f32; r.len() * n];
            let grey_prev = grey_steps.run(start, n, k, &mut grey_k);
            let tail = tail::tail_block(&grey_k, &grey_prev, &grey, clusters, &coarse);
            drop((grey_k, grey_prev));
            let (lo, hi) = (
                (rows.start.max(r.start) - r.start) * n,
                (rows.end.min(r.end) - r.start) * n,
            );
            let out = colour
                .iter()
                .map(|steps| {
                    let mut out = vec![0.0f32; r.len() * n];
                    steps.run(start, n, k, &mut out);
                    for (o, t) in out.iter_mut().zip(&tail) {
                        *o += t;
                    }
                    out.truncate(hi);
                    out.drain(..lo);
                    out
                })
                .collect();
            progress(((hi - lo) / n.max(1) * colour.len()) as u64);
            out
        })
        .collect();
    let mut out = Vec::with_capacity(rows.len() * n * colour.len());
    for c in 0..colour.len() {
        for b in &blocks {
            out.extend_from_slice(&b[c]);
        }
    }
    finite(out)
}

/// `out`, unless a value in it is not finite: a singular system.
fn finite(out: Vec<f32>) -> Result<Vec<f32>, TransportError> {
    if out.iter().any(|v| !v.is_finite()) {
        return Err(TransportError::Singular);
    }
    Ok(out)
}

/// All bounces with the tail on clusters (`crate::tail`): rows of `T_K` and `T_{K−1}` by the
/// Horner steps a `K`-bounce bake takes, then the tail on each block.
fn clustered_rows(
    f: &DenseMatrix,
    rho: &[f32],
    clusters: &Clusters,
    rows: Range<usize>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<f32>, TransportError> {
    let n = f.n;
    let k = tail::EXACT_BOUNCES;
    let steps = Steps::new(f, rho);
    let coarse = coarse_of(f, rho, clusters, &steps)?;
    let out = by_blocks(n, rows, progress, |r, out| {
        let prev = steps.run(&f.data[r.start * n..r.end * n], n, k, out);
        tail::add_tail(out, &prev, rho, clusters, &coarse);
    });
    finite(out)
}

fn infinite_rows(
    f: &DenseMatrix,
    rho: &[f32],
    rows: Range<usize>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<f32>, TransportError> {
    let n = f.n;
    let g = scaled_rows(f, rho, |v| v as f64);
    let a = Mat::<f64>::from_fn(n, n, |i, j| {
        let d = if i == j { 1.0 } else { 0.0 };
        d - g[i * n + j]
    });
    drop(g);
    // The factorisation is the one step that is not per row block; it is deterministic for a
    // given matrix (pivoting by largest magnitude, ties by index), so every shard gets the same.
    let lu = PartialPivLu::new(a.as_ref());
    // The factorisation holds its own copy.
    drop(a);
    let out = by_blocks(n, rows, progress, |r, out| {
        let m = r.len();
        // Xᵀ (column-major n × m) has the same memory as X (row-major m × n).
        let mut xt = Mat::<f64>::from_fn(n, m, |j, i| f.data[(r.start + i) * n + j] as f64);
        lu.solve_transpose_in_place(xt.as_mut());
        for i in 0..m {
            for j in 0..n {
                out[i * n + j] = xt[(j, i)] as f32;
            }
        }
    });
    finite(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(super) fn lcg(seed: &mut u64) -> f32 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 40) as f32 / (1u64 << 24) as f32
    }

    /// A random matrix with rows summing to at most 1, like a form-factor matrix.
    fn random_ff(n: usize, seed: u64) -> DenseMatrix {
        let mut s = seed;
        let mut data: Vec<f32> = (0..n * n).map(|_| lcg(&mut s)).collect();
        for i in 0..n {
            data[i * n + i] = 0.0;
            let sum: f32 = data[i * n..(i + 1) * n].iter().sum();
            let scale = (0.5 + 0.5 * lcg(&mut s)) / sum;
            data[i * n..(i + 1) * n]
                .iter_mut()
                .for_each(|v| *v *= scale);
        }
        DenseMatrix {
            n,
            channels: 1,
            data,
        }
    }

    fn random_albedo(n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut s = seed;
        (0..n)
            .map(|_| [lcg(&mut s) * 0.9, lcg(&mut s) * 0.9, lcg(&mut s) * 0.9])
            .collect()
    }

    /// `Σ_{h<k} F (D F)^h` by explicit powers, in f64.
    fn explicit_power_sum(f: &DenseMatrix, rho: &[f32], k: u32) -> Vec<f64> {
        let n = f.n;
        let fm = Mat::<f64>::from_fn(n, n, |i, j| f.get(0, i, j) as f64);
        let dfm = Mat::<f64>::from_fn(n, n, |i, j| rho[i] as f64 * f.get(0, i, j) as f64);
        let mut power = Mat::<f64>::identity(n, n);
        let mut sum = Mat::<f64>::zeros(n, n);
        for _ in 0..k {
            sum += &fm * &power;
            power = &power * &dfm;
        }
        (0..n * n).map(|idx| sum[(idx / n, idx % n)]).collect()
    }

    fn no_progress(_: u64) {}

    #[test]
    fn horner_equals_the_explicit_power_sum() {
        for (n, k) in [(5, 2), (17, 3), (70, 5), (130, 4)] {
            let f = random_ff(n, n as u64);
            let albedo = random_albedo(n, 7);
            let t = transport(&f, &albedo, Bounces::K(k), Tail::Exact, 3, &no_progress).unwrap();
            assert_eq!(t.channels, 3);
            for c in 0..3 {
                let rho = channel_albedo(&albedo, c, 3);
                let want = explicit_power_sum(&f, &rho, k);
                for (idx, (&got, &want)) in t.channel(c).iter().zip(&want).enumerate() {
                    assert!(
                        (got as f64 - want).abs() <= 1e-5 * want.abs() + 1e-7,
                        "n={n} k={k} c={c} entry {idx}: {got} vs {want}"
                    );
                }
            }
        }
    }

    /// A form-factor-like matrix where each row meets only `per_row` others.
    fn sparse_ff(n: usize, per_row: usize, seed: u64) -> DenseMatrix {
        let mut f = random_ff(n, seed);
        let mut s = seed ^ 0x9e37;
        for i in 0..n {
            let row = &mut f.data[i * n..(i + 1) * n];
            let keep: Vec<usize> = (0..per_row)
                .map(|_| (lcg(&mut s) * n as f32) as usize % n)
                .collect();
            for (j, v) in row.iter_mut().enumerate() {
                if !keep.contains(&j) || j == i {
                    *v = 0.0;
                }
            }
            let sum: f32 = row.iter().sum();
            if sum > 0.0 {
                let scale = (0.5 + 0.5 * lcg(&mut s)) / sum;
                row.iter_mut().for_each(|v| *v *= scale);
            }
        }
        f
    }

    #[test]
    fn a_grey_tail_is_each_colours_first_bounces_and_the_grey_rest_as_measured() {
        let n = 120;
        for f in [random_ff(n, 41), sparse_ff(n, 6, 47)] {
            let albedo = random_albedo(n, 43);
            // One cluster a row: the clustered tail is the exact one the measure assumes.
            let own = Clusters::singletons(n);
            let all = |tail, channels| {
                transport(&f, &albedo, Bounces::All, tail, channels, &no_progress).unwrap()
            };
            let three = |channels| {
                transport(
                    &f,
                    &albedo,
                    Bounces::K(3),
                    Tail::Exact,
                    channels,
                    &no_progress,
                )
                .unwrap()
            };
            let colour = all(Tail::Clustered(&own), 3);
            let mixed = all(Tail::ClusteredGrey(&own), 3);
            let (t3, grey_all, grey_t3) = (three(3), all(Tail::Clustered(&own), 1), three(1));
            for c in 0..3 {
                for (idx, &got) in mixed.channel(c).iter().enumerate() {
                    let want = t3.channel(c)[idx] + grey_all.data[idx] - grey_t3.data[idx];
                    assert!(
                        (got - want).abs() <= 1e-5 * want.abs() + 1e-6,
                        "channel {c} entry {idx}: {got} vs {want}"
                    );
                }
                // A channel asked alone is that channel of the three.
                let alone = transport_rows(
                    &f,
                    &albedo,
                    (c, 3),
                    Bounces::All,
                    Tail::ClusteredGrey(&own),
                    0..n,
                    &no_progress,
                )
                .unwrap();
                assert_eq!(alone, mixed.channel(c), "channel {c}");
            }
            // The choice's measure is what the grey tail changes.
            let probes = probe_vectors(n, 4);
            let choice = choose_channels(&f, &albedo, Bounces::All, &probes, 0.0).unwrap();
            let measured = choice.grey_tail_rel_l2.unwrap();
            let (a, b) = (apply(&colour, &probes), apply(&mixed, &probes));
            let num: f64 = a.iter().zip(&b).map(|(x, y)| (x - y) * (x - y)).sum();
            let den: f64 = a.iter().map(|x| x * x).sum();
            let actual = (num / den).sqrt();
            assert!(
                (actual - measured).abs() <= 0.02 * actual && actual > 1e-4,
                "measured {measured}, the transports differ by {actual}"
            );
            assert!(measured < choice.grey_rel_l2, "{choice:?}");
            // A number of bounces has no tail to measure.
            let k = choose_channels(&f, &albedo, Bounces::K(3), &probes, 0.0).unwrap();
            assert_eq!(k.grey_tail_rel_l2, None);
        }
    }

    #[test]
    fn the_channel_measure_takes_a_sparse_f_by_its_nonzeros() {
        let n = 300;
        let f = sparse_ff(n, 6, 29);
        assert!(density(&f) <= SPARSE_MAX_DENSITY, "{}", density(&f));
        let mut s = 5u64;
        let x = Mat::<f64>::from_fn(n, 12, |_, _| f64::from(lcg(&mut s)));
        let dense = mat_f64_product(MatRef::from_row_major_slice(&f.data, n, n), x.as_ref());
        let csr = sparse_rows(&f, &vec![1.0; n]);
        let sparse = sparse_f64_product(&csr, x.as_ref());
        for i in 0..n {
            for c in 0..12 {
                let (a, b) = (sparse[(i, c)], dense[(i, c)]);
                assert!(
                    (a - b).abs() <= 1e-12 * b.abs().max(1.0),
                    "({i}, {c}): {a} vs {b}"
                );
            }
        }
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| sparse_f64_product(&csr, x.as_ref()));
        assert_eq!(one, sparse, "the same bits on one thread");
        // And the choice it serves: all bounces of a coloured scene, on the sparse path.
        let albedo = random_albedo(n, 31);
        let probes = probe_vectors(n, 2);
        let choice = choose_channels(&f, &albedo, Bounces::All, &probes, 0.0).unwrap();
        assert_eq!(choice.channels, 3);
        assert!(choice.grey_rel_l2 > 0.0 && choice.grey_rel_l2.is_finite());
    }

    #[test]
    fn a_sparse_transport_is_the_power_sum_and_the_same_bits_on_any_rows_and_threads() {
        let (n, k) = (300, 4);
        let f = sparse_ff(n, 6, 13);
        assert!(density(&f) <= SPARSE_MAX_DENSITY, "{}", density(&f));
        let rho: Vec<f32> = random_albedo(n, 17).iter().map(|a| a[1]).collect();
        let sparse = sparse_horner_rows(&f, &rho, k, 0..n, &no_progress);
        let want = explicit_power_sum(&f, &rho, k);
        for (idx, (&got, &want)) in sparse.iter().zip(&want).enumerate() {
            assert!(
                (f64::from(got) - want).abs() <= 1e-5 * want.abs() + 1e-7,
                "entry {idx}: {got} vs {want}"
            );
        }
        let dense = dense_horner_rows(&f, &rho, k, 0..n, &no_progress);
        for (a, b) in sparse.iter().zip(&dense) {
            assert!((a - b).abs() <= 1e-5 * b.abs() + 1e-7, "{a} vs {b}");
        }
        // The transport takes the sparse path for it.
        assert_eq!(horner_rows(&f, &rho, k, 0..n, &no_progress), sparse);
        // Any row range, on one thread or many: the same bits.
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| sparse_horner_rows(&f, &rho, k, 37..211, &no_progress));
        assert_eq!(one, sparse[37 * n..211 * n]);
    }

    #[test]
    fn infinite_bounces_are_the_limit_of_many() {
        let n = 90;
        let f = random_ff(n, 3);
        let albedo = random_albedo(n, 11);
        let t_inf = transport(&f, &albedo, Bounces::All, Tail::Exact, 3, &no_progress).unwrap();
        // ρ ≤ 0.9 and row sums ≤ 1: the tail after 200 bounces is below 0.9^200 ≈ 7e-10.
        let t_many = transport(&f, &albedo, Bounces::K(200), Tail::Exact, 3, &no_progress).unwrap();
        for (a, b) in t_inf.data.iter().zip(&t_many.data) {
            assert!((a - b).abs() <= 1e-5 * b.abs() + 1e-7, "{a} vs {b}");
        }
    }

    #[test]
    fn one_bounce_is_the_form_factors_in_one_channel() {
        let f = random_ff(20, 5);
        let albedo = random_albedo(20, 1);
        let t = transport(&f, &albedo, Bounces::K(1), Tail::Exact, 1, &no_progress).unwrap();
        assert_eq!(t, f);
        let probes = probe_vectors(20, 4);
        let one = choose_channels(&f, &albedo, Bounces::K(1), &probes, 0.0).unwrap();
        assert_eq!((one.channels, one.grey_rel_l2), (1, 0.0));
        let grey: Vec<[f32; 3]> = (0..20).map(|i| [0.1 * (i % 9) as f32; 3]).collect();
        let g = choose_channels(&f, &grey, Bounces::K(3), &probes, 0.0).unwrap();
        assert_eq!((g.channels, g.grey_rel_l2), (1, 0.0));
        // A grey scene's one channel bounces on the albedo itself, not on a rounded mean.
        let red = transport(&f, &grey, Bounces::K(3), Tail::Exact, 3, &no_progress).unwrap();
        let mono = transport(&f, &grey, Bounces::K(3), Tail::Exact, 1, &no_progress).unwrap();
        assert_eq!(mono.channel(0), red.channel(0));
    }

    /// `count` positive, varying `B0` vectors, one per row, row-major by set.
    fn probe_vectors(n: usize, count: usize) -> Vec<[f32; 3]> {
        let mut s = 17;
        (0..n * count)
            .map(|_| [lcg(&mut s), lcg(&mut s), lcg(&mut s)])
            .collect()
    }

    /// `T · B0` of a 1- or 3-channel transport, in f64, every probe set and colour.
    fn apply(t: &DenseMatrix, probes: &[[f32; 3]]) -> Vec<f64> {
        let n = t.n;
        let mut out = Vec::new();
        for set in probes.chunks(n) {
            for c in 0..3 {
                let m = t.channel(c.min(t.channels - 1));
                for i in 0..n {
                    let row = &m[i * n..(i + 1) * n];
                    out.push(
                        row.iter()
                            .zip(set)
                            .map(|(&t, b)| t as f64 * b[c] as f64)
                            .sum(),
                    );
                }
            }
        }
        out
    }

    #[test]
    fn the_grey_channel_is_chosen_by_the_change_it_makes() {
        let n = 150;
        let f = random_ff(n, 4);
        let probes = probe_vectors(n, 5);
        let rel = |a: &[f64], b: &[f64]| {
            let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
            (num / a.iter().map(|x| x * x).sum::<f64>()).sqrt()
        };
        for bounces in [Bounces::K(3), Bounces::All] {
            // Gently and randomly tinted: a few per cent of colour; then a warm scene, every
            // surface redder than it is blue.
            for (tint, warm, want) in [(0.03f32, 0.0f32, 1), (0.1, 0.5, 3)] {
                let mut s = 5;
                let albedo: Vec<[f32; 3]> = (0..n)
                    .map(|_| {
                        let g = 0.3 + 0.5 * lcg(&mut s);
                        [1.0 + warm, 1.0, 1.0 - warm]
                            .map(|w| g * w * (1.0 + tint * (2.0 * lcg(&mut s) - 1.0)))
                    })
                    .collect();
                let choice =
                    choose_channels(&f, &albedo, bounces, &probes, DEFAULT_MAX_GREY_ERROR).unwrap();
                assert_eq!(choice.channels, want, "{bounces} tint {tint}: {choice:?}");
                // No tolerance keeps colour whenever albedos differ.
                let strict = choose_channels(&f, &albedo, bounces, &probes, 0.0).unwrap();
                assert_eq!(strict.channels, 3);
                let unmeasured = choose_channels(&f, &albedo, bounces, &[], 1.0).unwrap();
                assert_eq!(unmeasured.channels, 3);
                // The measured change is the one the two transports really make.
                let rgb = apply(
                    &transport(&f, &albedo, bounces, Tail::Exact, 3, &no_progress).unwrap(),
                    &probes,
                );
                let one = apply(
                    &transport(&f, &albedo, bounces, Tail::Exact, 1, &no_progress).unwrap(),
                    &probes,
                );
                let real = rel(&rgb, &one);
                assert!(real > 0.0);
                assert!(
                    (choice.grey_rel_l2 - real).abs() <= 0.02 * real + 1e-6,
                    "{bounces} tint {tint}: measured {} against {real}",
                    choice.grey_rel_l2
                );
            }
        }
    }

    #[test]
    fn the_channel_choice_is_the_same_on_any_thread_count() {
        let n = ROW_BLOCK + 40;
        let f = random_ff(n, 6);
        let albedo = random_albedo(n, 8);
        let probes = probe_vectors(n, 3);
        let choose = || choose_channels(&f, &albedo, Bounces::K(3), &probes, 0.02).unwrap();
        let want = choose();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let one = pool.install(choose);
        assert_eq!(want, one);
    }

    #[test]
    fn row_ranges_and_thread_counts_give_identical_bits() {
        let b = ROW_BLOCK;
        let n = 2 * b + b / 3; // three row blocks, the last one partial
        let f = random_ff(n, 9);
        let albedo = random_albedo(n, 2);
        // Clusters of three consecutive rows, areas varying.
        let area: Vec<f32> = (0..n).map(|i| 1.0 + (i % 5) as f32).collect();
        let clusters = Clusters::new((0..n as u32).map(|i| i / 3).collect(), &area).unwrap();
        for (bounces, tail) in [
            (Bounces::K(3), Tail::Exact),
            (Bounces::All, Tail::Exact),
            (Bounces::All, Tail::Clustered(&clusters)),
            (Bounces::All, Tail::ClusteredGrey(&clusters)),
        ] {
            let full =
                transport_rows(&f, &albedo, (1, 3), bounces, tail, 0..n, &no_progress).unwrap();
            for range in [0..n, 10..20, b - 5..2 * b + 7, n - 1..n, 0..0] {
                let part = transport_rows(
                    &f,
                    &albedo,
                    (1, 3),
                    bounces,
                    tail,
                    range.clone(),
                    &no_progress,
                )
                .unwrap();
                assert_eq!(
                    part,
                    full[range.start * n..range.end * n],
                    "{bounces} {range:?}"
                );
            }
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let t = pool.install(|| {
                    transport_rows(&f, &albedo, (1, 3), bounces, tail, 0..n, &no_progress).unwrap()
                });
                assert_eq!(t, full, "{bounces} with {threads} threads");
            }
            // Every channel at once, as a shard asks: each channel's rows of that range.
            let each: Vec<Vec<f32>> = (0..3)
                .map(|c| {
                    transport_rows(&f, &albedo, (c, 3), bounces, tail, 0..n, &no_progress).unwrap()
                })
                .collect();
            for range in [0..n, b - 5..2 * b + 7, 0..0] {
                let at_once = transport_channel_rows(
                    &f,
                    &albedo,
                    3,
                    bounces,
                    tail,
                    range.clone(),
                    &no_progress,
                )
                .unwrap();
                let want: Vec<f32> = each
                    .iter()
                    .flat_map(|t| t[range.start * n..range.end * n].iter().copied())
                    .collect();
                assert_eq!(at_once, want, "{bounces} {range:?}, three channels at once");
            }
        }
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let f = random_ff(4, 1);
        let albedo = random_albedo(3, 1);
        assert!(matches!(
            transport(&f, &albedo, Bounces::K(2), Tail::Exact, 3, &no_progress),
            Err(TransportError::AlbedoCount { .. })
        ));
        let mut albedo = random_albedo(4, 1);
        albedo[2][1] = f32::NAN;
        assert!(matches!(
            transport(&f, &albedo, Bounces::All, Tail::Exact, 3, &no_progress),
            Err(TransportError::AlbedoNotFinite { patch: 2 })
        ));
        let albedo = random_albedo(4, 1);
        assert!(matches!(
            transport_rows(
                &f,
                &albedo,
                (0, 3),
                Bounces::K(2),
                Tail::Exact,
                2..9,
                &no_progress
            ),
            Err(TransportError::RowRange { .. })
        ));
    }
}

#[cfg(test)]
mod tail_tests {
    use super::tests::lcg;
    use super::{Tail, transport};
    use crate::matrix::DenseMatrix;
    use crate::meta::Bounces;
    use crate::patch::PatchLayout;
    use crate::patch::{Face, Patch};
    use crate::tail::{ClusterError, Clusters};

    /// Form factors of two rooms that never see each other: rows and columns `0..half` and
    /// `half..n`, each row summing to 0.9.
    fn two_rooms(n: usize, seed: u64) -> DenseMatrix {
        let (half, mut s) = (n / 2, seed);
        let mut data = vec![0.0f32; n * n];
        for i in 0..n {
            let room = if i < half { 0..half } else { half..n };
            let row = &mut data[i * n..(i + 1) * n];
            for j in room {
                if j != i {
                    row[j] = 0.2 + lcg(&mut s);
                }
            }
            let sum: f32 = row.iter().sum();
            row.iter_mut().for_each(|v| *v *= 0.9 / sum);
        }
        DenseMatrix {
            n,
            channels: 1,
            data,
        }
    }

    /// Every row in the voxels of one 2×2×2 block, facing +X.
    fn one_block(n: usize) -> PatchLayout {
        PatchLayout {
            origin: [0.0; 3],
            voxel_size: 1.0,
            dims: [2, 2, 2],
            patches: (0..n)
                .map(|i| Patch {
                    voxel: [(i % 2) as u32, (i / 2 % 2) as u32, (i / 4 % 2) as u32],
                    face: Face::PosX,
                    albedo: [0.6, 0.7, 0.8],
                    centroid: [0.0; 3],
                    normal: [1.0, 0.0, 0.0],
                    source_area: 0.5 + (i % 3) as f32 * 0.25,
                    emission: [0.0; 3],
                })
                .collect(),
        }
    }

    #[test]
    fn every_row_its_own_cluster_is_the_exact_solve() {
        let n = 40;
        let f = two_rooms(n, 3);
        let albedo = one_block(n)
            .patches
            .iter()
            .map(|p| p.albedo)
            .collect::<Vec<_>>();
        let exact = transport(&f, &albedo, Bounces::All, Tail::Exact, 3, &|_| {}).unwrap();
        let own = Clusters::singletons(n);
        let t = transport(&f, &albedo, Bounces::All, Tail::Clustered(&own), 3, &|_| {}).unwrap();
        for (a, b) in t.data.iter().zip(&exact.data) {
            assert!((a - b).abs() <= 1e-5 * b.abs() + 1e-7, "{a} vs {b}");
        }
    }

    #[test]
    fn rows_that_see_different_rooms_share_no_cluster_and_no_light() {
        let n = 48;
        let (f, layout) = (two_rooms(n, 7), one_block(n));
        let albedo: Vec<[f32; 3]> = layout.patches.iter().map(|p| p.albedo).collect();
        let clusters = Clusters::of_layout(&layout, &f);
        assert_eq!(clusters.rows(), n);
        let half = n / 2;
        for i in 0..half {
            for j in half..n {
                assert_ne!(clusters.of()[i], clusters.of()[j], "rows {i} and {j}");
            }
        }
        let exact = transport(&f, &albedo, Bounces::All, Tail::Exact, 3, &|_| {}).unwrap();
        let t = transport(
            &f,
            &albedo,
            Bounces::All,
            Tail::Clustered(&clusters),
            3,
            &|_| {},
        );
        let t = t.unwrap();
        // Not a ray crosses between the rooms, and no light does.
        for c in 0..3 {
            let ch = t.channel(c);
            for i in 0..n {
                for j in 0..n {
                    if (i < half) != (j < half) {
                        assert_eq!(ch[i * n + j], 0.0, "channel {c}, {i} from {j}");
                    }
                }
            }
        }
        let rel = |t: &DenseMatrix| {
            let num: f64 = t
                .data
                .iter()
                .zip(&exact.data)
                .map(|(a, b)| f64::from(a - b).powi(2))
                .sum();
            let den: f64 = exact.data.iter().map(|b| f64::from(*b).powi(2)).sum();
            (num / den).sqrt()
        };
        let err = rel(&t);
        assert!(err < 0.01, "clustered tail {err} from the exact solve");
        // The whole block as one cluster pours each room's light into the other.
        let block = Clusters::new(vec![0; n], &vec![1.0; n]).unwrap();
        let leaky = transport(
            &f,
            &albedo,
            Bounces::All,
            Tail::Clustered(&block),
            3,
            &|_| {},
        );
        let leaky = leaky.unwrap();
        assert!(leaky.data[n - 1] > 0.0, "{}", leaky.data[n - 1]);
        assert!(rel(&leaky) > err, "{} against {err}", rel(&leaky));
    }

    #[test]
    fn clusters_are_checked() {
        assert!(matches!(
            Clusters::new(vec![0, 2], &[1.0, 1.0]),
            Err(ClusterError::Empty { cluster: 1 })
        ));
        assert!(matches!(
            Clusters::new(vec![0], &[1.0, 1.0]),
            Err(ClusterError::Count { .. })
        ));
        let f = two_rooms(6, 1);
        let wrong = Clusters::singletons(5);
        let albedo = vec![[0.5f32; 3]; 6];
        assert!(
            transport(
                &f,
                &albedo,
                Bounces::All,
                Tail::Clustered(&wrong),
                1,
                &|_| {}
            )
            .is_err()
        );
    }
}
