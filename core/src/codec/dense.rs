//! Dense codecs: `dense-f32` (exact, the reference every other codec is measured against) and
//! `dense-f16` (half the bytes; IEEE half keeps about 3 significant digits over a wide range, and
//! transport entries below its subnormal range round to zero).
//!
//! [`DenseOp`] is also the decoded form other codecs reuse: a dense f32 matrix per channel.

use half::f16;
use rayon::prelude::*;

use super::lanes::{Entry, Lanes, dots, served};
use super::{Codec, CodecError, MatrixOp, batch_len};
use crate::matrix::{DenseMatrix, EncodedMatrix};

pub const DENSE_F16: &str = "dense-f16";

/// The exact codec.
pub struct DenseF32;

impl Codec for DenseF32 {
    fn name(&self) -> &'static str {
        crate::matrix::DENSE_F32
    }
    fn encode(&self, t: &DenseMatrix) -> Result<EncodedMatrix, CodecError> {
        Ok(EncodedMatrix::encode_dense_f32(t))
    }
}

/// IEEE half precision, little-endian, same order as `dense-f32`.
pub struct DenseF16;

impl Codec for DenseF16 {
    fn name(&self) -> &'static str {
        DENSE_F16
    }
    fn encode(&self, t: &DenseMatrix) -> Result<EncodedMatrix, CodecError> {
        let mut payload = Vec::with_capacity(t.data.len() * 2);
        for &v in &t.data {
            payload.extend_from_slice(&f16::from_f32(v).to_le_bytes());
        }
        Ok(EncodedMatrix::dense(DENSE_F16, t, payload))
    }
}

pub(super) fn decode_f16(m: &EncodedMatrix) -> Result<Dense<f16>, CodecError> {
    let n = m.rows as usize;
    let channels = m.channels as usize;
    let expected = n
        .checked_mul(n)
        .and_then(|v| v.checked_mul(channels))
        .and_then(|v| v.checked_mul(2));
    if expected != Some(m.payload.len()) {
        return Err(CodecError::Corrupt {
            codec: DENSE_F16.to_string(),
            reason: format!(
                "payload has {} bytes for a {n}×{n}×{channels} half matrix",
                m.payload.len()
            ),
        });
    }
    let data: Vec<f16> = m
        .payload
        .chunks_exact(2)
        .map(|b| f16::from_le_bytes([b[0], b[1]]))
        .collect();
    if data.iter().any(|v| !v.is_finite()) {
        return Err(CodecError::Corrupt {
            codec: DENSE_F16.to_string(),
            reason: "non-finite entry".to_string(),
        });
    }
    Ok(Dense { n, channels, data })
}

/// From this many light sets on, a CPU product is a matrix–matrix product by faer's blocked
/// kernels (dense f32 directly; the block codecs on panels decoded to f32); below, the row
/// kernel, which also skips dark columns. Either way a light set's result is the same to f32
/// rounding, but only the row kernel keeps its bits whatever else is in the batch.
pub const GEMM_FROM: usize = 8;

/// A dense matrix ready for products: `data[c·n·n + i·n + j]`, as [`DenseMatrix`].
pub struct Dense<T> {
    pub n: usize,
    pub channels: usize,
    pub data: Vec<T>,
}

/// The exact decoded form.
pub type DenseOp = Dense<f32>;

impl From<DenseMatrix> for DenseOp {
    fn from(m: DenseMatrix) -> Self {
        Dense {
            n: m.n,
            channels: m.channels,
            data: m.data,
        }
    }
}

impl<T: Entry> Dense<T> {
    fn row(&self, c: usize, i: usize) -> &[T] {
        let n = self.n;
        &self.data[c * n * n + i * n..c * n * n + (i + 1) * n]
    }
}

impl<T: Entry> MatrixOp for Dense<T> {
    fn n(&self) -> usize {
        self.n
    }

    fn channels(&self) -> usize {
        self.channels
    }

