//! `bc1` / `bc4` on the GPU: the blocks go up untouched as a BC texture (one layer for BC1, one
//! per channel for BC4) so the texture unit decodes them; `logblock.wgsl` dequantises, gathers
//! the light by the column order and scatters the result by the row order, and the sparse part
//! follows as its own pass. An image wider than the device's texture side goes up in square
//! tiles, each its own array layer (or layers), all read by the one block pass.

use bounce_core::codec::MatrixOp;
use bounce_core::codec::logblock::{self, Blocks, LogBlockOp};
use bounce_core::matrix::EncodedMatrix;

use super::kernel::{Body, Split, matvec_variants, storage, u32_bytes};
use super::matrix::{Bound, Pass};
use super::tensor::TensorKernel;
use super::{GpuContext, GpuError, sparse};

/// What goes up for a block codec: the block pass, the sparse passes if any, the per-channel
/// maxima for [`super::Params`], and the image's column order (storage column `l` multiplies
/// patch `col_order[l]`), by which the host finds the lit column groups.
pub(super) struct Uploaded {
    pub block: Pass,
    pub sparse: Vec<Pass>,
    pub max: [f32; 4],
    pub col_order: Vec<u32>,
}

pub(super) fn upload(
    ctx: &GpuContext,
    m: &EncodedMatrix,
    split: Split,
) -> Result<Uploaded, GpuError> {
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
    let (texture, tile) = texture(device, queue, &op, split)?;
    let row_perm = storage(device, "row order", u32_bytes(op.row_perm()))?;
    let col_perm = storage(device, "column order", u32_bytes(op.col_perm()))?;
    let bc4 = if blocks == Blocks::Bc1 { 0.0 } else { 1.0 };
    // A driver that rejects the experimental kernel leaves the FP32 one in charge, and says why.
    let tensor = ctx.adapter().tensor_cores.then(|| {
        TensorKernel::new(
            device,
            bc4,
            texture.clone(),
            row_perm.clone(),
            col_perm.clone(),
        )
        .map_err(|e| e.to_string())
    });
    let pass = Pass {
        variants: matvec_variants(device, "logblock_matvec", Body::Blocks, &[("BC4", bc4)])?,
        bound: vec![
            (3, Bound::Texture(texture)),
            (4, Bound::Buffer(row_perm)),
            (5, Bound::Buffer(col_perm)),
        ],
        row0: 0,
        rows: op.row_perm().len() as u32,
        tile,
        nnz: 0,
        tensor,
    };
    // The table's top entry is the channel maximum itself (code 255 = max · e^0).
    let mut max = [0.0f32; 4];
    for (c, lut) in op.lut().iter().enumerate().take(3) {
        max[c] = lut[255];
    }
    Ok(Uploaded {
        block: pass,
        sparse: sparse::upload(device, op.sparse(), split)?,
        max,
        col_order: op.col_perm().to_vec(),
    })
}

/// The block image as a texture array: one tile when it fits the texture side, else square
/// tiles of side `tile` (a multiple of 4, so tiles cut between blocks), row-major, `L` layers
/// each (1 for BC1, one per channel otherwise). Returns the view and the tile side.
fn texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    op: &LogBlockOp,
    split: Split,
) -> Result<(wgpu::TextureView, u32), GpuError> {
    let width = op.width() as u32;
    let side_limit = split.texture_side / 4 * 4;
    if side_limit == 0 {
        return Err(GpuError::TooLarge {
            what: "block image side",
            needed: width.into(),
            limit: split.texture_side.into(),
        });
    }
    // As few tiles across as the side allows, then as small a tile as that count allows, so
    // the last row and column of tiles waste little.
    let across = width.div_ceil(side_limit).max(1);
    let tile = width.div_ceil(across).div_ceil(4) * 4;
    let (format, per_tile) = match op.blocks() {
        Blocks::Bc1 => (wgpu::TextureFormat::Bc1RgbaUnorm, 1),
        Blocks::Bc4 => (wgpu::TextureFormat::Bc4RUnorm, op.channels() as u32),
        // Raw codes: an 8-bit texture per channel, read like BC4's red layers.
        Blocks::Raw8 => (wgpu::TextureFormat::R8Unorm, op.channels() as u32),
    };
    let layers = u64::from(across).pow(2) * u64::from(per_tile);
    if layers > u64::from(split.texture_layers) {
        return Err(GpuError::TooLarge {
            what: "block image tiles (texture array layers)",
            needed: layers,
            limit: split.texture_layers.into(),
        });
    }
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("transport blocks"),
        size: wgpu::Extent3d {
            width: tile.max(4),
            height: tile.max(4),
            depth_or_array_layers: layers as u32,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    // (bytes per row of blocks or texels, texel rows per such row) of the whole image; a tile
    // is a rectangle of it, copied with the image's own stride.
    let (row_bytes, texel_rows, texel_bytes) = match op.blocks() {
        Blocks::Raw8 => (width as usize, 1, 1),
        Blocks::Bc1 | Blocks::Bc4 => (width as usize / 4 * 8, 4, 8),
    };
    let image_bytes = row_bytes * width as usize / texel_rows;
    let raw = op.raw_blocks();
    for ty in 0..across {
        for tx in 0..across {
            let (x0, y0) = (tx * tile, ty * tile);
            let w = tile.min(width - x0);
            let h = tile.min(width - y0);
            for c in 0..per_tile {
                // Texel (x0, y0) of channel image c: its block (or byte) and that block's row.
                let offset = c as usize * image_bytes
                    + (y0 as usize / texel_rows) * row_bytes
                    + x0 as usize / texel_rows * texel_bytes;
                queue.write_texture(
                    wgpu::TexelCopyTextureInfo {
                        texture: &texture,
                        mip_level: 0,
                        origin: wgpu::Origin3d {
                            x: 0,
                            y: 0,
                            z: (ty * across + tx) * per_tile + c,
                        },
                        aspect: wgpu::TextureAspect::All,
                    },
                    &raw[offset..],
                    wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(row_bytes as u32),
                        rows_per_image: Some(h / texel_rows as u32),
                    },
                    wgpu::Extent3d {
                        width: w,
                        height: h,
                        depth_or_array_layers: 1,
                    },
                );
            }
        }
    }
    let view = texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    });
    Ok((view, tile))
}
