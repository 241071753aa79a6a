//! The CPU product over the still-compressed payload: one 4-row strip of blocks decoded at a
//! time, as a GPU samples them, multiplied with a batch of light sets. The twin of the GPU's
//! product (`bounce-engine`'s `gpu/logblock.rs`).

use rayon::prelude::*;

use super::{Blocks, Params, SparseStore, corrupt, image_bytes, lut};
use crate::codec::bc;
use crate::codec::lanes::{Lanes, dots, served};
use crate::codec::transform::{SparsePart, is_permutation};
use crate::codec::{CodecError, MatrixOp, batch_len};
use crate::matrix::{DenseMatrix, EncodedMatrix};

/// Strips (4 image rows each) a larger-batch product decodes and multiplies at a time: 64 rows,
/// a few MB of f32 per panel at 4,000 patches, so panels spread over the threads and stay in cache.
const PANEL_STRIPS: usize = 16;

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

    fn u16s(&mut self, count: usize, what: &str) -> Result<Vec<u16>, CodecError> {
        let len = count
            .checked_mul(2)
            .ok_or_else(|| corrupt(self.blocks, format!("{what} too long")))?;
        Ok(self
            .take(len, what)?
            .chunks_exact(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .collect())
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
    pub(super) row_perm: Vec<u32>,
    pub(super) col_perm: Vec<u32>,
    /// `lut[c][q]`: the value code `q` stands for in channel `c`.
    pub(super) lut: Vec<[f32; 256]>,
    pub(super) sparse: SparsePart,
    /// BC1: one image; BC4: one image per channel.
    pub(super) raw: Vec<u8>,
    /// Per image and block (image-major, then row-major blocks): does the block decode to all
    /// zeros? Products skip those. Empty for raw codes.
    zero: Vec<bool>,
}

impl LogBlockOp {
    #[allow(clippy::too_many_arguments)]
    pub(super) fn assemble(
        n: usize,
        channels: usize,
        blocks: Blocks,
        width: usize,
        row_perm: Vec<u32>,
        col_perm: Vec<u32>,
        lut: Vec<[f32; 256]>,
        sparse: SparsePart,
        raw: Vec<u8>,
    ) -> LogBlockOp {
        let zero = match blocks {
            Blocks::Raw8 => Vec::new(),
            Blocks::Bc1 => raw
                .par_chunks_exact(bc::BLOCK_BYTES)
                .map(|b| {
                    let mut block = [0u8; 8];
                    block.copy_from_slice(b);
                    bc::decode_bc1_block(&block).iter().all(|t| *t == [0; 3])
                })
                .collect(),
            Blocks::Bc4 => raw
                .par_chunks_exact(bc::BLOCK_BYTES)
                .map(|b| {
                    let mut block = [0u8; 8];
                    block.copy_from_slice(b);
                    bc::decode_bc4_block(&block).iter().all(|t| *t == 0)
                })
                .collect(),
        };
        LogBlockOp {
            n,
            channels,
            blocks,
            width,
            row_perm,
            col_perm,
            lut,
            sparse,
            raw,
            zero,
        }
    }
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
    let (col_idx, values): (Vec<u32>, Vec<f32>) = match p.store {
        SparseStore::U32f32 => (
            cur.u32s(p.nnz, "sparse columns")?,
            cur.u32s(p.nnz.saturating_mul(ch), "sparse values")?
                .into_iter()
                .map(f32::from_bits)
                .collect(),
        ),
        SparseStore::U16f16 => {
            if p.sparse_scale.len() != ch
                || p.sparse_scale.iter().any(|s| !(s.is_finite() && *s > 0.0))
            {
                return Err(corrupt(blocks, "bad sparse scales"));
            }
            let cols = cur.u16s(p.nnz, "sparse columns")?;
            let raw = cur.u16s(p.nnz.saturating_mul(ch), "sparse values")?;
            let values = raw
                .iter()
                .enumerate()
                .map(|(k, &b)| half::f16::from_bits(b).to_f32() * p.sparse_scale[k / p.nnz.max(1)])
                .collect();
            (cols.into_iter().map(u32::from).collect(), values)
        }
    };
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
        Blocks::Bc4 | Blocks::Raw8 => ch,
    };
    let block_bytes = image_bytes(blocks, w);
    let raw = cur.take(block_bytes.saturating_mul(images), "blocks")?;
    if !cur.bytes.is_empty() {
        return Err(corrupt(blocks, "trailing bytes after the blocks"));
    }
    let lut = p.max.iter().map(|&max| lut(max)).collect();
    Ok(LogBlockOp::assemble(
        n,
        ch,
        blocks,
        w,
        row_perm,
        col_perm,
        lut,
        sparse,
        raw.to_vec(),
    ))
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

    /// The product for larger batches: panels of [`PANEL_STRIPS`] strips decoded to f32 and
    /// multiplied by the whole batch with faer's blocked matrix product, panels in parallel. Per
    /// value decoded, the row kernel does one multiply-add per light set and colour from memory;
    /// the matrix product keeps them in registers, which is what batches of 8 and more need.
    fn matvec_panels(&self, x: &[[f32; 3]], out: &mut [[f32; 3]], batch: usize) {
        use faer::{Accum, MatMut, MatRef, Par};
        let (n, w, ch) = (self.n, self.width, self.channels);
        // Per stored channel: the (light set, colour) columns it serves, and the light in image
        // column order, `xs[c][l·m + col]`.
        let serves = served(ch, batch);
        let xs: Vec<Vec<f32>> = serves
            .iter()
            .map(|sv| {
                let m = sv.len();
                let mut v = vec![0.0f32; w * m];
                for (l, &j) in self.col_perm.iter().enumerate() {
                    for (col, &(k, cc)) in sv.iter().enumerate() {
                        v[l * m + col] = x[k * n + j as usize][cc];
                    }
                }
                v
            })
            .collect();
        let strips = w / 4;
        let panels: Vec<(usize, Vec<Vec<f32>>)> = (0..strips.div_ceil(PANEL_STRIPS))
            .into_par_iter()
            .map(|p| {
                let s0 = p * PANEL_STRIPS;
                let s1 = (s0 + PANEL_STRIPS).min(strips);
                let rows = 4 * (s1 - s0);
                let mut vals = vec![vec![0.0f32; rows * w]; ch];
                for s in s0..s1 {
                    let codes = self.strip(s, None);
                    for (c, plane) in codes.iter().enumerate() {
                        let lut = &self.lut[c];
                        for (r, row) in plane.iter().enumerate() {
                            let at = (4 * (s - s0) + r) * w;
                            for (v, &q) in vals[c][at..at + w].iter_mut().zip(row) {
                                *v = lut[q as usize];
                            }
                        }
                    }
                }
                let ys: Vec<Vec<f32>> = (0..ch)
                    .map(|c| {
                        let m = serves[c].len();
                        let mut y = vec![0.0f32; rows * m];
                        faer::linalg::matmul::matmul(
                            MatMut::from_row_major_slice_mut(&mut y, rows, m),
                            Accum::Replace,
                            MatRef::from_row_major_slice(&vals[c], rows, w),
                            MatRef::from_row_major_slice(&xs[c], w, m),
                            1.0f32,
                            Par::Seq,
                        );
                        y
                    })
                    .collect();
                (s0, ys)
            })
            .collect();
        for (s0, ys) in panels {
            for (c, y) in ys.iter().enumerate() {
                let m = serves[c].len();
                for (r, yr) in y.chunks_exact(m).enumerate() {
                    let k_img = 4 * s0 + r;
                    if k_img >= n {
                        break;
                    }
                    let i = self.row_perm[k_img] as usize;
                    for (&(k, cc), &v) in serves[c].iter().zip(yr) {
                        out[k * n + i][cc] = v;
                    }
                }
            }
        }
        let sp = &self.sparse;
        out.par_chunks_mut(n).enumerate().for_each(|(k, o)| {
            for (i, oi) in o.iter_mut().enumerate() {
                for e in sp.row_ptr[i] as usize..sp.row_ptr[i + 1] as usize {
                    let j = sp.col_idx[e] as usize;
                    for (c, v) in oi.iter_mut().enumerate() {
                        let cc = c.min(ch - 1);
                        *v += sp.values[cc * sp.nnz() + e] * x[k * n + j][c];
                    }
                }
            }
        });
    }

    /// Codes of image rows `4·strip .. 4·strip + 4`, per channel: `[channel][row][column]`.
    /// Blocks that decode to zeros, and block columns `lit` marks dark, are left at code 0.
    fn strip(&self, strip: usize, lit: Option<&[bool]>) -> Vec<[Vec<u8>; 4]> {
        let w = self.width;
        let blocks_per_row = w / 4;
        let mut out: Vec<[Vec<u8>; 4]> = (0..self.channels)
            .map(|_| std::array::from_fn(|_| vec![0u8; w]))
            .collect();
        let image_bytes = image_bytes(self.blocks, w);
        if self.blocks == Blocks::Raw8 {
            for (c, plane) in out.iter_mut().enumerate() {
                for (r, row) in plane.iter_mut().enumerate() {
                    let at = c * image_bytes + (4 * strip + r) * w;
                    row.copy_from_slice(&self.raw[at..at + w]);
                }
            }
            return out;
        }
        let per_image = blocks_per_row * blocks_per_row;
        for bx in 0..blocks_per_row {
            if lit.is_some_and(|l| !l[bx]) {
                continue;
            }
            let block = strip * blocks_per_row + bx;
            let at = block * bc::BLOCK_BYTES;
            match self.blocks {
                Blocks::Bc1 if self.zero[block] => {}
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
                // Copied above, before the block loop.
                Blocks::Raw8 => {}
                Blocks::Bc4 => {
                    for (c, plane) in out.iter_mut().enumerate() {
                        if self.zero[c * per_image + block] {
                            continue;
                        }
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
        if batch >= crate::codec::dense::GEMM_FROM {
            self.matvec_panels(x, out, batch);
            return Ok(());
        }
        // Inputs in image column order, dark block columns dropped, once per batch.
        let lanes = Lanes::new(x, n, Some(&self.col_perm), self.width);
        let lit: Option<Vec<bool>> = lanes.cols.as_ref().map(|cols| {
            let mut lit = vec![false; self.width / 4];
            for &l in cols {
                lit[l as usize / 4] = true;
            }
            lit
        });
        let (lanes, lit) = (&lanes, lit.as_deref());
        let served = served(self.channels, batch);
        let served = &served;
        let sp = &self.sparse;
        let rows: Vec<(usize, Vec<[f32; 3]>)> = (0..self.width / 4)
            .into_par_iter()
            .flat_map_iter(|s| {
                let codes = (!lanes.dark()).then(|| self.strip(s, lit));
                let mut values = vec![vec![0.0f32; lanes.len]; self.channels];
                (0..4)
                    .filter(move |r| 4 * s + r < n)
                    .map(move |r| {
                        let i = self.row_perm[4 * s + r] as usize;
                        if let Some(codes) = &codes {
                            // Decoded once per row, used by every light set of the batch.
                            for (c, v) in values.iter_mut().enumerate() {
                                let (lut, row) = (&self.lut[c], &codes[c][r]);
                                match &lanes.cols {
                                    None => v
                                        .iter_mut()
                                        .zip(row)
                                        .for_each(|(v, &q)| *v = lut[q as usize]),
                                    Some(cols) => v
                                        .iter_mut()
                                        .zip(cols)
                                        .for_each(|(v, &l)| *v = lut[row[l as usize] as usize]),
                                }
                            }
                        }
                        let mut per_set = vec![[0.0f32; 3]; batch];
                        if codes.is_some() {
                            let mut sums = vec![0.0f32; 3 * batch];
                            for (v, serves) in values.iter().zip(served) {
                                let ls: Vec<&[f32]> =
                                    serves.iter().map(|&(k, cc)| lanes.lane(k, cc)).collect();
                                dots(v, None, &ls, &mut sums[..ls.len()]);
                                for (&(k, cc), &s) in serves.iter().zip(&sums) {
                                    per_set[k][cc] = s;
                                }
                            }
                        }
                        for (k, acc) in per_set.iter_mut().enumerate() {
                            for (c, a) in acc.iter_mut().enumerate() {
                                let cc = c.min(self.channels - 1);
                                for e in sp.row_ptr[i] as usize..sp.row_ptr[i + 1] as usize {
                                    let j = sp.col_idx[e] as usize;
                                    *a += sp.values[cc * sp.nnz() + e] * x[k * n + j][c];
                                }
                            }
                        }
                        (i, per_set)
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        for (i, per_set) in rows {
            for (k, v) in per_set.into_iter().enumerate() {
                out[k * n + i] = v;
            }
        }
        Ok(())
    }

    fn to_dense(&self) -> DenseMatrix {
        let n = self.n;
        let ch = self.channels;
        let mut data = vec![0.0f32; n * n * ch];
        for s in 0..self.width / 4 {
            for (c, plane) in self.strip(s, None).iter().enumerate().take(ch) {
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