    fn matvec_batch(&self, x: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<(), CodecError> {
        let n = self.n;
        let batch = batch_len(n, x, out)?;
        if batch >= GEMM_FROM
            && let Some(data) = T::as_f32(&self.data)
        {
            gemm(data, n, self.channels, batch, x, out);
            return Ok(());
        }
        let m = self;
        let lanes = Lanes::new(x, n, None, n);
        if lanes.dark() {
            out.fill([0.0; 3]);
            return Ok(());
        }
        let lanes = &lanes;
        let served = served(m.channels, batch);
        let served = &served;
        // Rows in parallel; every light set of the batch shares the row's one pass over memory,
        // which is what makes batching pay.
        let rows: Vec<[f32; 3]> = (0..n)
            .into_par_iter()
            .flat_map_iter(|i| {
                let mut acc = vec![[0.0f32; 3]; batch];
                let mut sums = vec![0.0f32; 3 * batch];
                let mut wide = Vec::new();
                for (c, serves) in served.iter().enumerate() {
                    let ls: Vec<&[f32]> = serves.iter().map(|&(k, cc)| lanes.lane(k, cc)).collect();
                    // Rows not stored as f32 are widened once and used by the whole batch.
                    let row: &[f32] = match T::as_f32(m.row(c, i)) {
                        Some(row) => row,
                        None => {
                            wide.resize(n, 0.0);
                            T::widen(m.row(c, i), &mut wide);
                            &wide
                        }
                    };
                    dots(row, lanes.cols.as_deref(), &ls, &mut sums[..ls.len()]);
                    for (&(k, cc), &v) in serves.iter().zip(&sums) {
                        acc[k][cc] = v;
                    }
                }
                acc
            })
            .collect();
        for (i, per_set) in rows.chunks_exact(batch).enumerate() {
            for (k, v) in per_set.iter().enumerate() {
                out[k * n + i] = *v;
            }
        }
        Ok(())
    }

    fn to_dense(&self) -> DenseMatrix {
        DenseMatrix {
            n: self.n,
            channels: self.channels,
            data: self.data.iter().map(|v| v.value()).collect(),
        }
    }
}

/// `out = T · x` as one `n × m` matrix product per stored channel (faer, all threads), `m` the
/// (light set, colour) pairs the channel serves: a one-channel matrix serves all three colours of
/// every set in one product.
fn gemm(t: &[f32], n: usize, channels: usize, batch: usize, x: &[[f32; 3]], out: &mut [[f32; 3]]) {
    use faer::{Accum, MatMut, MatRef, Par};
    for (tc, serves) in served(channels, batch).iter().enumerate() {
        let m = serves.len();
        let mut xs = vec![0.0f32; n * m];
        for (col, &(k, c)) in serves.iter().enumerate() {
            for j in 0..n {
                xs[j * m + col] = x[k * n + j][c];
            }
        }
        let mut ys = vec![0.0f32; n * m];
        faer::linalg::matmul::matmul(
            MatMut::from_row_major_slice_mut(&mut ys, n, m),
            Accum::Replace,
            MatRef::from_row_major_slice(&t[tc * n * n..(tc + 1) * n * n], n, n),
            MatRef::from_row_major_slice(&xs, n, m),
            1.0f32,
            Par::rayon(0),
        );
        for (col, &(k, c)) in serves.iter().enumerate() {
            for i in 0..n {
                out[k * n + i][c] = ys[i * m + col];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::{by_name, decode};

    fn sample_matrix(n: usize, channels: usize) -> DenseMatrix {
        let mut s = 12345u64;
        let data = (0..n * n * channels)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
                let u = (s >> 40) as f32 / (1u64 << 24) as f32;
                // Transport-like: many small entries over several decades.
                (u * 20.0 - 18.0).exp2() * 0.01
            })
            .collect();
        DenseMatrix { n, channels, data }
    }

    #[test]
    fn matvec_equals_decode_then_dense_matvec_for_every_dense_codec() {
        for channels in [1, 3] {
            let t = sample_matrix(37, channels);
            let x: Vec<[f32; 3]> = (0..37 * 4)
                .map(|k| [k as f32 * 0.1, 1.0, (k % 7) as f32])
                .collect();
            for name in ["dense-f32", "dense-f16"] {
                let enc = by_name(name).unwrap().encode(&t).unwrap();
                assert_eq!(enc.codec, name);
                let op = decode(&enc).unwrap();
                let dense = op.to_dense();
                let mut got = vec![[0.0; 3]; x.len()];
                op.matvec_batch(&x, &mut got).unwrap();
                for k in 0..4 {
                    for i in 0..37 {
                        for c in 0..3 {
                            let cc = c.min(channels - 1);
                            let want: f64 = (0..37)
                                .map(|j| dense.get(cc, i, j) as f64 * x[k * 37 + j][c] as f64)
                                .sum();
                            let g = got[k * 37 + i][c] as f64;
                            assert!((g - want).abs() <= 1e-5 * want.abs() + 1e-9, "{name}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn f16_keeps_three_digits_and_f32_is_exact() {
        let t = sample_matrix(20, 3);
        let exact = decode(&DenseF32.encode(&t).unwrap()).unwrap().to_dense();
        assert_eq!(exact, t);
        let half = decode(&DenseF16.encode(&t).unwrap()).unwrap().to_dense();
        for (&a, &b) in t.data.iter().zip(&half.data) {
            // Normal halves are within 2^-11 relative; smaller values lose precision gradually.
            if a >= 6.2e-5 {
                assert!((a - b).abs() <= a * 4.9e-4, "{a} -> {b}");
            } else {
                assert!((a - b).abs() <= 6e-8, "{a} -> {b}");
            }
        }
    }

    #[test]
    fn bad_batches_and_payloads_are_errors() {
        let t = sample_matrix(5, 1);
        let op = decode(&DenseF16.encode(&t).unwrap()).unwrap();
        let mut out = vec![[0.0; 3]; 7];
        assert!(op.matvec_batch(&[[0.0; 3]; 7], &mut out).is_err());
        let mut enc = DenseF16.encode(&t).unwrap();
        enc.payload.pop();
        assert!(decode(&enc).is_err());
        enc.codec = "dense-f99".into();
        assert!(matches!(decode(&enc), Err(CodecError::Unknown { .. })));
        assert!(by_name("nope").is_err());
    }
}
