//! The thesis' codec (`bc1`, section 4.2) and its one-channel sibling (`bc4`): the largest entries
//! kept exactly in CSR, the rest log-quantised to 8 bits per channel, rows and columns reordered
//! by the greedy nearest-neighbour chain so that similar ones sit together, and the 8-bit image
//! block-compressed: BC1 packs the three channels as RGB (1/6 byte an entry), BC4 stores each
//! channel as its own single-channel texture (1/2 byte an entry, far finer steps).
//!
//! Payload, little-endian: row permutation (u32 × n), column permutation (u32 × n), CSR row
//! pointers (u32 × (n+1)), column indices (u32 × nnz), values (f32 × nnz × channels, channel-major),
//! then the blocks (BC1: one image; BC4: one image per channel). Image row `k`, column `l` holds
//! entry `(row_perm[k], col_perm[l])`. Parameters (JSON): sparse share, reorder passes, per-channel
//! maxima, nnz, padded image size.

use serde::{Deserialize, Serialize};

use super::bc;
use rayon::prelude::*;

use super::transform::{
    SparsePart, greedy_chain, is_permutation, log_dequantize, log_quantize, split_largest,
};
use super::{Codec, CodecError, MatrixOp, batch_len};
use crate::matrix::{DenseMatrix, EncodedMatrix};

/// Which block format holds the quantised image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Blocks {
    Bc1,
    Bc4,
}

/// The thesis' codec family with its knobs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogBlock {
    pub blocks: Blocks,
    /// Share of entry positions kept exactly (thesis: 4%).
    pub sparse_share: f64,
    /// Reorder passes; a pass chains the rows, then the columns (thesis: up to 2).
    pub passes: u32,
}

impl LogBlock {
    pub const fn bc1() -> Self {
        LogBlock {
            blocks: Blocks::Bc1,
            sparse_share: 0.04,
            passes: 2,
        }
    }

    pub const fn bc4() -> Self {
        LogBlock {
            blocks: Blocks::Bc4,
            sparse_share: 0.04,
            passes: 2,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Params {
    sparse_share: f64,
    passes: u32,
    max: Vec<f32>,
    nnz: usize,
    width: usize,
}

fn name_of(blocks: Blocks) -> &'static str {
    match blocks {
        Blocks::Bc1 => "bc1",
        Blocks::Bc4 => "bc4",
    }
}

impl Codec for LogBlock {
    fn name(&self) -> &'static str {
        name_of(self.blocks)
    }

    fn encode(&self, t: &DenseMatrix) -> Result<EncodedMatrix, CodecError> {
        let n = t.n;
        let ch = t.channels;
        let mut dense: Vec<Vec<f32>> = (0..ch).map(|c| t.channel(c).to_vec()).collect();
        let sparse = split_largest(&mut dense, n, self.sparse_share);
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
        let blocks = match self.blocks {
            Blocks::Bc1 => {
                let planes: Vec<Vec<u8>> = (0..ch).map(image).collect();
                let rgb: Vec<[u8; 3]> = (0..width * width)
                    .map(|p| {
                        let v = |c: usize| planes[c.min(ch - 1)][p];
                        [v(0), v(1), v(2)]
                    })
                    .collect();
                bc::encode_bc1(&rgb, width, width)
            }
            Blocks::Bc4 => (0..ch)
                .flat_map(|c| bc::encode_bc4(&image(c), width, width))
                .collect(),
        };

        let mut payload = Vec::new();
        for v in row_perm.iter().chain(&col_perm).chain(&sparse.row_ptr) {
            payload.extend_from_slice(&v.to_le_bytes());
        }
        for v in &sparse.col_idx {
            payload.extend_from_slice(&v.to_le_bytes());
        }
        for v in &sparse.values {
            payload.extend_from_slice(&v.to_le_bytes());
        }
        payload.extend_from_slice(&blocks);
        let params = Params {
            sparse_share: self.sparse_share,
            passes: self.passes,
            max,
            nnz: sparse.nnz(),
            width,
        };
        Ok(EncodedMatrix {
            codec: self.name().to_string(),
            rows: n as u32,
            cols: n as u32,
            channels: ch as u32,
            params: serde_json::to_value(&params).map_err(|e| corrupt(self.blocks, e))?,
            payload,
        })
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

fn corrupt(blocks: Blocks, reason: impl std::fmt::Display) -> CodecError {
    CodecError::Corrupt {
        codec: name_of(blocks).to_string(),
        reason: reason.to_string(),
    }
}

/// Reads little-endian arrays off the payload, refusing anything past its end.
struct Cursor<'a> {
    bytes: &'a [u8],
    blocks: Blocks,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, len: usize, what: &str) -> Result<&'a [u8], CodecError> {
        if len > self.bytes.len() {
            return Err(corrupt(
                self.blocks,
                format!("payload too short for {what}"),
            ));
        }
        let (head, rest) = self.bytes.split_at(len);
        self.bytes = rest;
        Ok(head)
    }

