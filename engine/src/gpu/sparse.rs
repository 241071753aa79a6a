//! The exactly kept entries of `bc1` / `bc4` (a CSR [`SparsePart`] in matrix order), added by
//! `sparse.wgsl` onto the block product in further dispatches of the same compute pass: one per
//! row band, each band's entries no larger than one storage binding.

use bounce_core::codec::transform::SparsePart;

use super::GpuError;
use super::kernel::{Split, sparse_variants, storage, u32_bytes};
use super::matrix::{Bound, Pass};

/// The passes, one per row band; none when nothing was kept.
pub(super) fn upload(
    device: &wgpu::Device,
    sp: &SparsePart,
    split: Split,
) -> Result<Vec<Pass>, GpuError> {
    let nnz = sp.nnz();
    if nnz == 0 {
        return Ok(Vec::new());
    }
    let channels = sp.channels;
    let limit = split.binding_bytes as usize;
    // The largest of a band's bindings: its values (4 bytes an entry a channel).
    let bytes = |entries: usize| entries * 4 * channels;
    let variants = sparse_variants(device)?;
    let mut passes = Vec::new();
    let mut row0 = 0;
    while row0 < sp.n {
        let start = sp.row_ptr[row0] as usize;
        let mut end_row = row0 + 1;
        while end_row < sp.n
            && bytes(sp.row_ptr[end_row + 1] as usize - start) <= limit
            && 4 * (end_row + 2 - row0) <= limit
        {
            end_row += 1;
        }
        let (end, rows) = (sp.row_ptr[end_row] as usize, end_row - row0);
        if bytes(end - start) > limit || 4 * (rows + 1) > limit {
            return Err(GpuError::TooLarge {
                what: "one row of the sparse part",
                needed: bytes(end - start) as u64,
                limit: split.binding_bytes,
            });
        }
        let row_ptr: Vec<u32> = sp.row_ptr[row0..=end_row]
            .iter()
            .map(|&p| p - start as u32)
            .collect();
        let values: Vec<f32> = (0..channels)
            .flat_map(|c| &sp.values[c * nnz + start..c * nnz + end])
            .copied()
            .collect();
        passes.push(Pass {
            variants: variants.clone(),
            bound: vec![
                (
                    3,
                    Bound::Buffer(storage(device, "sparse row pointers", u32_bytes(&row_ptr))?),
                ),
                (
                    4,
                    Bound::Buffer(storage(
                        device,
                        "sparse columns",
                        u32_bytes(&sp.col_idx[start..end]),
                    )?),
                ),
                (
                    5,
                    Bound::Buffer(storage(
                        device,
                        "sparse values",
                        bytemuck::cast_slice(&values),
                    )?),
                ),
            ],
            row0: row0 as u32,
            rows: rows as u32,
            tile: 0,
            nnz: (end - start) as u32,
            tensor: None,
        });
        row0 = end_row;
    }
    Ok(passes)
}
