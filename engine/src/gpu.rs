//! wgpu compute for `E_ind = T · B0` on batches of light configurations.
//!
//! [`GpuContext`] picks an adapter and opens a device; [`GpuMatrix`] uploads one encoded matrix
//! (`dense-f32`, `dense-f16`, `bc1`, `bc1-resid`, `bc4`, `log8`) and multiplies batches against it, blocking until the
//! result is read back: one light set with the matrix-vector kernel, larger batches with the
//! tiled FP32 kernel or, for the block codecs on a device with tensor cores, the
//! cooperative-matrix kernel ([`BatchKernel`]). [`GpuDirect`] computes direct light with voxel-grid shadows and
//! [`GpuSurfaceDirect`] with shadows against the triangles of a surface-geometry bake, both twins
//! of `bounce_core::direct::direct_irradiance`; the latter also computes the near-field
//! correction (`bounce_core::nearfield`) from its per-sample values without leaving the device. Kernels live in `gpu/shaders/*.wgsl`. [`light`]
//! is the light model both direct-light kernels and bounce-render's shading are compiled with:
//! one [`GpuLight`] and one WGSL module, prepended to each shader.

pub mod bandwidth;
mod context;
mod dense;
mod direct;
mod direct_surface;
mod error;
mod kernel;
pub mod light;
mod lit;
mod logblock;
mod matrix;
mod near_field;
mod sparse;
mod tensor;

pub use context::{AdapterSummary, GpuContext, tensor_support};
pub use direct::{DIRECT_WG, DirectParams, GpuDirect, GpuPatch};
pub use direct_surface::{
    GpuSample, GpuSurfaceDirect, RAYS_PER_PIECE, SURFACE_STACK, SURFACE_WG, SurfaceParams,
};
pub use error::GpuError;
pub use kernel::{
    ALL_COLUMNS, CHUNK, CHUNKS, LIT_GROUP, Params, ROWS, Split, TILE_ROWS, TILE_SETS, variant_for,
    variant_within,
};
pub use light::GpuLight;
pub use matrix::{BatchKernel, GpuMatrix};
pub use near_field::{NEAR_WG, NearParams};

/// WGSL sources as compiled (the shared prelude plus the kernel's file), for tools and the naga
/// layout tests.
pub mod sources {
    pub use super::direct::direct_source;
    pub use super::direct_surface::direct_surface_source;
    pub use super::kernel::{
        dense_source, dense_tiled_source, logblock_source, logblock_tiled_source, sparse_source,
        tensor_source, with_chunk,
    };
    pub use super::near_field::near_field_source;

    /// The bandwidth probe's kernel.
    pub fn bandwidth_source() -> &'static str {
        include_str!("gpu/shaders/bandwidth.wgsl")
    }
}