    fn u32s(&mut self, count: usize, what: &str) -> Result<Vec<u32>, CodecError> {
        let len = count
            .checked_mul(4)
            .ok_or_else(|| corrupt(self.blocks, format!("{what} too long")))?;
        Ok(self
            .take(len, what)?
            .chunks_exact(4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect())
    }
}

/// The thesis codec ready for products, still compressed: blocks, permutations, per-channel
/// dequantisation tables and the sparse part. Products decode one 4-row strip of blocks at a time,
/// as a GPU samples them, so memory stays at the encoded size.
pub struct LogBlockOp {
    n: usize,
    channels: usize,
    blocks: Blocks,
    width: usize,
    row_perm: Vec<u32>,
    col_perm: Vec<u32>,
    /// `lut[c][q]`: the value code `q` stands for in channel `c`.
    lut: Vec<[f32; 256]>,
    sparse: SparsePart,
    /// BC1: one image; BC4: one image per channel.
    raw: Vec<u8>,
}

/// Check and unpack a stored matrix of this family (GPU engines call it for the blocks).
pub fn decode(m: &EncodedMatrix, blocks: Blocks) -> Result<LogBlockOp, CodecError> {
    let n = m.rows as usize;
    let ch = m.channels as usize;
    let p: Params = serde_json::from_value(m.params.clone()).map_err(|e| corrupt(blocks, e))?;
    if p.max.len() != ch || p.max.iter().any(|v| !v.is_finite() || *v < 0.0) {
        return Err(corrupt(blocks, "bad per-channel maxima"));
    }
    if p.width != n.div_ceil(4) * 4 || p.nnz > n.saturating_mul(n) {
        return Err(corrupt(blocks, "bad image size or sparse count"));
    }
    let mut cur = Cursor {
        bytes: &m.payload,
        blocks,
    };
    let row_perm = cur.u32s(n, "row permutation")?;
    let col_perm = cur.u32s(n, "column permutation")?;
    if !is_permutation(&row_perm, n) || !is_permutation(&col_perm, n) {
        return Err(corrupt(blocks, "a stored order is not a permutation"));
    }
    let row_ptr = cur.u32s(n + 1, "sparse row pointers")?;
    let col_idx = cur.u32s(p.nnz, "sparse columns")?;
    let values: Vec<f32> = cur
        .u32s(p.nnz.saturating_mul(ch), "sparse values")?
        .into_iter()
        .map(f32::from_bits)
        .collect();
    let ptr_ok = row_ptr.first() == Some(&0)
        && row_ptr.last().map(|&v| v as usize) == Some(p.nnz)
        && row_ptr.windows(2).all(|w| w[0] <= w[1]);
    if !ptr_ok || col_idx.iter().any(|&c| c as usize >= n) || values.iter().any(|v| !v.is_finite())
    {
        return Err(corrupt(blocks, "malformed sparse part"));
    }
    let sparse = SparsePart {
        n,
        channels: ch,
        row_ptr,
        col_idx,
        values,
    };
    let w = p.width;
    let images = match blocks {
        Blocks::Bc1 => 1,
        Blocks::Bc4 => ch,
    };
    let block_bytes = bc::encoded_len(w, w);
    let raw = cur.take(block_bytes.saturating_mul(images), "blocks")?;
    if !cur.bytes.is_empty() {
        return Err(corrupt(blocks, "trailing bytes after the blocks"));
    }
    let lut = p
        .max
        .iter()
        .map(|&max| {
            let mut t = [0.0f32; 256];
            for (q, v) in t.iter_mut().enumerate() {
                *v = log_dequantize(q as u8, max);
            }
            t
        })
        .collect();
    Ok(LogBlockOp {
        n,
        channels: ch,
        blocks,
        width: w,
        row_perm,
        col_perm,
        lut,
        sparse,
        raw: raw.to_vec(),
    })
}

impl LogBlockOp {
    /// Which block format the image is in.
    pub fn blocks(&self) -> Blocks {
        self.blocks
    }

    /// Side of the (square, padded to a multiple of 4) block image.
    pub fn width(&self) -> usize {
        self.width
    }

    /// `row_perm[k]`: the matrix row stored in image row `k`.
    pub fn row_perm(&self) -> &[u32] {
        &self.row_perm
    }

    /// `col_perm[l]`: the matrix column stored in image column `l`.
    pub fn col_perm(&self) -> &[u32] {
        &self.col_perm
    }

    /// `lut()[c][q]`: the value code `q` stands for in channel `c` (code 0 is exactly zero).
    pub fn lut(&self) -> &[[f32; 256]] {
        &self.lut
    }

    /// The entries kept exactly, in matrix (not image) order; added to the block product.
    pub fn sparse(&self) -> &SparsePart {
        &self.sparse
    }

    /// The raw blocks: BC1, one `width × width` image of 8-byte blocks in row-major block order;
    /// BC4, one such image per channel, one after another.
    pub fn raw_blocks(&self) -> &[u8] {
        &self.raw
    }

