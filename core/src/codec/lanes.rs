//! The CPU products' shared inner loop: a batch of light vectors rearranged so each matrix row is
//! read once for the whole batch, the dot products vectorise, and columns no light reaches are
//! never touched.
//!
//! A light vector arrives as `[f32; 3]` per patch (RGB interleaved), one light set after another.
//! Products want the opposite: per light set and channel, one contiguous run of values, in the
//! order the matrix stores its columns, holding only the columns that carry light. Shadowed scenes
//! leave many patches dark (their `B0` is zero in every light set of the batch), and their columns
//! contribute nothing, so dropping them is exact.

use half::f16;

/// A stored entry type the dense product reads directly (so `dense-f16` products read half the
/// bytes, which is the point of the codec).
pub trait Entry: Copy + Send + Sync {
    fn value(self) -> f32;
    /// The entries as f32 when they are f32 already, for library matrix products.
    fn as_f32(entries: &[Self]) -> Option<&[f32]> {
        let _ = entries;
        None
    }
    /// Widen `src` into `dst` (same length), as fast as the type allows.
    fn widen(src: &[Self], dst: &mut [f32]) {
        for (d, s) in dst.iter_mut().zip(src) {
            *d = s.value();
        }
    }
}

impl Entry for f32 {
    #[inline]
    fn value(self) -> f32 {
        self
    }

    fn as_f32(entries: &[f32]) -> Option<&[f32]> {
        Some(entries)
    }
}

impl Entry for f16 {
    #[inline]
    fn value(self) -> f32 {
        self.to_f32()
    }

    /// `half`'s slice conversion uses F16C where the CPU has it, eight values an instruction;
    /// one at a time it is a software routine per value.
    fn widen(src: &[f16], dst: &mut [f32]) {
        use half::slice::HalfFloatSliceExt;
        src.convert_to_f32_slice(dst);
    }
}

/// Below this share of lit columns the products gather the lit ones; above it they run over all
/// columns contiguously (a gather costs about twice a contiguous load).
pub const GATHER_BELOW: f64 = 0.5;

/// Partial sums of a dot product. Column `j` always goes to partial sum `j % LANES`, whether the
/// product runs over all columns or gathers the lit ones (which are kept in aligned runs of
/// `LANES`), so a light set's result has the same bits whatever else is in its batch.
pub const LANES: usize = 8;

/// A batch of light vectors, per light set and channel, over the kept columns.
pub struct Lanes {
    /// The kept columns in the matrix's storage order, ascending; `None` when all are kept.
    pub cols: Option<Vec<u32>>,
    /// Light sets in the batch.
    pub batch: usize,
    /// Kept columns per lane.
    pub len: usize,
    /// `data[(k * 3 + c) * len + m]`: light set `k`, channel `c`, `m`-th kept column.
    data: Vec<f32>,
}

impl Lanes {
    /// Rearrange `x` (`batch × n`, light set `k` at `x[k*n..]`). Stored column `s` of the matrix
    /// holds patch `order[s]` (identity without `order`); the matrix stores `width ≥ n` columns
    /// (BC images are padded to a multiple of 4), the ones past `n` being zero. Columns are kept
    /// or dropped in aligned runs of [`LANES`].
    pub fn new(x: &[[f32; 3]], n: usize, order: Option<&[u32]>, width: usize) -> Lanes {
        let group = LANES;
        let batch = x.len() / n.max(1);
        let patch = |s: usize| order.map_or(s, |o| o[s] as usize);
        let lit_group: Vec<bool> = (0..n.div_ceil(group))
            .map(|g| {
                (g * group..((g + 1) * group).min(n)).any(|s| {
                    let j = patch(s);
                    (0..batch).any(|k| x[k * n + j] != [0.0; 3])
                })
            })
            .collect();
        let lit = lit_group.iter().filter(|&&l| l).count() * group;
        let cols: Option<Vec<u32>> = ((lit as f64) < GATHER_BELOW * width as f64).then(|| {
            lit_group
                .iter()
                .enumerate()
                .filter(|(_, l)| **l)
                .flat_map(|(g, _)| (g * group..((g + 1) * group).min(n)).map(|s| s as u32))
                .collect()
        });
        // Without gathering, lanes run over the stored width so block rows line up.
        let len = cols.as_ref().map_or(width, Vec::len);
        let mut data = vec![0.0f32; batch * 3 * len];
        for k in 0..batch {
            for m in 0..len {
                let s = cols.as_ref().map_or(m, |c| c[m] as usize);
                if s >= n {
                    continue;
                }
                let v = x[k * n + patch(s)];
                for (c, &vc) in v.iter().enumerate() {
                    data[(k * 3 + c) * len + m] = vc;
                }
            }
        }
        Lanes {
            cols,
            batch,
            len,
            data,
        }
    }

    pub fn lane(&self, k: usize, c: usize) -> &[f32] {
        &self.data[(k * 3 + c) * self.len..(k * 3 + c + 1) * self.len]
    }

    /// Is every column dark? Then every product is zero.
    pub fn dark(&self) -> bool {
        self.len == 0
    }
}

