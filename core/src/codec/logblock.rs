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

use super::lanes::{Lanes, dots, served};
use super::transform::{
    SparsePart, gather_positions, greedy_chain, is_permutation, log_dequantize, log_quantize,
    select_largest, split_largest,
};
use super::{Codec, CodecError, MatrixOp, batch_len};
use crate::matrix::{DenseMatrix, EncodedMatrix};

/// Which block format holds the quantised image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Blocks {
    Bc1,
    Bc4,
    /// The 8-bit codes as they are, one byte per entry and channel: no block compression. The
    /// reference that shows how much of the thesis codec's error the blocks add.
    Raw8,
}

/// The thesis' codec family with its knobs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogBlock {
    /// The codec's name, stored in the file; the parameters say the rest.
    pub name: &'static str,
    pub blocks: Blocks,
    /// Share of entry positions kept exactly (thesis: 4%).
    pub sparse_share: f64,
    /// Reorder passes; a pass chains the rows, then the columns (thesis: up to 2).
    pub passes: u32,
    /// Fraction of the sparse positions chosen by the blocks' own error rather than by size
    /// (thesis: 0). Those positions are picked after a first encoding, where the decoded blocks
    /// are furthest from the exact matrix; then they are zeroed and the blocks encoded again.
    pub residual: f64,
    /// How the sparse part is stored.
    pub store: SparseStore,
}

/// Storage of the sparse part's column indices and values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SparseStore {
    /// u32 columns, f32 values (thesis): 4 + 4·channels bytes a position.
    #[default]
    U32f32,
    /// u16 columns, f16 values: 2 + 2·channels bytes a position. Each channel's values are
    /// divided by a scale that maps its largest magnitude to 2^14 before rounding to f16, so they
    /// sit in f16's normal range (11 significant bits) from that largest down by a factor of
    /// about 2.7·10^8, and cannot overflow. Needs `n ≤ 65,536`; a larger matrix falls back to
    /// `U32f32` (recorded in the parameters).
    U16f16,
}

/// The thesis codec's name.
pub const BC1: &str = "bc1";
/// One BC4 image per channel instead of one BC1 image.
pub const BC4: &str = "bc4";
/// The thesis codec's 8-bit log codes without block compression.
pub const LOG8: &str = "log8";
/// BC1 blocks with residual-chosen corrections in half precision.
pub const BC1_RESID: &str = "bc1-resid";

impl LogBlock {
    /// The thesis codec (section 4.2): the largest 4% kept exactly, two reorder passes, BC1.
    pub const fn bc1() -> Self {
        LogBlock {
            name: BC1,
            blocks: Blocks::Bc1,
            sparse_share: 0.04,
            passes: 2,
            residual: 0.0,
            store: SparseStore::U32f32,
        }
    }

    /// The thesis codec with each channel in its own BC4 image (3× the block bytes of BC1,
    /// 8-bit endpoints instead of 5:6:5).
    pub const fn bc4() -> Self {
        LogBlock {
            name: BC4,
            blocks: Blocks::Bc4,
            sparse_share: 0.04,
            passes: 2,
            residual: 0.0,
            store: SparseStore::U32f32,
        }
    }

    /// The thesis codec's sparse part and 8-bit log codes, stored without block compression
    /// and without reordering (which only serves the blocks).
    pub const fn log8() -> Self {
        LogBlock {
            name: LOG8,
            blocks: Blocks::Raw8,
            sparse_share: 0.04,
            passes: 0,
            residual: 0.0,
            store: SparseStore::U32f32,
        }
    }

    /// Beyond the thesis: the whole matrix log-quantised into BC1 blocks, then the 8% of
    /// positions where the decoded blocks are furthest from the exact matrix kept exactly (zeroed
    /// in the blocks, which are encoded again), stored as scaled f16 with u16 columns (8 bytes a
    /// position instead of 16). At the thesis codec's bytes this keeps twice the positions, and
    /// chooses them by the error the blocks actually leave rather than by size.
    pub const fn bc1_resid() -> Self {
        LogBlock {
            name: BC1_RESID,
            blocks: Blocks::Bc1,
            sparse_share: 0.08,
            passes: 2,
            residual: 1.0,
            store: SparseStore::U16f16,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Params {
    sparse_share: f64,
    passes: u32,
    #[serde(default)]
    residual: f64,
    #[serde(default)]
    store: SparseStore,
    /// `U16f16`: per channel, the factor the stored f16 values are multiplied by.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    sparse_scale: Vec<f32>,
    max: Vec<f32>,
    nnz: usize,
    width: usize,
}

fn name_of(blocks: Blocks) -> &'static str {
    match blocks {
        Blocks::Bc1 => BC1,
        Blocks::Bc4 => BC4,
        Blocks::Raw8 => LOG8,
    }
}

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
        let blocks = encode_blocks(self.blocks, &codes, n, width, &row_perm, &col_perm);
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
            let blocks = encode_blocks(self.blocks, &codes, n, width, &op.row_perm, &op.col_perm);
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

/// What the largest sparse magnitude of a channel is scaled to before rounding to f16: a power of
/// two well below f16's maximum (65504), so scaling is exact in the exponent and rounding up
/// cannot overflow.
const F16_TOP: f32 = 16384.0;

/// Bytes of one `w × w` image (one channel for BC4 and raw codes, all three for BC1).
fn image_bytes(blocks: Blocks, w: usize) -> usize {
    match blocks {
        Blocks::Bc1 | Blocks::Bc4 => bc::encoded_len(w, w),
        Blocks::Raw8 => w * w,
    }
}

/// Strips (4 image rows each) a larger-batch product decodes and multiplies at a time: 64 rows,
/// a few MB of f32 per panel at 4,000 patches, so panels spread over the threads and stay in cache.
const PANEL_STRIPS: usize = 16;

/// Value of every code in a channel whose maximum is `max`.
fn lut(max: f32) -> [f32; 256] {
    let mut t = [0.0f32; 256];
    for (q, v) in t.iter_mut().enumerate() {
        *v = log_dequantize(q as u8, max);
    }
    t
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
    blocks: Blocks,
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
    match blocks {
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
    row_perm: Vec<u32>,
    col_perm: Vec<u32>,
    /// `lut[c][q]`: the value code `q` stands for in channel `c`.
    lut: Vec<[f32; 256]>,
    sparse: SparsePart,
    /// BC1: one image; BC4: one image per channel.
    raw: Vec<u8>,
    /// Per image and block (image-major, then row-major blocks): does the block decode to all
    /// zeros? Products skip those. Empty for raw codes.
    zero: Vec<bool>,
}

impl LogBlockOp {
    #[allow(clippy::too_many_arguments)]
    fn assemble(
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
        if batch >= super::dense::GEMM_FROM {
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
