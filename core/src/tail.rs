//! All bounces without an `n³` solve: the first [`EXACT_BOUNCES`] by Horner, the rest on
//! clusters of rows (docs/design.md §1).
//!
//! `T_∞ = T_K + Δ_K D_ρ T_∞`, where `Δ_K = F G^{K-1}` is Horner's last increment
//! (`T_K − T_{K−1}`) and `G = D_ρ F`. The tail `Δ_K D_ρ T_∞` is light that has bounced `K` times
//! already, so `T_∞` there is taken as one row per cluster of rows, `T_∞ ≈ P T_c`, with
//! `T_c = R T_∞` its rows' area-weighted mean (`R` averages a cluster's rows, `P` copies a
//! cluster's row to its members). `T_c` comes from the same identity averaged,
//! `T_c = R T_K + (R Δ_K D_ρ P) T_c`, an `m × m` system for `m` clusters whose right side is the
//! same Horner steps run on the clusters' mean rows of `F`. Where a receiver sees a cluster from
//! afar, its form factors to the cluster's rows go as their areas and the mean is exact; what is
//! approximated is how near clusters exchange light after the third bounce. Rows that see
//! different surfaces (the two sides of a wall) never share a cluster: their mean would pour one
//! room's light into the other.
//!
//! The cost is the exact bounces, an `m × m` factorisation and `n × m × n` multiply-adds, where
//! the exact solve costs `n³` in f64: on `pandora` (11,810 rows, 3 channels) the LU took 240 s.
//! A clustering of every row into its own cluster gives the exact `T_∞` (a test checks it).
//!
//! Like the Horner steps, rows are computed in the transport's fixed row blocks and `T_c` is the
//! same for every block and shard, so a row's bits depend only on `F`, `ρ` and the clusters.

use faer::linalg::solvers::{PartialPivLu, Solve};
use faer::{Accum, Mat, MatMut, MatRef, Par};
use rayon::prelude::*;

use crate::matrix::DenseMatrix;
use crate::patch::PatchLayout;
use thiserror::Error;

/// Clusters that do not fit their rows.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum ClusterError {
    #[error("{clusters} cluster numbers for {rows} rows")]
    Count { clusters: usize, rows: usize },
    #[error("cluster {cluster} has no rows")]
    Empty { cluster: usize },
}

/// Bounces summed exactly before the clustered tail. Three keep the first three bounces, the
/// light that varies most over a scene, bit for bit those of a `--bounces 3` bake.
pub const EXACT_BOUNCES: u32 = 3;

/// At most this many clusters: the tail's product costs `n² m` multiply-adds, the coarse solve
/// `m² n` (on `pandora`, 11,810 rows and 1,834 clusters, the transport's three channels took
/// 28 s against the exact solve's 240 s).
pub const MAX_CLUSTERS: usize = 2048;

/// A partition of a transport's rows into clusters, with each row's share of its cluster's
/// area.
#[derive(Debug, Clone, PartialEq)]
pub struct Clusters {
    of: Vec<u32>,
    count: usize,
    /// Per row, its area over its cluster's (the cluster's rows equally where it has none).
    weight: Vec<f64>,
}

impl Clusters {
    /// Rows `of[i]` in cluster `of[i]` (numbered from 0, every number up to the largest used),
    /// weighted by `area`.
    pub fn new(of: Vec<u32>, area: &[f32]) -> Result<Self, ClusterError> {
        if of.len() != area.len() {
            return Err(ClusterError::Count {
                clusters: of.len(),
                rows: area.len(),
            });
        }
        let count = of.iter().map(|&c| c as usize + 1).max().unwrap_or(0);
        let mut total = vec![0.0f64; count];
        let mut members = vec![0usize; count];
        for (&c, &a) in of.iter().zip(area) {
            let a = if a.is_finite() && a > 0.0 {
                f64::from(a)
            } else {
                0.0
            };
            total[c as usize] += a;
            members[c as usize] += 1;
        }
        if let Some(empty) = members.iter().position(|&m| m == 0) {
            return Err(ClusterError::Empty { cluster: empty });
        }
        let weight = of
            .iter()
            .zip(area)
            .map(|(&c, &a)| {
                let c = c as usize;
                let a = if a.is_finite() && a > 0.0 {
                    f64::from(a)
                } else {
                    0.0
                };
                if total[c] > 0.0 {
                    a / total[c]
                } else {
                    1.0 / members[c] as f64
                }
            })
            .collect();
        Ok(Clusters { of, count, weight })
    }

