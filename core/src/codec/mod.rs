//! Transport-matrix codecs behind one interface: encode an exact `T` into an [`EncodedMatrix`]
//! (what the baked file stores), and decode that into a [`MatrixOp`] that multiplies a batch of
//! light vectors on the CPU. GPU engines read the same encoded bytes (issue 5); this module owns
//! only the CPU side and the exact building blocks.
//!
//! Vectors are RGB per patch: a batch of `b` light configurations is `b × n` `[f32; 3]`, light
//! set `k` at `x[k * n..(k + 1) * n]`. A one-channel (colourless) matrix applies the same matrix to
//! all three colours.

pub mod bc;
pub mod dense;
pub mod error;
pub mod lanes;
pub mod logblock;
pub mod transform;

use thiserror::Error;

use crate::matrix::{DenseMatrix, EncodedMatrix, MatrixError};

#[derive(Debug, Error)]
pub enum CodecError {
    #[error("unknown codec '{name}' (known: {known})")]
    Unknown { name: String, known: String },
    #[error(transparent)]
    Matrix(#[from] MatrixError),
    #[error("codec '{codec}': {reason}")]
    Corrupt { codec: String, reason: String },
    #[error("batch of {got} values is not a multiple of the {n} patches")]
    Batch { got: usize, n: usize },
}

/// A matrix decoded for products.
pub trait MatrixOp: Send + Sync {
    fn n(&self) -> usize;
    fn channels(&self) -> usize;
    /// `out[k·n + i][c] = Σ_j M_c(i, j) · x[k·n + j][c]` for every light set `k` of the batch.
    fn matvec_batch(&self, x: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<(), CodecError>;
    /// The decoded matrix in patch order, for error measurement.
    fn to_dense(&self) -> DenseMatrix;
}

/// An encoder of exact transport matrices.
pub trait Codec: Send + Sync {
    /// The name stored in the file and given to `--codec`.
    fn name(&self) -> &'static str;
    fn encode(&self, t: &DenseMatrix) -> Result<EncodedMatrix, CodecError>;
}

/// Every codec this build knows, in the order benchmarks list them.
pub fn all() -> Vec<Box<dyn Codec>> {
    vec![
        Box::new(dense::DenseF32),
        Box::new(dense::DenseF16),
        Box::new(logblock::LogBlock::bc1()),
        Box::new(logblock::LogBlock::bc4()),
        Box::new(logblock::LogBlock::log8()),
        Box::new(logblock::LogBlock::bc1_resid()),
    ]
}

pub fn by_name(name: &str) -> Result<Box<dyn Codec>, CodecError> {
    all()
        .into_iter()
        .find(|c| c.name() == name)
        .ok_or_else(|| unknown(name))
}

fn unknown(name: &str) -> CodecError {
    CodecError::Unknown {
        name: name.to_string(),
        known: all()
            .iter()
            .map(|c| c.name())
            .collect::<Vec<_>>()
            .join(", "),
    }
}

/// A codec by name with the knobs a bake gives it: a sparse share replaces the codec's own
/// default where the codec has one.
pub fn configured(name: &str, sparse_share: Option<f64>) -> Result<Box<dyn Codec>, CodecError> {
    let with_share = |base: logblock::LogBlock| -> Box<dyn Codec> {
        Box::new(logblock::LogBlock {
            sparse_share: sparse_share.unwrap_or(base.sparse_share),
            ..base
        })
    };
    match name {
        logblock::BC1 => Ok(with_share(logblock::LogBlock::bc1())),
        logblock::BC4 => Ok(with_share(logblock::LogBlock::bc4())),
        logblock::LOG8 => Ok(with_share(logblock::LogBlock::log8())),
        logblock::BC1_RESID => Ok(with_share(logblock::LogBlock::bc1_resid())),
        other => by_name(other),
    }
}

/// What [`choose`] picked and why.
#[derive(Debug, Clone)]
pub struct Choice {
    pub encoded: EncodedMatrix,
    /// `E_ind` relative L2 error of `encoded` against the exact matrix.
    pub rel_l2: f64,
    /// Every candidate encoded: name, bytes, error (those that could not be smaller are left
    /// out).
    pub candidates: Vec<(String, usize, f64)>,
}

/// The codecs `--codec auto` weighs, each with the fewest payload bytes it can take for an
/// `n × n` matrix of `channels` channels (its blocks or values alone, before any exact entries
/// or headers), in order of that bound. `bc1` is not among them: `bc1-resid` has its blocks
/// and is more accurate at its bytes (`core/tests/it/codec.rs`), and encoding both cost the
/// demo's bake 15 s of its 57.
pub fn auto_candidates(n: usize, channels: usize) -> [(&'static str, usize); 4] {
    let blocks = (n / 4) * (n / 4) * 8;
    [
        // One BC1 block holds sixteen entries of all three colours.
        (logblock::BC1_RESID, blocks),
        (logblock::BC4, blocks * channels),
        (logblock::LOG8, n * n * channels),
        (dense::DENSE_F16, n * n * channels * 2),
    ]
}

/// The smallest encoding among [`auto_candidates`] whose `E_ind` error over `b0` stays within
/// `max_error`; the exact `dense-f32` when none does. A candidate whose fewest bytes are no
/// fewer than a fitting one's payload cannot be smaller, and is not encoded.
pub fn choose(
    exact: &DenseMatrix,
    b0: &[[f32; 3]],
    max_error: f64,
    sparse_share: Option<f64>,
) -> Result<Choice, CodecError> {
    let exact_op = dense::DenseOp::from(exact.clone());
    let mut best: Option<(EncodedMatrix, f64)> = None;
    let mut candidates = Vec::new();
    for (name, fewest) in auto_candidates(exact.n, exact.channels) {
        if best
            .as_ref()
            .is_some_and(|(b, _)| fewest >= b.payload.len())
        {
            continue;
        }
        let codec = configured(name, sparse_share)?;
        let enc = codec.encode(exact)?;
        let op = decode(&enc)?;
        let err = error::irradiance_errors(&exact_op, op.as_ref(), b0)?.rel_l2;
        let bytes = enc.payload.len();
        candidates.push((enc.codec.clone(), bytes, err));
        let better = best.as_ref().is_none_or(|(b, _)| bytes < b.payload.len());
        if err <= max_error && better {
            best = Some((enc, err));
        }
    }
    let (encoded, rel_l2) = match best {
        Some(b) => b,
        None => (EncodedMatrix::encode_dense_f32(exact), 0.0),
    };
    Ok(Choice {
        encoded,
        rel_l2,
        candidates,
    })
}

/// Decode a stored matrix for products, whichever codec wrote it.
pub fn decode(m: &EncodedMatrix) -> Result<Box<dyn MatrixOp>, CodecError> {
    m.validate_shape()?;
    match m.codec.as_str() {
        crate::matrix::DENSE_F32 => Ok(Box::new(dense::DenseOp::from(m.decode()?))),
        dense::DENSE_F16 => Ok(Box::new(dense::decode_f16(m)?)),
        logblock::BC1 | logblock::BC1_RESID => {
            Ok(Box::new(logblock::decode(m, logblock::Blocks::Bc1)?))
        }
        logblock::BC4 => Ok(Box::new(logblock::decode(m, logblock::Blocks::Bc4)?)),
        logblock::LOG8 => Ok(Box::new(logblock::decode(m, logblock::Blocks::Raw8)?)),
        other => Err(unknown(other)),
    }
}

/// Check a batch's length against the matrix.
pub(crate) fn batch_len(n: usize, x: &[[f32; 3]], out: &[[f32; 3]]) -> Result<usize, CodecError> {
    if n == 0 || !x.len().is_multiple_of(n) || out.len() != x.len() {
        return Err(CodecError::Batch { got: x.len(), n });
    }
    Ok(x.len() / n)
}
