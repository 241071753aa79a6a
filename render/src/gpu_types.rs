//! The Rust mirrors of `shade.wgsl`'s own shared structs (a naga test checks the layouts agree).
//! The light is the engine's: `bounce_engine::gpu::GpuLight`, with its WGSL prepended to the
//! shader (`renderer::shade_source`).

use bytemuck::{Pod, Zeroable};

/// `Globals` in `shade.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct Globals {
    pub view_proj: [[f32; 4]; 4],
    pub eye: [f32; 3],
    pub exposure: f32,
    pub volume_origin: [f32; 3],
    pub voxel_size: f32,
    pub volume_dims: [f32; 3],
    pub light_count: u32,
    pub indirect: u32,
    pub normal_offset: f32,
    /// [`FLAG_LINEAR`] | [`FLAG_NO_EMISSION`].
    pub flags: u32,
    pub pad1: u32,
}

/// `Globals::flags`: write linear radiance (no exposure, no tonemap), for a float target.
pub const FLAG_LINEAR: u32 = 1;
/// `Globals::flags`: leave emission out (indirect light only).
pub const FLAG_NO_EMISSION: u32 = 2;

/// One vertex of the scene's vertex buffer (`VertexIn` in `shade.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    /// Linear RGB, multiplied by the albedo map's texel.
    pub albedo: [f32; 3],
    pub emission: [f32; 3],
    /// Albedo map coordinates.
    pub uv: [f32; 2],
    /// Albedo map layer; 0 is white.
    pub layer: u32,
    /// How the layer wraps: [`WRAP_REPEAT_U`] | [`WRAP_REPEAT_V`], clamped to the edge where a
    /// bit is clear.
    pub wrap: u32,
}

pub const WRAP_REPEAT_U: u32 = 1;
pub const WRAP_REPEAT_V: u32 = 2;

/// `Object` in `shade.wgsl`: the probe-lit sphere ([`crate::ProbeSphere`]), drawn from a unit
/// sphere's vertices as instance 1.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct Object {
    pub centre: [f32; 3],
    pub radius: f32,
    /// Linear RGB.
    pub albedo: [f32; 3],
    pub pad: u32,
    /// The ambient cube, +X, −X, +Y, −Y, +Z, −Z (rgb, w unused).
    pub cube: [[f32; 4]; 6],
}