    /// The rows of a layout (a bake's transport rows, with their form factors `f`) in blocks
    /// of `2^s` voxels a side, one cluster per block, face direction and view: rows of one
    /// block and direction share a cluster only when they see the same surfaces (so the floors
    /// either side of a wall, or the lit and unlit rooms a block straddles, do not share one).
    /// The strictest of [`VIEWS`] and then the smallest `s ≥ 1` that make at most
    /// [`MAX_CLUSTERS`] are taken. A row's area is its `source_area` (the voxel face's where it
    /// has none).
    pub fn of_layout(rows: &PatchLayout, f: &DenseMatrix) -> Self {
        let face_area = rows.patch_area();
        let area: Vec<f32> = rows
            .patches
            .iter()
            .map(|p| {
                if p.source_area > 0.0 {
                    p.source_area
                } else {
                    face_area
                }
            })
            .collect();
        if f.n != rows.len() {
            return Clusters::singletons(rows.len());
        }
        let views = views(f);
        // Past the shift whose one block holds the whole grid, blocks do not change: trying
        // them again cost `pandora` 10 s of its bake.
        let widest = rows.patches.iter().flat_map(|p| p.voxel).max().unwrap_or(0);
        let last = (1..=MAX_SHIFT)
            .find(|&s| widest >> s == 0)
            .unwrap_or(MAX_SHIFT);
        // The strictest view that fits, then the smallest blocks; the last view merges a
        // block's rows whatever they see, and is taken at the largest blocks whatever it makes.
        for view in VIEWS {
            for shift in 1..=last {
                let limit = if view == 0.0 && shift == last {
                    usize::MAX
                } else {
                    MAX_CLUSTERS
                };
                if let Some(of) = split_by_view(rows, &views, view, shift, limit) {
                    // Numbers and areas come from the layout itself, so they agree.
                    return Clusters::new(of, &area)
                        .unwrap_or_else(|_| Clusters::singletons(rows.len()));
                }
            }
        }
        Clusters::singletons(rows.len())
    }

    /// Every row its own cluster: the exact `T_∞`.
    pub fn singletons(n: usize) -> Self {
        Clusters {
            of: (0..n as u32).collect(),
            count: n,
            weight: vec![1.0; n],
        }
    }

    /// The number of clusters.
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The number of rows clustered.
    pub fn rows(&self) -> usize {
        self.of.len()
    }

    /// Each row's cluster.
    pub fn of(&self) -> &[u32] {
        &self.of
    }
}

/// `R F`: each cluster's rows of `F` averaged by area (`m × n`, row-major), summed in row
/// order so that they are the same on any thread count.
pub(crate) fn cluster_rows(f: &DenseMatrix, clusters: &Clusters) -> Vec<f32> {
    let (n, m) = (f.n, clusters.count);
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); m];
    for (i, &c) in clusters.of.iter().enumerate() {
        members[c as usize].push(i);
    }
    let mut out = vec![0.0f32; m * n];
    out.par_chunks_mut(n.max(1))
        .zip(members.par_iter())
        .for_each(|(row, rows)| {
            let mut acc = vec![0.0f64; n];
            for &i in rows {
                let w = clusters.weight[i];
                for (a, &v) in acc.iter_mut().zip(&f.data[i * n..(i + 1) * n]) {
                    *a += w * f64::from(v);
                }
            }
            for (o, a) in row.iter_mut().zip(acc) {
                *o = a as f32;
            }
        });
    out
}

/// The views tried, strictest first: rows in one cluster see at least this share of the same
/// surfaces, `Σ_x min(F_ix, F_rx)` over the smaller of the two rows' sums, against the cluster's
/// first row `r`. Measured against the exact solve (`bounce bake --all-bounces exact`): the
/// Cornell box fits at 0.5 (969 clusters of 3,129 rows, 0.07% from exact), `pandora`, whose rows
/// meet a hundred columns each, at 0.05 (1,834 of 11,810, 1.1%); with blocks alone (0) it was
/// 1.4% and 3.7%, the blocks' mean pouring a lit room's light into the dark one beside it.
pub const VIEWS: [f32; 5] = [0.5, 0.25, 0.1, 0.05, 0.0];

