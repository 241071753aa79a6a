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
//!
//! The encoder is [`encode`] (quantise, reorder, block-compress, and for `bc1-resid` the worst
//! residuals into the sparse part); the CPU product over the still-compressed payload is
//! [`product`], the twin of the GPU's (`bounce-engine`'s `gpu/logblock.rs`). What both read of
//! the payload (its parameters, the code tables, the image sizes) is here.

mod encode;
mod product;

use serde::{Deserialize, Serialize};

use super::CodecError;
use super::bc;
use super::transform::log_dequantize;

pub use product::{LogBlockOp, decode};

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
    /// The BC1 encoder's endpoint search (not stored: a decoder reads either).
    pub fit: bc::Fit,
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
            fit: bc::Fit::Cluster,
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
            fit: bc::Fit::Cluster,
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
            fit: bc::Fit::Cluster,
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
            fit: bc::Fit::Cluster,
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

/// Value of every code in a channel whose maximum is `max`.
fn lut(max: f32) -> [f32; 256] {
    let mut t = [0.0f32; 256];
    for (q, v) in t.iter_mut().enumerate() {
        *v = log_dequantize(q as u8, max);
    }
    t
}

fn corrupt(blocks: Blocks, reason: impl std::fmt::Display) -> CodecError {
    CodecError::Corrupt {
        codec: name_of(blocks).to_string(),
        reason: reason.to_string(),
    }
}
