//! The near-field correction on the GPU (`bounce_core::nearfield`): the matrix `C` and the rows'
//! albedo resident beside a [`super::GpuSurfaceDirect`], and the pass (`shaders/near_field.wgsl`)
//! that turns the direct light's per-sample values and means, still on the device, into
//! `ΔE = C · ρ ⊙ (E_q − Ē_j)` per light set and row, the twin of `NearField::correction`.
//! [`super::GpuSurfaceDirect::with_near_field`] attaches it and
//! [`super::GpuSurfaceDirect::irradiance_near`] runs it.
//!
//! Measured on lavapipe (software Vulkan, 2 cores) on the 2,752-row pillar room with 27,377
//! entries and 16 samples a row (`near_field_timing` in `engine/tests/it/gpu_near_field.rs`):
//! the correction adds about 1 ms to 20 ms of direct light at one light set and about 45 ms to
//! 140 ms at eight (the per-sample writes and one more pass); lavapipe only, as for the direct
//! light itself.

use bounce_core::nearfield::NearField;
use bytemuck::{Pod, Zeroable};

use super::GpuError;
use super::kernel::{pipeline, storage};

/// Threads per workgroup (mirrors `NEAR_WG` in `near_field.wgsl`).
pub const NEAR_WG: u32 = 64;

/// The uniform of the near-field pass (`NearParams` in `near_field.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct NearParams {
    /// Rows in the scene.
    pub n: u32,
    /// Light sets in this dispatch.
    pub sets: u32,
    /// Sample points per row, the matrix's and the values kept.
    pub per_row: u32,
    pub pad: u32,
}

pub fn near_field_source() -> &'static str {
    include_str!("shaders/near_field.wgsl")
}

/// `C` and the albedo on the device, with the pass that reads them.
pub(super) struct NearBuffers {
    pub(super) per_row: u32,
    pub(super) pass: wgpu::ComputePipeline,
    pub(super) row_ptr: wgpu::Buffer,
    pub(super) cols: wgpu::Buffer,
    pub(super) values: wgpu::Buffer,
    pub(super) albedo: wgpu::Buffer,
}

impl NearBuffers {
    /// Upload `near` over `rows` rows of `per_row` samples with one albedo a row. A matrix that
    /// does not fit those (by [`NearField::check`]: it comes from a file) or an albedo of another
    /// length is refused with [`GpuError::NearField`], an array over a binding with
    /// [`GpuError::TooLarge`].
    pub(super) fn upload(
        device: &wgpu::Device,
        near: &NearField,
        albedo: &[[f32; 3]],
        rows: usize,
        per_row: u32,
    ) -> Result<NearBuffers, GpuError> {
        near.check(rows, rows, per_row)
            .map_err(GpuError::NearField)?;
        if albedo.len() != rows {
            return Err(GpuError::NearField(format!(
                "{} albedo values for {rows} rows",
                albedo.len()
            )));
        }
        Ok(NearBuffers {
            per_row,
            pass: pipeline(device, "near_field", near_field_source(), "near_field", &[])?,
            row_ptr: storage(
                device,
                "near-field row offsets",
                bytemuck::cast_slice(&near.row_ptr),
            )?,
            cols: storage(
                device,
                "near-field columns",
                bytemuck::cast_slice(&near.cols),
            )?,
            values: storage(
                device,
                "near-field values",
                bytemuck::cast_slice(&near.values),
            )?,
            albedo: storage(device, "near-field albedo", bytemuck::cast_slice(albedo))?,
        })
    }
}