/// Blocks grow to at most `2^MAX_SHIFT` voxels a side.
pub const MAX_SHIFT: u32 = 8;

/// Each row's nonzeros `(column, value)` in column order, and each row's sum.
type Views = (Vec<Vec<(u32, f32)>>, Vec<f32>);

/// Each row of `f`'s nonzeros in column order, and its sum. A level's rows meet a hundred
/// columns of ten thousand, so comparing two views is a merge of short lists.
fn views(f: &DenseMatrix) -> Views {
    let n = f.n;
    let sparse: Vec<Vec<(u32, f32)>> = (0..n)
        .into_par_iter()
        .map(|i| {
            f.data[i * n..(i + 1) * n]
                .iter()
                .enumerate()
                .filter(|(_, v)| **v > 0.0)
                .map(|(j, &v)| (j as u32, v))
                .collect()
        })
        .collect();
    let sums = sparse.iter().map(|r| r.iter().map(|e| e.1).sum()).collect();
    (sparse, sums)
}

/// Cluster numbers for the rows of `rows`: by block of `2^shift` voxels and face, then by view
/// within each (see [`Clusters::of_layout`]), numbered in order of each cluster's first row;
/// `None` as soon as they pass `limit` clusters (the strict views pass it by thousands, each
/// further row compared with every cluster so far).
fn split_by_view(
    rows: &PatchLayout,
    (sparse, sums): &Views,
    view: f32,
    shift: u32,
    limit: usize,
) -> Option<Vec<u32>> {
    let n = rows.len();
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut ids = std::collections::HashMap::new();
    for (i, p) in rows.patches.iter().enumerate() {
        let key = (p.voxel.map(|v| v >> shift), p.face as u8);
        let g = *ids.entry(key).or_insert_with(|| {
            groups.push(Vec::new());
            groups.len() - 1
        });
        groups[g].push(i);
    }
    let common = |a: &[(u32, f32)], b: &[(u32, f32)]| {
        let (mut x, mut y, mut sum) = (0, 0, 0.0f32);
        while x < a.len() && y < b.len() {
            match a[x].0.cmp(&b[y].0) {
                std::cmp::Ordering::Less => x += 1,
                std::cmp::Ordering::Greater => y += 1,
                std::cmp::Ordering::Equal => {
                    sum += a[x].1.min(b[y].1);
                    x += 1;
                    y += 1;
                }
            }
        }
        sum
    };
    // Per group, each row's sub-cluster: the first whose first row it sees alike, else a new one.
    // Every new cluster counts towards the limit, whatever group makes it, so the answer (over
    // or not) is the same on any thread count.
    let made = std::sync::atomic::AtomicUsize::new(0);
    let local: Vec<Vec<usize>> = groups
        .par_iter()
        .map(|members| {
            let mut firsts: Vec<usize> = Vec::new();
            let mut local = Vec::with_capacity(members.len());
            for &i in members {
                let found = firsts.iter().position(|&r| {
                    let least = sums[i].min(sums[r]);
                    if least <= 0.0 {
                        // A row that sees nothing goes only with another that sees nothing.
                        return sums[i].max(sums[r]) <= 0.0;
                    }
                    common(&sparse[i], &sparse[r]) >= view * least
                });
                local.push(match found {
                    Some(sub) => sub,
                    None => {
                        if made.fetch_add(1, std::sync::atomic::Ordering::Relaxed) >= limit {
                            return None;
                        }
                        firsts.push(i);
                        firsts.len() - 1
                    }
                });
            }
            Some(local)
        })
        .collect::<Option<_>>()?;
    let mut of = vec![0u32; n];
    let mut next = 0u32;
    let mut number = std::collections::HashMap::new();
    for (g, members) in groups.iter().enumerate() {
        for (&i, &sub) in members.iter().zip(&local[g]) {
            of[i] = *number.entry((g, sub)).or_insert_with(|| {
                next += 1;
                next - 1
            });
        }
    }
    Some(of)
}

