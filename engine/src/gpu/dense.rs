//! `dense-f32` and `dense-f16` on the GPU: the stored bytes are the buffer (both codecs are
//! little-endian, channel-major, row-major), read by `dense.wgsl`.

use bounce_core::codec::dense::DENSE_F16;
use bounce_core::matrix::{DENSE_F32, EncodedMatrix};

use bounce_core::codec::CodecError;

use super::GpuError;
use super::kernel::{ROWS, dense_source, pipeline, storage};
use super::matrix::{Bound, Pass};

pub(super) fn upload(device: &wgpu::Device, m: &EncodedMatrix) -> Result<Pass, GpuError> {
    let half = match m.codec.as_str() {
        DENSE_F32 => false,
        DENSE_F16 => true,
        other => return Err(GpuError::UnsupportedCodec(other.to_string())),
    };
    check_payload(m, half)?;
    let n = m.rows;
    let matrix = storage(device, "dense matrix", &m.payload)?;
    let constants = [("HALF", if half { 1.0 } else { 0.0 })];
    Ok(Pass {
        pipeline: pipeline(
            device,
            "dense_matvec",
            &dense_source(),
            "dense_matvec",
            &constants,
        )?,
        bound: vec![(3, Bound::Buffer(matrix))],
        groups: n.div_ceil(ROWS),
    })
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
