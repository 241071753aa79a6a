//! `bc1` / `bc4` on the GPU: the blocks go up untouched as a BC texture (one layer for BC1, one
//! per channel for BC4) so the texture unit decodes them; `logblock.wgsl` dequantises, gathers
//! the light by the column order and scatters the result by the row order, and the sparse part
//! follows as its own pass.

use bounce_core::codec::MatrixOp;
use bounce_core::codec::logblock::{self, Blocks, LogBlockOp};
use bounce_core::matrix::EncodedMatrix;

use super::kernel::{ROWS, logblock_source, pipeline, storage, u32_bytes};
use super::matrix::{Bound, Pass};
use super::{GpuContext, GpuError, sparse};

/// The block pass, the sparse pass if any, and the per-channel maxima and sparse count for
/// [`super::Params`].
pub(super) fn upload(
    ctx: &GpuContext,
    m: &EncodedMatrix,
) -> Result<(Pass, Option<Pass>, [f32; 4], u32), GpuError> {
    let (device, queue) = (&ctx.device, &ctx.queue);
    let blocks = match m.codec.as_str() {
        "bc1" | "bc1-resid" => Blocks::Bc1,
        "bc4" => Blocks::Bc4,
        "log8" => Blocks::Raw8,
        other => return Err(GpuError::UnsupportedCodec(other.to_string())),
    };
    if blocks != Blocks::Raw8
        && !device
            .features()
            .contains(wgpu::Features::TEXTURE_COMPRESSION_BC)
    {
        return Err(GpuError::MissingFeature {
            adapter: ctx.adapter().name.clone(),
            feature: "TEXTURE_COMPRESSION_BC",
            codec: m.codec.clone(),
        });
    }
    m.validate_shape()
        .map_err(bounce_core::codec::CodecError::from)?;
    let op = logblock::decode(m, blocks)?;
    let texture = texture(device, queue, &op)?;
    let row_perm = storage(device, "row order", u32_bytes(op.row_perm()))?;
    let col_perm = storage(device, "column order", u32_bytes(op.col_perm()))?;
    let bc4 = if blocks == Blocks::Bc1 { 0.0 } else { 1.0 };
    let pass = Pass {
        pipeline: pipeline(
            device,
            "logblock_matvec",
            &logblock_source(),
            "logblock_matvec",
            &[("BC4", bc4)],
        )?,
        bound: vec![
            (3, Bound::Texture(texture)),
            (4, Bound::Buffer(row_perm)),
            (5, Bound::Buffer(col_perm)),
        ],
        groups: (op.row_perm().len() as u32).div_ceil(ROWS),
    };
    // The table's top entry is the channel maximum itself (code 255 = max · e^0).
    let mut max = [0.0f32; 4];
    for (c, lut) in op.lut().iter().enumerate().take(3) {
        max[c] = lut[255];
    }
    let nnz = op.sparse().nnz() as u32;
    Ok((pass, sparse::upload(device, op.sparse())?, max, nnz))
}

fn texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    op: &LogBlockOp,
) -> Result<wgpu::TextureView, GpuError> {
    let width = op.width() as u32;
    let limit = device.limits().max_texture_dimension_2d;
    if width > limit {
        return Err(GpuError::TooLarge {
            what: "block image side",
            needed: width.into(),
            limit: limit.into(),
        });
    }
    let (format, layers) = match op.blocks() {
        Blocks::Bc1 => (wgpu::TextureFormat::Bc1RgbaUnorm, 1),
        Blocks::Bc4 => (wgpu::TextureFormat::Bc4RUnorm, op.channels() as u32),
        // Raw codes: an 8-bit texture per channel, read like BC4's red layers.
        Blocks::Raw8 => (wgpu::TextureFormat::R8Unorm, op.channels() as u32),
    };
    let size = wgpu::Extent3d {
        width,
        height: width,
        depth_or_array_layers: layers,
    };
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("transport blocks"),
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    // (bytes per row, rows per image) of the upload: 4 × 4 texel blocks of 8 bytes, or bytes.
    let (row_bytes, rows) = match op.blocks() {
        Blocks::Raw8 => (width, width),
        Blocks::Bc1 | Blocks::Bc4 => (width / 4 * 8, width / 4),
    };
    queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture: &texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        op.raw_blocks(),
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(row_bytes),
            rows_per_image: Some(rows),
        },
        size,
    );
    Ok(texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    }))
}