/// The coarse all-bounce transport `T_c ≈ R T_∞` (`m × n`, row-major) of one channel, from
/// the clusters' mean rows of `T_K` (`rt`, `R T_K`) and of `T_{K−1}` (`rt_prev`):
/// `T_c = R T_K + (R Δ_K D_ρ P) T_c`, an `m × m` system in f64; `None` when it is singular.
pub(crate) fn coarse_transport(
    rt: &[f32],
    rt_prev: &[f32],
    rho: &[f32],
    clusters: &Clusters,
) -> Option<Vec<f32>> {
    let (n, m) = (rho.len(), clusters.count);
    // I − R Δ_K D_ρ P.
    let mut a = Mat::<f64>::identity(m, m);
    for ca in 0..m {
        let (x, p) = (&rt[ca * n..(ca + 1) * n], &rt_prev[ca * n..(ca + 1) * n]);
        for j in 0..n {
            let d = f64::from(x[j]) - f64::from(p[j]);
            if d != 0.0 {
                a[(ca, clusters.of[j] as usize)] -= d * f64::from(rho[j]);
            }
        }
    }
    let lu = PartialPivLu::new(a.as_ref());
    drop(a);
    let mut x = Mat::<f64>::from_fn(m, n, |ca, j| f64::from(rt[ca * n + j]));
    lu.solve_in_place(x.as_mut());
    let mut out = vec![0.0f32; m * n];
    for ca in 0..m {
        for j in 0..n {
            let v = x[(ca, j)];
            if !v.is_finite() {
                return None;
            }
            out[ca * n + j] = v as f32;
        }
    }
    Some(out)
}

/// Adds the clustered tail to a block of rows: `out` holds `T_K`'s rows and `prev` `T_{K−1}`'s
/// (both `rows × n`); afterwards `out` holds `T_K + (Δ_K D_ρ P) T_c`.
pub(crate) fn add_tail(
    out: &mut [f32],
    prev: &[f32],
    rho: &[f32],
    clusters: &Clusters,
    coarse: &[f32],
) {
    let (n, m) = (rho.len(), clusters.count);
    if n == 0 || m == 0 {
        return;
    }
    let rows = out.len() / n;
    let w = tail_weights(out, prev, rho, clusters);
    faer::linalg::matmul::matmul(
        MatMut::from_row_major_slice_mut(out, rows, n),
        Accum::Add,
        MatRef::from_row_major_slice(&w, rows, m),
        MatRef::from_row_major_slice(coarse, m, n),
        1.0f32,
        Par::Seq,
    );
}

/// The tail alone of a block of rows whose `T_K` is `tk` and `T_{K−1}` is `prev`:
/// `(Δ_K D_ρ P) T_c` (`rows × n`).
pub(crate) fn tail_block(
    tk: &[f32],
    prev: &[f32],
    rho: &[f32],
    clusters: &Clusters,
    coarse: &[f32],
) -> Vec<f32> {
    let (n, m) = (rho.len(), clusters.count);
    let mut out = vec![0.0f32; tk.len()];
    if n == 0 || m == 0 {
        return out;
    }
    let rows = tk.len() / n;
    let w = tail_weights(tk, prev, rho, clusters);
    faer::linalg::matmul::matmul(
        MatMut::from_row_major_slice_mut(&mut out, rows, n),
        Accum::Replace,
        MatRef::from_row_major_slice(&w, rows, m),
        MatRef::from_row_major_slice(coarse, m, n),
        1.0f32,
        Par::Seq,
    );
    out
}

/// `Δ_K D_ρ P` for a block of rows (`rows × m`): `T_K − T_{K−1}` times the albedo, summed over
/// each cluster's columns.
fn tail_weights(tk: &[f32], prev: &[f32], rho: &[f32], clusters: &Clusters) -> Vec<f32> {
    let (n, m) = (rho.len(), clusters.count);
    let rows = tk.len() / n;
    let mut w = vec![0.0f64; rows * m];
    for r in 0..rows {
        let (o, p) = (&tk[r * n..(r + 1) * n], &prev[r * n..(r + 1) * n]);
        let wr = &mut w[r * m..(r + 1) * m];
        for j in 0..n {
            let d = o[j] - p[j];
            if d != 0.0 {
                wr[clusters.of[j] as usize] += f64::from(d) * f64::from(rho[j]);
            }
        }
    }
    w.into_iter().map(|v| v as f32).collect()
}
