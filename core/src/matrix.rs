//! Dense transport matrices in memory, and the codec-tagged encoded form the baked file stores.
//!
//! Later codecs (BC1, BC4, f16, ...) produce an [`EncodedMatrix`] with their own name, parameters and
//! payload; this module owns only the exact `dense-f32` form they are all measured against.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// A square per-channel matrix, row-major per channel: `data[c * n * n + i * n + j]` is entry
/// `(i, j)` of channel `c`. One channel when the transport is colourless.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseMatrix {
    pub n: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl DenseMatrix {
    pub fn zeros(n: usize, channels: usize) -> Self {
        DenseMatrix {
            n,
            channels,
            data: vec![0.0; n * n * channels],
        }
    }

    pub fn channel(&self, c: usize) -> &[f32] {
        &self.data[c * self.n * self.n..(c + 1) * self.n * self.n]
    }

    pub fn channel_mut(&mut self, c: usize) -> &mut [f32] {
        let nn = self.n * self.n;
        &mut self.data[c * nn..(c + 1) * nn]
    }

    pub fn get(&self, c: usize, i: usize, j: usize) -> f32 {
        self.data[c * self.n * self.n + i * self.n + j]
    }

    pub fn bytes(&self) -> usize {
        self.data.len() * std::mem::size_of::<f32>()
    }
}

/// A matrix as stored: which codec made it, its shape and the codec's own parameters and bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct EncodedMatrix {
    /// Codec name, e.g. `dense-f32`. At most 32 bytes of ASCII.
    pub codec: String,
    pub rows: u32,
    pub cols: u32,
    pub channels: u32,
    /// Codec parameters as JSON (e.g. a BC1 codec's sparse share and permutations' seeds).
    pub params: serde_json::Value,
    pub payload: Vec<u8>,
}

#[derive(Debug, Error)]
pub enum MatrixError {
    #[error("unknown matrix codec '{0}'")]
    UnknownCodec(String),
    #[error("matrix payload of codec '{codec}' has {got} bytes, expected {expected}")]
    PayloadSize {
        codec: String,
        got: usize,
        expected: usize,
    },
    #[error("matrix shape {rows}x{cols}x{channels} is not a square 1- or 3-channel matrix")]
    Shape { rows: u32, cols: u32, channels: u32 },
    #[error("matrix entry {index} is not finite")]
    NotFinite { index: usize },
}

pub const DENSE_F32: &str = "dense-f32";

/// Codec parameters recorded for `dense-f32` (none).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct DenseF32Params {}

impl EncodedMatrix {
    /// A parameterless encoding of `m`'s shape: the dense codecs' header.
    pub fn dense(codec: &str, m: &DenseMatrix, payload: Vec<u8>) -> EncodedMatrix {
        EncodedMatrix {
            codec: codec.to_string(),
            rows: m.n as u32,
            cols: m.n as u32,
            channels: m.channels as u32,
            params: serde_json::json!({}),
            payload,
        }
    }

    /// The exact codec: little-endian f32, channel-major then row-major.
    pub fn encode_dense_f32(m: &DenseMatrix) -> EncodedMatrix {
        let mut payload = Vec::with_capacity(m.bytes());
        for v in &m.data {
            payload.extend_from_slice(&v.to_le_bytes());
        }
        EncodedMatrix::dense(DENSE_F32, m, payload)
    }

    /// Bytes the dense matrix would take; checked arithmetic so a hostile header cannot overflow.
    pub fn dense_len(&self) -> Option<usize> {
        (self.rows as usize)
            .checked_mul(self.cols as usize)?
            .checked_mul(self.channels as usize)?
            .checked_mul(4)
    }

    pub fn validate_shape(&self) -> Result<(), MatrixError> {
        if self.rows != self.cols || !(self.channels == 1 || self.channels == 3) {
            return Err(MatrixError::Shape {
                rows: self.rows,
                cols: self.cols,
                channels: self.channels,
            });
        }
        Ok(())
    }

    /// Decode to the exact dense form. Only `dense-f32` is known so far.
    pub fn decode(&self) -> Result<DenseMatrix, MatrixError> {
        self.validate_shape()?;
        if self.codec != DENSE_F32 {
            return Err(MatrixError::UnknownCodec(self.codec.clone()));
        }
        let expected = self.dense_len().unwrap_or(usize::MAX);
        if self.payload.len() != expected {
            return Err(MatrixError::PayloadSize {
                codec: self.codec.clone(),
                got: self.payload.len(),
                expected,
            });
        }
        let data: Vec<f32> = self
            .payload
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        if let Some(index) = data.iter().position(|v| !v.is_finite()) {
            return Err(MatrixError::NotFinite { index });
        }
        Ok(DenseMatrix {
            n: self.rows as usize,
            channels: self.channels as usize,
            data,
        })
    }
}
