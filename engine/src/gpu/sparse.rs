//! The exactly kept entries of `bc1` / `bc4` (a CSR [`SparsePart`] in matrix order), added by
//! `sparse.wgsl` onto the block product in a second dispatch of the same compute pass.

use bounce_core::codec::transform::SparsePart;

use super::GpuError;
use super::kernel::{pipeline, sparse_source, storage, u32_bytes};
use super::matrix::{Bound, Pass};

/// The pass, or `None` when nothing was kept.
pub(super) fn upload(device: &wgpu::Device, sp: &SparsePart) -> Result<Option<Pass>, GpuError> {
    if sp.nnz() == 0 {
        return Ok(None);
    }
    let row_ptr = storage(device, "sparse row pointers", u32_bytes(&sp.row_ptr))?;
    let col_idx = storage(device, "sparse columns", u32_bytes(&sp.col_idx))?;
    let values = storage(device, "sparse values", bytemuck::cast_slice(&sp.values))?;
    Ok(Some(Pass {
        pipeline: pipeline(device, "sparse_add", &sparse_source(), "sparse_add", &[])?,
        bound: vec![
            (3, Bound::Buffer(row_ptr)),
            (4, Bound::Buffer(col_idx)),
            (5, Bound::Buffer(values)),
        ],
        groups: sp.n as u32,
        row0: 0,
        rows: sp.n as u32,
        tile: 0,
    }))
}
