//! `dense-f32` and `dense-f16` on the GPU: the stored bytes (little-endian, channel-major,
//! row-major) go up as row bands, each as large as one storage binding allows and read by its
//! own pass of `dense.wgsl`; a matrix that fits one binding is one band of the stored bytes.

use bounce_core::codec::dense::DENSE_F16;
use bounce_core::matrix::{DENSE_F32, EncodedMatrix};

use bounce_core::codec::CodecError;

use super::GpuError;
use super::kernel::{Body, Split, matvec_variants, storage};
use super::matrix::{Bound, Pass};

pub(super) fn upload(
    device: &wgpu::Device,
    m: &EncodedMatrix,
    split: Split,
) -> Result<Vec<Pass>, GpuError> {
    let half = match m.codec.as_str() {
        DENSE_F32 => false,
        DENSE_F16 => true,
        other => return Err(GpuError::UnsupportedCodec(other.to_string())),
    };
    check_payload(m, half)?;
    let (n, channels) = (m.rows as usize, m.channels as usize);
    let width = if half { 2 } else { 4 };
    // A band's bytes are `rows · n · channels · width` (f16 halves are indexed across the
    // band's channel planes, so an odd plane needs no alignment).
    let row_bytes = (n * channels * width) as u64;
    let band = (split.binding_bytes / row_bytes.max(1)).min(n as u64) as usize;
    if band == 0 && n > 0 {
        return Err(GpuError::TooLarge {
            what: "one dense matrix row",
            needed: row_bytes,
            limit: split.binding_bytes,
        });
    }
    let constants = [("HALF", if half { 1.0 } else { 0.0 })];
    let variants = matvec_variants(device, "dense_matvec", Body::Dense, &constants)?;
    let plane = n * n * width;
    let mut passes = Vec::new();
    let mut row0 = 0;
    while row0 < n {
        let rows = band.min(n - row0);
        let matrix = if rows == n {
            storage(device, "dense matrix", &m.payload)?
        } else {
            let (from, len) = (row0 * n * width, rows * n * width);
            let bytes: Vec<u8> = (0..channels)
                .flat_map(|c| &m.payload[c * plane + from..c * plane + from + len])
                .copied()
                .collect();
            storage(device, "dense matrix band", &bytes)?
        };
        passes.push(Pass {
            variants: variants.clone(),
            bound: vec![(3, Bound::Buffer(matrix))],
            row0: row0 as u32,
            rows: rows as u32,
            tile: 0,
            nnz: 0,
            tensor: None,
        });
        row0 += rows;
    }
    Ok(passes)
}

/// The checks the CPU decoders make (length, finite entries), without decoding a copy.
fn check_payload(m: &EncodedMatrix, half: bool) -> Result<(), GpuError> {
    let width = if half { 2 } else { 4 };
    let expected = (m.rows as usize)
        .checked_mul(m.cols as usize)
        .and_then(|v| v.checked_mul(m.channels as usize))
        .and_then(|v| v.checked_mul(width));
    let finite = if half {
        // All-ones exponent: infinity or NaN.
        m.payload
            .chunks_exact(2)
            .all(|b| u16::from_le_bytes([b[0], b[1]]) & 0x7c00 != 0x7c00)
    } else {
        m.payload
            .chunks_exact(4)
            .all(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]).is_finite())
    };
    if expected != Some(m.payload.len()) || !finite {
        return Err(CodecError::Corrupt {
            codec: m.codec.clone(),
            reason: format!(
                "payload of {} bytes is not {}x{}x{} finite entries",
                m.payload.len(),
                m.rows,
                m.cols,
                m.channels
            ),
        }
        .into());
    }
    Ok(())
}
