//! The encoder: the largest entries into the sparse part, the rest log-quantised, rows and
//! columns reordered by the greedy chain, the 8-bit image block-compressed; for `bc1-resid`, the
//! decoded blocks' worst residuals then take part of the sparse budget.

use super::product::LogBlockOp;
use super::{Blocks, F16_TOP, LogBlock, Params, SparseStore, corrupt, lut};
use crate::codec::bc;
use crate::codec::transform::{
    SparsePart, gather_positions, greedy_chain, log_quantize, select_largest, split_largest,
};
use crate::codec::{Codec, CodecError, MatrixOp};
use crate::matrix::{DenseMatrix, EncodedMatrix};

impl Codec for LogBlock {
    fn name(&self) -> &'static str {
        self.name
    }

    fn encode(&self, t: &DenseMatrix) -> Result<EncodedMatrix, CodecError> {
        let n = t.n;
        let ch = t.channels;
        let nn = n * n;
        let share = clamp_share(self.sparse_share);
        let residual = clamp_share(self.residual);
        let total = ((share * nn as f64).round() as usize).min(nn);
        let by_size = ((1.0 - residual) * total as f64).round() as usize;
        let mut dense: Vec<Vec<f32>> = (0..ch).map(|c| t.channel(c).to_vec()).collect();
        let sparse = split_largest(&mut dense, n, by_size as f64 / nn.max(1) as f64);
        let (codes, max): (Vec<Vec<u8>>, Vec<f32>) = dense.iter().map(|d| log_quantize(d)).unzip();
        drop(dense);

        // Rows are compared on all channels at once: row i is its codes in every channel.
        let mut row_perm: Vec<u32> = (0..n as u32).collect();
        let mut col_perm: Vec<u32> = (0..n as u32).collect();
        for _ in 0..self.passes {
            let rows = gather(&codes, n, &row_perm, &col_perm, false);
            let chain = greedy_chain(&rows, n, n * ch);
            row_perm = chain.iter().map(|&k| row_perm[k as usize]).collect();
            let cols = gather(&codes, n, &row_perm, &col_perm, true);
            let chain = greedy_chain(&cols, n, n * ch);
            col_perm = chain.iter().map(|&k| col_perm[k as usize]).collect();
        }

        let width = n.div_ceil(4) * 4;
        let mut codes = codes;
        let blocks = encode_blocks(self, &codes, n, width, &row_perm, &col_perm);
        let lut: Vec<[f32; 256]> = max.iter().map(|&m| lut(m)).collect();
        let no_sparse = SparsePart {
            n,
            channels: ch,
            row_ptr: vec![0; n + 1],
            col_idx: Vec::new(),
            values: Vec::new(),
        };
        let mut op = LogBlockOp::assemble(
            n,
            ch,
            self.blocks,
            width,
            row_perm,
            col_perm,
            lut,
            no_sparse,
            blocks,
        );
        if by_size == total {
            op.sparse = sparse;
        } else {
            // Where the blocks miss most, the entries are zeroed (code 0, which every BC1 and
            // BC4 decoder returns as exactly 0) and the blocks encoded again, so the sparse part
            // holds exact values that add to a decoded zero on any decoder, GPU texture units
            // included, rather than corrections tied to one decoder's rounding.
            let positions = worst_positions(t, &op, &sparse, total);
            for code in codes.iter_mut() {
                for &p in &positions {
                    code[p as usize] = 0;
                }
            }
            let blocks = encode_blocks(self, &codes, n, width, &op.row_perm, &op.col_perm);
            let channels: Vec<&[f32]> = (0..ch).map(|c| t.channel(c)).collect();
            let sparse = gather_positions(&channels, n, &positions);
            op = LogBlockOp::assemble(
                n,
                ch,
                self.blocks,
                width,
                op.row_perm,
                op.col_perm,
                op.lut,
                sparse,
                blocks,
            );
        }
        drop(codes);

        let store = if n <= 1 << 16 {
            self.store
        } else {
            SparseStore::U32f32
        };
        let nnz = op.sparse.nnz();
        let sparse_scale: Vec<f32> = match store {
            SparseStore::U32f32 => Vec::new(),
            SparseStore::U16f16 => (0..ch)
                .map(|c| {
                    let m = op.sparse.values[c * nnz..(c + 1) * nnz]
                        .iter()
                        .fold(0.0f32, |m, v| m.max(v.abs()));
                    if m > 0.0 && m.is_finite() {
                        m / F16_TOP
                    } else {
                        1.0
                    }
                })
                .collect(),
        };
        let mut payload = Vec::new();
        for v in op
            .row_perm
            .iter()
            .chain(&op.col_perm)
            .chain(&op.sparse.row_ptr)
        {
            payload.extend_from_slice(&v.to_le_bytes());
        }
        match store {
            SparseStore::U32f32 => {
                for v in &op.sparse.col_idx {
                    payload.extend_from_slice(&v.to_le_bytes());
                }
                for v in &op.sparse.values {
                    payload.extend_from_slice(&v.to_le_bytes());
                }
            }
            SparseStore::U16f16 => {
                // n ≤ 2^16, so every column index fits.
                for &v in &op.sparse.col_idx {
                    payload.extend_from_slice(&(v as u16).to_le_bytes());
                }
                let nnz = op.sparse.nnz();
                for (c, &scale) in sparse_scale.iter().enumerate() {
                    for &v in &op.sparse.values[c * nnz..(c + 1) * nnz] {
                        payload.extend_from_slice(&half::f16::from_f32(v / scale).to_le_bytes());
                    }
                }
            }
        }
        payload.extend_from_slice(&op.raw);
        let params = Params {
            sparse_share: self.sparse_share,
            passes: self.passes,
            residual: self.residual,
            store,
            sparse_scale,
            max,
            nnz: op.sparse.nnz(),
            width,
        };
        Ok(EncodedMatrix {
            codec: self.name.to_string(),
            rows: n as u32,
            cols: n as u32,
            channels: ch as u32,
            params: serde_json::to_value(&params).map_err(|e| corrupt(self.blocks, e))?,
            payload,
        })
    }
}