    /// Codes of image rows `4·strip .. 4·strip + 4`, per channel: `[channel][row][column]`.
    fn strip(&self, strip: usize) -> Vec<[Vec<u8>; 4]> {
        let w = self.width;
        let blocks_per_row = w / 4;
        let mut out: Vec<[Vec<u8>; 4]> = (0..self.channels)
            .map(|_| std::array::from_fn(|_| vec![0u8; w]))
            .collect();
        let image_bytes = bc::encoded_len(w, w);
        for bx in 0..blocks_per_row {
            let at = (strip * blocks_per_row + bx) * bc::BLOCK_BYTES;
            match self.blocks {
                Blocks::Bc1 => {
                    let mut b = [0u8; 8];
                    b.copy_from_slice(&self.raw[at..at + 8]);
                    let texels = bc::decode_bc1_block(&b);
                    for (t, rgb) in texels.iter().enumerate() {
                        for (c, plane) in out.iter_mut().enumerate() {
                            plane[t / 4][bx * 4 + t % 4] = rgb[c];
                        }
                    }
                }
                Blocks::Bc4 => {
                    for (c, plane) in out.iter_mut().enumerate() {
                        let at = c * image_bytes + at;
                        let mut b = [0u8; 8];
                        b.copy_from_slice(&self.raw[at..at + 8]);
                        let texels = bc::decode_bc4_block(&b);
                        for (t, &v) in texels.iter().enumerate() {
                            plane[t / 4][bx * 4 + t % 4] = v;
                        }
                    }
                }
            }
        }
        out
    }
}

impl MatrixOp for LogBlockOp {
    fn n(&self) -> usize {
        self.n
    }

    fn channels(&self) -> usize {
        self.channels
    }

    fn matvec_batch(&self, x: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<(), CodecError> {
        let n = self.n;
        let batch = batch_len(n, x, out)?;
        // Inputs in image column order, once per batch.
        let xp: Vec<[f32; 3]> = (0..batch)
            .flat_map(|b| self.col_perm.iter().map(move |&j| x[b * n + j as usize]))
            .collect();
        let xp = &xp;
        let strips = self.width / 4;
        let rows: Vec<(usize, Vec<[f32; 3]>)> = (0..strips)
            .into_par_iter()
            .flat_map_iter(|s| {
                let codes = self.strip(s);
                (0..4)
                    .filter(move |r| 4 * s + r < n)
                    .map(move |r| {
                        let i = self.row_perm[4 * s + r] as usize;
                        let per_set = (0..batch)
                            .map(|b| {
                                let xs = &xp[b * n..(b + 1) * n];
                                let mut acc = [0.0f32; 3];
                                for (c, a) in acc.iter_mut().enumerate() {
                                    let cc = c.min(self.channels - 1);
                                    let lut = &self.lut[cc];
                                    *a = codes[cc][r][..n]
                                        .iter()
                                        .zip(xs)
                                        .map(|(&q, xl)| lut[q as usize] * xl[c])
                                        .sum();
                                }
                                acc
                            })
                            .collect();
                        (i, per_set)
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        for (i, per_set) in rows {
            for (b, v) in per_set.into_iter().enumerate() {
                out[b * n + i] = v;
            }
        }
        let sp = &self.sparse;
        for i in 0..n {
            for e in sp.row_ptr[i] as usize..sp.row_ptr[i + 1] as usize {
                let j = sp.col_idx[e] as usize;
                for b in 0..batch {
                    for c in 0..3 {
                        let cc = c.min(self.channels - 1);
                        out[b * n + i][c] += sp.values[cc * sp.nnz() + e] * x[b * n + j][c];
                    }
                }
            }
        }
        Ok(())
    }

    fn to_dense(&self) -> DenseMatrix {
        let n = self.n;
        let ch = self.channels;
        let mut data = vec![0.0f32; n * n * ch];
        for s in 0..self.width / 4 {
            for (c, plane) in self.strip(s).iter().enumerate().take(ch) {
                for (r, codes) in plane.iter().enumerate() {
                    let k = 4 * s + r;
                    if k >= n {
                        break;
                    }
                    let i = self.row_perm[k] as usize;
                    let out = &mut data[c * n * n + i * n..c * n * n + (i + 1) * n];
                    for (l, &j) in self.col_perm.iter().enumerate() {
                        out[j as usize] = self.lut[c][codes[l] as usize];
                    }
                }
            }
        }
        let sp = &self.sparse;
        for c in 0..ch {
            for i in 0..n {
                for e in sp.row_ptr[i] as usize..sp.row_ptr[i + 1] as usize {
                    let j = sp.col_idx[e] as usize;
                    data[c * n * n + i * n + j] += sp.values[c * sp.nnz() + e];
                }
            }
        }
        DenseMatrix {
            n,
            channels: ch,
            data,
        }
    }
}
