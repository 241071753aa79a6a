//! The near-field correction on the GPU (`bounce_core::nearfield`): the matrix `C` and the rows'
//! albedo resident beside a [`super::GpuSurfaceDirect`], and the pass (`shaders/near_field.wgsl`)
//! that turns the direct light's per-sample values and means, still on the device, into
//! `ΔE = C · (ρ_e ⊙ E_q − ρ_j ⊙ Ē_j)` per light set and row (`ρ_e` the albedo where entry
//! `e`'s rays landed), the twin of
//! `NearField::correction_with`.
//! [`super::GpuSurfaceDirect::with_near_field`] attaches it and
//! [`super::GpuSurfaceDirect::irradiance_near`] runs it.
//!
//! Each entry's albedo goes up as f32×3 (12 bytes an entry, 17 MB for `pandora`'s 1.4 M
//! entries): the file's own (format version 12), or for an older file its sample's or its row's,
//! filled in here, so one pass serves every version.
//!
//! A file whose near field keeps its samples' sky view (format version 9) has it uploaded too
//! (9 coefficients a sample: 6.8 MB for `pandora`'s 189 k samples). A slice of light sets with a
//! sky then runs `sky_samples` before the correction: each sample's sky irradiance joins the
//! sample's punctual value, and its row's mean of them the row's, on the device, and the one
//! sparse pass corrects both (`NearField::correction_with`). Before, the sky's correction ran on the host
//! for either engine, and on an H200 took `pandora`'s direct light from 0.71 to 9.48 ms a set.
//!
//! Measured on lavapipe (software Vulkan, 2 cores) on the 2,752-row pillar room with 27,377
//! entries and 16 samples a row (`near_field_timing` in `engine/tests/it/gpu_near_field.rs`):
//! the correction adds about 1 ms to 20 ms of direct light at one light set and about 45 ms to
//! 140 ms at eight (the per-sample writes and one more pass); lavapipe only, as for the direct
//! light itself.

use bounce_core::nearfield::{NearField, Reflect};
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
    /// Samples a row's mean is taken over, its first (those spread by area): the sky's mean
    /// must be the one the punctual lights' means are.
    pub averaged: u32,
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
    /// Per entry, the albedo its landings reflect with: the entry's own (format version 12), else
    /// its sample's (11), else its sample's row's.
    pub(super) landed_albedo: wgpu::Buffer,
    /// The samples' sky view and the pass that adds a sky through it, when the file has one.
    pub(super) sky: Option<SkyBuffers>,
}

/// `NearField::sky` on the device, with `sky_samples`.
pub(super) struct SkyBuffers {
    pub(super) pass: wgpu::ComputePipeline,
    pub(super) view: wgpu::Buffer,
}

impl NearBuffers {
    /// Upload `near` over `rows` rows of `per_row` samples with one albedo a row, and its
    /// samples' sky view when it has one. A matrix that
    /// does not fit those (by [`NearField::check`]: it comes from a file) or an albedo of another
    /// length is refused with [`GpuError::NearField`], an array over a binding with
    /// [`GpuError::TooLarge`].
    pub(super) fn upload(
        device: &wgpu::Device,
        near: &NearField,
        albedo: Reflect<'_>,
        rows: usize,
        per_row: u32,
    ) -> Result<NearBuffers, GpuError> {
        near.check(rows, rows, per_row)
            .map_err(GpuError::NearField)?;
        if albedo.rows.len() != rows {
            return Err(GpuError::NearField(format!(
                "{} albedo values for {rows} rows",
                albedo.rows.len()
            )));
        }
        let samples = rows * per_row as usize;
        if let Some(a) = albedo.samples
            && a.len() != samples
        {
            return Err(GpuError::NearField(format!(
                "{} sample albedo values for {samples} sample points",
                a.len()
            )));
        }
        // One albedo an entry whatever the file keeps, so one pass serves every version. The
        // check above holds the columns inside the samples.
        let landed_albedo: Vec<[f32; 3]> = match &near.albedo {
            Some(a) => a.clone(),
            None => near
                .cols
                .iter()
                .map(|&q| match albedo.samples {
                    Some(a) => a[q as usize],
                    None => albedo.rows[q as usize / per_row as usize],
                })
                .collect(),
        };
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
            albedo: storage(
                device,
                "near-field albedo",
                bytemuck::cast_slice(albedo.rows),
            )?,
            landed_albedo: storage(
                device,
                "near-field landings' albedo",
                bytemuck::cast_slice(&landed_albedo),
            )?,
            sky: match &near.sky {
                Some(view) => Some(SkyBuffers {
                    pass: pipeline(
                        device,
                        "near_field sky_samples",
                        near_field_source(),
                        "sky_samples",
                        &[],
                    )?,
                    view: storage(
                        device,
                        "samples' sky view",
                        bytemuck::cast_slice(&view.rows),
                    )?,
                }),
                None => None,
            },
        })
    }
}