/// A share in `0..=1`; NaN reads as 0 (the knob may come from a file).
fn clamp_share(share: f64) -> f64 {
    if share.is_nan() {
        0.0
    } else {
        share.clamp(0.0, 1.0)
    }
}

/// The `total` positions the sparse part keeps: those already taken by size (`by_size`, zeroed
/// before encoding) plus those where the decoded `blocks` are furthest from the exact matrix
/// (largest absolute error over the channels), ascending.
fn worst_positions(
    t: &DenseMatrix,
    blocks: &LogBlockOp,
    by_size: &SparsePart,
    total: usize,
) -> Vec<u32> {
    let n = t.n;
    let ch = t.channels;
    let decoded = blocks.to_dense();
    let mut taken = vec![false; n * n];
    for i in 0..n {
        for &j in &by_size.col_idx[by_size.row_ptr[i] as usize..by_size.row_ptr[i + 1] as usize] {
            taken[i * n + j as usize] = true;
        }
    }
    let more = total.saturating_sub(by_size.nnz());
    let extra = select_largest(n * n, more, |p| {
        if taken[p] {
            return 0.0;
        }
        (0..ch)
            .map(|c| (t.channel(c)[p] - decoded.channel(c)[p]).abs())
            .fold(0.0f32, f32::max)
    });
    let mut positions: Vec<u32> = (0..n * n).filter(|&p| taken[p]).map(|p| p as u32).collect();
    positions.extend(extra);
    positions.sort_unstable();
    positions
}

/// The block image of `codes` (one `n × n` plane per channel) under the permutations: BC1 packs
/// the channels as RGB (a single channel repeated), BC4 and raw codes store one image each.
fn encode_blocks(
    codec: &LogBlock,
    codes: &[Vec<u8>],
    n: usize,
    width: usize,
    row_perm: &[u32],
    col_perm: &[u32],
) -> Vec<u8> {
    let ch = codes.len();
    let image = |c: usize| -> Vec<u8> {
        let mut img = vec![0u8; width * width];
        for (k, &r) in row_perm.iter().enumerate() {
            let src = &codes[c][r as usize * n..(r as usize + 1) * n];
            for (l, &col) in col_perm.iter().enumerate() {
                img[k * width + l] = src[col as usize];
            }
        }
        img
    };
    match codec.blocks {
        Blocks::Bc1 => {
            let planes: Vec<Vec<u8>> = (0..ch).map(image).collect();
            let rgb: Vec<[u8; 3]> = (0..width * width)
                .map(|p| {
                    let v = |c: usize| planes[c.min(ch - 1)][p];
                    [v(0), v(1), v(2)]
                })
                .collect();
            bc::encode_bc1_with(&rgb, width, width, codec.fit)
        }
        Blocks::Bc4 => (0..ch)
            .flat_map(|c| bc::encode_bc4(&image(c), width, width))
            .collect(),
        Blocks::Raw8 => (0..ch).flat_map(image).collect(),
    }
}

/// The quantised matrix under the current permutations, as rows (or, `by_column`, as columns)
/// of `n × channels` bytes.
fn gather(
    codes: &[Vec<u8>],
    n: usize,
    row_perm: &[u32],
    col_perm: &[u32],
    by_column: bool,
) -> Vec<u8> {
    let ch = codes.len();
    let mut out = vec![0u8; n * n * ch];
    for (k, &r) in row_perm.iter().enumerate() {
        for (l, &col) in col_perm.iter().enumerate() {
            for (c, code) in codes.iter().enumerate() {
                let v = code[r as usize * n + col as usize];
                let at = if by_column {
                    l * n * ch + c * n + k
                } else {
                    k * n * ch + c * n + l
                };
                out[at] = v;
            }
        }
    }
    out
}