/// `Σ a[m]·b[m]` in [`LANES`] independent partial sums, which the compiler keeps in one SIMD
/// register (a single running sum would serialise on the adds). With `a` and `b` compacted to the
/// kept columns of a [`Lanes`], the partial sums are the same as over all columns.
#[inline]
pub fn dot<T: Entry>(a: &[T], b: &[f32]) -> f32 {
    let len = a.len().min(b.len());
    let (a, b) = (&a[..len], &b[..len]);
    let mut acc = [0.0f32; LANES];
    let mut ac = a.chunks_exact(LANES);
    let mut bc = b.chunks_exact(LANES);
    for (x, y) in (&mut ac).zip(&mut bc) {
        for l in 0..LANES {
            acc[l] += x[l].value() * y[l];
        }
    }
    for (l, (x, y)) in ac.remainder().iter().zip(bc.remainder()).enumerate() {
        acc[l] += x.value() * y;
    }
    acc.iter().sum()
}

/// `Σ row[cols[m]]·b[m]`: the dot over the kept columns of a [`Lanes`], with the same partial
/// sums as [`dot`] over the whole row.
#[inline]
pub fn dot_gather<T: Entry>(row: &[T], cols: &[u32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; LANES];
    let mut cc = cols.chunks_exact(LANES);
    let mut bc = b.chunks_exact(LANES);
    for (c, y) in (&mut cc).zip(&mut bc) {
        for l in 0..LANES {
            acc[l] += row[c[l] as usize].value() * y[l];
        }
    }
    for (l, (&c, y)) in cc.remainder().iter().zip(bc.remainder()).enumerate() {
        acc[l] += row[c as usize].value() * y;
    }
    acc.iter().sum()
}

/// Per stored channel `c` of a matrix with `channels` channels, the (light set, colour) pairs it
/// serves in a batch of `batch`: a three-channel matrix serves colour `c` of every set, a
/// one-channel matrix all three colours of every set from the same row.
pub fn served(channels: usize, batch: usize) -> Vec<Vec<(usize, usize)>> {
    (0..channels)
        .map(|c| {
            (0..batch)
                .flat_map(|k| (0..3).map(move |cc| (k, cc)))
                .filter(|&(_, cc)| cc.min(channels - 1) == c)
                .collect()
        })
        .collect()
}

/// Light sets (and channels) whose dots one pass over a row computes together: the row's values
/// are loaded once for all of them, and their independent partial sums keep the FMA units busy
/// (one dot alone waits on its own adds).
const GROUP: usize = 4;

/// `out[t] = Σ_m row[col(m)] · lanes[t][m]` for every lane `t`, with `col(m) = cols[m]` when
/// gathering and `m` otherwise; each with exactly the partial sums of [`dot`] / [`dot_gather`],
/// so grouping never changes a result's bits.
pub fn dots<T: Entry>(row: &[T], cols: Option<&[u32]>, lanes: &[&[f32]], out: &mut [f32]) {
    let mut t = 0;
    while t + GROUP <= lanes.len() {
        let group: [&[f32]; GROUP] = std::array::from_fn(|g| lanes[t + g]);
        let sums = match cols {
            None => dot_group(row, &group),
            Some(cols) => dot_gather_group(row, cols, &group),
        };
        out[t..t + GROUP].copy_from_slice(&sums);
        t += GROUP;
    }
    for (lane, o) in lanes[t..].iter().zip(&mut out[t..]) {
        *o = match cols {
            None => dot(row, lane),
            Some(cols) => dot_gather(row, cols, lane),
        };
    }
}

#[inline]
fn dot_group<T: Entry>(a: &[T], b: &[&[f32]; GROUP]) -> [f32; GROUP] {
    let len = b.iter().fold(a.len(), |l, x| l.min(x.len()));
    let mut acc = [[0.0f32; LANES]; GROUP];
    let full = len / LANES * LANES;
    for base in (0..full).step_by(LANES) {
        let x: [f32; LANES] = std::array::from_fn(|l| a[base + l].value());
        for (acc, b) in acc.iter_mut().zip(b) {
            let y = &b[base..base + LANES];
            for l in 0..LANES {
                acc[l] += x[l] * y[l];
            }
        }
    }
    for m in full..len {
        let x = a[m].value();
        for (acc, b) in acc.iter_mut().zip(b) {
            acc[m - full] += x * b[m];
        }
    }
    acc.map(|a| a.iter().sum())
}

#[inline]
fn dot_gather_group<T: Entry>(row: &[T], cols: &[u32], b: &[&[f32]; GROUP]) -> [f32; GROUP] {
    let len = b.iter().fold(cols.len(), |l, x| l.min(x.len()));
    let mut acc = [[0.0f32; LANES]; GROUP];
    let full = len / LANES * LANES;
    for base in (0..full).step_by(LANES) {
        let x: [f32; LANES] = std::array::from_fn(|l| row[cols[base + l] as usize].value());
        for (acc, b) in acc.iter_mut().zip(b) {
            let y = &b[base..base + LANES];
            for l in 0..LANES {
                acc[l] += x[l] * y[l];
            }
        }
    }
    for m in full..len {
        let x = row[cols[m] as usize].value();
        for (acc, b) in acc.iter_mut().zip(b) {
            acc[m - full] += x * b[m];
        }
    }
    acc.map(|a| a.iter().sum())
}
